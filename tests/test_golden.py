"""Golden outputs: the simulator, the env and compare give today the numbers they gave when the
files were recorded (``scripts/record_golden.py``; cases in ``scripts/golden_cases.py``).  The test runs
on every machine, never skipped:

* **On the machine of the recording** (same CPU features, numpy, scipy and numba: the
  fingerprint): bitwise, ``np.array_equal`` with NaN equal to NaN.
* **Elsewhere**: the CPU-dependent inputs (BLAS/LAPACK results: the shaker's ``expm``, the pad
  damping's fit, the filters' design) differ in their last bit, and impacts amplify that, so
  bitwise equality is not defined.  Each array that is not bitwise equal may then differ by what
  the integration itself resolves: the case is run again with its integrator's tolerance
  loosened ``LOOSEN`` times (dopri5 in contact at ``integrator.rtol``; the ``split`` integrator's
  free flight is exact), and the array may differ from the recording by at most ``K`` times
  its largest change under those loosenings, plus round-off (``ROUNDOFF`` of the array's largest
  magnitude).  A change of the model or of a kernel's arithmetic beyond the method's own
  accuracy fails; the machine's last bits do not.  Several loosenings, not one: a closed loop
  whose contact detector decides a tick apart (a bang-bang law, a network) is chaotic, and one
  perturbation may happen to leave an entry alone that another moves a lot (measured between
  two x86-64 CPUs, AVX2 and AVX-512 BLAS kernels: a catch time 0.09 s here and 0.31 s there,
  0.09 to 0.40 s across the loosenings; every array within 1.0 times its largest change, the
  worst a detector bit or a saturated command flipped on a tick, a full-range change either
  way), so K = 3.  An entry finite on one side and not on the other (a catch time ``inf``: not
  caught within the horizon, against one near its end) is allowed only in an array that a
  loosening changes too.  The fixed-step cases (``ideal``: an elastic pad, no shaker, no BLAS
  input) have nothing to loosen: they are bitwise everywhere.
* A policy network that computes in float32 (an SB3 model through torch) is a CPU-dependent
  input too: its command may come out a float32 ulp apart on another instruction set, before
  any contact (where no loosening moves it).  Its arrays are allowed ``F32_ROUNDOFF`` of their
  largest magnitude as round-off instead of ``ROUNDOFF``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from golden_cases import CASES, fingerprint, float32_policy_array, run_case

GOLDEN = Path(__file__).resolve().parent / "golden"
LOOSEN = (10.0, 100.0, 1000.0)  # the integrator's tolerance, loosened: the changes measure what it resolves
K = 3.0  # the recording may differ from this machine by K times the largest change
ROUNDOFF = 1024 * np.finfo(float).eps  # of an array's largest magnitude: a few hundred ulps
# a float32 network's arrays: 16 float32 ulps (1.9e-6) of the largest magnitude; measured 1 ulp
# (a command 1.19e-5 N apart on 167 N); 16 leaves room for a reordered sum over a 64-wide layer
F32_ROUNDOFF = 16 * float(np.finfo(np.float32).eps)


@pytest.fixture(scope="module")
def same_machine() -> bool:
    return json.loads((GOLDEN / "fingerprint.json").read_text()) == fingerprint()


def _differ(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Where a and b are not the same value (NaN equal to NaN)."""
    return ~((a == b) | (np.isnan(a) & np.isnan(b)))


def _within_what_the_method_resolves(want: np.ndarray, got: np.ndarray, looser: list,
                                     roundoff: float = ROUNDOFF) -> str | None:
    """None if ``got`` is within K times its largest change under the loosenings (``looser``)
    of ``want``; else what is wrong."""
    want, got = np.asarray(want, dtype=np.float64), np.asarray(got, dtype=np.float64)
    looser = [np.asarray(x, dtype=np.float64) for x in looser]
    if np.any(np.isfinite(want) != np.isfinite(got)) and not any(np.any(_differ(x, got)) for x in looser):
        return "finite on one side only, where no loosening changes anything"
    both = np.isfinite(want) & np.isfinite(got)
    if np.any(~both & _differ(want, got) & (np.isfinite(want) == np.isfinite(got))):
        return "a non-finite entry differs"
    if not np.any(both):
        return None
    scale = max(float(np.max(np.abs(want[both]))), float(np.max(np.abs(got[both]))))
    resolved = max(float(np.max(np.abs(x[both & np.isfinite(x)] - got[both & np.isfinite(x)]), initial=0.0))
                   for x in looser)
    gap = float(np.max(np.abs(want[both] - got[both])))
    bound = K * resolved + roundoff * scale
    if gap <= bound:
        return None
    return f"differs by {gap:.3g}, more than {bound:.3g} (K x {resolved:.3g} + round-off)"


@pytest.mark.parametrize("name", list(CASES))
def test_golden_outputs(name, same_machine):
    want = np.load(GOLDEN / f"{name}.npz")
    got = run_case(name)
    assert sorted(got) == sorted(want.files), f"{name}: arrays added or missing"
    assert all(got[k].shape == want[k].shape for k in want.files), f"{name}: an array changed shape"
    unequal = [k for k in want.files if not np.array_equal(got[k], want[k], equal_nan=True)]
    if same_machine:
        assert not unequal, f"{name}: arrays differ bitwise from the golden recording: {unequal[:8]}"
        return
    if not unequal:
        return
    looser = [run_case(name, f) for f in LOOSEN]
    bad = {k: why for k in unequal
           if (why := _within_what_the_method_resolves(
               want[k], got[k], [x[k] for x in looser],
               F32_ROUNDOFF if float32_policy_array(name, k) else ROUNDOFF))}
    assert not bad, f"{name} (recorded on another machine): {dict(list(bad.items())[:6])}"
