"""The up-front checks of a fixed step (impact_env/hardware/stability.py) and the graded zone after
a touch on a damped pad (impact_env/plant/integrators.py), with the restitution error that
scripts/steps_per_contact.py measures.

Oracles: the stability polynomial's real-axis limit (a root found by numpy), the closed-form
undamped limits, and simulations just inside and outside the limits the checks report.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from steps_per_contact import restitution_error

import impact_env
from impact_env.config import ConfigError
from impact_env.hardware import stability
from impact_env.scene import load_scene
from impact_env.sim.simulator import Simulator


def rk4_real_limit() -> float:
    """Where RK4's stability polynomial ``R(x) = 1 + x + x^2/2 + x^3/6 + x^4/24`` leaves the
    unit disc on the negative real axis: the real root below -1 of ``R(x) = 1`` (R stays
    positive there, so ``R = -1`` has no real root)."""
    roots = np.roots([1 / 24, 1 / 6, 1 / 2, 1, 0])  # R(x) - 1 = 0
    real = [r.real for r in roots if abs(r.imag) < 1e-12 and r.real < -1]
    return min(real)


def test_rk4_limits_match_the_stability_polynomial():
    """A pure decay (body 2's suspension damper alone) is stable up to h c2/m2 = 2.785 and an
    undamped oscillation up to omega h = 2 sqrt 2: the one-step matrices reproduce both."""
    x = rk4_real_limit()
    assert x == pytest.approx(-2.785293563405282, rel=1e-12)
    A = stability.linear_matrix(1.0, 1.0, 0.0, 0.0, 0.0, 1.0)  # v2' = -v2: lambda = -1
    assert stability.stable("rk4", -0.999 * x * A) and not stability.stable("rk4", -1.001 * x * A)
    w = 2.0
    A = stability.linear_matrix(1.0, 1.0, 0.0, 0.0, w * w, 0.0)  # body 2 on a spring: omega = 2
    lim = stability.STABILITY_LIMIT["rk4"] / w
    assert stability.stable("rk4", 0.999 * lim * A) and not stability.stable("rk4", 1.001 * lim * A)
    for method in ("symplectic-euler", "euler"):
        lim = stability.STABILITY_LIMIT[method] / w
        assert stability.stable(method, 0.999 * lim * A) and not stability.stable(method,
                                                                                  1.001 * lim * A), method


def test_the_issue_case_is_refused_naming_dt():
    """Pad restitution 0.01 at c = 1e13: the damped mode (h lambda = -2.8 at 1 us) is outside
    RK4's region; it used to return restitution -155.8 and 1e4 J from a 0.049 J drop."""
    scene = load_scene("rig", {"plant.restitution": 0.01, "plant.c": 1e13, "integrator.method": "rk4"})
    with pytest.raises(ConfigError, match=r"integrator.dt = 1e-06 s is beyond the stability limit"):
        impact_env.simulate(scene, plant_only=True)


@pytest.mark.parametrize("method", ["rk4", "symplectic-euler", "euler"])
def test_a_stiff_suspension_damper_is_refused_and_its_limit_runs(method):
    """Not the pad: body 2's damper alone (c2 = 2e6 N s/m on 1 kg, lambda = -2e6 1/s) makes a
    1.5 us step unstable for every method, however well the contact is resolved; the step the
    message proposes runs and stays finite and bounded."""
    ov = {"integrator.method": method, "integrator.dt": 1.5e-6, "control.rate": 1 / 1.5e-6,
          "plant.suspension_damping": 2e6, "plant.restitution": 0.8}
    with pytest.raises(ConfigError, match="stability limit") as err:
        impact_env.simulate("ideal", t_end=3e-3, overrides=ov)
    limit = float(str(err.value).split("needs dt <= ")[1].split(" s")[0])
    dt = 1e-6 * math.floor(limit / 1e-6 * 10) / 10 if limit > 1e-7 else limit
    ov.update({"integrator.dt": dt, "control.rate": 1 / dt})
    tr = impact_env.simulate("ideal", t_end=round(3e-3 / dt) * dt, overrides=ov)
    assert np.all(np.isfinite(tr.x2)) and np.max(np.abs(tr.v1)) < 1.5


def test_too_few_steps_per_contact_is_refused_with_the_dt_that_works():
    """c = 1e12 at dt = 10 us (about 2 steps a contact) gave e = 0.843 for a requested 1: it is
    refused, naming dt, the count and a step that would do; at that step e is within 1e-3."""
    with pytest.raises(ConfigError, match=r"integrator.dt = 1e-05 s resolves the impact .* with 1.96 steps"
                       ) as err:
        impact_env.simulate("ideal", overrides={"plant.c": 1e12, "integrator.dt": 1e-5})
    good = float(str(err.value).split("use integrator.dt <= ")[1].split(" s")[0])
    v = load_scene("ideal").impact_speed  # the same impact, without gravity during the contact
    scene = load_scene("ideal", {"plant.c": 1e12, "plant.gravity": 0.0, "initial.impact_speed": v,
                                 "integrator.dt": good, "initial.pre_contact_time": 1e-5})
    tr = impact_env.simulate(scene, t_end=round(6e-5 / good) * good)
    assert abs(tr.restitution() - 1.0) < 1e-3
    with pytest.raises(ConfigError, match="steps"):
        impact_env.simulate("ideal", overrides={"plant.m1": 1e-9, "plant.m2": 1e-8})


@pytest.mark.parametrize("e", [1.0, 0.8, 0.3])
def test_the_threshold_holds_what_it_says(e):
    """At the default threshold (8 steps per contact) RK4's restitution error is within 1e-3 at
    every touch phase (scripts/steps_per_contact.py measured <= 5.4e-4 over 7 phases), and at
    4 steps it is not, for the elastic pad (measured 1.2e-2): the threshold is where the
    measured curve crosses 1e-3, not a guess."""
    need = load_scene("ideal").integrator.min_steps_per_contact
    assert need == 8
    for phase in (0.1, 0.5, 0.9):
        assert restitution_error("rk4", need, e, phase) < 1e-3
    if e == 1.0:
        assert max(restitution_error("rk4", 4, e, ph) for ph in (0.1, 0.5, 0.9)) > 1e-3


def test_randomised_corners_are_checked():
    """A range of pads whose stiffest corner is under-resolved is refused, naming the corner."""
    with pytest.raises(ConfigError, match="corner of the randomize ranges"):
        Simulator(load_scene("rig", {"randomize.c": [1e6, 1e14], "integrator.method": "rk4"}), 1)


def test_damped_touch_converges_past_order_1_25():
    """The pad's d^0.25 factor is not smooth at the touch, which holds RK4 to order 1.25 in dt.
    Without the graded zone (GRADE_STEPS = 0 in integrators.py, scripts/steps_per_contact.py,
    worst of 7 touch phases) |e - 0.8| is 6.5e-6 at 1000 steps per contact and |e - 0.3|
    1.3e-5; with it 2.3e-9 and 4.7e-9.  The bound 1e-7, 65x below the ungraded error and far
    above rounding (1e-13), tells the two apart on any machine."""
    assert restitution_error("rk4", 1000, 0.8, 0.37) < 1e-7
    assert restitution_error("rk4", 1000, 0.3, 0.37) < 1e-7
