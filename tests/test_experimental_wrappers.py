"""agents.experimental_wrappers: hold_ticks, residual and chatter_weight, their documented
semantics checked against independent constructions (single envs in SB3's DummyVecEnv, the
classic law run by the comparison)."""

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

import impact_env  # noqa: F401  (registers ImpactCatch-v0)
from agents.experimental_wrappers import (
    HeldPolicy,
    HoldResidualVecEnv,
    HoldResidualWrapper,
    LearnabilityOptions,
)
from baselines import make_policy
from impact_env.config import ConfigError
from impact_env.env.sb3 import make_sb3_vec_env
from impact_env.eval.rollout import rollout
from impact_env.scene import load_scene

# 51 control periods: not a multiple of 4, so an episode ends in the middle of a hold
HORIZON = 0.0051


def _actions(rng, n, steps):
    # smooth-ish random actions with some beyond the bounds (the wrappers clip them)
    return np.clip(np.cumsum(rng.normal(0, 0.3, (steps, n)), axis=0), -1.3, 1.3).astype(np.float32)


@pytest.mark.parametrize("options", [dict(hold_ticks=4), dict(hold_ticks=4, residual="pd-penetration",
                                                              chatter_weight=0.05),
                                     dict(hold_ticks=1, residual="pd-penetration")])
def test_vector_wrapper_env_i_equals_single_wrapped_env_seeded_seed_plus_i(options):
    opt = LearnabilityOptions(**options)
    n, seed, steps = 3, 11, 160 // opt.hold_ticks  # 160 ticks: three episodes of 51 ticks each
    vec = HoldResidualVecEnv(make_sb3_vec_env("rig", num_envs=n, horizon=HORIZON), opt)
    ref = DummyVecEnv([lambda: HoldResidualWrapper(gym.make("ImpactCatch-v0", scene="rig", horizon=HORIZON),
                                                   **options) for _ in range(n)])
    vec.seed(seed)
    ref.seed(seed)
    np.testing.assert_array_equal(vec.reset(), ref.reset())
    acts = _actions(np.random.default_rng(0), n, steps)
    ends = 0
    for k in range(steps):
        o1, r1, d1, i1 = vec.step(acts[k][:, None])
        o2, r2, d2, i2 = ref.step(acts[k][:, None])
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(d1, d2)
        for i in np.nonzero(d1)[0]:
            ends += 1
            np.testing.assert_array_equal(i1[i]["terminal_observation"], i2[i]["terminal_observation"])
            assert i1[i]["TimeLimit.truncated"] == i2[i]["TimeLimit.truncated"]
            assert i1[i]["t"] == pytest.approx(i2[i]["t"], abs=0) == pytest.approx(HORIZON)
    assert ends >= 2 * n  # episodes did end inside holds (51 ticks = 12 holds of 4 + 3 ticks)
    if opt.hold_ticks == 4:
        assert vec.ticks == n * steps * 4 - ends * 1  # each episode's last hold is 3 ticks long


def test_hold_ticks_applies_the_same_command_k_times_and_sums_the_rewards():
    n, k = 2, 5
    vec = HoldResidualVecEnv(make_sb3_vec_env("rig", num_envs=n), LearnabilityOptions(hold_ticks=k))
    raw = make_sb3_vec_env("rig", num_envs=n)
    vec.seed(3)
    raw.seed(3)
    vec.reset()
    raw.reset()
    a = np.array([[0.3], [-0.7]], dtype=np.float32)
    o1, r1, _, _ = vec.step(a)
    total = np.zeros(n)
    for _ in range(k):
        o2, r, _, _ = raw.step(a)
        total += r  # float32 rewards of the plain adapter
    np.testing.assert_array_equal(o1, o2)
    np.testing.assert_allclose(r1, total, rtol=1e-6)
    assert vec.ticks == n * k


def test_residual_with_zero_action_is_the_law_itself_in_the_comparison_rollout():
    # a zero residual, held for 4 ticks, must reproduce pd-penetration exactly: the law runs
    # on every tick's observation with its own memory
    scene = load_scene("rig")

    class Zero:
        def predict(self, obs, deterministic=True):
            return np.zeros((len(obs), 1), dtype=np.float32), None

    seeds = [1000, 1001, 1002]
    held = HeldPolicy(Zero(), LearnabilityOptions(hold_ticks=4, residual="pd-penetration"), scene)
    a = rollout(scene, held, seeds, horizon=0.05, trace_rate=0)
    b = rollout(scene, make_policy("pd-penetration", scene), seeds, horizon=0.05, trace_rate=0)
    for key, v in b.metrics.items():
        np.testing.assert_array_equal(a.metrics[key], v, err_msg=key)


def test_held_policy_matches_the_vector_wrapper_episode():
    # the tick-level adapter (evaluation) and the wrapper (training) apply the same commands
    scene = load_scene("rig")
    opt = LearnabilityOptions(hold_ticks=3, residual="pd-penetration")

    class Affine:  # a deterministic "model" reading the observation
        def predict(self, obs, deterministic=True):
            return np.tanh(0.4 * obs[:, :1] - 0.2 * obs[:, 1:2]).astype(np.float32), None

    model = Affine()
    vec = HoldResidualVecEnv(make_sb3_vec_env("rig", num_envs=2, terminate_on_catch=False), opt)
    vec.seed(1000)
    obs = vec.reset()
    energy = []
    for _ in range(100):
        obs, _, _, _ = vec.step(model.predict(obs)[0])
        energy.append(vec.task.energy.copy())
    r = rollout(scene, HeldPolicy(model, opt, scene), [1000, 1001], horizon=300 * scene.control_period,
                trace_rate=1.0 / (3 * scene.control_period))
    traced = r.traces["catch_energy"][1:]  # every 3rd tick, i.e. after each policy step
    np.testing.assert_array_equal(traced, np.array(energy))


def test_chatter_penalty_is_the_total_variation_of_the_action():
    w = 0.5
    pen = HoldResidualVecEnv(make_sb3_vec_env("rig", num_envs=1), LearnabilityOptions(2, None, w))
    ref = HoldResidualVecEnv(make_sb3_vec_env("rig", num_envs=1), LearnabilityOptions(2, None, 0.0))
    for v in (pen, ref):
        v.seed(5)
        v.reset()
    acts = [0.2, -0.4, -0.4, 0.9, 2.0]  # the last one is clipped to 1 first
    expected = [0.2, 0.6, 0.0, 1.3, 0.1]
    for a, e in zip(acts, expected, strict=True):
        _, r1, _, _ = pen.step(np.array([[a]], dtype=np.float32))
        _, r2, _, _ = ref.step(np.array([[a]], dtype=np.float32))
        assert float(r2[0] - r1[0]) == pytest.approx(w * e, rel=1e-5)


def test_bad_options_are_refused_naming_the_option():
    with pytest.raises(ConfigError, match="hold_ticks"):
        LearnabilityOptions(hold_ticks=0)
    with pytest.raises(ConfigError, match="chatter_weight"):
        LearnabilityOptions(chatter_weight=-1.0)
    with pytest.raises(ConfigError, match="unknown policy"):
        LearnabilityOptions(residual="pd-penetrat").make_law("rig")
    with pytest.raises(ConfigError, match="sensors"):
        HoldResidualVecEnv(make_sb3_vec_env("rig", num_envs=1, observation="privileged"),
                           LearnabilityOptions(residual="pd-penetration"))
    vec = HoldResidualVecEnv(make_sb3_vec_env("rig", num_envs=1), LearnabilityOptions(hold_ticks=2))
    vec.reset()
    with pytest.raises(ValueError, match="NaN"):
        vec.step(np.array([[np.nan]], dtype=np.float32))


def test_residual_law_reads_the_sensor_part_of_observation_both():
    # with observation "both" the law gets the sensor entries of the current frame: same commands
    # (so the same energy) as with the sensor observation
    out = []
    for observation in ("sensors", "both"):
        vec = HoldResidualVecEnv(make_sb3_vec_env("rig", num_envs=2, observation=observation),
                                 LearnabilityOptions(hold_ticks=2, residual="pd-penetration"))
        vec.seed(7)
        vec.reset()
        for _ in range(30):
            vec.step(np.full((2, 1), 0.05, dtype=np.float32))
        out.append(vec.task.energy.copy())
    np.testing.assert_array_equal(out[0], out[1])
