"""Error budgets for comparing a simulation with a reference: tolerances derived from the
methods, not copied from one machine's figure.

A simulated value differs from a reference value by at most the sum of

* the simulation's own error, estimated from a second run at a finer setting
  (:func:`richardson`: a method of order p at steps h and h/2, the error of the h run is
  ``|y_h - y_h/2| 2^p / (2^p - 1)``; for dopri5, whose global error is proportional to rtol,
  the run at rtol/100 plays the part of the finer one: ``|y - y_fine| 100 / 99``);
* the reference's own error (:func:`reference_error`): ``solve_ivp`` keeps each step's local
  error within its rtol relative to the components' scales, and the errors of its n steps add
  at most linearly, so ``n rtol`` bounds the global error, with n = nfev / 12 (DOP853's
  evaluations per step, rejected steps included, so n is an upper bound);
* rounding (:func:`rounding`): a few roundings of eps per step, adding at most linearly.

Tests assert ``error <= SAFETY * estimate + reference_error + rounding``; the estimate is an
asymptotic one, hence the factor SAFETY = 4 (the estimate is off by less than a factor of two
when the finer run's error is at most half the coarser's, which holds in the asymptotic regime
of an order >= 1 method).  Everything is relative to the scales the caller divides by.
"""

from __future__ import annotations

import numpy as np

EPS = float(np.finfo(float).eps)
SAFETY = 4.0
ROUNDINGS_PER_STEP = 16  # an RK stage is a handful of operations per component


def richardson(coarse, fine, order: float) -> np.ndarray:
    """Estimated error of ``coarse`` from a run ``fine`` at half the step (method of
    ``order``); for dopri5 pass the runs at rtol and rtol/100 and ``order=None``."""
    diff = np.abs(np.asarray(coarse, dtype=float) - np.asarray(fine, dtype=float))
    if order is None:  # tolerance proportionality: fine's error is 1/100 of coarse's
        return diff * 100.0 / 99.0
    return diff * 2.0**order / (2.0**order - 1.0)


def reference_error(ref, rtol: float = 1e-12) -> float:
    """Bound on the global error of a :func:`reference.reference_drop` run relative to its
    scales: (its steps) x rtol."""
    return max(ref.n_rhs / 12.0, 1.0) * rtol


def rounding(n_steps: float) -> float:
    """Bound on the accumulated rounding of ``n_steps`` steps, relative to the scales."""
    return ROUNDINGS_PER_STEP * max(n_steps, 1.0) * EPS


def bound(estimate, ref, n_steps: float, rtol_ref: float = 1e-12):
    """The tolerance: SAFETY x estimate + the reference's error + rounding."""
    ref_err = 0.0 if ref is None else reference_error(ref, rtol_ref)
    return SAFETY * np.asarray(estimate) + ref_err + rounding(n_steps)
