"""The env's learnability options: ``hold_ticks`` (a policy rate below the control rate) and
``residual`` (the action adds to a classic law evaluated every tick), against the plain env
stepped tick by tick."""

from __future__ import annotations

import numpy as np
import pytest

from baselines import make_policy
from impact_env.control.policy import act_batch
from impact_env.env.catch_env import ImpactCatchEnv
from impact_env.scene import load_scene

RIG = load_scene("rig")


def test_hold_ticks_equals_the_action_held_tick_by_tick():
    """One step of hold_ticks = 4 is four steps of the plain env under the same action: the same
    observation bitwise (the sensor noise stream does not depend on the hold), the reward the sum
    of the four (to rounding: the sum is taken in another order)."""
    held = ImpactCatchEnv(RIG, hold_ticks=4, horizon=0.04)
    plain = ImpactCatchEnv(RIG, horizon=0.04)
    o4, _ = held.reset(seed=5)
    o1, _ = plain.reset(seed=5)
    assert np.array_equal(o4, o1)
    rng = np.random.default_rng(1)
    for _ in range(100):
        a = rng.uniform(-1, 1, 1).astype(np.float32)
        o4, r4, te4, tr4, i4 = held.step(a)
        r1 = 0.0
        for _ in range(4):
            o1, r, te1, tr1, i1 = plain.step(a)
            r1 += r
        assert np.array_equal(o4, o1)
        assert r4 == pytest.approx(r1, rel=1e-13, abs=1e-15)
        assert i4["t"] == i1["t"] and i4["force_applied"] == i1["force_applied"]
        if te4 or tr4:
            break
    assert tr4 and tr1  # 0.04 s = 100 steps of 4 ticks


def test_hold_ticks_is_validated():
    for bad in (0, 1.5, True, -3):
        with pytest.raises(ValueError, match="hold_ticks"):
            ImpactCatchEnv(RIG, hold_ticks=bad)


@pytest.mark.parametrize("hold", [1, 3])
def test_residual_adds_the_action_to_the_law_every_tick(hold):
    """residual='pd-penetration': each tick's command is clip(action + the compiled law on that
    tick's observation); the same as the plain env driven tick by tick from outside."""
    res = ImpactCatchEnv(RIG, residual="pd-penetration", hold_ticks=hold, horizon=0.03)
    plain = ImpactCatchEnv(RIG, horizon=0.03)
    law = make_policy("pd-penetration", RIG).compiled()
    pi, pf, m = law.arrays()
    mem = np.zeros((1, m))
    o_r, _ = res.reset(seed=8)
    o_p, _ = plain.reset(seed=8)
    rng = np.random.default_rng(2)
    peak = 0.0
    for _ in range(300 // hold):
        a = rng.uniform(-0.2, 0.2, 1).astype(np.float32)
        o_r, *_rest, info_r = res.step(a)
        for _ in range(hold):
            u = float(np.clip(np.float64(a[0]) + act_batch(pi, pf, o_p[None, :], mem, np.empty(1))[0], -1, 1))
            o_p, *_r, info_p = plain.step(np.array([u]))
        assert np.array_equal(o_r, o_p)
        assert info_r["force_demand"] == info_p["force_demand"]
        peak = max(peak, abs(info_r["force_applied"]))
    assert peak > 50.0  # the law acted


def test_residual_is_validated():
    with pytest.raises(ValueError, match="residual"):
        ImpactCatchEnv(RIG, residual="")
    with pytest.raises(ValueError, match="unknown policy"):
        ImpactCatchEnv(RIG, residual="pd-penetrashun")


def test_every_env_takes_the_task_options_from_one_definition():
    """ImpactCatch-v0, the vector env and ImpactCatchRig-v0 take the task's options as
    TaskConfig's fields, listed nowhere else: a new option is one edit (TaskConfig) plus its test.
    An unknown option is refused naming the valid ones."""
    import inspect

    from impact_env.env.task import TASK_OPTIONS, TaskConfig
    from impact_env.env.vector import ImpactCatchVectorEnv
    from impact_env.rig.host import RigEnv

    assert TASK_OPTIONS == tuple(inspect.signature(TaskConfig).parameters)
    for cls in (ImpactCatchEnv, ImpactCatchVectorEnv, RigEnv):
        params = inspect.signature(cls.__init__).parameters
        assert not set(params) & set(TASK_OPTIONS), cls
        assert params["task"].kind is inspect.Parameter.VAR_KEYWORD, cls
    with pytest.raises(TypeError, match="'catch_treshold'.*catch_threshold"):
        ImpactCatchEnv(RIG, catch_treshold=0.1)
    with pytest.raises(TypeError, match="'catch_treshold'"):
        RigEnv("udp://127.0.0.1:9", catch_treshold=0.1)  # refused before any datagram is sent


def test_the_reward_effort_term():
    """``effort_weight`` w adds ``w (f_applied / command_scale)^2 * T / 1 ms`` to each tick's cost:
    two envs on the same seed and actions (the weight changes no state) differ in reward by
    exactly that, to rounding; the observations stay bitwise the same."""
    w = 0.3
    weighted = ImpactCatchEnv(RIG, effort_weight=w, horizon=0.02)
    plain = ImpactCatchEnv(RIG, horizon=0.02)
    ow, _ = weighted.reset(seed=2)
    op, _ = plain.reset(seed=2)
    rng = np.random.default_rng(4)
    scale = RIG.effects.command_scale
    step_weight = RIG.control_period / 1e-3
    pushed = 0
    for _ in range(200):
        a = rng.uniform(-1, 1, 1).astype(np.float32)
        ow, rw, tew, trw, iw = weighted.step(a)
        op, rp, tep, trp, ip = plain.step(a)
        assert np.array_equal(ow, op) and iw["force_applied"] == ip["force_applied"]
        u = iw["force_applied"] / scale
        assert rw - rp == pytest.approx(-w * u * u * step_weight, rel=1e-9, abs=1e-15)
        pushed += abs(u) > 0.1
        if tew or trw:
            break
    assert pushed > 10  # the term was exercised, not only its zero


def test_task_options_derive_the_evaluation_and_the_docs():
    """Each option's metadata says what follows from it: the kernel's parameters (the options it
    reads, by name), the values at evaluation (every reward penalty 0; agents.train applies
    them) and the env's documented option list."""
    from dataclasses import fields

    from impact_env.env.task import EVALUATION_OPTIONS, REWARD_FORMULA, TaskConfig, TaskParams

    cfg = TaskConfig()
    p = cfg.params(RIG)
    for f in fields(TaskConfig):
        assert (f.name in TaskParams._fields) == f.metadata["kernel"], f.name
        if f.metadata["kernel"]:
            assert getattr(p, f.name) == float(getattr(cfg, f.name))
        if f.name.endswith("_weight"):  # a reward penalty: off when an agent is evaluated, in the formula
            assert EVALUATION_OPTIONS[f.name] == 0.0, f.name
            assert f" {f.name} " in REWARD_FORMULA, f"task.REWARD_FORMULA lacks its term in {f.name}"
        assert f"``{f.name}=" in ImpactCatchEnv.__doc__, f.name
    assert EVALUATION_OPTIONS["terminate_on_catch"] is False
    assert REWARD_FORMULA in ImpactCatchEnv.__doc__
