"""Recording loop: many control periods of constant force in one compiled call."""

from __future__ import annotations

from impact_env._jit import jit
from impact_env.plant.integrators import advance, dopri_run
from impact_env.plant.layout import DOPRI5, OK


@jit
def run_periods(y, mode, f2, t0, period, n, p, method, dt, rtol, scale, hstate, ev, evn,
                out_y, out_mode, out_peak, k0, peak):
    """Advance y over ``n`` periods of ``period`` s under the constant force f2 (N), writing
    the state at each period end into ``out_y[k0 + k]`` (and the mode and the peak contact
    force within the period into ``out_mode``/``out_peak``).

    Fixed-step methods step on to each period end (a whole number of steps).  dopri5 integrates
    the whole span without stopping at the period ends and records them from its continuous
    extension (:func:`impact_env.plant.integrators.dopri_run`), so its records do not depend on
    the record rate.

    ``peak`` (float64[2]): scratch for the period's peak force, and ``peak[1]`` raised to the
    largest penetration (m) at every integrator step, across calls (the caller zeroes it).

    Returns ``(status, mode, periods_done)``.
    """
    if method == DOPRI5:
        return dopri_run(y, mode, f2, t0, n * period, p, rtol, scale, hstate, ev, evn, peak, n,
                         out_y, out_mode, out_peak, k0)
    for k in range(n):
        peak[0] = 0.0
        status, mode = advance(y, mode, f2, t0 + k * period, period, p, method, dt, rtol, scale,
                               hstate, ev, evn, peak)
        for j in range(y.shape[0]):
            out_y[k0 + k, j] = y[j]
        out_mode[k0 + k] = mode
        out_peak[k0 + k] = peak[0]
        if status != OK:
            return status, mode, k + 1
    return OK, mode, n
