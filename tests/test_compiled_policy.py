"""Compiled policies (``impact_env.control.policy``): the numba ``act`` against the Python it
replaces.

* Classic laws: the compiled law against the baseline's float64 command (``Policy.command``,
  the float64 actions of :meth:`predict`), over 10^4 observations of real episodes, memory and
  all: within 1e-12 (the same operations in the same order; the bound leaves room for a libm
  ``pow`` that rounds differently in numba and numpy).
* Networks: the compiled MLP against ``model.predict(obs, deterministic=True)`` over 10^4
  observations (of episodes and random ones): within 1e-5.  torch computes in float32 (unit
  roundoff 6e-8); through two 64-wide layers the error grows to about sqrt(64) * 64 * 6e-8 =
  3e-5 in the worst case of |weights| of order one, typically far less; 1e-5 is the issue's bound
  and what the measured 1e-7 leaves room for.
* Files round-trip bitwise; ONNX (onnxruntime) agrees with ``act`` to float32's 1e-5.
"""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from baselines import make_policy
from impact_env.control import laws
from impact_env.control.policy import CompiledPolicy, act_batch
from impact_env.env.vector import ImpactCatchVectorEnv
from impact_env.policy.export import export_policy, write_onnx
from impact_env.scene import load_scene

RIG = load_scene("rig")
MODEL = "ppo:agents/models/ppo_rig/model.zip"


def episodes_obs(observation: str, driver: str, n_envs: int = 8, steps: int = 1250, seed: int = 3):
    """Observations (float32[steps, n_envs, size]) and episode starts of rig drops driven by
    ``driver`` (a baseline; None: uniform random commands), autoreset on."""
    venv = ImpactCatchVectorEnv(n_envs, RIG, autoreset_mode=AutoresetMode.SAME_STEP, observation=observation,
                                horizon=0.06)
    pol = make_policy(driver, RIG) if driver else None
    rng = np.random.default_rng(seed)
    obs, _ = venv.reset(seed=seed)
    starts = np.ones(n_envs, dtype=bool)
    out, st = [], []
    for _ in range(steps):
        out.append(obs.copy())
        st.append(starts.copy())
        a = pol.predict(obs, episode_start=starts)[0] if pol else rng.uniform(-1, 1, (n_envs, 1))
        obs, _r, te, tr, _i = venv.step(a)
        starts = te | tr
    return np.array(out), np.array(st)


@pytest.mark.parametrize("law, observation", [*((law.name, law.observation) for law in laws.REGISTRY),
                                              ("pd-penetration:kp=1e5,kd=900,dref=1e-5", "sensors")])
def test_compiled_law_equals_the_baseline(law, observation):
    obs, starts = episodes_obs(observation, "pd-penetration" if observation == "sensors" else "thesis-ideal")
    base = make_policy(law, RIG)
    pi, pf, m = base.compiled().arrays()
    mem = np.zeros((obs.shape[1], m))
    state = None
    worst = 0.0
    for k in range(obs.shape[0]):
        mem[starts[k]] = 0.0
        want, state = base.command(obs[k], state, starts[k])
        got = act_batch(pi, pf, obs[k], mem, np.empty(obs.shape[1]))
        worst = max(worst, float(np.max(np.abs(got - want))))
    assert obs.shape[0] * obs.shape[1] >= 10_000
    assert worst <= 1e-12, worst


def test_a_compiled_law_reads_its_channels_by_name():
    """pd-penetration on the 'both' layout (sensors, then the true state) acts as on 'sensors'."""
    obs, starts = episodes_obs("both", None, n_envs=2, steps=300)
    base = make_policy("pd-penetration", RIG)
    on_both = CompiledPolicy.from_law(base.name, base.params, base.law_constants(), RIG, "both")
    on_sensors = base.compiled()
    outs = []
    for comp, cols in ((on_both, slice(None)), (on_sensors, slice(0, 4))):
        pi, pf, m = comp.arrays()
        mem = np.zeros((2, m))
        u = []
        for k in range(obs.shape[0]):
            mem[starts[k]] = 0.0
            u.append(act_batch(pi, pf, np.ascontiguousarray(obs[k][:, cols]), mem, np.empty(2)))
        outs.append(np.array(u))
    assert np.array_equal(outs[0], outs[1]) and np.abs(outs[0]).max() > 0.1


def test_compiled_ppo_equals_sb3_predict():
    pol = make_policy(MODEL, RIG)
    comp = export_policy(MODEL, RIG)
    obs, _ = episodes_obs("sensors", "pd-penetration", steps=1000)
    rng = np.random.default_rng(0)
    x = np.concatenate([obs.reshape(-1, obs.shape[-1]), rng.normal(0, 3, (2000, obs.shape[-1]))])
    x = x.astype(np.float32)
    want, _ = pol.model.predict(x, deterministic=True)
    pi, pf, m = comp.arrays()
    got = act_batch(pi, pf, x, np.zeros((len(x), m)), np.empty(len(x)))
    assert len(x) >= 10_000
    np.testing.assert_allclose(got, want[:, 0], rtol=0, atol=1e-5)


@pytest.mark.parametrize("algo", ["sac", "ppo-sde-squash", "td3"])
def test_compiled_networks_of_other_algorithms(algo, tmp_path):
    """SAC (tanh-squashed, ReLU), PPO with gSDE and squash_output, TD3 (actor ends in tanh):
    untrained networks of the shape agents.train makes, saved, loaded and exported."""
    import stable_baselines3 as sb3

    from impact_env.env.sb3_vecenv import make_sb3_vec_env

    venv = make_sb3_vec_env("rig", num_envs=1, history=2)
    if algo == "sac":
        model = sb3.SAC("MlpPolicy", venv, policy_kwargs={"net_arch": [16, 16]}, seed=1, device="cpu")
    elif algo == "td3":
        model = sb3.TD3("MlpPolicy", venv, policy_kwargs={"net_arch": [16, 16]}, seed=1, device="cpu")
    else:
        model = sb3.PPO("MlpPolicy", venv, use_sde=True, seed=1, device="cpu",
                        policy_kwargs={"net_arch": [16], "squash_output": True})
    path = tmp_path / "m.zip"
    model.save(path)
    spec = f"{algo.split('-')[0]}:{path}:observation=sensors,history=2,hold_ticks=1,residual=none"
    comp = export_policy(spec, RIG)
    x = np.random.default_rng(2).normal(0, 2, (10_000, comp.layout.size)).astype(np.float32)
    want, _ = make_policy(spec, RIG).model.predict(x, deterministic=True)
    pi, pf, m = comp.arrays()
    got = act_batch(pi, pf, x, np.zeros((len(x), m)), np.empty(len(x)))
    np.testing.assert_allclose(got, want[:, 0], rtol=0, atol=1e-5)


def test_policy_file_round_trip_is_bitwise(tmp_path):
    for spec in (MODEL, "thesis-rig:h01=1.8e6"):
        comp = export_policy(spec, RIG)
        path = comp.save(tmp_path / "p.policy.json")
        again = CompiledPolicy.load(path)
        for a, b in zip(comp.arrays(), again.arrays(), strict=True):
            assert np.array_equal(a, b)
        assert again.sha256() == comp.sha256()
        make_policy(f"compiled:{path}", RIG)  # joins compare by spec


def test_onnx_export_matches_act(tmp_path):
    import onnxruntime as ort

    comp = export_policy(MODEL, RIG)
    path = write_onnx(comp, tmp_path / "p.onnx")
    x = np.random.default_rng(4).normal(0, 2, (5000, comp.layout.size)).astype(np.float32)
    (got,) = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(None, {"obs": x})
    pi, pf, m = comp.arrays()
    want = act_batch(pi, pf, x, np.zeros((len(x), m)), np.empty(len(x)))
    np.testing.assert_allclose(got[:, 0], want, rtol=0, atol=1e-5)
    with pytest.raises(ValueError, match="only MLP policies"):
        write_onnx(export_policy("pd-penetration", RIG), tmp_path / "law.onnx")


def test_bad_policy_files_are_refused(tmp_path):
    comp = export_policy("pd-penetration", RIG)
    d = comp.to_dict()
    p = tmp_path / "bad.json"
    p.write_text("{not json")
    with pytest.raises(ValueError, match="not JSON"):
        CompiledPolicy.load(p)
    with pytest.raises(ValueError, match="not found"):
        CompiledPolicy.load(tmp_path / "missing.json")
    with pytest.raises(ValueError, match="version"):
        CompiledPolicy.from_dict({**d, "version": 99})
    with pytest.raises(ValueError, match="reads x1"):
        CompiledPolicy.from_dict({**d, "law": {**d["law"], "name": "thesis-ideal"}})
    other = load_scene("rig", {"plant.c": 3e6})
    with pytest.raises(ValueError, match="scales"):
        comp.check_scene(other)
    with pytest.raises(ValueError, match="one value per parameter"):
        make_policy("pd-penetration", RIG).__class__(RIG, kp=np.array([1e5, 2e5])).compiled()


@pytest.mark.parametrize("spec", [MODEL, "thesis-rig"])
def test_compiled_rollout_equals_the_python_loop(spec):
    """A compiled policy inside the compiled loop gives the numbers its predict() gives from
    Python, bitwise: same act, same simulator step, same metrics kernel."""
    from impact_env.eval.rollout import rollout

    comp = export_policy(spec, RIG)
    a = rollout(RIG, comp, [11, 12, 13], horizon=0.05, trace_rate=2e3)
    b = rollout(RIG, comp, [11, 12, 13], horizon=0.05, trace_rate=2e3, compiled=False)
    for key in a.metrics:
        np.testing.assert_array_equal(a.metrics[key], b.metrics[key], err_msg=key)
    for key in a.traces:
        np.testing.assert_array_equal(a.traces[key], b.traces[key], err_msg=key)
    assert a.metrics["peak_force_N"].max() > 1.0


def test_compiled_rollout_reports_a_non_finite_action():
    from impact_env.eval.rollout import rollout

    comp = export_policy("pd-penetration", RIG)
    pi, pf, m = comp.arrays()
    pf[0] = 0.0  # command scale 0: f / 0 is not finite once the law acts
    r = rollout(RIG, comp, [1, 2], horizon=0.02)
    assert {f["episode"] for f in r.failures} == {0, 1}
    assert all(f["error"] == "non-finite action" for f in r.failures)
    assert np.isnan(r.metrics["energy_integral_ms"]).all()
