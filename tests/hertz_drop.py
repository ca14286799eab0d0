"""One free two-body collision simulated by the package (:func:`hertz_drop`), for the tests that
check it against the closed-form Hertz results of :mod:`impact_env.plant.hertz`."""

from __future__ import annotations

import math

from impact_env.plant.reference import sim_overrides


def hertz_drop(m1, m2, c, v, method, restitution=1.0, rtol=1e-11, steps_per_contact=2000):
    """Simulate one free two-body collision (gravity 0) at relative speed v (m/s) with
    ``impact_env.simulate``; return ``(trajectory, effective mass, Hertz contact time, dt)``.

    The step (also the record and control period) is the power of ten at or below
    ``t_c / steps_per_contact`` (at least 1e-8 s, the fastest control rate), so the grids stay
    whole multiples of it; the touch falls mid-step, 5 % of t_c after the start.
    """
    import impact_env
    from impact_env.plant import hertz

    m = m1 * m2 / (m1 + m2)
    tc = hertz.contact_time(m, c, v)
    dt = max(10.0 ** math.floor(math.log10(tc / steps_per_contact)), 1e-8)
    pre = round(0.05 * tc / dt) * dt + 0.5 * dt
    n = math.ceil((pre + 1.1 * tc) / dt)
    ov = sim_overrides(method, dt=dt, rtol=rtol, control_rate=1.0 / dt, plant_m1=m1, plant_m2=m2,
                       plant_c=c, plant_gravity=0.0, plant_restitution=restitution,
                       initial_impact_speed=v, initial_pre_contact_time=pre)
    tr = impact_env.simulate("ideal", t_end=n * dt, record_rate=1.0 / dt, overrides=ov)
    return tr, m, tc, dt
