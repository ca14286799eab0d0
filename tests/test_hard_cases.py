"""Hard cases for the plant: stiff and soft pads, light and heavy bodies, tiny and tall drops,
grazing contact, a body resting for 10 s, 100 kN shaker forces, and steps beyond stability.

Every case either ends finite and matches a reference (closed-form Hertz, a static
equilibrium, or ``reference.reference_drop``: solve_ivp DOP853 at rtol 1e-12 with event
restarts) to the tolerance stated next to it, or, with a fixed step beyond the stability
limit, raises ValueError before simulating or SimulationDiverged while simulating; a NaN
never comes back.
"""

from __future__ import annotations

import math

import budget
import numpy as np
import pytest
from hertz_drop import hertz_drop
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import impact_env
from impact_env import SimulationDiverged
from impact_env.hardware.arrays import initial_state, plant_params
from impact_env.hardware.stability import STABILITY_LIMIT
from impact_env.plant import hertz
from impact_env.plant.reference import Params, reference_drop, sim_overrides

G = 9.81


def rel(a: float, b: float) -> float:
    return abs(a - b) / abs(b)


def finite(tr) -> bool:
    return all(np.isfinite(getattr(tr, k)).all() for k in ("x1", "v1", "x2", "v2", "work_shaker",
                                                          "dissipated", "contact_force", "events"))


def check_hertz(tr, m, c, v, tc, tol_time=1e-8, tol_force=1e-6):
    """Closed-form Hertz at gravity 0.  Contact time, restitution and d_max are at rounding
    level for both methods at t_c/dt >= 2000 (measured <= 2e-11); the peak force is sampled at
    step ends, which misses the top by up to ~(pi dt / 2 t_c)^2 / 2 (measured <= 1e-7)."""
    assert finite(tr)
    mt = tr.metrics()
    assert mt["n_contacts"] == 1
    assert rel(mt["first_contact_duration_s"], tc) < tol_time
    assert abs(mt["restitution"] - 1.0) < tol_time
    assert rel(mt["max_penetration_m"], hertz.max_penetration(m, c, v)) < tol_time
    assert rel(mt["peak_contact_force_N"], hertz.peak_force(m, c, v)) < tol_force


# --------------------------------------------------------------------------------------------
# stiff and soft pads, light and heavy bodies (gravity 0: closed form)
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["rk4", "dopri5", "split"])
@pytest.mark.parametrize("c", [1e4, 1e6, 1e8, 1e10, 1e11])
def test_stiff_and_soft_pads(c, method):
    """c from 1e4 to 1e11 N/m^1.5 (contact 31 ms to 49 us); rk4's step scales with t_c."""
    tr, m, tc, _dt = hertz_drop(0.1, 1.0, c, 1.0, method, rtol=1e-10)
    check_hertz(tr, m, c, 1.0, tc)


@pytest.mark.parametrize("method", ["rk4", "dopri5", "split"])
@pytest.mark.parametrize("m1,m2", [(1e-3, 1e-3), (1e-3, 10.0), (10.0, 1e-3), (10.0, 10.0),
                                   (10.0, 1e6)])
def test_light_and_heavy_bodies(m1, m2, method):
    """1 g to 10 kg (and a 1000 t anvil): mass ratios 1e-4 to 1e8."""
    tr, m, tc, _dt = hertz_drop(m1, m2, 2e6, 1.0, method, rtol=1e-10)
    check_hertz(tr, m, 2e6, 1.0, tc)


def test_fixed_step_not_scaled_to_a_stiff_contact():
    """RK4 at the default 1 us on c = 1e11 (t_c = 49 us, 49 steps a contact): stable (omega dt
    = 0.08) and still accurate to a few 1e-6 (measured: contact time 9e-7, restitution 1.5e-6,
    d_max 2.7e-6 from a parabola through the 1 us records, peak force 7e-4 from sampling the
    top at 1 us)."""
    ov = sim_overrides("rk4", plant_c=1e11, plant_gravity=0.0, initial_impact_speed=1.0,
                       initial_pre_contact_time=1e-5)
    tr = impact_env.simulate("ideal", t_end=1e-4, overrides=ov)
    m = 1 / 11
    check_hertz(tr, m, 1e11, 1.0, hertz.contact_time(m, 1e11, 1.0), tol_time=1e-5, tol_force=3e-3)


# --------------------------------------------------------------------------------------------
# drops from 0.1 mm to 2 m (gravity on: solve_ivp reference)
# --------------------------------------------------------------------------------------------

def finer(scene, method):
    """The same scene at half the step (rk4) or rtol / 100 (dopri5): the run that estimates
    the error of ``scene``'s (tests/budget.py)."""
    if method == "rk4":
        return scene.with_overrides({"integrator.dt": scene.integrator.dt / 2})
    return scene.with_overrides({"integrator.rtol": scene.integrator.rtol / 100})


def order(method):
    return 4 if method == "rk4" else None


@pytest.mark.parametrize("method", ["rk4", "dopri5", "split"])
@pytest.mark.parametrize("height", [1e-4, 1e-2, 2.0])
def test_drop_heights(height, method):
    """First contact of a drop from 0.1 mm (gravity is 40 % of the peak pad force) to 2 m
    (6.3 m/s) against solve_ivp: restitution, contact time, d_max and the state 0.5 t_c after
    the separation (relative to d_max and v), each within the error budget of tests/budget.py
    (4x the error estimated from a finer run, plus the reference's error and rounding).  The
    peak force is the largest at a 1 us step end or record: it misses the top of a contact of
    t_c >= 2.5 ms by at most (pi dt / (2 t_c))^2 / 2 = 2e-7 relative; bound 3e-6."""
    v = math.sqrt(2 * G * height)
    m = 1.0 / 11.0
    tc = hertz.contact_time(m, 2e6, v)
    ov = sim_overrides(method, rtol=1e-10, initial_drop_height=height)
    scene = impact_env.load_scene("ideal", ov)
    y0, t_touch = initial_state(scene)
    t_end = round((t_touch + 1.5 * tc) * 1e6) * 1e-6
    ref = reference_drop(Params.from_array(plant_params(scene)), y0, t_end)
    tr = impact_env.simulate(scene, t_end=t_end, record_rate=1e6)
    fine = impact_env.simulate(finer(scene, method), t_end=t_end, record_rate=1e6)
    assert finite(tr)
    assert tr.events[:, 1].tolist() == ref.events[:, 1].tolist() == [1.0, -1.0]
    n = t_end / 1e-6
    dmax = hertz.max_penetration(m, 2e6, v)

    def check(got, got_fine, want, scale):
        est = budget.richardson(got / scale, got_fine / scale, order(method))
        assert np.all(np.abs(got - want) / scale <= budget.bound(est, ref, n)), (got, want)

    check(tr.restitution(), fine.restitution(), ref.restitution(), 1.0)
    check(tr.first_contact_duration(), fine.first_contact_duration(), ref.first_contact_duration(), tc)
    check(tr.max_penetration(), fine.max_penetration(), ref.max_penetration, dmax)
    assert rel(tr.metrics()["peak_contact_force_N"], ref.peak_force) < 3e-6
    last = lambda t: np.array([t.x1[-1], t.v1[-1], t.x2[-1], t.v2[-1]])  # noqa: E731
    check(last(tr), last(fine), ref.y_end[:4], np.array([dmax, v, dmax, v]))


# --------------------------------------------------------------------------------------------
# grazing contact
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["rk4", "dopri5", "split"])
@pytest.mark.parametrize("v", [1e-6, 1e-4])
def test_grazing_impact_closed_form(v, method):
    """Impact at 1 um/s (d_max = 22 nm, a 65 ms contact): Hertz's closed form (exact), within
    the error budget of tests/budget.py (4x the error estimated from a run at half the step or
    rtol/100, plus rounding).  dopri5's steps over such a long contact are long (its records
    no longer cap them), and each carries up to rtol of the state: the end of the contact,
    where d crosses 0 at 1 um/s, turns a position error into a time error of dd / v, which the
    budget sees.  The peak force, sampled at the 10 us records, misses the top by at most
    (pi 10 us / (2 t_c))^2 / 2 = 3e-8 relative."""
    m = 1.0 / 11.0
    tc = hertz.contact_time(m, 2e6, v)
    ov = sim_overrides(method, rtol=1e-10, control_rate=1e5, plant_gravity=0.0,
                       initial_impact_speed=v, initial_pre_contact_time=1e-4)
    scene = impact_env.load_scene("ideal", ov)
    t_end = round(1.2 * tc, 5)
    tr = impact_env.simulate(scene, t_end=t_end, record_rate=1e5)
    fine = impact_env.simulate(finer(scene, method), t_end=t_end, record_rate=1e5)
    assert finite(tr) and tr.metrics()["n_contacts"] == 1
    n = t_end / 1e-6
    for got, want, name in ((lambda t: t.first_contact_duration() / tc, 1.0, "contact time"),
                            (lambda t: t.restitution(), 1.0, "restitution"),
                            (lambda t: t.max_penetration() / hertz.max_penetration(m, 2e6, v), 1.0, "d_max")):
        est = budget.richardson(got(tr), got(fine), order(method))
        assert abs(got(tr) - want) <= budget.bound(est, None, n), (name, got(tr) - want, est)
    assert rel(tr.metrics()["peak_contact_force_N"], hertz.peak_force(m, 2e6, v)) < 1e-6


@pytest.mark.parametrize("method", ["rk4", "dopri5", "split", "euler", "symplectic-euler"])
def test_touching_at_zero_speed_without_gravity_stays_put(method):
    """Surfaces touching, nothing moving, no gravity: exactly nothing happens."""
    ov = sim_overrides(method, control_rate=1e4, plant_gravity=0.0, initial_impact_speed=0.0)
    tr = impact_env.simulate("ideal", t_end=0.05, record_rate=1e4, overrides=ov)
    assert len(tr.events) == 0
    for k in ("x1", "v1", "x2", "v2", "contact_force", "work_shaker", "dissipated"):
        assert np.all(getattr(tr, k) == 0.0), k


@pytest.mark.parametrize("method", ["rk4", "dopri5", "split"])
def test_grazing_landing_with_gravity(method):
    """A 1 pm drop (4.4 um/s at the touch) under gravity: body 1 settles into an oscillation
    between d = 0 and 1.84 d_static, leaving the pad each period for a hop of only
    2 v / g = 0.9 us; the relative motion is conservative, so every hop must last that long.
    A hop shorter than a step is seen only if a step ends inside it: rk4's 1 us grid catches
    both hops in 30 ms here, dopri5's long steps (like solve_ivp's) step over them, which
    changes nothing measurable.

    The state at 30 ms is compared with solve_ivp relative to the motion's own scales: d_static
    for positions and the oscillation's largest speed (about 29 mm/s) for velocities (the
    4.4 um/s impact speed, used before, made the reference's own rounding-level error look
    like 2e-8 on another machine).  Bound (tests/budget.py): 4x the run's error estimated
    against a run at half the step (rk4, order 4) or rtol/100 (dopri5), plus the reference's
    error (its steps x 1e-12) and rounding (16 eps per 1 us of run)."""
    h = 1e-12
    v = math.sqrt(2 * G * h)
    ov = sim_overrides(method, rtol=1e-10, control_rate=1e5, initial_drop_height=h)
    scene = impact_env.load_scene("ideal", ov)
    y0, _ = initial_state(scene)
    ref = reference_drop(Params.from_array(plant_params(scene)), y0, 0.03)
    tr = impact_env.simulate(scene, t_end=0.03, record_rate=1e5)
    assert finite(tr)
    kinds = tr.events[:, 1].tolist()
    assert kinds[0] == 1.0 and all(a == -b for a, b in zip(kinds[:-1], kinds[1:], strict=True))
    seps = np.nonzero(tr.events[:, 1] < 0)[0]
    if method == "rk4":
        assert len(seps) == 2  # one hop per period of about 13 ms
    for k in seps:
        dd = tr.events[k, 3] - tr.events[k, 5]  # relative speed at separation (< 0)
        assert rel(-dd, v) < 1e-4  # the relative motion is conservative
        hop = tr.events[k + 1, 0] - tr.events[k, 0]
        assert rel(hop, 2 * -dd / G) < 1e-6
    finer = {"integrator.dt": 5e-7} if method == "rk4" else {"integrator.rtol": 1e-12}
    fine = impact_env.simulate(scene.with_overrides(finer), t_end=0.03, record_rate=1e5)
    ds = scene.plant.static_penetration
    u = max(np.abs(tr.v1).max(), np.abs(tr.v2).max())
    scale = np.array([ds, u, ds, u])
    y = np.array([tr.x1[-1], tr.v1[-1], tr.x2[-1], tr.v2[-1]]) / scale
    yf = np.array([fine.x1[-1], fine.v1[-1], fine.x2[-1], fine.v2[-1]]) / scale
    est = budget.richardson(y, yf, 4 if method == "rk4" else None)
    err = np.abs(y - ref.y_end[:4] / scale)
    assert np.all(err <= budget.bound(est, ref, 0.03 / 1e-6)), (err, est)


def test_small_impact_speed_with_gravity_starts_clear_of_the_pad():
    """impact_speed = 1 um/s under gravity: the free fall is never extrapolated past the
    release (v / g = 0.1 us before the touch), so body 1 starts above the pad and touches at
    the requested speed (before the fix it started 4.9 um inside the pad, moving up)."""
    ov = sim_overrides("rk4", initial_impact_speed=1e-6)
    tr = impact_env.simulate("ideal", t_end=2e-3, record_rate=1e5, overrides=ov)
    assert tr.x1[0] <= tr.x2[0]
    on = tr.onsets()
    assert len(on) >= 1 and abs(on[0, 3] - 1e-6) < 1e-9


# --------------------------------------------------------------------------------------------
# body 1 resting on body 2 for 10 s
# --------------------------------------------------------------------------------------------

def resting(method, restitution, c2):
    dt = 1e-5 if method == "rk4" else 1e-6
    ov = sim_overrides(method, dt=dt, rtol=1e-10, control_rate=1e3 if method == "dopri5" else 1 / dt,
                       initial_drop_height=0.0, plant_suspension_stiffness=1e4,
                       plant_suspension_damping=c2, plant_restitution=restitution)
    return impact_env.simulate("ideal", t_end=10.0, record_rate=1e3, overrides=ov)


@pytest.mark.parametrize("method", ["rk4", "dopri5", "split"])
def test_resting_damped_settles_to_static_equilibrium(method):
    """Released touching (drop height 0) on a damped pad (e = 0.5) and a damped suspension:
    after 10 s body 1 rests at d_static = (m1 g / c)^(2/3) with body 2 at m1 g / k2 (measured
    to 1e-14; tolerance 1e-9), in contact all along."""
    tr = resting(method, 0.5, 20.0)
    assert finite(tr)
    pl = tr.scene.plant
    assert tr.events[:, 1].tolist() == [1.0]
    assert rel(tr.x1[-1] - tr.x2[-1], pl.static_penetration) < 1e-9
    assert rel(tr.x2[-1], pl.m1 * pl.gravity / pl.suspension_stiffness) < 1e-9
    assert abs(tr.v1[-1]) < 1e-9 and abs(tr.v2[-1]) < 1e-9
    assert tr.energy_balance_error() < 1e-6  # measured 1e-11 (rk4), 4e-10 (dopri5)


@pytest.mark.parametrize("method", ["rk4", "dopri5", "split"])
def test_resting_elastic_keeps_its_energy_for_10s(method):
    """The same without damping: body 1 oscillates on the pad for 10 s (about 800 periods)
    between d = 0 and 1.84 d_static.  The energy ledger closes to 1e-8 of the catch energy for
    rk4 at h = 10 us (it takes (omega h)^6 / 72 of an oscillation's energy per step: over
    800 periods of 2 pi / (omega h) steps that is 2.4e-10 at omega = 510 rad/s; 40x margin for
    the Hertz contact's non-linearity) and 2e-5 for dopri5 at rtol 1e-10 (at most rtol per
    step over its 1.1e5 steps in 10 s, counted with NUMBA_DISABLE_JIT).  The state at 100 ms matches
    solve_ivp within the error budget of tests/budget.py, relative to d_static and the
    oscillation's largest speed."""
    tr = resting(method, 1.0, 0.0)
    assert finite(tr)
    ds = tr.scene.plant.static_penetration
    d = tr.x1 - tr.x2
    assert d.min() > -1e-12 * ds and d.max() < 1.85 * ds
    assert tr.energy_balance_error() < (1e-8 if method == "rk4" else 2e-5)
    y0, _ = initial_state(tr.scene)
    ref = reference_drop(Params.from_array(tr.params), y0, 0.1)
    fine = impact_env.simulate(finer(tr.scene, method), t_end=0.1, record_rate=1e3)
    u = max(np.abs(tr.v1).max(), np.abs(tr.v2).max())
    scale = np.array([ds, u, ds, u])
    y = np.array([tr.x1[100], tr.v1[100], tr.x2[100], tr.v2[100]]) / scale
    yf = np.array([fine.x1[100], fine.v1[100], fine.x2[100], fine.v2[100]]) / scale
    est = budget.richardson(y, yf, order(method))
    err = np.abs(y - ref.y_end[:4] / scale)
    assert np.all(err <= budget.bound(est, ref, 0.1 / 1e-6)), (err, est)


# --------------------------------------------------------------------------------------------
# 100 kN shaker forces
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["rk4", "dopri5", "split"])
@pytest.mark.parametrize("force", [1e5, -1e5])
def test_shaker_100kN(force, method):
    """+1e5 N drives body 2 into body 1 and both to 500 m/s in 5 ms (three contact events);
    -1e5 N pulls body 2 away before the touch.  The states at 0.1 ms records match solve_ivp
    under the same constant force, relative to each variable's range, within the error budget
    of tests/budget.py; the energy ledger closes relative to the shaker's work within twice
    the state's bound (an energy's relative error is at most about twice its state's) and
    never below rounding (16 eps a step)."""
    ov = sim_overrides(method, rtol=1e-10, control_rate=1e4, initial_impact_speed=1.0)
    runs = [impact_env.simulate(sc, controller=lambda t, y: force, t_end=5e-3, record_rate=1e4)
            for sc in (impact_env.load_scene("ideal", ov), finer(impact_env.load_scene("ideal", ov), method))]
    tr, fine = runs
    assert finite(tr)
    y0, _ = initial_state(tr.scene)
    ref = reference_drop(Params.from_array(tr.params), y0, 5e-3, f2=force, t_eval=tr.t)
    got = np.column_stack([tr.x1, tr.v1, tr.x2, tr.v2])
    got_fine = np.column_stack([fine.x1, fine.v1, fine.x2, fine.v2])
    scale = np.abs(ref.y[:, :4]).max(axis=0)
    est = budget.richardson(got / scale, got_fine / scale, order(method)).max(axis=0)
    tol = budget.bound(est, ref, 5e-3 / 1e-6)
    err = np.abs(got - ref.y[:, :4]) / scale
    assert np.all(err <= tol), (err.max(axis=0), tol)
    assert tr.events[:, 1].tolist() == ref.events[:, 1].tolist()
    e = tr.energies()["total"]
    resid = e + tr.dissipated - tr.work_shaker - e[0]
    assert np.abs(resid).max() < max(2 * tol.max(), budget.rounding(5e3)) * np.abs(tr.work_shaker).max()
    if force < 0:
        t = tr.t  # body 2 in free flight from rest: x2 = (f/m2) t^2 / 2
        np.testing.assert_allclose(tr.x2, 0.5 * (-force / 1.0) * t * t, rtol=1e-12, atol=1e-18)
        assert len(tr.events) == 0


# --------------------------------------------------------------------------------------------
# fixed steps beyond the stability limit
# --------------------------------------------------------------------------------------------

# t_c = 6 us: under-resolved at every step tested here, so the resolution check is off
# (integrator.min_steps_per_contact = 0) and the stability check is tested alone
STIFF = dict(plant_m1=1e-3, plant_m2=1e-3, plant_c=1e11, initial_impact_speed=1.0,
             initial_pre_contact_time=1e-5, integrator_min_steps_per_contact=0.0)


def deepest(m1, m, c, v):
    """Deepest penetration of an elastic drop under gravity on body 1 (m): the root of
    ``0.4 c d^2.5 = 0.5 m v^2 + m g d`` (relative motion, m the effective mass), and at least
    ``(2.5 m1 g / c)^(2/3)`` (body 1 let go touching the pad)."""
    from scipy.optimize import brentq

    f = lambda d: 0.4 * c * d**2.5 - 0.5 * m * v * v - m * G * d  # noqa: E731
    hi = max(hertz.max_penetration(m, c, max(v, 1e-9)), 1e-30)
    while f(hi) < 0:
        hi *= 2.0
    root = brentq(f, 0.0, hi, xtol=1e-300, rtol=1e-14) if v > 0 else 0.0
    return max(root, (2.5 * m1 * G / c) ** (2 / 3))


def stiff_limit(method):
    """Largest stable step for the STIFF drop (s): the method's omega*dt limit over the
    frequency of the Hertz contact at its deepest."""
    m = 0.5e-3
    d = hertz.max_penetration(m, 1e11, 1.0)
    return STABILITY_LIMIT[method] / hertz.max_contact_frequency(m, 1e11, d)


@pytest.mark.parametrize("method", ["euler", "symplectic-euler", "rk4"])
def test_step_beyond_stability_is_refused_up_front(method):
    dt = 1.2 * stiff_limit(method)
    with pytest.raises(ValueError, match="integrator.dt"):
        impact_env.simulate("ideal", t_end=200 * dt, overrides=sim_overrides(method, dt=dt, **STIFF))
    # just inside the limit the run goes ahead and ends finite (however inaccurate)
    dt = 0.8 * stiff_limit(method)
    tr = impact_env.simulate("ideal", t_end=200 * dt, overrides=sim_overrides(method, dt=dt, **STIFF))
    assert finite(tr) and tr.events[:2, 1].tolist() == [1.0, -1.0]


def test_shaker_pushing_past_stability_raises_diverged():
    """The drop alone passes the up-front check at dt = 4 us (omega dt = 2.6 < 2.83), but a
    100 kN push presses the pad deeper, where omega dt = 6: RK4 blows up, and simulate says so
    with the last finite state instead of returning NaN."""
    dt = 4e-6
    assert dt < stiff_limit("rk4")
    with pytest.raises(SimulationDiverged) as err:
        impact_env.simulate("ideal", controller=lambda t, y: 1e5, t_end=2e-3, record_rate=1 / (50 * dt),
                            overrides=sim_overrides("rk4", dt=dt, **STIFF))
    assert np.all(np.isfinite(err.value.state)) and math.isfinite(err.value.t)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(method=st.sampled_from(["euler", "symplectic-euler", "rk4", "dopri5"]),
       logc=st.floats(4.0, 11.0), logm1=st.floats(-3.0, 1.0), logm2=st.floats(-3.0, 1.0),
       v=st.floats(0.0, 5.0), factor=st.floats(0.05, 3.0),
       force=st.sampled_from([0.0, 1e5, -1e5, "sine"]))
def test_never_nan(method, logc, logm1, logm2, v, factor, force):
    """Random pads, bodies, speeds, steps (a factor of the stability limit) and forces up to
    100 kN: a step beyond the limit is refused up front, and every run either raises
    SimulationDiverged or comes back finite.  (The resolution check is off: most of these
    steps take a contact in a few steps, which is what this test is about.)"""
    m1, m2, c = 10.0**logm1, 10.0**logm2, 10.0**logc
    m = m1 * m2 / (m1 + m2)
    # the stiffest contact the drop excites (as simulate's up-front check sees it)
    d = deepest(m1, m, c, v)
    omega = hertz.max_contact_frequency(m, c, d)
    if method == "dopri5":
        dt = 1e-6
        ratio = 0.0
    else:
        dt = min(max(factor * STABILITY_LIMIT[method] / omega, 1e-8), 1e-3)
        ratio = dt * omega / STABILITY_LIMIT[method]  # factor, unless dt was clamped
    tc = hertz.contact_time(m, c, max(v, 1e-3))
    n = 400
    ctrl = None
    if force == "sine":
        def ctrl(t, y):
            return 1e5 * math.sin(2 * math.pi * t / (n * dt))
    elif force:
        def ctrl(t, y):
            return force
    ov = sim_overrides(method, dt=dt, rtol=1e-8, control_rate=1 / dt, plant_m1=m1, plant_m2=m2,
                       plant_c=c, initial_impact_speed=v, integrator_min_steps_per_contact=0.0,
                       initial_pre_contact_time=min(0.1 * tc, 10.0))
    try:
        tr = impact_env.simulate("ideal", controller=ctrl, t_end=n * dt, record_rate=1 / (10 * dt),
                                 overrides=ov)
    except SimulationDiverged as err:
        assert np.all(np.isfinite(err.state)) and math.isfinite(err.t)
        return
    except ValueError as err:
        assert ratio > 0.999 and "integrator.dt" in str(err), str(err)
        return
    assert ratio <= 1.001
    assert finite(tr)
