"""agents.train: a tiny PPO run is saved, loads through the policy registry and runs in compare."""

import json

import pytest

from agents.train import train
from baselines import make_policy
from impact_env.eval.compare import compare

pytestmark = pytest.mark.training

HORIZON = 0.005  # s: 50 control periods on rig, so that episodes end during the tiny run


def test_ppo_trains_saves_and_joins_the_comparison(tmp_path):
    out = tmp_path / "ppo"
    result = train("ppo", "rig", steps=256, envs=4, seed=3, out=out, observation="sensors", history=2,
                   env_kwargs={"horizon": HORIZON},
                   hyperparameters={"n_steps": 32, "batch_size": 64, "n_epochs": 1, "net_arch": [8]})
    assert result.steps >= 256 and result.episodes >= 4  # 4 envs x 64+ steps of 50-step episodes
    meta = json.loads((out / "model.json").read_text())
    assert (meta["algo"], meta["observation"], meta["history"], meta["scene"], meta["seed"]) == \
        ("ppo", "sensors", 2, "rig", 3)
    assert meta["steps"] == result.steps and meta["wall_time_s"] > 0

    spec = f"ppo:{out / 'model.zip'}"
    policy = make_policy(spec, "rig")  # observation and history come from model.json
    assert (policy.observation, policy.history) == ("sensors", 2)
    runs = compare("rig", ["passive", spec], episodes=2, seed=1000, horizon=HORIZON, workers=1,
                   progress=False)
    s = runs[spec].summary
    assert s["episodes"] == 2 and s["failed_episodes"] == 0
    assert s["peak_demand_N"] <= 200.0 + 1e-9  # actions clipped to the command scale


def test_bad_arguments_are_refused(tmp_path):
    with pytest.raises(ValueError, match="algo"):
        train("dqn", "rig", steps=10, out=tmp_path)
    with pytest.raises(ValueError, match="steps"):
        train("ppo", "rig", steps=0, out=tmp_path)
    with pytest.raises(ValueError, match="hyperparameter"):
        train("ppo", "rig", steps=10, out=tmp_path, hyperparameters={"n_step": 8})
    with pytest.raises(ValueError, match="observation"):
        train("ppo", "rig", steps=10, out=tmp_path, observation="camera")
