"""The plant against oracles: closed-form Hertz, the slow references in ``impact_env.plant.reference``
(pure-Python steppers and a solve_ivp with event restarts), energy ledgers, the restitution
calibration, determinism, the known error of explicit Euler, and input validation.

Tolerances are stated next to each check with their derivation: against a closed form, the
method's error (its order and step) and rounding; against solve_ivp, the error budget of
``budget.py`` (the run's own error estimated from a finer run, the reference's error, rounding).
Measured values, where given, are illustrations, not the source of a bound.
"""

from __future__ import annotations

import math
import re

import budget
import numpy as np
import pytest
from hertz_drop import hertz_drop
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import impact_env
from impact_env.hardware.arrays import METHOD_CODES, initial_state, plant_params
from impact_env.plant import hertz, reference
from impact_env.plant.integrators import PlantCarry, PlantConsts, advance
from impact_env.plant.layout import (
    AUTO,
    DIVERGED,
    FREE,
    N_EVENT_COLS,
    N_PARAM,
    OK,
    PARAM,
    STATE,
    STEP_UNDERFLOW,
)
from impact_env.plant.reference import Params, reference_drop, sim_overrides

G = 9.81


def state(tr) -> np.ndarray:
    """(n, 6) array of a Trajectory's recorded states, with the energy ledgers."""
    return np.column_stack([tr.x1, tr.v1, tr.x2, tr.v2, tr.work_shaker, tr.dissipated])


def rel(a: float, b: float) -> float:
    return abs(a - b) / abs(b)


# --------------------------------------------------------------------------------------------
# closed-form Hertz (gravity 0): d_max, t_c, F_max, e = 1
# --------------------------------------------------------------------------------------------

HERTZ_CASES = [  # (m1, m2, c, v): kg, kg, N/m^1.5, m/s
    (0.1, 1.0, 2.0e6, 1.0),  # the thesis rig
    (0.01, 0.01, 1.0e5, 0.1),  # equal light bodies, soft pad, slow
    (1.0, 10.0, 1.0e8, 3.0),  # heavy, stiff, fast
    (1.0e-3, 1.0e3, 1.0e9, 0.5),  # a bead on an anvil
    (5.0, 0.05, 3.0e7, 2.0),  # heavy body 1 on a light body 2
]


@pytest.mark.parametrize("method", ["rk4", "dopri5", "split"])
@pytest.mark.parametrize("m1,m2,c,v", HERTZ_CASES)
def test_hertz_closed_form(m1, m2, c, v, method):
    tr, m, tc, dt = hertz_drop(m1, m2, c, v, method)
    mt = tr.metrics()
    assert mt["n_contacts"] == 1
    # contact duration and restitution come from located events.  RK4's error falls as N^-4
    # with N = t_c/dt steps a contact: 3.6e-6 at N = 30 (scripts/steps_per_contact.py), so
    # <= 3.6e-6 (30/2000)^4 = 2e-13 at N >= 2000; dopri5 at rtol 1e-11 commits <= rtol a step
    # over ~1e3 steps; rounding over 2000 steps is 2000 x 16 eps = 7e-12.  Bound 1e-8.
    assert rel(mt["first_contact_duration_s"], tc) < 1e-8
    assert abs(mt["restitution"] - 1.0) < 1e-8
    # d_max from the records (every step) refined by a parabola: measured <= 1.3e-11
    assert rel(mt["max_penetration_m"], hertz.max_penetration(m, c, v)) < 1e-8
    # F_max is the largest force at a step end or record: it misses the true peak by up to
    # about (pi dt / (2 t_c))^2 / 2 relative (<= 3e-7 at t_c/dt >= 2000); measured <= 5e-8
    fmax = hertz.peak_force(m, c, v)
    assert mt["peak_contact_force_N"] <= fmax * (1 + 1e-12)
    assert rel(mt["peak_contact_force_N"], fmax) < 1e-6
    # gravity 0, no shaker, no damping: the total energy is conserved (measured <= 3e-11)
    assert mt["energy_balance_error"] < 1e-8


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(m1=st.floats(1e-3, 10.0), m2=st.floats(1e-3, 10.0), logc=st.floats(4.0, 10.0),
       v=st.floats(0.01, 5.0))
def test_hertz_closed_form_property(m1, m2, logc, v):
    """Random bodies, pads and speeds (dopri5): the collision time and restitution match Hertz."""
    c = 10.0**logc
    tr, m, tc, _dt = hertz_drop(m1, m2, c, v, "dopri5", steps_per_contact=500)
    assert rel(tr.first_contact_duration(), tc) < 1e-8
    assert abs(tr.restitution() - 1.0) < 1e-8
    assert rel(tr.max_penetration(), hertz.max_penetration(m, c, v)) < 1e-7


# --------------------------------------------------------------------------------------------
# compiled kernels against the obvious Python steppers (force switched in the rhs)
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["euler", "symplectic-euler", "rk4"])
def test_kernel_matches_naive_stepper(method):
    """simulate() without event location is the naive stepper, step for step: a drop through
    a damped contact on a suspended body 2, under a sampled-and-held shaker force.  Only the
    order of floating-point operations differs (inverse masses, pow vs sqrt), so the records
    agree to rounding: measured 1e-14 of each column's range; 1e-12 allowed."""
    dt = 1e-6

    def ctrl(t, y):
        return 30.0 * math.sin(2000.0 * t) - 5.0 * y[3]

    ov = sim_overrides(method, dt=dt, events=False, control_rate=2.5e5, initial_impact_speed=1.0,
                       plant_suspension_stiffness=1e4, plant_suspension_damping=5.0,
                       plant_restitution=0.7, initial_pre_contact_time=1e-4)
    tr = impact_env.simulate("ideal", controller=ctrl, t_end=5e-3, record_rate=2.5e5, overrides=ov)
    p = Params.from_array(tr.params)
    y0, _ = initial_state(tr.scene)
    ref = reference.run_fixed(y0, p, dt, 5000, method, f2=ctrl, control_every=4)[::4]
    got = state(tr)
    assert got.shape == ref.shape
    # all six columns, the shaker-work ledger included: both book -f2 times the x2 update,
    # which for symplectic Euler is -f2 h v2_new.  (A W_ext that lags one step here, about
    # 1e-3 of its range, is what a stale numba cache of run.run_periods, compiled before
    # integrators.py booked the work that way, produces: see impact_env._jit.)
    scale = np.abs(ref).max(axis=0)
    assert np.all(np.abs(got - ref) <= 1e-12 * scale), np.abs(got - ref).max(axis=0) / scale
    # one touch and one separation, logged at the end of the straddling step
    assert tr.events[:, 1].tolist() == [1.0, -1.0]


@pytest.mark.parametrize("method", ["euler", "symplectic-euler", "rk4"])
def test_advance_matches_naive_stepper(method):
    """The kernel ``advance`` called directly (AUTO mode: the force switches inside the rhs)
    over one long span: end state, the logged switches and the peak force match the naive
    stepper (rtol 1e-12; measured ~1e-14)."""
    p = Params(m1=0.05, m2=0.7, c=3e6, b=40.0, g=G, k2=2e3, c2=3.0)
    parr = np.zeros(N_PARAM)
    parr[[PARAM.m1, PARAM.m2, PARAM.c, PARAM.b, PARAM.g, PARAM.k2, PARAM.c2]] = [p.m1, p.m2, p.c, p.b, p.g,
                                                                                 p.k2, p.c2]
    dt, n, f2 = 1e-6, 6000, 12.0
    y0 = reference.free_fall_start(0.8, G, 2e-4) + [0.0, 0.0]
    y = np.array(y0)
    ev = np.zeros((16, N_EVENT_COLS))
    evn = np.zeros(1, dtype=np.int64)
    peak = np.zeros(1)
    consts = PlantConsts(parr, np.ones(6), METHOD_CODES[method], dt, 1e-9)
    status, mode = advance(AUTO, f2, 0.0, n * dt, consts, PlantCarry(y, np.zeros(1), ev, evn, peak))
    assert status == OK and mode == AUTO
    ref = reference.run_fixed(y0, p, dt, n, method, f2=f2)
    scale = np.abs(ref).max(axis=0)
    assert np.all(np.abs(y - ref[-1]) <= 1e-12 * scale)
    # switches: logged at the end of the step that crosses d = 0, with that step's state
    d = ref[:, 0] - ref[:, 2]
    cross = np.nonzero((d[1:] > 0) != (d[:-1] > 0))[0] + 1
    assert evn[0] == len(cross) >= 2
    np.testing.assert_allclose(ev[: evn[0], 0], cross * dt, rtol=1e-13)
    for row, k in zip(ev[: evn[0]], cross, strict=True):
        assert row[1] == (1.0 if d[k] > 0 else -1.0)
        assert np.all(np.abs(row[2:6] - ref[k, :4]) <= 1e-12 * scale[:4])
    forces = [reference.pad_force(r[0] - r[2], r[1] - r[3], p)[0] for r in ref[1:]]
    assert rel(peak[0], max(forces)) < 1e-12


@pytest.mark.parametrize("method", ["rk4", "dopri5", "symplectic-euler", "euler"])
def test_free_flight_is_exact(method):
    """Free flight under gravity (body 1) and a constant shaker pull (body 2, no suspension):
    accelerations are constant, which RK4 and DOPRI5 integrate exactly and the Euler methods
    with a known O(dt) offset.  Checked against the closed form."""
    dt, n, f2 = 1e-5, 2000, -3.0  # body 2 pulled down, away from body 1
    p = np.zeros(N_PARAM)
    p[[PARAM.m1, PARAM.m2, PARAM.c, PARAM.g]] = [0.1, 1.0, 2e6, G]
    y0 = np.array([-0.5, 0.1, 0.0, 0.0, 0.0, 0.0])  # 0.5 m above body 2
    y = y0.copy()
    ev = np.zeros((4, N_EVENT_COLS))
    evn = np.zeros(1, dtype=np.int64)
    t = n * dt
    consts = PlantConsts(p, np.array([1e-3, 1.0, 1e-3, 1.0, 1e-3, 1e-3]), METHOD_CODES[method], dt, 1e-10)
    status, mode = advance(FREE, f2, 0.0, t, consts, PlantCarry(y, np.zeros(1), ev, evn, np.zeros(1)))
    assert status == OK and mode == FREE and evn[0] == 0
    a2 = -f2 / 1.0
    exact = np.array([-0.5 + 0.1 * t + 0.5 * G * t * t, 0.1 + G * t, 0.5 * a2 * t * t, a2 * t,
                      -f2 * 0.5 * a2 * t * t, 0.0])
    if method in ("rk4", "dopri5"):
        np.testing.assert_allclose(y, exact, rtol=1e-12, atol=1e-15)
    else:  # positions lag (Euler) or lead (symplectic) by a * t * dt / 2; velocities exact
        off = 0.5 * t * dt * (1 if method == "symplectic-euler" else -1)
        np.testing.assert_allclose(y[[1, 3]], exact[[1, 3]], rtol=1e-12)
        np.testing.assert_allclose(y[0], exact[0] + G * off, rtol=1e-12)
        np.testing.assert_allclose(y[2], exact[2] + a2 * off, rtol=1e-12)


# --------------------------------------------------------------------------------------------
# event-located trajectories against solve_ivp (DOP853, event restarts)
# --------------------------------------------------------------------------------------------

def three_bounce_scene(restitution, c2):
    """A 2 mm drop on a suspended body 2 (k2 = 1e4 N/m): bounces recur every 30-40 ms."""
    return dict(initial_drop_height=2e-3, plant_suspension_stiffness=1e4,
                plant_suspension_damping=c2, plant_restitution=restitution)


@pytest.fixture(scope="module")
def three_bounce_refs():
    """solve_ivp references for the elastic and the damped three-bounce scenes, and the time
    midway between the third separation and the fourth touch (on the 1 us grid)."""
    out = {}
    for e, c2 in [(1.0, 0.0), (0.8, 5.0)]:
        scene = impact_env.load_scene("ideal", sim_overrides("rk4", **three_bounce_scene(e, c2)))
        p = Params.from_array(plant_params(scene))
        y0, _ = initial_state(scene)
        first = reference_drop(p, y0, 0.2)
        off = first.events[first.events[:, 1] < 0]
        on = first.events[first.events[:, 1] > 0]
        t_end = round(0.5 * (off[2, 0] + on[3, 0]) * 1e6) * 1e-6
        ref = reference_drop(p, y0, t_end)
        out[e] = (t_end, ref, 0.5 * math.sqrt(2 * G * 2e-3))
    return out


@pytest.mark.parametrize("method,knob", [("rk4", 1e-6), ("rk4", 1e-7), ("dopri5", 1e-9), ("dopri5", 1e-11),
                                         ("split", 1e-9), ("split", 1e-11)])
def test_three_bounces_match_solve_ivp(three_bounce_refs, method, knob):
    """Three bounces of a 2 mm drop on a suspended body 2, elastic and damped (e = 0.8), against
    solve_ivp: the state midway through the third flight (positions / 2 mm, velocities / the
    impact speed v0), the event times and the dissipation ledger.

    Bound (tests/budget.py): 4x the run's own error, estimated against a run at half the step
    (rk4, order 4) or at rtol/100 (dopri5, whose error is proportional to rtol), plus the
    reference's error (its steps x 1e-12) and rounding (16 eps a step).  Event times: an error
    dx in the crossing penetration moves the event by dx / (relative speed there), at least
    e v0 / 2 for these bounces, so the bound x 2 mm / (0.4 v0) = bound x 25 ms."""
    v0 = math.sqrt(2 * G * 2e-3)
    scale = np.array([2e-3, v0, 2e-3, v0])
    e0 = 0.1 * G * 2e-3
    for e, c2 in [(1.0, 0.0), (0.8, 5.0)]:
        t_end, ref, _ = three_bounce_refs[e]
        runs = []
        for k in (knob, knob / 2 if method == "rk4" else knob / 100):
            ov = sim_overrides(method, dt=k if method == "rk4" else 1e-6, rtol=k,
                               control_rate=1e6 if method == "rk4" else None, **three_bounce_scene(e, c2))
            runs.append(impact_env.simulate("ideal", t_end=t_end, record_rate=1e6, overrides=ov))
        tr, fine = runs
        assert tr.events[:, 1].tolist() == ref.events[:, 1].tolist() == [1.0, -1.0] * 3
        y, yf = state(tr)[-1], state(fine)[-1]
        est = budget.richardson(y[:4] / scale, yf[:4] / scale, 4 if method == "rk4" else None)
        tol = budget.bound(est, ref, t_end / (knob if method == "rk4" else 1e-7))
        err = np.abs(y[:4] - ref.y_end[:4]) / scale
        assert np.all(err <= tol), (e, err, tol)
        assert np.abs(tr.events[:, 0] - ref.events[:, 0]).max() < tol.max() * 0.025
        est_w = budget.richardson(y[STATE.w_diss] / e0, yf[STATE.w_diss] / e0, 4 if method == "rk4" else None)
        tol_w = budget.bound(est_w, ref, t_end / (knob if method == "rk4" else 1e-7))
        assert abs(y[STATE.w_diss] - ref.y_end[STATE.w_diss]) / e0 <= max(tol_w, tol.max())


# --------------------------------------------------------------------------------------------
# energy balance: E + W_diss - W_ext = E(0)
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("case,method", [(c, m) for c in ("elastic", "damped pad and suspension", "shaker")
                                         for m in ("rk4", "split")] + [("no events", "rk4")])
def test_energy_balance_closes(case, method):
    """RK4 at 1 us, split at rtol 1e-12: the energy ledger closes to 1e-8 of the drop energy
    over a 0.3 s run with several bounces (RK4 measured 7e-11 elastic, 9e-11 damped, 1.3e-10
    without event location, 8e-10 with the shaker, whose work is 3000x the drop energy; split
    keeps its free-flight ledger exactly, the damper's share from body 2's stored energy)."""
    controller = None
    kw = {}
    if case == "damped pad and suspension":
        kw = dict(plant_restitution=0.6, plant_suspension_stiffness=5e3, plant_suspension_damping=8.0)
    elif case == "shaker":
        kw = dict(plant_restitution=0.8, plant_suspension_stiffness=5e3)

        def controller(t, y):
            return 20.0 * math.sin(300.0 * t) + 2e3 * (y[0] - y[2])
    elif case == "no events":
        kw = dict(plant_restitution=0.6, plant_suspension_stiffness=5e3, plant_suspension_damping=8.0,
                  events=False)
    ov = sim_overrides(method, rtol=1e-12, control_rate=1e5, initial_drop_height=0.01, **kw)
    tr = impact_env.simulate("ideal", controller=controller, t_end=0.3, record_rate=1e4, overrides=ov)
    assert tr.metrics()["n_contacts"] >= 3
    if case != "elastic":
        assert tr.dissipated[-1] > 0.1 * 0.1 * G * 0.01  # the dissipation ledger is not idle
    if case == "shaker":
        assert abs(tr.work_shaker).max() > 1e-3
    assert tr.energy_balance_error() < 1e-8


# --------------------------------------------------------------------------------------------
# calibrated restitution of the Tsuji pad
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("e", [0.3, 0.6, 0.9])
@pytest.mark.parametrize("m1,m2,c,v", HERTZ_CASES[:4])
@pytest.mark.parametrize("method", ["rk4", "dopri5", "split"])
def test_delivered_restitution(method, m1, m2, c, v, e):
    """The calibrated damping delivers the requested e for every mass, stiffness and speed
    (gravity 0).  The issue asks for 1 %.  RK4 at N = t_c/dt >= 2000 steps a contact: the
    d^0.25 factor at the touch holds it to order 1.25 without the graded zone after the touch
    (at most 0.06 N^-1.25 = 4.4e-6 at N = 2000 for e >= 0.3, measured before the zone), and
    that is the bound kept here; dopri5 at rtol 1e-11: <= rtol a step over ~1e3 steps, 1e-7."""
    tr, _m, _tc, _dt = hertz_drop(m1, m2, c, v, method, restitution=e)
    got = tr.restitution()
    assert abs(got - e) < 0.01 * e
    assert abs(got - e) < (2e-5 if method == "rk4" else 1e-7)
    assert tr.energy_balance_error() < 1e-8


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(e=st.floats(0.2, 0.99), logc=st.floats(5.0, 9.0), v=st.floats(0.05, 3.0))
def test_delivered_restitution_property(e, logc, v):
    tr, _m, _tc, _dt = hertz_drop(0.1, 1.0, 10.0**logc, v, "dopri5", restitution=e,
                                 steps_per_contact=500)
    assert abs(tr.restitution() - e) < 1e-7


# --------------------------------------------------------------------------------------------
# determinism and the known error of explicit Euler
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["rk4", "dopri5", "euler"])
def test_same_inputs_same_trajectory(method):
    def controller(t, y):
        return 50.0 * math.sin(500.0 * t) + 200.0 * y[3]  # a damper on body 2

    ov = sim_overrides(method, control_rate=1e5, plant_restitution=0.7, plant_suspension_stiffness=1e4,
                       initial_drop_height=0.005)
    a = impact_env.simulate("ideal", controller=controller, t_end=0.05, record_rate=1e4, overrides=ov)
    b = impact_env.simulate("ideal", controller=controller, t_end=0.05, record_rate=1e4, overrides=ov)
    for name in ("t", "x1", "v1", "x2", "v2", "contact_force", "peak_force", "shaker_force",
                 "work_shaker", "dissipated", "events"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert len(a.events) >= 2


@pytest.mark.parametrize("events", [True, False])
@pytest.mark.parametrize("dt", [1e-6, 1e-7])
def test_explicit_euler_is_super_elastic(dt, events):
    """Explicit Euler gains energy in contact: e - 1 = k dt / t_c with k ~ 5.6 for the Hertz
    contact (measured 5.57; a linear spring would give pi^2/2 = 4.9).  Checked within 20 %."""
    m = 0.1 * 1.0 / 1.1
    tc = hertz.contact_time(m, 2e6, 1.0)
    ov = sim_overrides("euler", dt=dt, events=events, plant_gravity=0.0, initial_impact_speed=1.0)
    tr = impact_env.simulate("ideal", t_end=6e-3, record_rate=1e4, overrides=ov)
    k = (tr.restitution() - 1.0) / (dt / tc)
    assert abs(k / 5.6 - 1.0) < 0.2, k


# --------------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------------

BAD = [
    ("plant.m1", -0.1), ("plant.m1", 0.0), ("plant.m2", -1.0), ("plant.m2", 0.0),
    ("plant.c", 0.0), ("plant.c", -2e6), ("integrator.dt", 0.0), ("integrator.dt", -1e-6),
    ("plant.restitution", 0.0), ("plant.restitution", 1.5), ("plant.restitution", -0.3),
    ("initial.impact_speed", float("nan")), ("initial.drop_height", float("nan")),
    ("initial.pre_contact_time", float("nan")), ("plant.gravity", float("nan")),
    ("plant.m1", float("nan")), ("plant.c", float("inf")), ("integrator.rtol", 0.0),
    ("integrator.method", "rk5"), ("integrator.method", "RK4"), ("integrator.method", ""),
]


@pytest.mark.parametrize("key,value", BAD)
def test_bad_values_raise_naming_the_parameter(key, value):
    with pytest.raises(ValueError, match=re.escape(key)):
        impact_env.simulate("ideal", t_end=1e-3, overrides={key: value})


@pytest.mark.parametrize("key,named", [("plant.mass1", "plant.mass1"), ("integrater.dt", "integrater"),
                                       ("plant.c.x", "plant.c.x"), ("initial.speed", "initial.speed"),
                                       ("dt", "dt")])
def test_unknown_keys_raise_naming_the_key(key, named):
    with pytest.raises(ValueError, match=re.escape(named)):
        impact_env.simulate("ideal", t_end=1e-3, overrides={key: 1.0})


def test_bad_run_arguments():
    with pytest.raises(ValueError, match="t_end"):
        impact_env.simulate("ideal", t_end=-1.0)
    with pytest.raises(ValueError, match="t_end"):
        impact_env.simulate("ideal", t_end=float("nan"))
    with pytest.raises(ValueError, match="record_rate"):
        impact_env.simulate("ideal", t_end=1e-3, record_rate=0.0)
    with pytest.raises(ValueError, match="record_rate"):  # 1/3 us is not a whole number of steps
        impact_env.simulate("ideal", t_end=1e-3, record_rate=3e6)
    with pytest.raises(ValueError, match="control.rate"):  # 0.3 us period on a 1 us grid
        impact_env.simulate("ideal", t_end=1e-3, overrides={"control.rate": 3e6})
    with pytest.raises(ValueError, match="unknown scene"):
        impact_env.simulate("idael", t_end=1e-3)
    with pytest.raises(ValueError, match="non-finite"):
        impact_env.simulate("ideal", controller=lambda t, y: float("nan"), t_end=1e-3)


def test_simulate_refuses_a_scene_with_effects_naming_what_runs_them():
    """simulate() integrates the bare plant: a scene with effects is refused (before any
    simulation) unless the caller says plant_only; the plant alone is then what it integrates."""
    with pytest.raises(ValueError, match=r"'rig' has effects.*Simulator.*plant_only=True"):
        impact_env.simulate("rig", t_end=1e-3)
    scene = impact_env.load_scene("rig")
    bare = scene.with_overrides({"effects.active": []})
    a = impact_env.simulate(scene, t_end=1e-3, plant_only=True)
    b = impact_env.simulate(bare, t_end=1e-3)
    np.testing.assert_array_equal(np.c_[a.x1, a.v1, a.x2, a.v2], np.c_[b.x1, b.v1, b.x2, b.v2])


def test_kernel_reports_nan_state_as_divergence():
    """A NaN in the state handed to the kernel is reported, not propagated silently."""
    p = np.zeros(N_PARAM)
    p[[PARAM.m1, PARAM.m2, PARAM.c, PARAM.g]] = [0.1, 1.0, 2e6, G]
    for method in ("euler", "rk4", "dopri5"):
        y = np.array([-1e-3, float("nan"), 0.0, 0.0, 0.0, 0.0])
        consts = PlantConsts(p, np.ones(6), METHOD_CODES[method], 1e-6, 1e-9)
        status, _ = advance(FREE, 0.0, 0.0, 1e-4, consts,
                            PlantCarry(y, np.zeros(1), np.zeros((4, 6)), np.zeros(1, dtype=np.int64),
                                       np.zeros(1)))
        # fixed-step: DIVERGED; dopri5 rejects the NaN error estimate until its step
        # underflows and reports STEP_UNDERFLOW (simulate raises SimulationDiverged for both)
        assert status in ((DIVERGED, STEP_UNDERFLOW) if method == "dopri5" else (DIVERGED,))
