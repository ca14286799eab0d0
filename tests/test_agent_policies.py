"""agents.policies: the asymmetric actor-critic's actor reads only the sensor entries (the deployed
controller never sees the true state), its critic reads them all; it saves and loads."""

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO

from agents.policies import AsymmetricActorCriticPolicy, actor_indices
from impact_env.env.sb3_vecenv import make_sb3_vec_env


def test_actor_indices_pick_the_sensor_entries_of_every_frame_and_the_past_commands():
    # frames of 8 entries (4 sensors + 4 true-state), 3 frames, then 3 past commands
    assert actor_indices(8, 4, 1) == [0, 1, 2, 3]
    assert actor_indices(8, 4, 3) == [0, 1, 2, 3, 8, 9, 10, 11, 16, 17, 18, 19, 24, 25, 26]
    with pytest.raises(ValueError):
        actor_indices(4, 8, 1)


@pytest.mark.parametrize("history", [1, 3])
def test_actor_ignores_the_true_state_and_critic_reads_it(tmp_path, history):
    env = make_sb3_vec_env("rig", num_envs=2, observation="both", history=history)
    size = env.observation_space.shape[0]
    model = PPO(AsymmetricActorCriticPolicy, env, n_steps=8, batch_size=16, device="cpu", seed=0,
                policy_kwargs=dict(frame_size=8, actor_frame_size=4, history=history, log_std_init=-1.0,
                                   net_arch=dict(pi=[16], vf=[16])))
    with torch.no_grad():  # move the actor's output off its near-zero initialisation
        model.policy.action_net.weight.mul_(100.0)
    rng = np.random.default_rng(1)
    obs = rng.normal(size=(5, size)).astype(np.float32)
    privileged = np.ones(size, dtype=bool)
    privileged[actor_indices(8, 4, history)] = False
    moved = obs.copy()
    moved[:, privileged] += rng.normal(size=(5, int(privileged.sum()))).astype(np.float32) * 3
    a1, _ = model.predict(obs, deterministic=True)
    a2, _ = model.predict(moved, deterministic=True)
    np.testing.assert_array_equal(a1, a2)
    sensors_moved = obs.copy()
    sensors_moved[:, 0] += 3.0
    assert not np.array_equal(model.predict(sensors_moved, deterministic=True)[0], a1)
    with torch.no_grad():
        v1 = model.policy.predict_values(torch.as_tensor(obs))
        v2 = model.policy.predict_values(torch.as_tensor(moved))
    assert not torch.equal(v1, v2)
    model.save(tmp_path / "m.zip")
    again = PPO.load(tmp_path / "m.zip", device="cpu")
    np.testing.assert_array_equal(again.predict(obs, deterministic=True)[0], a1)


def test_sac_actor_starts_as_ppo_does_near_the_law_with_a_small_std(tmp_path):
    """init_sac_actor: the deterministic action starts near 0 (on a residual env: the law itself)
    and the exploration std is exp(log_std_init) in every state, where SB3's SAC (without gSDE)
    ignores log_std_init and starts with a std near 1 (about +-200 N); the model stays a plain
    SAC MlpPolicy that saves, loads and exports."""
    from stable_baselines3 import SAC

    from agents.policies import init_sac_actor
    from impact_env.policy.export import export_policy

    env = make_sb3_vec_env("rig", num_envs=2, hold_ticks=4, residual="pd-penetration")
    model = SAC("MlpPolicy", env, seed=0, device="cpu", policy_kwargs={"net_arch": [64, 64]})
    obs = torch.as_tensor(np.random.default_rng(0).normal(size=(256, env.observation_space.shape[0])),
                          dtype=torch.float32)
    with torch.no_grad():
        _, log_std_before, _ = model.policy.actor.get_action_dist_params(obs)
    assert float(log_std_before.exp().mean()) > 0.5  # SB3's own start: the reason for the init

    init_sac_actor(model, -2.5)
    with torch.no_grad():
        mean, log_std, _ = model.policy.actor.get_action_dist_params(obs)
    np.testing.assert_allclose(log_std.numpy(), -2.5)  # std exp(-2.5) = 0.08 (16 N) in every state
    # mean head orthogonal with gain 0.01 on 64 tanh/relu features of order 1: |mean| well below 0.1
    assert float(mean.abs().max()) < 0.1
    path = tmp_path / "sac.zip"
    model.save(path)
    loaded = SAC.load(path, device="cpu")
    assert type(loaded.policy).__name__ == "SACPolicy"
    a, _ = loaded.predict(obs.numpy()[:8], deterministic=True)
    np.testing.assert_allclose(a, np.tanh(mean.numpy()[:8]), atol=1e-6)
    (tmp_path / "sac.json").write_text('{"algo": "sac", "observation": "sensors", "history": 1, '
                                       '"hold_ticks": 4, "residual": "pd-penetration"}')
    assert export_policy(f"sac:{path}", "rig").mlp["output"] == "squash"
    with pytest.raises(ValueError, match="log_std_init"):
        init_sac_actor(model, float("nan"))


@pytest.mark.training
@pytest.mark.parametrize("algo, hp, policy", [
    ("sac", {"batch_size": 16, "net_arch": [8], "buffer_size": 1000}, "agents.policies.AsymmetricSACPolicy"),
    ("ppo", {"n_steps": 32, "batch_size": 64, "n_epochs": 1, "net_arch": [8]},
     "agents.policies.AsymmetricActorCriticPolicy")])
def test_an_asymmetric_model_becomes_the_sensor_controller_it_deploys(tmp_path, algo, hp, policy):
    """agents.train with an asymmetric policy (SAC's too: its critics read the true state, its
    actor the sensors), then sensor_actor_model: a plain MlpPolicy model on the sensor observation
    that acts exactly as the trained actor did, episode after episode, and exports as a sensor
    policy."""
    import json

    from stable_baselines3 import PPO, SAC

    from agents.policies import is_asymmetric, sensor_actor_model
    from agents.train import Tooling, make_config, run
    from impact_env.policy.export import export_policy

    out = tmp_path / algo
    cfg = make_config(algo, scene="rig", steps=64, envs=4, seed=1, observation="both", history=2,
                      env_kwargs={"horizon": 0.005}, hyperparameters=hp, policy=policy)
    run(cfg, out, Tooling(eval_every=None))
    dst = sensor_actor_model(out / "model.zip", out / "actor" / "model.zip")
    cls = PPO if algo == "ppo" else SAC
    trained, plain = cls.load(out / "model.zip", device="cpu"), cls.load(dst, device="cpu")
    assert is_asymmetric(trained) and not is_asymmetric(plain)
    meta = json.loads(dst.with_suffix(".json").read_text())
    assert (meta["observation"], meta["env_kwargs"]["observation"], meta["policy"]) == \
        ("sensors", "sensors", "MlpPolicy")
    kw = dict(monitor=False, history=2, hold_ticks=4, residual="pd-penetration")
    both = make_sb3_vec_env("rig", 3, observation="both", **kw)
    sensors = make_sb3_vec_env("rig", 3, observation="sensors", **kw)
    both.seed(5)
    sensors.seed(5)
    ob, os_ = both.reset(), sensors.reset()
    for _ in range(40):
        x, _ = trained.predict(ob, deterministic=True)
        y, _ = plain.predict(os_, deterministic=True)
        np.testing.assert_array_equal(x, y)
        ob, os_ = both.step(x)[0], sensors.step(y)[0]
    pol = export_policy(f"{algo}:{dst}", "rig")
    assert pol.observation == "sensors" and pol.history == 2
    with pytest.raises(ValueError, match="not an asymmetric model"):
        sensor_actor_model(dst, tmp_path / "again.zip")
