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
