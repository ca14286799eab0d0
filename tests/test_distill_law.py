"""agents.distill with a compiled classic law as the teacher (``--teacher law:NAME``): a tiny
DAgger run, its determinism, the student moving towards the teacher, and the refusals that come
before any work."""

import json

import numpy as np
import pytest

from agents.distill import distill, main
from agents.law_teacher import LawTeacher, law_names
from impact_env.config import ConfigError

HORIZON = 0.01  # s: 100 control periods on rig, the validation episodes' length here
TINY = {"history": 2, "iterations": 3, "envs": 4, "eval_episodes": 2, "scene": "rig",
        "env_kwargs": {"horizon": HORIZON}, "fit_samples": 4096, "batch_size": 512}
TEACHER = "law:thesis-ideal:h01=2.15e6,h11=1460"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two runs of the same seed (the determinism check) and their model.json contents."""
    base = tmp_path_factory.mktemp("law_teacher")
    out = []
    for k in range(2):
        folder = base / f"student{k}"
        out.append((folder, distill(TEACHER, folder, **TINY)))
    return out


@pytest.mark.training
def test_a_law_teacher_trains_a_sensor_student_that_moves_towards_it(runs):
    """The student's mean squared error against the teacher's labels on the data it has not been
    fitted to yet falls from the untrained first iteration, and the run is judged against the
    teacher itself on the same validation drops."""
    folder, meta = runs[0]
    assert (meta["observation"], meta["history"], meta["hold_ticks"]) == ("sensors", 2, 1)
    assert meta["residual"] is None
    assert meta["label"] == "dagger-thesis-ideal-h2-s0"
    errors = meta["imitation_error"]
    assert len(errors) == 3 and errors[-1] < 0.75 * errors[0]
    best = meta["validation"]["best"]
    assert best["teacher"] == TEACHER and best["teacher_return"] < 0 and best["mean_reward"] < 0
    assert [h["beta"] for h in meta["validation"]["history"]] == [1.0, 0.5, 0.25]
    assert json.loads((folder / "best_model.json").read_text())["env_kwargs"]["hold_ticks"] == 1


@pytest.mark.training
def test_one_seed_gives_one_student(runs):
    from stable_baselines3 import PPO

    (a_dir, a_meta), (b_dir, b_meta) = runs
    assert a_meta["imitation_error"] == b_meta["imitation_error"]
    a, b = (PPO.load(d / "model.zip", device="cpu") for d in (a_dir, b_dir))
    for pa, pb in zip(a.policy.parameters(), b.policy.parameters(), strict=True):
        assert np.array_equal(pa.detach().numpy(), pb.detach().numpy())


def test_the_law_teacher_is_the_registry_kernel():
    """The teacher's command is the law's policy class's (the same compiled kernel) on the true
    state read out of the 'both' frame."""
    from impact_env.control.observation import make_layout
    from impact_env.policy.laws import LAW_POLICIES
    from impact_env.scene import load_scene

    scene = load_scene("rig")
    both = make_layout(scene, "both", 1)
    rng = np.random.default_rng(0)
    frames = rng.normal(size=(5, both.frame_size)).astype(np.float32)
    teacher = LawTeacher("law:thesis-ideal:h11=1000", scene, both.names, both.scales, 5)
    policy = LAW_POLICIES["thesis-ideal"](scene, h11=1000.0)
    true_state = frames[:, 4:].astype(np.float64)  # x1, v1, x2, v2 after the 4 sensor entries
    expected, _ = policy.predict(true_state)
    np.testing.assert_array_equal(teacher.act(frames), expected)


@pytest.mark.parametrize("teacher, message", [
    ("law:nope", "'nope' is not a compiled classic law; choose law:NAME with NAME one of"),
    ("law:", "is not a compiled classic law"),
    ("law:thesis-ideal:h11=-1", "h11"),
    ("no/such/model.zip", "no such file; choose law:NAME"),
])
def test_a_bad_teacher_is_refused_naming_the_choices_before_any_work(tmp_path, capsys, teacher, message):
    out = tmp_path / "run"
    assert main(["--teacher", teacher, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and not out.exists()
    if "choose" in message:
        assert all(name in err for name in law_names())


def test_a_law_teacher_refuses_a_held_action(tmp_path):
    with pytest.raises(ConfigError, match="hold_ticks"):
        distill(TEACHER, tmp_path / "run", env_kwargs={"hold_ticks": 4})
    with pytest.raises(ConfigError, match="residual"):
        distill(TEACHER, tmp_path / "run", env_kwargs={"residual": "compiled:x.json"})
    assert not (tmp_path / "run").exists()


def test_quick_with_a_teacher_refuses_rl_options_and_bad_names_before_any_work(tmp_path, capsys, monkeypatch):
    """``agents.train --quick --teacher``: DAgger with its own budget; an RL option or a name that is
    not a compiled law exits 2 naming the choices, with no run folder made."""
    from agents.train import main as train_main

    monkeypatch.chdir(tmp_path)
    assert train_main(["--quick", "--teacher", "law:nope"]) == 2
    err = capsys.readouterr().err
    assert "'nope' is not a compiled classic law" in err and all(name in err for name in law_names())
    assert train_main(["--quick", "--teacher", "law:thesis-ideal", "--algo", "sac"]) == 2
    assert "drop --algo" in capsys.readouterr().err
    assert train_main(["--teacher", "law:thesis-ideal"]) == 2
    assert "goes with --quick" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()


def test_an_mpc_teacher_follows_the_commands_the_envs_applied():
    """mpc-state's memory drives its model of the shaker with its own demands; told the commands
    the envs applied (a student's, a perturbed teacher's), its shaker states are the model's
    driven by those, and its slew reference is the last one applied, whatever it demanded."""
    from impact_env.control.mpc.model import NZ, STATE, K
    from impact_env.control.mpc.solver import MEM
    from impact_env.control.mpc.solver import STATE as SOLVER_STATE
    from impact_env.control.observation import make_layout
    from impact_env.scene import load_scene

    scene = load_scene("rig")
    both = make_layout(scene, "both", 1)
    frames = np.zeros((2, both.frame_size), np.float32)
    frames[:, 4:] = [-0.5, 0.9, 0.0, 0.0]  # x1, v1, x2, v2 (scaled): body 1 falling towards body 2
    teacher = LawTeacher("law:mpc-state", scene, both.names, both.scales, 2)
    k = teacher.constants[0]
    A = np.array([[k[K.a00], k[K.a01], k[K.a02]], [k[K.a10], k[K.a11], k[K.a12]],
                  [k[K.a20], k[K.a21], k[K.a22]]])
    B = np.array([k[K.b0], k[K.b1], k[K.b2]])
    scale = float(scene.effects.command_scale)
    z = np.zeros((2, NZ))
    own = []
    for applied in ([[0.3], [-2.0]], [[-1.0], [0.25]], [[0.5], [0.5]]):
        own.append(teacher.act(frames)[:, 0])
        teacher.applied(np.array(applied))
        u = np.clip(np.array(applied)[:, 0] * scale, -k[K.umax], k[K.umax])
        z = z @ A.T + u[:, None] * B
        zs = teacher.memory[:, SOLVER_STATE + STATE.z0:SOLVER_STATE + STATE.z0 + NZ]
        np.testing.assert_allclose(zs, z, rtol=1e-12, atol=1e-9 * np.abs(z).max())
        np.testing.assert_array_equal(teacher.memory[:, MEM.u_prev], u)
    assert not np.allclose(np.array(own)[:, 0], [0.3, -1.0, 0.5])  # it demanded something else
