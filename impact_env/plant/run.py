"""Recording loop: many control periods of constant force in one compiled call."""

from __future__ import annotations

from impact_env._jit import jit
from impact_env.plant.integrators import advance, dopri_run
from impact_env.plant.layout import DOPRI5, OK


@jit
def run_periods(mode, f2, t0, period, consts, carry, rec):
    """Advance ``carry.y`` over ``rec.n`` periods of ``period`` s under the constant force f2 (N),
    writing the state at each period end into ``rec.y[rec.k0 + k]`` (and the mode and the peak
    contact force within the period into ``rec.mode``/``rec.peak``).  ``consts``: PlantConsts,
    ``carry``: PlantCarry, ``rec``: Records (:mod:`impact_env.plant.integrators`).

    Fixed-step methods step on to each period end (a whole number of steps).  dopri5 integrates
    the whole span without stopping at the period ends and records them from its continuous
    extension (:func:`impact_env.plant.integrators.dopri_run`), so its records do not depend on
    the record rate.

    ``carry.peak`` (float64[2]): scratch for the period's peak force, and ``peak[1]`` raised to the
    largest penetration (m) at every integrator step, across calls (the caller zeroes it).

    Returns ``(status, mode, periods_done)``.
    """
    n = rec.n
    if consts.method == DOPRI5:
        return dopri_run(mode, f2, t0, n * period, consts, carry, rec)
    y, peak, k0 = carry.y, carry.peak, rec.k0
    for k in range(n):
        peak[0] = 0.0
        status, mode = advance(mode, f2, t0 + k * period, period, consts, carry)
        for j in range(y.shape[0]):
            rec.y[k0 + k, j] = y[j]
        rec.mode[k0 + k] = mode
        rec.peak[k0 + k] = peak[0]
        if status != OK:
            return status, mode, k + 1
    return OK, mode, n
