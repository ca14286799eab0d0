"""RL Zoo (rl_zoo3) trains on ImpactCatch-v0 with the project's YAML files, with a tiny budget,
and what it saves joins the evaluation.  PPO trains whole rollouts, and the YAML's is 64 000
policy steps (about a minute of this test's time), so the test shortens PPO's rollout to 5 steps
of the YAML's 64 envs with ``--hyperparams`` (one mini-batch of all 320); every other setting is
the file's."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

pytestmark = pytest.mark.training
pytest.importorskip("rl_zoo3")
ROOT = Path(__file__).resolve().parents[1]


def _eval_env_kwargs(conf: Path, **extra) -> list[str]:
    """``--eval-env-kwargs`` repeating the YAML's ``env_kwargs`` (rl_zoo3 2.9 builds its evaluation
    env without them otherwise; see docs/agents-zoo.md), plus ``extra``."""
    kwargs = {**yaml.safe_load(conf.read_text())["ImpactCatch-v0"].get("env_kwargs", {}), **extra}
    return [f"{k}:{v!r}" for k, v in kwargs.items()]


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_rl_zoo_trains_with_the_project_yaml_and_the_model_runs(tmp_path, algo):
    conf = ROOT / "agents" / "hyperparams" / f"{algo}.yml"
    logs = tmp_path / "logs"
    cmd = [sys.executable, "-m", "rl_zoo3.train", "--algo", algo, "--env", "ImpactCatch-v0",
           "--gym-packages", "impact_env", "--conf-file", str(conf), "-n", "300", "-f", str(logs),
           "--seed", "0", "--num-threads", "1", "--device", "cpu", "--eval-freq", "160",
           "--eval-episodes", "1",
           *(["--hyperparams", "n_steps:5", "batch_size:320"] if algo == "ppo" else []),
           # short evaluation episodes (5 ms) keep the test's many evaluations cheap
           "--eval-env-kwargs", *_eval_env_kwargs(conf, horizon=0.005)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           "MPLBACKEND": "Agg"}
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    run = logs / algo / "ImpactCatch-v0_1"
    model = run / "ImpactCatch-v0.zip"
    assert model.is_file() and (run / "best_model.zip").is_file()  # the evaluation callback ran
    saved = (run / "ImpactCatch-v0" / "config.yml").read_text()  # what RL Zoo used, for reproduction
    assert "env_kwargs" in saved and "scene: rig" in saved  # rig or rig-randomized

    # the model, with the YAML's hold and residual (its sidecar JSON), on two held-out drops of the
    # comparison, as the SB3 model and as its compiled export
    from agents.evaluate import evaluate
    from agents.run_config import read_conf, resolve

    cfg = resolve(algo, read_conf(conf))
    meta = {"algo": algo, "observation": cfg.observation, "history": cfg.history,
            "env_kwargs": cfg.env_kwargs}
    (run / "ImpactCatch-v0.json").write_text(json.dumps(meta))
    rows = {}
    for compiled in (False, True):
        runs, _ = evaluate(model, cfg.scene, baselines=("passive",), episodes=2, seed=1000, horizon=0.01,
                           label="agent", compiled=compiled)
        s = runs["agent"].summary
        assert s["episodes"] == 2 and s["failed_episodes"] == 0
        rows[compiled] = runs["agent"].metrics["energy_integral_ms"]
    np.testing.assert_allclose(rows[True], rows[False], rtol=1e-4)
