"""The shipped agents (agents/models/best: PPO on the sensors; agents/models/candidate: its
stronger-teacher successor; agents/models/sac: SAC's actor as a
plain sensor model, whose squashed output is bounded to +-0.25 by its action space): each one's
compiled policy file and ONNX graph are its SB3 model, and it joins ``impact-env compare`` as a
model spec and as a compiled policy, with its history, hold and residual law.

Tolerance 1e-5 on the network's command, as tests/test_compiled_policy.py derives it (torch's
float32 through two 64-wide layers against the float64 compiled MLP)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from impact_env.control.policy import CompiledPolicy
from impact_env.eval.compare import compare
from impact_env.policy.export import export_policy
from impact_env.policy.registry import make_policy
from impact_env.scene import load_scene

MODELS = Path(__file__).resolve().parents[1] / "agents" / "models"
# (folder, file stem); the candidate: docs/agents-stronger-teacher.md
AGENTS = [(MODELS / "best", "best"), (MODELS / "sac", "sac"), (MODELS / "candidate", "best")]


def _agent(folder: Path, stem: str):
    meta = json.loads((folder / "model.json").read_text())
    return meta, f"{meta['algo']}:{folder / 'model.zip'}", f"compiled:{folder / f'{stem}.policy.json'}"


def _observations(scene, meta, n=64, steps=150):
    """Observations of real episodes of the agent's env (hold, residual) under small random
    actions, and random ones around them."""
    from impact_env.env.vector import ImpactCatchVectorEnv

    kw = {k: v for k, v in meta["env_kwargs"].items() if k in ("observation", "history", "hold_ticks",
                                                                  "residual")}
    venv = ImpactCatchVectorEnv(n, scene, horizon=0.06, **kw)
    rng = np.random.default_rng(7)
    obs, _ = venv.reset(seed=2000)
    out = []
    for _ in range(steps):
        out.append(obs.copy())
        obs, *_ = venv.step(rng.uniform(-0.1, 0.1, (n, 1)))
    real = np.concatenate(out)
    return np.concatenate([real, (real * rng.uniform(0.5, 2.0, real.shape)).astype(np.float32)])


@pytest.mark.parametrize("folder, stem", AGENTS)
def test_the_shipped_files_are_there_and_say_what_the_agent_is(folder, stem):
    meta, model, _ = _agent(folder, stem)
    for name in ("model.zip", "model.json", f"{stem}.policy.json", f"{stem}.onnx"):
        assert (folder / name).is_file(), name
    pol = CompiledPolicy.load(folder / f"{stem}.policy.json")
    assert pol.hold_ticks == meta["env_kwargs"].get("hold_ticks", 1) == make_policy(model, "rig").hold_ticks
    assert (pol.residual_policy().law["name"] if pol.residual else None) == meta["env_kwargs"].get("residual")
    # the file is this model's export (not an older one)
    assert export_policy(model, meta["scene"]).to_dict()["mlp"] == pol.to_dict()["mlp"]


@pytest.mark.parametrize("folder, stem", AGENTS)
@pytest.mark.parametrize("scene", ["rig", "rig-randomized"])
def test_compiled_policy_and_onnx_match_the_sb3_model(scene, folder, stem):
    meta, model_spec, compiled = _agent(folder, stem)
    scene = load_scene(scene)
    model = make_policy(model_spec, scene)
    pol = make_policy(compiled, scene)  # checks the scene gives the observation it was made for
    obs = _observations(scene, meta)
    assert len(obs) >= 10_000
    want, _ = model.predict(obs, deterministic=True)
    got, _ = pol.predict(obs, episode_start=np.ones(len(obs), dtype=bool))
    assert np.max(np.abs(got.reshape(-1) - want.reshape(-1))) <= 1e-5
    import onnxruntime as ort

    sess = ort.InferenceSession(str(folder / f"{stem}.onnx"), providers=["CPUExecutionProvider"])
    onnx_out = sess.run(None, {"obs": obs.astype(np.float32)})[0]
    assert np.max(np.abs(onnx_out.reshape(-1) - got.reshape(-1))) <= 1e-5


@pytest.mark.parametrize("folder, stem", AGENTS)
def test_the_agent_runs_in_compare_as_model_and_as_compiled_policy(folder, stem):
    """Two drops, 50 ms: the model spec (Python loop, SB3's predict) and the compiled file
    (compiled loop) issue the same commands to float32 rounding, so their episodes agree."""
    _, model, compiled = _agent(folder, stem)
    runs = compare("rig", ["pd-penetration", model, compiled], episodes=2, seed=1000, horizon=0.05, workers=1,
                   progress=False)
    a, b = runs[model].metrics, runs[compiled].metrics
    assert runs[model].summary["failed_episodes"] == runs[compiled].summary["failed_episodes"] == 0
    np.testing.assert_allclose(a["energy_integral_ms"], b["energy_integral_ms"], rtol=1e-3)
    assert not np.allclose(a["energy_integral_ms"], runs["pd-penetration"].metrics["energy_integral_ms"])
