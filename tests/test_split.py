"""The ``split`` integrator (the default): exact free flight, dopri5 in contact.

Oracles: ``scipy.linalg.expm`` for body 2's free motion, ``scipy.optimize.brentq`` on that
exact motion for the touch, and ``solve_ivp`` (DOP853, rtol 1e-12, event restarts:
``tests/naive.py``) for whole drops, at parameters no preset uses.  Tolerances:

* free flight: the exponential series is summed until a term no longer changes the sum, so
  its error is the sum's rounding: a few eps per term, at most ``MAX_TERMS``; the expm oracle
  has its own (Pade, scaling and squaring: a few eps of the norm).  Bound: 64 eps relative to
  the state's scale (position range + velocity x h).
* the touch: the located time is the contact side of a bracket ``ROOT_TOL h`` wide; brentq at
  xtol 1e-22 s adds nothing; the gap's rounding (64 eps of the positions) divided by the
  closing speed moves a root by at most that much.
* whole drops: dopri5's global error is proportional to rtol, so a run at rtol / 100 estimates
  it (tests/budget.py), plus the reference's error and rounding.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.optimize import brentq

sys.path.insert(0, str(Path(__file__).resolve().parent))

import budget  # noqa: E402
from naive import Params, reference_drop, sim_overrides  # noqa: E402

import impact_env  # noqa: E402
from impact_env.config import ConfigError  # noqa: E402
from impact_env.hardware.arrays import initial_state, plant_params  # noqa: E402
from impact_env.plant.free_flight import MAX_TERMS, ROOT_TOL, body2_after, free_cap, touch_time  # noqa: E402

EPS = float(np.finfo(float).eps)


def exact_body2(x2, v2, h, f2, m2, k2, c2):
    """Body 2 after h seconds by the matrix exponential of the input-augmented system."""
    a = np.array([[0.0, 1.0, 0.0], [-k2 / m2, -c2 / m2, -f2 / m2], [0.0, 0.0, 0.0]])
    z = expm(a * h) @ np.array([x2, v2, 1.0])
    return z[0], z[1]


def random_body2(rng):
    m2 = 10 ** rng.uniform(-1, 1)
    k2 = 0.0 if rng.random() < 0.2 else 10 ** rng.uniform(2, 6)
    c2 = 0.0 if rng.random() < 0.2 else 10 ** rng.uniform(-1, 2)
    return m2, k2, c2


def test_body2_free_motion_matches_expm():
    """300 random suspensions (k2 0 or 1e2-1e6 N/m, c2 0 or 0.1-100 N s/m, m2 0.1-10 kg),
    states and forces, at steps up to the sub-step cap: within 64 eps of the scale."""
    rng = np.random.default_rng(7)
    for _ in range(300):
        m2, k2, c2 = random_body2(rng)
        cap = free_cap(1.0 / m2, k2, c2)
        h = min(cap, 1e-3) * rng.uniform(0.01, 1.0)
        x2, v2, f2 = rng.normal(0, 1e-3), rng.normal(0, 0.1), rng.normal(0, 50.0)
        got = body2_after(x2, v2, h, f2, 1.0 / m2, k2, c2)
        want = exact_body2(x2, v2, h, f2, m2, k2, c2)
        sx = abs(x2) + abs(v2) * h + abs(want[0] - x2) + 1e-300
        sv = abs(v2) + abs(want[1] - v2) + 1e-300
        assert abs(got[0] - want[0]) <= 64 * EPS * sx, (m2, k2, c2, h)
        assert abs(got[1] - want[1]) <= 64 * EPS * sv, (m2, k2, c2, h)
    assert MAX_TERMS >= 20


def _gap(t, x1, v1, x2, v2, f2, g, m2, k2, c2):
    a2, _ = exact_body2(x2, v2, t, f2, m2, k2, c2)
    return x1 + v1 * t + 0.5 * g * t * t - a2


@pytest.mark.parametrize("graze", [False, True])
def test_touch_time_matches_brentq(graze):
    """The located touch against brentq on the exact gap (expm for body 2), for 200 random
    approaches; ``graze``: the gap is negative at both ends of the sub-step and positive only
    in between (a body 2 pulled away under body 1), which a sign test at the ends misses."""
    rng = np.random.default_rng(11 + graze)
    g = 9.81
    found = 0
    for _ in range(200):
        m2, k2, c2 = random_body2(rng)
        h = min(free_cap(1.0 / m2, k2, c2), 1e-4)
        x2, v2 = rng.normal(0, 1e-4), rng.normal(0, 0.01)
        if graze:
            # body 2 at rest, accelerated away from body 1 at acc: the gap rises to its top
            # rate^2 / (2 acc) at rate / acc < h / 5 and is negative again at h
            x2, v2 = 0.0, 0.0
            acc = rng.uniform(500, 2000)
            f2 = -m2 * (acc + g)
            rate = acc * h * rng.uniform(0.02, 0.2)
            x1 = -rate * rate / (2 * acc) * rng.uniform(0.05, 0.5)
        else:
            f2 = rng.normal(0, 10.0)
            rate = rng.uniform(0.05, 2.0)
            x1 = x2 - rate * h * rng.uniform(0.05, 0.95)
        v1 = v2 + rate
        args = (x1, v1, x2, v2, f2, g, m2, k2, c2)
        tau = touch_time(x1, v1, x2, v2, h, f2, g, 1.0 / m2, k2, c2, 2e6, 0.0)
        ends_negative = _gap(h, *args) < 0
        if graze:
            assert ends_negative
        if tau < 0:
            # no touch: the exact gap stays <= 0 on a fine grid
            ts = np.linspace(0, h, 2001)
            assert max(_gap(t, *args) for t in ts) <= 64 * EPS * (abs(x1) + abs(x2)), args
            continue
        found += 1
        hi = min(h, tau + 1e-6 * h)  # just past the located touch: the oracle's own bracket
        root = brentq(_gap, 0.0, hi, args=args, xtol=1e-22, rtol=4 * EPS)
        speed = v1 - v2 + g * root
        tol = ROOT_TOL * h + 64 * EPS * (abs(x1) + abs(x2) + 1e-12) / max(abs(speed), 1e-12) + 4 * EPS * h
        assert abs(tau - root) <= tol, (tau, root, tol)
        assert _gap(tau, *args) >= -64 * EPS * (abs(x1) + abs(x2))  # the contact side
    assert found >= 100


@pytest.mark.parametrize("rtol", [1e-10, 1e-12])
def test_drop_per_impact_matches_solve_ivp(rtol):
    """A drop on a suspended body 2 under a constant shaker force, several bounces on a damped
    pad, at unseen parameters: event times, per-impact restitution and the state at the end
    against solve_ivp, within the budget (4x the error estimated from a run at rtol / 100, plus
    the reference's error and rounding).  Event times: a state error dx moves a crossing by
    dx / (closing speed), and a later one inherits the earlier flights' speed errors: the event
    times and the speeds at them get the same budget from their own rtol / 100 runs."""
    kw = dict(plant_m1=0.0937, plant_m2=0.87, plant_c=3.3e6, plant_restitution=0.71,
              plant_suspension_stiffness=1.3e4, plant_suspension_damping=27.0, initial_drop_height=0.043)
    force = 3.7
    t_end = 0.25
    runs = []
    for r in (rtol, rtol / 100):
        ov = sim_overrides("split", rtol=r, control_rate=1e4, **kw)
        runs.append(impact_env.simulate("ideal", controller=lambda t, y: force, t_end=t_end,
                                        record_rate=1e4, overrides=ov))
    tr, fine = runs
    scene = tr.scene
    y0, _ = initial_state(scene)
    ref = reference_drop(Params.from_array(plant_params(scene)), y0, t_end, f2=force)
    assert tr.events[:, 1].tolist() == ref.events[:, 1].tolist()
    assert len(ref.events) >= 6
    v0 = math.sqrt(2 * 9.81 * 0.043)
    scale = np.array([1e-3, v0, 1e-3, v0])
    y = np.array([tr.x1[-1], tr.v1[-1], tr.x2[-1], tr.v2[-1]])
    yf = np.array([fine.x1[-1], fine.v1[-1], fine.x2[-1], fine.v2[-1]])
    tol = budget.bound(budget.richardson(y / scale, yf / scale, None), ref, t_end / 1e-6)
    assert np.all(np.abs(y - ref.y_end[:4]) / scale <= tol), (np.abs(y - ref.y_end[:4]) / scale, tol)
    # event times and the relative speeds at the events, each with its own estimate from the
    # rtol / 100 run (a later event inherits the earlier flights' velocity errors, over ~0.1 s)
    assert fine.events[:, 1].tolist() == ref.events[:, 1].tolist()
    ev_tol = (budget.SAFETY * budget.richardson(tr.events[:, 0], fine.events[:, 0], None)
              + budget.reference_error(ref) * t_end + budget.rounding(t_end / 1e-6) * t_end)
    assert np.all(np.abs(tr.events[:, 0] - ref.events[:, 0]) <= ev_tol)
    rate, rate_f, rate_ref = (e[:, 3] - e[:, 5] for e in (tr.events, fine.events, ref.events))
    rate_tol = (budget.SAFETY * budget.richardson(rate / v0, rate_f / v0, None)
                + budget.reference_error(ref) + budget.rounding(t_end / 1e-6))
    assert np.all(np.abs(rate - rate_ref) / v0 <= rate_tol)
    assert tr.energy_balance_error() < 1e-8


def test_split_is_the_default_and_ideal_keeps_rk4():
    assert impact_env.load_scene("rig").integrator.method == "split"
    assert impact_env.load_scene("rig-randomized").integrator.method == "split"
    assert impact_env.load_scene("ideal").integrator.method == "rk4"


def test_split_refuses_no_event_location():
    with pytest.raises(ConfigError, match="integrator.event_location"):
        impact_env.load_scene("rig", {"integrator.event_location": False})


def test_split_free_fall_is_exact():
    """Before the touch, body 1's fall is the closed-form parabola (to rounding) and the first
    touch is where it reaches body 2's surface: no integration error in either."""
    sc = impact_env.load_scene("rig", {"initial.pre_contact_time": 5e-3})
    tr = impact_env.simulate(sc, t_end=4e-3, record_rate=1e4, plant_only=True)
    y0, tau = initial_state(sc)
    g = sc.plant.gravity
    t = tr.t
    np.testing.assert_allclose(tr.x1, y0[0] + y0[1] * t + 0.5 * g * t * t, rtol=0, atol=8 * EPS * abs(y0[0]))
    np.testing.assert_allclose(tr.v1, y0[1] + g * t, rtol=0, atol=8 * EPS * abs(y0[1]))
    tr2 = impact_env.simulate(sc, t_end=6e-3, record_rate=1e4, plant_only=True)
    assert abs(tr2.events[0, 0] - tau) <= 1e-15 + 64 * EPS * tau
