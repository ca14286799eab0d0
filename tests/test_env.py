"""ImpactCatch-v0, its vector env and the SB3 adapter: conventions, determinism, semantics."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import impact_env
from impact_env.config import ConfigError
from impact_env.env.catch_env import ImpactCatchEnv
from impact_env.env.vector import ImpactCatchVectorEnv
from impact_env.plant.energy import catch_energy
from impact_env.scene.presets import PRESETS

FAST = {"control.rate": 1e4}  # ideal samples every 1 us by default: 10 kHz keeps tests short


def kwargs_for(scene):
    return {"scene": scene, "overrides": FAST if scene == "ideal" else None}


@pytest.mark.parametrize("scene", sorted(PRESETS))
def test_gymnasium_and_sb3_checkers_pass_without_warnings(scene):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = gym.make(impact_env.ENV_ID, **kwargs_for(scene))
        check_env(env.unwrapped)
        sb3_check_env(ImpactCatchEnv(**kwargs_for(scene)))


def test_registered_and_make_vec_returns_native_vector_env():
    assert impact_env.ENV_ID in gym.registry
    venv = gym.make_vec(impact_env.ENV_ID, num_envs=3, vectorization_mode="vector_entry_point", scene="rig")
    assert isinstance(venv.unwrapped if hasattr(venv, "unwrapped") else venv, ImpactCatchVectorEnv)
    assert venv.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    obs, info = venv.reset(seed=1)
    assert obs.shape == (3, 4) and obs.dtype == np.float32


def rollout(env, seed, n, action_seed=7):
    rng = np.random.default_rng(action_seed)
    obs, info = env.reset(seed=seed)
    out = [obs]
    for _ in range(n):
        obs, r, te, tr, info = env.step(rng.uniform(-1, 1, 1).astype(np.float32))
        out.append(np.append(obs, [r, te, tr]))
        if te or tr:
            break
    return out


def test_same_seed_same_episode_bitwise_and_different_seed_different_noise():
    a = rollout(ImpactCatchEnv("rig"), 3, 300)
    b = rollout(ImpactCatchEnv("rig"), 3, 300)
    c = rollout(ImpactCatchEnv("rig"), 4, 300)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True)) and len(a) == len(b)
    assert not all(np.array_equal(x, y) for x, y in zip(a[1:], c[1:], strict=False))


def test_step_types_and_info_contents():
    env = ImpactCatchEnv("rig")
    obs, info = env.reset(seed=0)
    obs, r, te, tr, info = env.step(np.array([0.5], np.float32))
    assert type(r) is float and type(te) is bool and type(tr) is bool
    assert env.observation_space.contains(obs)
    for key in ("catch_energy", "catch_energy_ratio", "impact_energy", "impact_speed", "contact",
                "contact_force", "force_demand", "force_applied", "saturated", "detected", "state",
                "diverged", "caught", "t", "t_touch"):
        assert key in info
    assert info["force_demand"] == pytest.approx(0.5 * env.scene.effects.command_scale)
    assert info["t"] == pytest.approx(env.scene.control_period)
    assert info["t_touch"] == pytest.approx(env.scene.initial.pre_contact_time)


def test_reward_is_minus_the_normalised_catch_energy_from_an_independent_formula():
    env = ImpactCatchEnv("rig")
    _, info0 = env.reset(seed=2)
    drawn = env.scene.with_draws(env.unwrapped.task.sim.drawn[0])  # rig draws m1 and the drop height
    p = drawn.plant
    v = info0["impact_speed"]
    assert v == pytest.approx(drawn.impact_speed, rel=1e-12) and v != env.scene.impact_speed
    # at the first touch the catch energy is the kinetic energy plus the resting offset
    ds = p.static_penetration
    e_touch = 0.5 * p.m1 * v**2 + p.m1 * p.gravity * 0.6 * ds
    assert info0["impact_energy"] == pytest.approx(e_touch, rel=1e-9)
    w = env.scene.control_period / env.reward_time_unit
    for _ in range(200):
        _, r, _, _, info = env.step(np.array([-0.2], np.float32))
        x1, v1, x2, _ = info["state"]
        e = float(catch_energy(x1, v1, x2, p.m1, p.c, p.gravity))
        assert info["catch_energy"] == pytest.approx(e, rel=1e-12, abs=1e-15)
        assert r == pytest.approx(-e / info0["impact_energy"] * w, rel=1e-12)


def test_passive_rig_drop_is_caught_near_the_calibrated_decay_time():
    env = ImpactCatchEnv("rig", overrides={"randomize.m1": [], "randomize.drop_height": []})  # nominal
    env.reset(seed=0)
    ret = 0.0
    while True:
        _, r, te, tr, info = env.step(np.zeros(1, np.float32))
        ret += r
        if te or tr:
            break
    assert te and info["caught"] and not info["diverged"]
    # below 1 % for good from about 0.34 s (impact-env drop --scene rig), plus the 10 ms hold
    assert 0.30 < info["t"] < 0.40
    assert -100 < ret < -20


def test_truncation_at_the_horizon():
    env = ImpactCatchEnv("rig", horizon=0.01)
    env.reset(seed=0)
    for k in range(100):
        _, _, te, tr, _ = env.step(np.zeros(1, np.float32))
        assert not te
        assert tr == (k == 99)


def test_divergence_ends_the_episode_with_finite_observations():
    """A step just inside RK4's limit for the drop (omega dt = 2.6 at 1 mm bodies on a stiff pad,
    the resolution check off), then 1e7 N pressing the pad far deeper: RK4 blows up within the
    first control period, and the env reports it with finite observations."""
    env = ImpactCatchEnv("ideal", overrides={"effects.command_scale": 1e7, "control.rate": 1e4,
                                             "plant.m1": 1e-3, "plant.m2": 1e-3, "plant.c": 1e11,
                                             "integrator.dt": 4e-6, "integrator.min_steps_per_contact": 0})
    obs0, _ = env.reset(seed=0)
    obs, r, te, tr, info = env.step(np.ones(1, np.float32))
    assert info["diverged"] and te and not tr
    assert np.all(np.isfinite(obs)) and np.isfinite(r)
    assert np.all(np.isfinite(info["state"]))


def test_bad_actions_and_bad_arguments():
    env = ImpactCatchEnv("rig")
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(1))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([np.nan]))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3))
    _, _, _, _, info = env.step(np.array([5.0]))  # documented clip
    assert info["force_demand"] == env.scene.effects.command_scale
    strict = ImpactCatchEnv("rig", action_bounds="raise")
    strict.reset(seed=0)
    with pytest.raises(ValueError, match=r"outside \[-1, 1\]"):
        strict.step(np.array([1.5]))
    with pytest.raises(ConfigError, match="presets"):
        ImpactCatchEnv("rigg")
    with pytest.raises(ConfigError, match="did you mean .m1."):
        ImpactCatchEnv("rig", overrides={"plant.mass1": 0.1})
    with pytest.raises(ConfigError, match="observation"):
        ImpactCatchEnv("rig", observation="everything")
    with pytest.raises(ConfigError, match="catch_threshold"):
        ImpactCatchEnv("rig", catch_threshold=0.0)


def test_privileged_observation_is_the_scaled_true_state_and_history_stacks():
    env = ImpactCatchEnv("rig", observation="privileged")
    obs, info = env.reset(seed=0)
    scales = env.layout.scales
    np.testing.assert_array_equal(obs, (info["state"] / scales).astype(np.float32))
    hist = ImpactCatchEnv("rig", history=3)
    obs, _ = hist.reset(seed=0)
    f = hist.layout.frame_size
    assert obs.shape == (3 * f + 3,) and not obs[f:].any()
    frames = [obs[:f]]
    for a in (0.1, -0.3):
        obs, *_ = hist.step(np.array([a], np.float32))
        frames.insert(0, obs[:f])
    np.testing.assert_array_equal(obs[:3 * f], np.concatenate(frames))
    np.testing.assert_allclose(obs[3 * f:], [-0.3, 0.1, 0.0], rtol=1e-6)


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_vector_env_equals_single_envs_step_by_step_through_autoresets(mode):
    n, seed, horizon = 3, 10, 0.004  # 40 steps per episode: several autoresets in 100 steps
    venv = ImpactCatchVectorEnv(n, "rig", horizon=horizon, autoreset_mode=mode)
    singles = [ImpactCatchEnv("rig", horizon=horizon) for _ in range(n)]
    vobs, _ = venv.reset(seed=seed)
    sobs = [e.reset(seed=seed + i)[0] for i, e in enumerate(singles)]
    np.testing.assert_array_equal(vobs, np.stack(sobs))
    rng = np.random.default_rng(0)
    pending = [False] * n
    for _ in range(100):
        actions = rng.uniform(-1, 1, (n, 1)).astype(np.float32)
        vobs, vr, vte, vtr, vinfo = venv.step(actions)
        for i, e in enumerate(singles):
            if mode == AutoresetMode.NEXT_STEP and pending[i]:
                o, _ = e.reset()
                assert vr[i] == 0.0 and not vte[i] and not vtr[i]
                pending[i] = False
            else:
                o, r, te, tr, _ = e.step(actions[i])
                assert (vr[i], vte[i], vtr[i]) == (r, te, tr)
                if te or tr:
                    if mode == AutoresetMode.SAME_STEP:
                        np.testing.assert_array_equal(vinfo["final_obs"][i], o)
                        o, _ = e.reset()
                    else:
                        pending[i] = True
            np.testing.assert_array_equal(vobs[i], o)


def test_vector_env_disabled_autoreset_and_reset_mask():
    venv = ImpactCatchVectorEnv(2, "rig", horizon=0.002, autoreset_mode=AutoresetMode.DISABLED)
    venv.reset(seed=0)
    for _ in range(20):
        _, _, _, tr, info = venv.step(np.zeros((2, 1), np.float32))
    assert tr.all() and np.all(info["t"] == pytest.approx(0.002))
    obs, info = venv.reset(options={"reset_mask": np.array([True, False])})
    assert info["t"][0] == 0.0 and info["t"][1] == pytest.approx(0.002)


def test_vector_env_state_for_4096_rig_envs_fits_in_100_MB():
    venv = ImpactCatchVectorEnv(4096, "rig")
    total = 0
    for obj in (venv.task, venv.task.sim):
        for value in vars(obj).values():
            if isinstance(value, np.ndarray):
                total += value.nbytes
    assert total < 100e6, total


def test_render_rgb_array_shows_the_bodies_moving():
    env = ImpactCatchEnv("rig", render_mode="rgb_array")
    env.reset(seed=0)
    f0 = env.render()
    assert f0.dtype == np.uint8 and f0.ndim == 3 and f0.shape[2] == 3
    for _ in range(20):
        env.step(np.zeros(1, np.float32))
    assert not np.array_equal(f0, env.render())


def test_ppo_and_sac_train_on_the_sb3_adapter():
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.vec_env import VecMonitor

    from impact_env.env.sb3_vecenv import SB3VecEnv, make_sb3_vec_env

    env = make_sb3_vec_env("rig", num_envs=4, horizon=0.003)
    assert isinstance(env, VecMonitor) and isinstance(env.venv, SB3VecEnv)  # episode stats for SB3's logger
    assert isinstance(make_sb3_vec_env("rig", num_envs=1, monitor=False), SB3VecEnv)
    ppo = PPO("MlpPolicy", env, n_steps=32, batch_size=64, n_epochs=1, policy_kwargs={"net_arch": [16]},
              seed=0, device="cpu")
    ppo.learn(256)
    assert ppo.num_timesteps >= 256
    assert len(ppo.ep_info_buffer) > 0  # the monitor's episode returns reached SB3
    sac = SAC("MlpPolicy", make_sb3_vec_env("rig", num_envs=2, horizon=0.003), learning_starts=32,
              batch_size=32, policy_kwargs={"net_arch": [16]}, seed=0, device="cpu")
    sac.learn(96)
    assert sac.num_timesteps >= 96
    obs = env.reset()
    action, _ = ppo.predict(obs, deterministic=True)
    assert action.shape == (4, 1)


def test_render_human_draws_into_a_matplotlib_window():
    import matplotlib

    matplotlib.use("Agg")  # headless: the window is an off-screen figure
    env = ImpactCatchEnv("rig", render_mode="human")
    env.reset(seed=0)
    assert env.render() is None
    env.step(np.zeros(1, np.float32))
    env.render()
    fig = env._viewer[0]
    env.close()
    import matplotlib.pyplot as plt

    assert not plt.fignum_exists(fig.number)


def test_same_step_infos_describe_the_new_episode_and_final_info_the_old():
    venv = ImpactCatchVectorEnv(2, "rig", horizon=0.001, autoreset_mode=AutoresetMode.SAME_STEP)
    venv.reset(seed=0)
    for _ in range(10):
        obs, _, _, tr, info = venv.step(np.zeros((2, 1), np.float32))
    assert tr.all()
    np.testing.assert_array_equal(info["t"], [0.0, 0.0])
    np.testing.assert_allclose(info["final_info"]["t"], [0.001, 0.001])
    assert info["_final_obs"].all() and info["final_obs"][0].shape == obs[0].shape


def test_rig_episodes_are_different_drops():
    """The main job benchmarks drops that differ: rig draws body 1's mass (0.08-0.12 kg) and the
    drop height (30-70 mm) per episode, so the impact speed and energy differ between seeds,
    while an episode's seed still fixes its drop."""
    env = ImpactCatchEnv("rig")
    speeds = []
    for seed in range(6):
        _, info = env.reset(seed=seed)
        speeds.append(info["impact_speed"])
    assert len(set(speeds)) == 6 and min(speeds) >= math.sqrt(2 * 9.81 * 0.03) - 1e-12
    assert max(speeds) <= math.sqrt(2 * 9.81 * 0.07) + 1e-12
    _, again = env.reset(seed=3)
    assert again["impact_speed"] == speeds[3]
