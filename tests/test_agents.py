"""agents.train: YAML hyperparameters, validation before anything is created, a tiny PPO run that is
saved, loads through the policy registry and runs in compare, TensorBoard, the evaluation
callback, checkpoints and --resume."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from agents.run_config import check_hyperparameter, read_conf, resolve
from agents.train import Tooling, main, train
from baselines import make_policy
from impact_env.config import ConfigError
from impact_env.eval.compare import compare

HORIZON = 0.005  # s: 50 control periods on rig, so that episodes end during the tiny run
TINY_PPO = {"n_steps": 32, "batch_size": 64, "n_epochs": 1, "net_arch": [8]}
ROOT = Path(__file__).resolve().parents[1]
PLAIN = ROOT / "agents" / "hyperparams" / "ppo_plain.yml"  # no options: the model joins compare as it is


@pytest.mark.training
def test_ppo_trains_saves_and_joins_the_comparison(tmp_path):
    out = tmp_path / "ppo"
    result = train("ppo", "rig", steps=256, envs=4, seed=3, out=out, observation="sensors", history=2,
                   env_kwargs={"horizon": HORIZON}, hyperparameters=TINY_PPO, conf_file=PLAIN,
                   tooling=Tooling(eval_every=None, label="ppo-tiny"))
    assert result.steps >= 256 and result.episodes >= 4  # 4 envs x 64+ steps of 50-step episodes
    meta = json.loads((out / "model.json").read_text())
    assert meta["label"] == "ppo-tiny"  # --label: the run's name in reports
    assert (meta["algo"], meta["observation"], meta["history"], meta["scene"], meta["seed"]) == \
        ("ppo", "sensors", 2, "rig", 3)
    assert meta["steps"] == result.steps == meta["ticks"] and meta["wall_time_s"] > 0
    assert meta["hyperparameters"]["gamma"] == 0.995  # from agents/hyperparams/ppo_plain.yml
    assert meta["hyperparameters"]["n_steps"] == 32  # the override

    spec = f"ppo:{out / 'model.zip'}"
    policy = make_policy(spec, "rig")  # observation and history come from model.json
    assert (policy.observation, policy.history) == ("sensors", 2)
    runs = compare("rig", ["passive", spec], episodes=2, seed=1000, horizon=HORIZON, workers=1,
                   progress=False)
    s = runs[spec].summary
    assert s["episodes"] == 2 and s["failed_episodes"] == 0
    assert s["peak_demand_N"] <= 200.0 + 1e-9  # actions clipped to the command scale


@pytest.mark.training
def test_tensorboard_eval_callback_checkpoints_and_resume(tmp_path, capsys):
    out, tb = tmp_path / "run", tmp_path / "tb"
    args = ["--algo", "ppo", "--out", str(out), "--steps", "256", "--envs", "4", "--seed", "2",
            "--horizon", str(HORIZON), "--tensorboard", str(tb), "--checkpoint-every", "128",
            "--eval-every", "128", "--eval-episodes", "2", "--env-kwargs", "hold_ticks=2",
            "--env-kwargs", "residual=pd-penetration", "--env-kwargs", "effort_weight=0.1",
            "--keep-checkpoints", "0"]  # 0: keep every checkpoint (the default keeps the newest)
    for key, value in TINY_PPO.items():
        args += ["--hp", f"{key}={value}"]
    assert main(args) == 0
    meta = json.loads((out / "model.json").read_text())
    # agents/hyperparams/ppo.yml holds hold 4 and the residual in env_kwargs; --env-kwargs overrides the hold
    assert (meta["hold_ticks"], meta["residual"]) == (2, "pd-penetration")
    assert meta["env_kwargs"]["hold_ticks"] == 2 and meta["env_kwargs"]["residual"] == "pd-penetration"
    assert meta["env_kwargs"]["terminate_on_catch"] is False and meta["hyperparameters"]["gae_lambda"] == 1.0
    assert meta["steps"] == 256 and meta["ticks"] == 512  # two control periods per policy step
    assert meta["validation"]["seeds"] == [900_000, 900_001]
    assert meta["validation"]["best"]["evaluations"] == 2
    assert (out / "best_model.zip").is_file() and (out / "best_model.json").is_file()
    saved = sorted(p.name for p in (out / "checkpoints").iterdir())
    assert saved == ["model_128_steps.json", "model_128_steps.zip", "model_256_steps.json",
                     "model_256_steps.zip"]
    # every saved model carries its settings: a checkpoint runs with its hold and residual law
    from impact_env.policy.registry import make_policy

    ck = make_policy(f"ppo:{out / 'checkpoints' / 'model_128_steps.zip'}", "rig")
    assert (ck.hold_ticks, ck.residual) == (2, "pd-penetration")
    best = json.loads((out / "best_model.json").read_text())
    assert (best["hold_ticks"], best["residual"]) == (2, "pd-penetration")
    assert list(tb.rglob("events.out.tfevents.*"))

    # resume from the 128-step checkpoint, as after a crash: the step counter goes on from 128
    (out / "checkpoints" / "model_256_steps.zip").unlink()
    state = json.loads((out / "run.json").read_text())
    # with a new name: a run continued to a longer budget is another run in reports
    assert main(["--resume", str(out), "--steps", "384", "--label", "ppo-tiny-384"]) == 0
    meta2 = json.loads((out / "model.json").read_text())
    assert meta2["steps"] == 384
    assert meta2["label"] == json.loads((out / "best_model.json").read_text())["label"] == "ppo-tiny-384"
    assert json.loads((out / "run.json").read_text())["tooling"]["label"] == "ppo-tiny-384"
    assert meta2["hyperparameters"] == meta["hyperparameters"]
    segs = json.loads((out / "run.json").read_text())["segments"]
    assert len(segs) == 2 and segs[1]["start_step"] == 128 and segs[1]["env_seed"] == 2 + 4
    assert json.loads((out / "run.json").read_text())["config"]["hyperparameters"] == \
        state["config"]["hyperparameters"]
    ev = np.load(out / "eval" / "evaluations.npz")
    assert list(ev["timesteps"]) == [128, 256, 256, 384]  # first run's two, then the resumed run's
    capsys.readouterr()
    # resuming with other settings is refused
    assert main(["--resume", str(out), "--hp", "gamma=0.9"]) == 2
    assert "--hp" in capsys.readouterr().err
    # a new name is checked as a new run's is, before any step
    assert main(["--resume", str(out), "--steps", "512", "--label", "a b"]) == 2
    assert "without spaces" in capsys.readouterr().err
    assert json.loads((out / "model.json").read_text())["steps"] == 384


@pytest.mark.parametrize("argv, names", [
    (["--hp", "learning_rate=abc"], ["learning_rate", "'abc'", "number > 0"]),
    (["--hp", "n_steps=0"], ["n_steps", "integer >= 1"]),
    (["--hp", "gamma=1.5"], ["gamma", "<= 1"]),
    (["--hp", "net_arch=[64, -1]"], ["net_arch", "layer widths"]),
    (["--hp", "n_step=8"], ["n_step", "did you mean 'n_steps'"]),
    (["--env-kwargs", "effort_weight=-1"], ["effort_weight", ">= 0"]),
    (["--env-kwargs", "hold_ticks=0"], ["hold_ticks", "[1, 10000]"]),
    (["--env-kwargs", "residual=pd"], ["unknown policy 'pd'"]),
    (["--env-kwargs", "colour=red"], ["unknown env_kwargs 'colour'"]),
    (["--env-kwargs", "chatter_weight=0.1"], ["chatter_weight", "did not help"]),
    (["--set", "plant.m1=-1"], ["plant.m1"]),
    (["--scene", "moon"], ["unknown scene 'moon'"]),
    (["--env-kwargs", f"residual=ppo:{ROOT}/agents/models/ppo_rig/model.zip"], ["residual", "classic law"]),
    (["--seed", "990"], ["test drops 1000..1099"]),
    (["--eval-seed", "5"], ["validation seeds 5..20"]),
    (["--action-limit", "1.5"], ["vec_env_wrapper limit", "<= 1"]),
    (["--action-limit", "0"], ["vec_env_wrapper limit", "> 0"]),
    (["--label", "ppo s0"], ["--label 'ppo s0'", "without spaces"]),
    (["--label", "a|b"], ["--label 'a|b'", "'|'"]),
])
def test_bad_arguments_exit_2_naming_the_value_and_create_nothing(tmp_path, capsys, argv, names):
    out, tb = tmp_path / "out", tmp_path / "tb"
    code = main(["--algo", "ppo", "--out", str(out), "--tensorboard", str(tb), *argv])
    err = capsys.readouterr().err
    assert code == 2
    for name in names:
        assert name in err
    assert not out.exists() and not tb.exists()


def test_an_existing_run_folder_is_not_overwritten(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "model.zip").write_bytes(b"")
    assert main(["--algo", "ppo", "--out", str(out)]) == 2
    assert "--resume" in capsys.readouterr().err
    assert main(["--resume", str(tmp_path / "nothing")]) == 2


def test_python_api_refuses_bad_values_before_creating_anything(tmp_path):
    with pytest.raises(ValueError, match="algo"):
        train("dqn", "rig", steps=10, out=tmp_path / "a")
    with pytest.raises(ValueError, match="n_timesteps"):
        train("ppo", "rig", steps=0, out=tmp_path / "a")
    with pytest.raises(ValueError, match="hyperparameter"):
        train("ppo", "rig", steps=10, out=tmp_path / "a", hyperparameters={"n_step": 8})
    with pytest.raises(ValueError, match="observation"):
        train("ppo", "rig", steps=10, out=tmp_path / "a", observation="camera")
    assert not (tmp_path / "a").exists()


@pytest.mark.parametrize("algo, name", [("ppo", "ppo"), ("ppo", "ppo_plain"), ("sac", "sac")])
def test_the_shipped_yaml_files_resolve_and_every_value_passes_its_check(algo, name):
    entry = read_conf(ROOT / "agents" / "hyperparams" / f"{name}.yml")
    cfg = resolve(algo, entry)
    assert cfg.n_envs == entry["n_envs"] and cfg.n_timesteps == int(entry["n_timesteps"])
    assert cfg.scene == entry["env_kwargs"]["scene"]
    for key, value in cfg.hyperparameters.items():
        assert check_hyperparameter(algo, key, value) == value


def test_schedules_and_sac_entropy_follow_rl_zoo_conventions():
    assert check_hyperparameter("ppo", "learning_rate", "lin_3e-4") == "lin_3e-4"
    assert check_hyperparameter("sac", "ent_coef", "auto_0.1") == "auto_0.1"
    assert check_hyperparameter("sac", "train_freq", [4, "step"]) == [4, "step"]
    with pytest.raises(ConfigError, match="lin_"):
        check_hyperparameter("ppo", "clip_range", "lin_x")
    with pytest.raises(ConfigError, match="batch_size"):
        resolve("ppo", {"n_timesteps": 10, "n_envs": 2, "n_steps": 8, "batch_size": 64})
    # a batch that does not divide the rollout: SB3 would truncate the last mini-batch (and warn)
    with pytest.raises(ConfigError, match=r"batch_size = 4096: must divide one rollout.*= 64000; e.g. "
                                          r"batch_size = 3200 or 4000"):
        resolve("ppo", {"n_timesteps": 10, "n_envs": 64, "n_steps": 1000, "batch_size": 4096})
    with pytest.raises(ConfigError, match="env_wrapper"):
        resolve("ppo", {"n_timesteps": 10, "env_wrapper": ["gymnasium.wrappers.ClipAction"]})
    with pytest.raises(ConfigError, match="residual"):
        resolve("ppo", {"n_timesteps": 10, "env_kwargs": {"residual": "pd-penetrashun"}})


def test_training_without_the_extra_says_how_to_get_it(tmp_path, capsys, monkeypatch):
    """In a core install (no stable-baselines3, torch or PyYAML: the extra 'sb3'), agents.train
    exits 2 with the install command, before anything is created (tests/minimal_install_check.py
    runs it for real in a core-only venv)."""
    import importlib.util

    import agents.train as agents_train

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "yaml" else real(name, *a))
    assert agents_train.main(["--algo", "ppo", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "yaml not installed" in err and "pip install 'impact-env[sb3]'" in err
    assert not (tmp_path / "run").exists()


def test_yaml_without_the_env_id_is_refused_naming_what_it_has(tmp_path):
    p = tmp_path / "x.yml"
    p.write_text("CartPole-v1:\n  n_timesteps: 10\n")
    with pytest.raises(ConfigError, match="CartPole-v1"):
        read_conf(p)
    shutil.rmtree(tmp_path)


TINY_SAC = {"buffer_size": 1000, "batch_size": 16, "net_arch": [8]}


@pytest.mark.training
@pytest.mark.parametrize("algo, hp", [("ppo", TINY_PPO), ("sac", TINY_SAC)])
def test_ctrl_c_saves_the_model_and_its_settings(tmp_path, capsys, monkeypatch, algo, hp):
    """A run interrupted with Ctrl-C (KeyboardInterrupt inside learn, here at step 64 of 128,
    before any periodic checkpoint) leaves model.zip and model.json, a checkpoint with its settings
    (and SAC's replay buffer), ends the progress line, says where they are and exits 130 without a
    traceback; ``--resume`` then continues from that checkpoint to a tiny budget (it refused with
    "no checkpoint" when the interrupted save went to model.zip only)."""
    from agents.callbacks import EpisodeStats

    real_on_step = EpisodeStats._on_step

    def interrupted_at_64(self):
        if self.num_timesteps >= 64:
            raise KeyboardInterrupt
        return real_on_step(self)

    monkeypatch.setattr(EpisodeStats, "_on_step", interrupted_at_64)
    out = tmp_path / "run"
    args = ["--algo", algo, "--out", str(out), "--steps", "128", "--envs", "4", "--horizon", str(HORIZON),
            "--eval-every", "0", "--progress"]
    for key, value in hp.items():
        args += ["--hp", f"{key}={value}"]
    assert main(args) == 130
    meta = json.loads((out / "model.json").read_text())
    assert meta["interrupted"] is True and (out / "model.zip").is_file() and meta["steps"] == 64
    ck = out / "checkpoints"
    saved = sorted(p.name for p in ck.iterdir())
    expected = ["model_64_steps.json", "model_64_steps.zip"]
    if algo == "sac":
        expected.append("model_replay_buffer_64_steps.pkl")
    assert saved == expected
    assert json.loads((ck / "model_64_steps.json").read_text())["algo"] == algo
    captured = capsys.readouterr()
    assert "interrupted (Ctrl-C)" in captured.out and f"--resume {out}" in captured.out
    assert captured.err.endswith("\n")  # the status line is ended, not overwritten by the next output

    monkeypatch.setattr(EpisodeStats, "_on_step", real_on_step)
    from stable_baselines3 import SAC

    buffers = []  # what the resumed SAC loaded, and how many transitions: the first segment's
    real_load = SAC.load_replay_buffer

    def load_replay_buffer(self, path, *a, **kw):
        real_load(self, path, *a, **kw)
        buffers.append((Path(path).name, self.replay_buffer.size() * self.n_envs))

    monkeypatch.setattr(SAC, "load_replay_buffer", load_replay_buffer)
    assert main(["--resume", str(out)]) == 0  # the run's own budget, 128 steps
    meta2 = json.loads((out / "model.json").read_text())
    assert meta2["interrupted"] is False and meta2["steps"] >= 128
    segs = json.loads((out / "run.json").read_text())["segments"]
    assert [s["start_step"] for s in segs] == [0, 64]
    if algo == "sac":  # the interrupted vector step (4 envs) was counted but its transitions not stored
        assert [name for name, _ in buffers] == ["model_replay_buffer_64_steps.pkl"]
        assert 64 - 4 <= buffers[0][1] <= 64
    else:
        assert buffers == []


@pytest.mark.training
@pytest.mark.parametrize("algo, hp, steps, planned", [("ppo", TINY_PPO, 100, 128), ("sac", TINY_SAC, 10, 12)])
def test_a_short_run_says_its_budget_and_ends_with_an_evaluation_and_a_checkpoint(tmp_path, capsys, algo, hp,
                                                                                   steps, planned):
    """A budget below --eval-every and --checkpoint-every (their defaults): the rounding is said
    before training (PPO: whole rollouts of 32 x 4; SAC: vector steps of 4 envs), the run ends
    where it said, with one evaluation of the final model (a line on stderr without a terminal),
    best_model.zip and a checkpoint that --resume can continue from."""
    out = tmp_path / "run"
    args = ["--algo", algo, "--out", str(out), "--steps", str(steps), "--envs", "4",
            "--horizon", str(HORIZON), "--eval-episodes", "2", "--no-progress"]
    for key, value in hp.items():
        args += ["--hp", f"{key}={value}"]
    assert main(args) == 0
    captured = capsys.readouterr()
    err, out_text = captured.err, captured.out
    budget = err.splitlines()[0]
    assert f"training {planned} policy steps" in budget and f"--steps {steps} rounded up" in budget
    assert f"eval: step {planned}/{planned} (100 %)" in err
    assert json.loads((out / "model.json").read_text())["steps"] == planned
    ev = np.load(out / "eval" / "evaluations.npz")
    assert list(ev["timesteps"]) == [planned] and ev["results"].shape == (1, 2)
    assert (out / "best_model.zip").is_file()
    assert json.loads((out / "best_model.json").read_text())["steps"] == planned
    assert (out / "checkpoints" / f"model_{planned}_steps.zip").is_file()
    # the run says whether its best model beats the residual's law alone on the same drops
    best = json.loads((out / "model.json").read_text())["validation"]["best"]
    assert best["residual_law"] == "pd-penetration" and best["residual_law_return"] < 0
    assert (f"energy integral {-best['mean_reward']:.2f} ms (best model) against pd-penetration's "
            f"{-best['residual_law_return']:.2f} ms alone: it ") in out_text
    # the env's share of the wall time and every evaluation's training time are kept
    meta = json.loads((out / "model.json").read_text())
    assert 0 < meta["env_time_s"] <= meta["wall_time_s"] and 0 < meta["env_share"] <= 1
    hist = meta["validation"]["history"]
    assert [h["step"] for h in hist] == [planned]
    assert hist[0]["return"] == pytest.approx(best["mean_reward"], abs=1e-4)
    assert 0 <= hist[0]["env_s"] <= hist[0]["wall_s"] <= meta["wall_time_s"] + 0.01  # rounded to 10 ms
    assert best["drops"] == [900000, 900001] and "the env" in out_text
    # the last lines name the model to evaluate (the best, not the last) and the command that does it
    *_, saved, last = out_text.strip().splitlines()
    assert f"the model to evaluate is the best on the validation drops, {out / 'best_model.zip'}" in saved
    assert last == (f"next: impact-env compare --scene {meta['scene']} --policies pd-penetration,"
                    f"{algo}:{out / 'best_model.zip'} --episodes 100 --seed 1000 --out {out / 'compare'}")


@pytest.mark.training
def test_progress_bar_and_a_budget_that_needs_no_rounding(tmp_path, capsys):
    """--progress: SB3's bar (tqdm + rich), no evaluation lines; 128 = 4 rollouts of 32 x 4 is
    trained as given and the budget line says no rounding; the default --checkpoint-every is kept
    and crossed checkpoints are written."""
    out = tmp_path / "run"
    args = ["--algo", "ppo", "--out", str(out), "--steps", "128", "--envs", "4", "--horizon", str(HORIZON),
            "--eval-every", "64", "--eval-episodes", "2", "--progress", "--checkpoint-every", "64"]
    for key, value in TINY_PPO.items():
        args += ["--hp", f"{key}={value}"]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "training 128 policy steps" in err and "rounded" not in err and "eval: step" not in err
    assert json.loads((out / "model.json").read_text())["steps"] == 128
    assert list(np.load(out / "eval" / "evaluations.npz")["timesteps"]) == [64, 128]  # none added at the end
    # two checkpoints crossed; the default keeps the newest (what --resume needs), not one per 64 steps
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["model_128_steps.json",
                                                                      "model_128_steps.zip"]
    from agents.train import CHECKPOINT_EVERY, build_parser

    assert build_parser().parse_args(["--algo", "ppo"]).checkpoint_every == CHECKPOINT_EVERY


def test_a_malformed_vec_env_wrapper_is_refused_naming_the_one_it_takes():
    for bad in ("impact_env.env.sb3_vecenv.ActionLimit", [{"some.Wrapper": {"limit": 0.5}}],
                [{"impact_env.env.sb3_vecenv.ActionLimit": {"limit": 0.5, "x": 1}}]):
        with pytest.raises(ConfigError, match="vec_env_wrapper: expected"):
            resolve("sac", {"n_timesteps": 10, "vec_env_wrapper": bad})


@pytest.mark.training
def test_the_action_limit_is_the_models_bound_in_predict_and_the_export(tmp_path):
    """sac.yml's ActionLimit: the saved model's action space is +-0.25, and the compiled export
    (which reads the model's bounds) and predict both stay within it."""
    from stable_baselines3 import SAC

    from impact_env.policy.export import export_policy

    out = tmp_path / "sac"
    train("sac", "rig", steps=32, envs=4, seed=1, out=out, env_kwargs={"horizon": HORIZON},
          hyperparameters=TINY_SAC, tooling=Tooling(eval_every=None))
    assert json.loads((out / "run.json").read_text())["config"]["action_limit"] == 0.25
    model = SAC.load(out / "model.zip", device="cpu")
    assert (float(model.action_space.low[0]), float(model.action_space.high[0])) == (-0.25, 0.25)
    obs = np.random.default_rng(0).normal(0, 3, (64, model.observation_space.shape[0])).astype(np.float32)
    a, _ = model.predict(obs, deterministic=True)
    assert np.all(np.abs(a) <= 0.25)
    from agents.policies import deployable

    actor = deployable(out / "model.zip")  # sac.yml's critics read the true state: the sensor actor
    assert actor != out / "model.zip"
    pol = export_policy(f"sac:{actor}", "rig")
    assert (pol.mlp["low"], pol.mlp["high"]) == (-0.25, 0.25) and pol.observation == "sensors"


def test_quick_defaults_to_ppo_a_short_budget_and_a_free_folder(tmp_path, monkeypatch):
    """--quick: PPO, the quick budget and evaluation interval, runs/quick or the first free
    runs/quick-N; what is given explicitly wins; it does not go with --resume."""
    from agents.train import QUICK_EVAL_EVERY, QUICK_STEPS, _from_args, build_parser

    monkeypatch.chdir(tmp_path)
    cfg, out, tooling, resume = _from_args(build_parser().parse_args(["--quick"]))
    assert (cfg.algo, cfg.n_timesteps, tooling.eval_every, out, resume) == \
        ("ppo", QUICK_STEPS["ppo"], QUICK_EVAL_EVERY["ppo"], Path("runs/quick"), False)
    (tmp_path / "runs" / "quick").mkdir(parents=True)
    (tmp_path / "runs" / "quick" / "run.json").write_text("{}")
    cfg, out, tooling, _ = _from_args(build_parser().parse_args(["--quick", "--algo", "sac", "--steps", "500",
                                                                 "--eval-every", "100"]))
    assert (cfg.algo, cfg.n_timesteps, tooling.eval_every, out) == ("sac", 500, 100, Path("runs/quick-1"))
    _, _, tooling, _ = _from_args(build_parser().parse_args(["--algo", "ppo", "--out", "x"]))
    assert tooling.eval_every == 100_000
    assert main(["--quick", "--resume", str(tmp_path / "runs" / "quick")]) == 2


@pytest.mark.training
def test_distill_a_privileged_teacher_into_a_sensor_student_with_history(tmp_path):
    """agents.distill: a tiny privileged PPO teacher, two DAgger iterations into a student on the
    sensors with history 2; the student is a plain PPO model with its settings, every evaluation
    kept, and it runs as a model spec and compiled (history in the compiled observation); the
    same seed gives the same student."""
    from agents.distill import distill

    teacher = tmp_path / "teacher"
    train("ppo", "rig", steps=128, envs=4, seed=3, out=teacher, observation="privileged",
          env_kwargs={"horizon": HORIZON, "hold_ticks": 2, "residual": "pd-penetration"},
          hyperparameters=TINY_PPO, tooling=Tooling(eval_every=None))
    outs = []
    for k in range(2):
        out = tmp_path / f"student{k}"
        meta = distill(teacher / "model.zip", out, history=2, iterations=2, envs=4, epochs=1, eval_episodes=2)
        outs.append(out)
    assert (meta["observation"], meta["history"], meta["hold_ticks"], meta["label"]) == \
        ("sensors", 2, 2, "distill-h2-s0")
    assert [h["beta"] for h in meta["validation"]["history"]] == [1.0, 0.5]
    assert meta["validation"]["best"]["residual_law"] == "pd-penetration" and 0 < meta["env_share"] <= 1
    from stable_baselines3 import PPO

    a, b = (PPO.load(o / "best_model.zip", device="cpu") for o in outs)
    for pa, pb in zip(a.policy.parameters(), b.policy.parameters(), strict=True):
        assert np.array_equal(pa.detach().numpy(), pb.detach().numpy())
    # the student reads the 2 sensor frames (4 entries each on rig), not its own past commands: their
    # first-layer weights stay 0 through the fit (what keeps the C export's float32 build in bounds)
    w = a.policy.mlp_extractor.policy_net[0].weight.detach().numpy()
    assert w.shape[1] > 2 * 4 and np.all(w[:, 2 * 4:] == 0) and np.any(w[:, :2 * 4] != 0)
    spec = f"ppo:{outs[0] / 'best_model.zip'}"
    from agents.evaluate import export_compiled

    compiled = export_compiled(outs[0] / "best_model.zip", "rig")
    runs = compare("rig", [spec, compiled], episodes=2, seed=1000, horizon=HORIZON, workers=1, progress=False)
    np.testing.assert_allclose(runs[spec].metrics["energy_integral_ms"],
                               runs[compiled].metrics["energy_integral_ms"], rtol=1e-3)
    with pytest.raises(ConfigError, match="privileged"):
        distill(outs[0] / "best_model.zip", tmp_path / "bad", history=2, iterations=1, envs=2)
    named = distill(teacher / "model.zip", tmp_path / "named", history=2, iterations=1, envs=2, epochs=1,
                    eval_episodes=1, label="student-x")
    assert named["label"] == "student-x"
    with pytest.raises(ConfigError, match="--label 'a b'"):
        distill(teacher / "model.zip", tmp_path / "bad_label", history=2, iterations=1, envs=2, label="a b")
    assert not (tmp_path / "bad_label").exists()
