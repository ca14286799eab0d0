"""A network behind the scene's extended Kalman filter (``estimator`` in a compiled policy,
``agents.distill --student-observation estimate``): the filter the compiled policy runs is, bit
for bit, the one the student was trained with; the network reads its estimate after the
observation row; the C export replays it bitwise in double and refuses float32; and what does not
fit is refused before any work."""

from __future__ import annotations

import json

import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from agents.estimate_input import StudentEstimator
from impact_env.config import ConfigError
from impact_env.control.estimation import features as estimate
from impact_env.control.estimation.layout import MEMORY as FILTER_MEMORY
from impact_env.control.estimation.layout import EkfMemory
from impact_env.control.observation import make_layout
from impact_env.control.policy import CompiledPolicy
from impact_env.env.vector import ImpactCatchVectorEnv
from impact_env.scene import load_scene

N_ENVS = 4
STEPS = 400  # 40 ms at 10 kHz: the fall, the touch and the first contact of rig's drops


def _network(scene, hidden: int = 16, seed: int = 0) -> list[dict]:
    """A random tanh network on the observation row and the filter's five estimates, its weights
    large enough that the command moves with the estimate (so the filter is told varied forces)."""
    n_in = make_layout(scene, "sensors", 1).size + estimate.N_FEATURES
    rng = np.random.default_rng(seed)
    return [{"weight": rng.normal(0.0, 1.0, (hidden, n_in)), "bias": rng.normal(0.0, 0.1, hidden),
             "activation": "tanh"},
            {"weight": rng.normal(0.0, 0.5, (1, hidden)), "bias": np.zeros(1), "activation": "identity"}]


def _policy(scene, **kw) -> CompiledPolicy:
    return CompiledPolicy.from_mlp("estimate-test", _network(scene), "clip", -1.0, 1.0, scene, "sensors", 1,
                                   estimator=True, **kw)


def _forward(layers: list[dict], x: np.ndarray) -> float:
    for ly in layers:
        x = np.asarray(ly["weight"]) @ x + np.asarray(ly["bias"])
        if ly["activation"] == "tanh":
            x = np.tanh(x)
    return float(x[0])


def test_the_compiled_filter_is_the_one_the_student_was_trained_with():
    """On the same observations and commands, the filter inside the compiled policy and the
    training side's (:class:`agents.estimate_input.StudentEstimator`) hold the same memory bit for
    bit, tick after tick; the command is the network (evaluated here by numpy) on ``[observation,
    estimate]``, so the estimate enters after the row, scaled as the docs say."""
    scene = load_scene("rig")
    pol = _policy(scene)
    layers = _network(scene)
    lay = pol.layout
    env = ImpactCatchVectorEnv(N_ENVS, "rig", None, autoreset_mode=AutoresetMode.DISABLED, observation="sensors",
                               history=1, terminate_on_catch=False)
    trained = StudentEstimator(scene, lay.names, lay.scales, N_ENVS)
    obs, _ = env.reset(seed=1000)
    memory = pol.new_memory(N_ENVS)
    filter_memory = memory[:, -FILTER_MEMORY:]
    commands = []
    for _ in range(STEPS):
        features = trained.read(obs)
        a, memory = pol.predict(obs, state=memory)
        trained.applied(a)
        assert np.array_equal(filter_memory, trained.memory)
        want = [_forward(layers, np.concatenate([obs[i].astype(np.float64), trained.out[i]]))
                for i in range(N_ENVS)]
        assert np.allclose(a[:, 0], np.clip(want, -1.0, 1.0), rtol=0, atol=1e-12)
        assert np.array_equal(features, trained.out.astype(np.float32))
        commands.append(a[:, 0].copy())
        obs, *_ = env.step_arrays(a, infos=False)
    env.close()
    commands = np.array(commands)
    assert np.ptp(commands) > 0.5  # the network did act, over a range of forces
    # the filter followed the drops: body 1's estimate within 5 % of the reference length of the
    # truth after the touch (tests/test_ekf.py bounds it properly), so the features are the state's
    x = trained.memory[:, EkfMemory.x:EkfMemory.x + 4]
    assert np.all(np.isfinite(x)) and np.all(trained.memory[:, EkfMemory.lost_count] == 0.0)


def test_off_its_model_the_filter_hands_over_to_pd_penetration():
    """On ``rig-randomized`` (drawn delays, pad and shaker gain: the filter's model is ``rig``'s)
    every drop hands over, latched, and from then on the policy's command is ``pd-penetration``'s
    compiled law's on the same observations, bit for bit (the fallback ran from the episode's
    start, as that law does); the count is the ticks since.  On ``rig`` the network drives."""
    from impact_env.policy.export import export_policy

    rig = load_scene("rig")
    pol = _policy(rig)
    pd = export_policy("pd-penetration", rig)
    # (the random network drives wildly: on rig its filter is consistent for the first 40 ms, the
    # fall, the touch and the first contact; on rig-randomized the last of these drops hands over
    # at 51 ms)
    for scene_name, hands_over, steps in (("rig-randomized", True, 600), ("rig", False, STEPS)):
        env = ImpactCatchVectorEnv(N_ENVS, scene_name, None, autoreset_mode=AutoresetMode.DISABLED,
                                   observation="sensors", history=1, terminate_on_catch=False)
        obs, _ = env.reset(seed=1000)
        memory, pd_memory = pol.new_memory(N_ENVS), pd.new_memory(N_ENVS)
        flag = memory.shape[1] - FILTER_MEMORY - 2
        since = np.zeros(N_ENVS)
        for _ in range(steps):
            a, memory = pol.predict(obs, state=memory)
            b, pd_memory = pd.predict(obs, state=pd_memory)
            on = memory[:, flag] > 0.0
            since += on
            assert np.array_equal(a[on], b[on])
            assert np.array_equal(memory[:, flag + 1], since)
            obs, *_ = env.step_arrays(a, infos=False)
        env.close()
        assert np.all(memory[:, flag] > 0.0) if hands_over else np.all(memory[:, flag] == 0.0)


def test_a_policy_file_keeps_its_filter_and_acts_the_same_after_loading(tmp_path):
    scene = load_scene("rig")
    pol = _policy(scene)
    path = pol.save(tmp_path / "p.policy.json")
    again = CompiledPolicy.load(path)
    assert again.sha256() == pol.sha256() and again.estimator == pol.estimator
    obs = np.random.default_rng(3).normal(0.0, 1.0, (5, pol.layout.size)).astype(np.float32)
    a, _ = pol.predict(obs, episode_start=np.ones(5, bool))
    b, _ = again.predict(obs, episode_start=np.ones(5, bool))
    assert np.array_equal(a, b)


def test_what_a_filter_before_the_network_cannot_do_is_refused():
    scene = load_scene("rig")
    with pytest.raises(ConfigError, match="hold_ticks 1"):
        _policy(scene, hold_ticks=4)
    d = _policy(scene).to_dict()
    d["estimator"] = {"filter": "ekf", "constants": {"c": 1.0}}
    with pytest.raises(ConfigError, match="every constant by name"):
        CompiledPolicy.from_dict(d)
    without = [{**_network(scene)[0], "weight": np.zeros((16, make_layout(scene, "sensors", 1).size))},
               _network(scene)[1]]
    with pytest.raises(ConfigError, match="the filter's 5 estimates"):
        CompiledPolicy.from_mlp("x", without, "clip", -1.0, 1.0, scene, "sensors", 1, estimator=True)
    from impact_env.policy.export import write_onnx

    with pytest.raises(ConfigError, match="Kalman filter before its network"):
        write_onnx(_policy(scene), "never.onnx")


@pytest.mark.slow
def test_the_c_export_replays_it_bitwise_in_double_and_has_no_float32_build(tmp_path):
    from impact_env.deploy import parity
    from impact_env.deploy.c_export import write_c

    scene = load_scene("rig")
    pol = _policy(scene)
    write_c(pol, scene, tmp_path / "c", force=True)
    src = (tmp_path / "c" / "impact_policy.c").read_text()
    assert "static void ekf_measure(" in src and "ekf_tick(EST_K, filter_mem, frame, u * COMMAND_SCALE_N);" in src
    cp = parity.CPolicy(parity.build_shared(tmp_path / "c", tmp_path / "lib.so", False), False)
    for scene_name in ("rig", "rig-randomized"):  # the network drives; the fallback takes over
        rec = parity.record(pol, load_scene(scene_name), 0, 2000)
        got = parity.replay(cp, rec)
        assert np.array_equal(got.command, rec.command), parity.compare_runs(rec, got)
        assert np.array_equal(got.status, rec.status)
        assert np.ptp(rec.command) > 0.5
    with pytest.raises(ConfigError, match="#error.*the filter before its network has no float32 build"):
        parity.build_shared(tmp_path / "c", tmp_path / "f32.so", float32=True)


def _float32_script():
    """scripts/c_float32_sources.py as a module."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "scripts" / "c_float32_sources.py"
    spec = importlib.util.spec_from_file_location("c_float32_sources", path)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    return script


def test_the_float32_diagnostic_builds_the_refused_build_with_its_filter_in_double(tmp_path):
    """scripts/c_float32_sources.py measures why the float32 build is refused by making it anyway:
    its edits of the generated C compile under -Werror with the refusal taken out, and with all
    but the front end in double the commands of the fall agree with the double build's within
    the float32 bound (the edits keep the policy's arithmetic; only the front end's precision
    moves)."""
    from impact_env.deploy import parity
    from impact_env.deploy.c_export import write_c

    script = _float32_script()
    scene = load_scene("rig")
    pol = _policy(scene)
    c_dir = tmp_path / "c"
    write_c(pol, scene, c_dir, force=True)
    source, header = c_dir / "impact_policy.c", c_dir / "impact_policy.h"
    source.write_text(script.mlp_in_double(script.filter_in_double(source.read_text())))
    header.write_text(script.header_for_filter_in_double(header.read_text()))
    assert "#error" not in header.read_text() and "double law_mem[" in header.read_text()
    cp = parity.CPolicy(parity.build_shared(c_dir, tmp_path / "f32.so", True), True)
    rec = parity.record(pol, scene, 0, 2000)
    got = parity.replay(cp, rec)
    touch = int(np.argmax(rec.detected > 0))
    assert touch > 10
    assert np.max(np.abs(got.command[:touch] - rec.command[:touch])) < parity.F32_BOUND
    assert np.ptp(rec.command[:touch]) > 1e-3  # the network drives in the fall: there is a command to compare


def test_the_float32_diagnostic_cuts_the_filters_loop_without_changing_the_double_build(tmp_path):
    """The script's last row tells the filter the double build's commands instead of its own.  That
    edit, in the double build, replays the target bit for bit (so the told command is the one the
    target's filter was told), and a build told commands other than its own departs from it (the
    told command reaches the filter: the edit is not a no-op)."""
    from impact_env.deploy import parity
    from impact_env.deploy.c_export import write_c

    script = _float32_script()
    scene = load_scene("rig")
    pol = _policy(scene)
    script.check_told_is_own(pol, scene, 1)  # raises SystemExit on any difference
    c_dir = tmp_path / "c"
    write_c(pol, scene, c_dir, force=True)
    source = c_dir / "impact_policy.c"
    source.write_text(script.told_given_command(source.read_text()))
    cp = parity.CPolicy(parity.build_shared(c_dir, tmp_path / "told.so", False), False)
    rec = parity.record(pol, scene, 0, 600)
    moved = parity.Recording(rec.readings, rec.command + 0.01, rec.force, rec.status, detected=rec.detected)
    got = script.replay_told(cp, moved)
    assert not np.array_equal(got.command, rec.command)


@pytest.mark.training
def test_a_student_of_the_estimate_is_saved_and_loaded_with_its_filter(tmp_path):
    """A tiny DAgger run with ``student_observation="estimate"``: its settings say so, and
    ``compare``'s loader gives the compiled policy with the filter inside, whose network is the
    student's actor (the same command as torch's on the same input, to float32's precision)."""
    pytest.importorskip("stable_baselines3")
    import torch
    from stable_baselines3 import PPO

    from agents.distill import distill
    from impact_env.policy.registry import make_policy

    out = tmp_path / "student"
    meta = distill("law:pd-penetration", out, history=1, iterations=2, envs=4, eval_episodes=2, scene="rig",
                   env_kwargs={"horizon": 0.01}, fit_samples=4096, batch_size=512,
                   student_observation="estimate")
    assert meta["estimator"] == "ekf" and meta["observation"] == "sensors" and meta["label"].endswith("-est-s0")
    assert json.loads((out / "best_model.json").read_text())["estimator"] == "ekf"
    pol = make_policy(f"ppo:{out / 'best_model.zip'}", "rig")
    assert isinstance(pol, CompiledPolicy) and pol.estimator is not None
    model = PPO.load(out / "best_model.zip", device="cpu")
    x = np.random.default_rng(0).normal(0.0, 0.3, (1, model.observation_space.shape[0])).astype(np.float32)
    with torch.no_grad():
        want = model.policy._predict(torch.as_tensor(x), deterministic=True).numpy()[0, 0]
    layers = [{"weight": ly["weight"], "bias": ly["bias"], "activation": ly["activation"]}
              for ly in pol.mlp["layers"]]
    assert _forward(layers, x[0].astype(np.float64)) == pytest.approx(float(want), abs=1e-5)


def test_a_student_of_the_estimate_is_refused_where_the_filter_cannot_follow(tmp_path):
    pytest.importorskip("stable_baselines3")
    from agents.distill import distill

    with pytest.raises(ConfigError, match="no residual law"):
        distill("law:mpc-state", tmp_path / "s", scene="rig", env_kwargs={"residual": "pd-penetration"},
                student_observation="estimate")
    assert not (tmp_path / "s").exists()
