"""Train a PPO or SAC agent (stable-baselines3) on ``ImpactCatch-v0`` and save it for the comparison.

    python -m agents.train --algo ppo --out runs/ppo0 [--seed 0] [--steps 2000000] [--envs 16]
        [--conf-file agents/hyperparams/ppo.yml] [--scene rig] [--set initial.pre_contact_time=1.0]
        [--observation sensors] [--history 4] [--horizon 0.4] [--env-kwargs effort_weight=0.1 ...]
        [--hp learning_rate=1e-4 ...] [--tensorboard runs/tb] [--checkpoint-every 200000]
        [--eval-every 100000] [--eval-episodes 16] [--progress]
    python -m agents.train --resume runs/ppo0 [--steps 4000000] [--progress]
    python -m agents.train --quick [--algo sac] [--seed 0]     # a first agent in about a minute

Hyperparameters come from the RL-Zoo-style YAML file (default ``agents/hyperparams/ALGO.yml``,
entry ``ImpactCatch-v0``; format in :mod:`agents.run_config`), which ``python -m rl_zoo3.train
--algo ppo --env ImpactCatch-v0 --gym-packages impact_env --conf-file agents/hyperparams/ppo.yml``
reads as it is; the options above override single values.  Every value is checked before
anything is created: a bad one exits with status 2 and a message naming it.

The vector env is the native one (:func:`impact_env.env.sb3_vecenv.make_sb3_vec_env`, all ``--envs``
rigs stepped in one compiled call, the env's own ``hold_ticks`` and ``residual`` included) in
SB3's ``VecMonitor``.  It is **not** normalised: the env divides every
observation by a reference scale, and leaving ``VecNormalize`` out makes ``model.zip`` the whole
policy.  ``--steps`` counts SB3 timesteps, i.e. policy steps (control periods when
``hold_ticks`` is 1); ``model.json`` also gives ``ticks``, the control periods simulated.

Writes into OUT: ``model.zip`` and ``model.json`` (observation, history, algo, scene, overrides,
env kwargs, hold_ticks, residual, steps, ticks, seed, wall time, hyperparameters, versions; read
by ``impact-env compare`` and :mod:`agents.evaluate`), ``run.json`` (the resolved settings, for
``--resume``), ``best_model.zip`` / ``best_model.json`` (the evaluation callback's best),
``eval/evaluations.npz``, ``checkpoints/model_<steps>_steps.zip`` with its ``.json`` (and SAC's
replay buffer) every ``--checkpoint-every`` steps and on Ctrl-C (exit 130; ``--resume OUT``
continues from it), and TensorBoard logs under ``--tensorboard DIR`` (``tensorboard --logdir DIR``).

``--quick`` is the YAML's settings with a short budget (:data:`QUICK_STEPS`), an evaluation
every :data:`QUICK_EVAL_EVERY` steps and the run folder ``runs/quick`` (or the first free
``runs/quick-N``); like every run with a residual it ends by saying whether its best model beats
the residual's law on the validation drops, with both figures.

What a run says: the budget and its rounding (PPO learns whole rollouts, SAC whole vector steps)
on stderr before training; SB3's progress bar in a terminal, one line per evaluation otherwise;
an evaluation of the final model at the end of every run (so ``best_model.zip`` exists however
short the budget) and, with a residual, whether the best model beats the residual's law alone on
the same validation drops, and after how much training time it first did.  ``model.json``
keeps the wall time, the env's part of it (``env_time_s``, ``env_share``: time inside the vector
env's reset and step) and every evaluation (``validation.history``: policy step, training wall
time before it with the evaluations' own time left out, the env's part, validation return).
SAC's actor starts as PPO's (:func:`agents.policies.init_sac_actor`)
whenever ``log_std_init`` is given; ``--action-limit`` (or the YAML's ``vec_env_wrapper``
:class:`~impact_env.env.sb3_vecenv.ActionLimit`) bounds the policy's action.

Seeds (none of the three ranges meets another; checked):

* training: the model (torch, numpy, action sampling) is seeded ``seed``; env i starts from
  seed ``seed + i`` and draws its next drops from its own Generator; resume number r (1, 2, ...)
  reseeds env i with ``seed + r * envs + i`` (the envs' Generators are not checkpointed);
* validation (``EvalCallback``, keeps ``best_model.zip``): ``--eval-episodes`` drops seeded
  ``eval_seed + j`` (default 900000 + j), the same drops at every evaluation, on the env
  with the task options at their evaluation values (no reward penalty: ``EVALUATION_OPTIONS`` of
  ``impact_env.env.task``) and
  without termination on catch, as ``compare`` runs them: the best model is the one with the
  lowest energy integral over the whole horizon (a model that catches and then lets go loses);
* test: ``impact-env compare --seed 1000`` (drops 1000 + j), what the README's tables use; the
  training seeds of a run may not reach 1000 (checked, seeds up to 1000 - envs x (resumes + 1)).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from agents.run_config import (
    ALGOS,
    ENV_ID,
    RunConfig,
    default_conf_file,
    read_conf,
    resolve,
)
from agents.run_facts import TEST_EPISODES, TEST_SEED, _literal, _load_average, _pairs, _versions  # noqa: F401
from impact_env.config import ConfigError
from impact_env.env.task import EVALUATION_OPTIONS

OBSERVATIONS = ("sensors", "privileged", "both")
EVAL_SEED = 900_000  # validation drops: eval_seed + j
CHECKPOINT_EVERY = 100_000  # policy steps between checkpoints by default (--resume needs one)
EVAL_EVERY = 100_000  # policy steps between evaluations by default
# --quick: a budget of about a minute on a 2-core machine with the YAML's settings (docs/agents-results.md,
# the training runs: where each algorithm first beats pd-penetration on the validation drops)
QUICK_STEPS = {"ppo": 1_000_000, "sac": 250_000}
QUICK_EVAL_EVERY = {"ppo": 256_000, "sac": 50_000}
# --quick --teacher law:NAME: DAgger from a compiled classic law (agents.distill), no RL; the budget
# (scripts/quick_teacher.py measures it and the student's ratio to the oracle).  The student reads
# its sensor frame and the scene's filter's estimate (a window of raw frames instead left it
# several times the oracle: docs/agents-distillation.md), so it trains on the scene the filter
# models, QUICK_SCENE; it does not read the accelerometer, which carries its own last command, and
# the teacher's applied command is perturbed (DART): without either, docs/agents-distillation.md
QUICK_DAGGER = {"history": 1, "iterations": 4, "envs": 64, "train_horizon": 0.05, "fit_samples": 1_200_000,
                "eval_every": 1, "teacher_noise": 0.3, "ignore": ("accelerometer",),
                "student_observation": "estimate"}
QUICK_SCENE = "rig"


@dataclass
class TrainResult:
    """What :func:`train` did: paths, budget, wall time and the last episodes' statistics."""

    model_path: Path
    meta_path: Path
    algo: str
    steps: int
    wall_time_s: float
    steps_per_s: float
    episodes: int
    stats: dict = field(default_factory=dict)
    ticks: int = 0
    best: dict = field(default_factory=dict)
    interrupted: bool = False
    checkpoint: Path | None = None  # written on Ctrl-C: what --resume continues from
    env_time_s: float = 0.0  # wall time inside the training env (reset and step)
    scene: str = "rig"  # the training scene: the next command's comparison runs on it

    def summary(self) -> str:
        s = self.stats
        lines = [f"{self.algo}: {self.steps} policy steps ({self.ticks} control periods) in "
                 f"{self.wall_time_s:.1f} s ({self.steps_per_s:.0f} steps/s, "
                 f"{self.ticks / max(self.wall_time_s, 1e-9):.0f} periods/s, the env "
                 f"{100 * self.env_time_s / max(self.wall_time_s, 1e-9):.0f} % of it), "
                 f"{self.episodes} episodes finished"]
        if s.get("episodes_last"):
            lines.append(f"last {s['episodes_last']} episodes: return {s['return_mean']:.2f} "
                         f"(min {s['return_min']:.2f}, max {s['return_max']:.2f}), length "
                         f"{s['length_mean_s'] * 1e3:.1f} ms, caught {100 * s['caught_fraction']:.0f} %, "
                         f"diverged {s['diverged']}")
        if s.get("return_first_mean") is not None:
            lines.append(f"first {s['episodes_first']} episodes: return {s['return_first_mean']:.2f}")
        if self.best:
            b = self.best
            lines.append(f"best validation return {b['mean_reward']:.2f} at step {b['step']}")
            if "residual_law_return" in b:
                law = b["residual_law_return"]
                drops = b.get("drops") or [0, -1]
                beats = b["mean_reward"] > law
                gain = 100 * (1 - b["mean_reward"] / law)
                verdict = (f"it beats {b['residual_law']} by {gain:.0f} %" if beats
                           else f"it does NOT beat {b['residual_law']}")
                line = (f"validation ({drops[1] - drops[0] + 1} drops, seeds {drops[0]}-{drops[1]}): energy "
                        f"integral {-b['mean_reward']:.2f} ms (best model) against {b['residual_law']}'s "
                        f"{-law:.2f} ms alone: {verdict}")
                first = b.get("first_beats_law")
                if first:
                    line += (f" (first at step {first['step']:,} after {first['wall_s']:.0f} s of training, "
                             f"evaluations excluded; the best after {b.get('wall_s') or 0:.0f} s)")
                lines.append(line)
        if self.interrupted:
            lines.append(f"interrupted (Ctrl-C) at step {self.steps}: the model so far is saved, and "
                         f"checkpoint {self.checkpoint}; continue with python -m agents.train --resume "
                         f"{self.model_path.parent} [--steps N]")
        best = self.model_path.parent / "best_model.zip"
        if self.interrupted or not best.is_file():
            lines.append(f"saved {self.model_path} (the last model) and {self.meta_path}")
            return "\n".join(lines)
        law = (self.best or {}).get("residual_law") or "pd-penetration"
        lines.append(f"saved {self.model_path} (the last model); the model to evaluate is the best on the "
                     f"validation drops, {best}")
        lines.append(f"next: impact-env compare --scene {self.scene} --policies {law},{self.algo}:{best} "
                     f"--episodes 100 --seed {TEST_SEED} --out {self.model_path.parent / 'compare'}")
        return "\n".join(lines)


@dataclass(frozen=True)
class Tooling:
    """Logging, evaluation and checkpoint settings of a run (kept in run.json for --resume)."""

    tensorboard: str | None = None
    checkpoint_every: int | None = None  # policy steps; None: no checkpoints
    keep_checkpoints: int | None = 1  # the newest checkpoints kept (what --resume needs); None: all
    eval_every: int | None = 100_000  # policy steps; None: no evaluation callback
    eval_episodes: int = 16
    eval_seed: int = EVAL_SEED
    label: str | None = None  # the run's name in reports (model.json); None: ALGO[-priv]-sSEED there

    def check(self, cfg: RunConfig, resumes: int = 0) -> None:
        from agents.run_facts import check_label

        check_label(self.label)
        for name, v, lo in (("checkpoint_every", self.checkpoint_every, 1),
                            ("keep_checkpoints", self.keep_checkpoints, 1),
                            ("eval_every", self.eval_every, 1), ("eval_episodes", self.eval_episodes, 1),
                            ("eval_seed", self.eval_seed, 0)):
            if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < lo):
                raise ConfigError(f"{name} = {v!r} must be an integer >= {lo}")
        if self.tensorboard is not None and Path(self.tensorboard).is_file():
            raise ConfigError(f"--tensorboard {self.tensorboard!r} is a file; give a folder")
        lo, hi = cfg.seed, cfg.seed + cfg.n_envs * (resumes + 1)  # training seeds [lo, hi)
        if self.eval_every is not None and lo < self.eval_seed + self.eval_episodes and self.eval_seed < hi:
            raise ConfigError(f"training seeds {lo}..{hi - 1} meet the validation seeds {self.eval_seed}.."
                              f"{self.eval_seed + self.eval_episodes - 1}; choose another --seed or "
                              "--eval-seed")
        if lo < TEST_SEED + TEST_EPISODES and TEST_SEED < hi:
            raise ConfigError(f"training seeds {lo}..{hi - 1} meet the test drops {TEST_SEED}.."
                              f"{TEST_SEED + TEST_EPISODES - 1} (compare --seed {TEST_SEED}); choose --seed "
                              f"so that seed + envs x (resumes + 1) <= {TEST_SEED}, or above "
                              f"{TEST_SEED + TEST_EPISODES}")

    def to_dict(self) -> dict:
        return {"tensorboard": self.tensorboard, "checkpoint_every": self.checkpoint_every,
                "keep_checkpoints": self.keep_checkpoints, "eval_every": self.eval_every,
                "eval_episodes": self.eval_episodes, "eval_seed": self.eval_seed, "label": self.label}


# -- building -----------------------------------------------------------------------------------
def _vec_env(cfg: RunConfig, num_envs: int, evaluation: bool = False):
    """The bare native SB3 vector env of ``cfg`` (no monitor); ``evaluation``: the test's objective,
    without reward penalties and with every episode the whole horizon."""
    from impact_env.env.sb3_vecenv import make_sb3_vec_env

    kwargs = dict(cfg.env_kwargs)
    if evaluation:
        kwargs.update(EVALUATION_OPTIONS)  # (the task's options that carry an evaluation value)
    env = make_sb3_vec_env(cfg.scene, num_envs=num_envs, overrides=cfg.overrides or None, monitor=False,
                           **kwargs)
    if cfg.action_limit is not None:  # the policy's bounds for a residual (YAML vec_env_wrapper)
        from impact_env.env.sb3_vecenv import ActionLimit

        env = ActionLimit(env, cfg.action_limit)
    return env


def _algo_kwargs(cfg: RunConfig) -> dict:
    hp = dict(cfg.hyperparameters)
    for key in ("learning_rate", "clip_range"):
        v = hp.get(key)
        if isinstance(v, str) and v.startswith("lin_"):
            x = float(v[4:])
            hp[key] = lambda progress, x=x: progress * x  # RL Zoo's linear schedule (progress 1 -> 0)
    if isinstance(hp.get("train_freq"), list):
        hp["train_freq"] = tuple(hp["train_freq"])
    return hp


def _period_per_step(cfg: RunConfig) -> tuple[float, float]:
    """(seconds per policy step, control period in s)."""
    from impact_env.scene import load_scene

    scene = load_scene(cfg.scene, cfg.overrides or None)
    return scene.control_period * cfg.hold_ticks, scene.control_period


def _latest_checkpoint(out: Path) -> tuple[Path, int] | None:
    best = None
    for p in (out / "checkpoints").glob("model_*_steps.zip"):
        try:
            n = int(p.stem.split("_")[1])
        except (IndexError, ValueError):
            continue
        if best is None or n > best[1]:
            best = (p, n)
    return best


def _check_out(out: Path) -> None:
    if out.is_file():
        raise ConfigError(f"--out {str(out)!r} is a file; give a folder")
    if out.is_dir() and any((out / name).exists() for name in ("run.json", "model.zip", "checkpoints")):
        raise ConfigError(f"--out {str(out)!r} already holds a run; continue it with --resume {out}, "
                          "or choose another folder")


# -- training -----------------------------------------------------------------------------------
def run(cfg: RunConfig, out, tooling: Tooling = Tooling(), *, progress: bool = False,
        torch_threads: int | None = 1, verbose: int = 0, resume: bool = False) -> TrainResult:
    """Train as ``cfg`` says into ``out`` (or continue the run there with ``resume``).  Every
    setting is checked before ``out`` is created."""
    out = Path(out)
    state = None
    if resume:
        state = json.loads((out / "run.json").read_text())
        ckpt = _latest_checkpoint(out)
        if ckpt is None:
            raise ConfigError(f"--resume {str(out)!r}: no checkpoint in {out / 'checkpoints'} (train with "
                              "--checkpoint-every N to make them)")
        if ckpt[1] >= cfg.n_timesteps:
            raise ConfigError(f"--resume {str(out)!r}: the last checkpoint is at step {ckpt[1]}, the run's "
                              f"budget is {cfg.n_timesteps}; raise it with --steps")
        resumes = len(state["segments"])
    else:
        _check_out(out)
        resumes = 0
    tooling.check(cfg, resumes)
    if torch_threads is not None and (isinstance(torch_threads, bool) or not isinstance(torch_threads, int)
                                      or torch_threads < 1):
        raise ConfigError(f"torch_threads = {torch_threads!r} must be an integer >= 1")

    import torch
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.vec_env import VecMonitor

    from agents.callbacks import (
        CheckpointWithSettings,
        EpisodeStats,
        EvalLine,
        FinalEval,
        FixedSeeds,
        SettingsBeside,
        StepTimer,
    )

    if torch_threads is not None:
        torch.set_num_threads(int(torch_threads))
    out.mkdir(parents=True, exist_ok=True)
    if state is None:
        state = {"config": cfg.to_dict(), "tooling": tooling.to_dict(), "segments": []}
    else:
        state["config"]["n_timesteps"] = cfg.n_timesteps
        state["tooling"]["label"] = tooling.label  # a new name given with --resume, for the next one too
    (out / "run.json").write_text(json.dumps(state, indent=2) + "\n")

    raw = _vec_env(cfg, cfg.n_envs)
    timer = StepTimer(raw)  # the env's share of the wall time
    venv = VecMonitor(timer)
    cls = PPO if cfg.algo == "ppo" else SAC
    env_seed = cfg.seed + resumes * cfg.n_envs
    tb = tooling.tensorboard
    tb_name = f"{cfg.algo}_seed{cfg.seed}"
    if resume:
        path, _ = _latest_checkpoint(out)
        model = cls.load(str(path), env=venv, device="cpu", tensorboard_log=tb)
        model.set_random_seed(cfg.seed + resumes)
        buf = path.with_name(path.name.replace("model_", "model_replay_buffer_").replace(".zip", ".pkl"))
        if cfg.algo == "sac" and buf.is_file():
            model.load_replay_buffer(str(buf))
    else:
        policy = cfg.policy
        if policy != "MlpPolicy":  # agents.policies.Asymmetric*: the class itself
            import agents.policies

            policy = getattr(agents.policies, policy.rsplit(".", 1)[1])
        model = cls(policy, venv, seed=cfg.seed, device="cpu", policy_kwargs=cfg.policy_kwargs,
                    verbose=verbose, tensorboard_log=tb, **_algo_kwargs(cfg))
        if cfg.algo == "sac" and "log_std_init" in cfg.policy_kwargs:  # SB3 reads it only with gSDE
            from agents.policies import init_sac_actor

            init_sac_actor(model, cfg.policy_kwargs["log_std_init"])
    venv.seed(env_seed)  # env i: env_seed + i at the first reset of this segment
    start_step = int(model.num_timesteps)

    total = planned_steps(cfg, start_step)  # where the run ends: PPO's whole rollouts, SAC's vector steps
    print(budget_line(cfg, start_step), file=sys.stderr, flush=True)
    stats = EpisodeStats(window=100)
    callbacks: list = [stats]
    bar = None
    if progress:  # SB3's tqdm/rich bar, on a terminal by default (main)
        import warnings

        from stable_baselines3.common.callbacks import ProgressBarCallback
        from tqdm import TqdmExperimentalWarning

        warnings.filterwarnings("ignore", category=TqdmExperimentalWarning)  # tqdm.rich's "experimental"
        bar = ProgressBarCallback()
        callbacks.append(bar)
    eval_cb = None
    settings = model_settings(cfg)
    if tooling.eval_every is not None:
        eval_raw = _vec_env(cfg, tooling.eval_episodes, evaluation=True)
        eval_env = VecMonitor(FixedSeeds(eval_raw, tooling.eval_seed))
        # one line per evaluation without the bar (logs, pipes); with it, the bar says enough
        line = None if bar is not None else EvalLine(stats, total, sys.stderr, start_step)
        eval_cb = FinalEval(eval_env, n_eval_episodes=tooling.eval_episodes,
                            eval_freq=max(tooling.eval_every // cfg.n_envs, 1), log_path=str(out / "eval"),
                            best_model_save_path=str(out), deterministic=True, verbose=verbose,
                            callback_on_new_best=SettingsBeside(out / "best_model.zip", settings),
                            callback_after_eval=line, timer=timer)
        _restore_evaluations(eval_cb, out / "eval" / "evaluations.npz")
        callbacks.append(eval_cb)
    if tooling.checkpoint_every is not None:
        every = max(tooling.checkpoint_every // cfg.n_envs, 1)
        callbacks.append(CheckpointWithSettings(settings, save_freq=every, save_path=str(out / "checkpoints"),
                                                name_prefix="model", save_replay_buffer=cfg.algo == "sac",
                                                keep=tooling.keep_checkpoints))
    load0 = _load_average()
    cpu0 = time.process_time()
    t0 = time.perf_counter()
    interrupted = False
    try:
        model.learn(total_timesteps=total - start_step, callback=callbacks, progress_bar=False,
                    reset_num_timesteps=not resume, tb_log_name=tb_name)
    except KeyboardInterrupt:  # Ctrl-C: keep what was learnt, with its settings, below
        interrupted = True
        if bar is not None and hasattr(bar, "pbar"):  # SB3 calls no _on_training_end here
            bar.pbar.refresh()
            bar.pbar.close()
        sys.stderr.write(f"agents.train: interrupted at step {int(model.num_timesteps)} of {total}\n")
    wall = time.perf_counter() - t0
    cpu = time.process_time() - cpu0  # this process's CPU time: on a shared machine, what the run cost
    load = [load0, _load_average()]  # the machine's 1-minute load average at the start and the end
    done_steps = int(model.num_timesteps)
    ticks = (done_steps - start_step) * cfg.hold_ticks  # every policy step is hold_ticks ticks
    model.save(out / "model.zip")
    checkpoint = None
    if interrupted or (tooling.checkpoint_every is not None
                       and not (out / "checkpoints" / f"model_{done_steps}_steps.zip").is_file()):
        # --resume continues only from checkpoints/ (model.zip may be a finished run's), and a new run
        # in this folder is refused: without this checkpoint an early Ctrl-C left a folder that
        # neither could use.  Written on Ctrl-C whatever --checkpoint-every says, and at the end of a
        # run with checkpoints (a budget below --checkpoint-every left checkpoints/ empty).
        checkpoint = _save_checkpoint(model, out, settings, replay_buffer=cfg.algo == "sac",
                                      keep=tooling.keep_checkpoints)
    venv.close()

    step_time, period = _period_per_step(cfg)
    state["segments"].append({"start_step": start_step, "end_step": done_steps, "env_seed": env_seed,
                              "model_seed": cfg.seed + resumes, "wall_time_s": round(wall, 2),
                              "ticks": ticks})
    (out / "run.json").write_text(json.dumps(state, indent=2) + "\n")
    wall_total = sum(s["wall_time_s"] for s in state["segments"])
    ticks_total = sum(s["ticks"] for s in state["segments"])
    seg_steps = done_steps - start_step
    train_stats = stats.stats(step_time)
    best = _best(out / "eval" / "evaluations.npz")
    history = _history(eval_cb)
    if best and cfg.residual is not None and not interrupted:
        # the residual's own law on the same validation drops (action 0 is the law): the run says
        # whether its best model beats it, and when it first did
        best["residual_law"] = cfg.residual
        best["residual_law_return"] = _law_return(cfg, tooling)
        first = next((h for h in history if h["return"] > best["residual_law_return"]), None)
        best["first_beats_law"] = first
    if best:
        best["drops"] = [tooling.eval_seed, tooling.eval_seed + tooling.eval_episodes - 1]
    if history:
        at_best = [h for h in history if h["step"] == best.get("step")]
        best["wall_s"] = at_best[-1]["wall_s"] if at_best else None
    meta = {"algo": cfg.algo, **({"label": tooling.label} if tooling.label else {}),
            "observation": cfg.observation, "history": cfg.history, "scene": cfg.scene,
            "overrides": dict(cfg.overrides), "env_kwargs": dict(cfg.env_kwargs),
            "hold_ticks": cfg.hold_ticks, "residual": cfg.residual, "steps": done_steps, "ticks": ticks_total,
            "envs": cfg.n_envs, "seed": cfg.seed, "wall_time_s": round(wall_total, 2),
            "steps_per_s": round(seg_steps / wall, 1), "ticks_per_s": round(ticks / wall, 1),
            "env_time_s": round(timer.seconds, 4), "env_share": round(timer.seconds / max(wall, 1e-9), 4),
            "torch_threads": torch_threads, "load_average": load, "cpu_time_s": round(cpu, 2),
            "control_period_s": period, "policy_period_s": step_time,
            "hyperparameters": {**cfg.hyperparameters, **cfg.policy_kwargs}, "conf_file": cfg.conf_file,
            "policy": cfg.policy,
            "episodes": len(stats.returns), "train_stats_last_episodes": train_stats,
            "validation": {"seeds": [tooling.eval_seed, tooling.eval_seed + tooling.eval_episodes - 1],
                           "best": best, "history": history} if eval_cb is not None else None,
            "segments": state["segments"], "versions": _versions(), "interrupted": interrupted}
    meta_path = out / "model.json"
    meta_path.write_text(json.dumps(meta, indent=2, default=str) + "\n")
    if (out / "best_model.zip").is_file():
        (out / "best_model.json").write_text(json.dumps({**meta, "steps": best.get("step")}, indent=2,
                                                        default=str) + "\n")
    return TrainResult(out / "model.zip", meta_path, cfg.algo, done_steps, wall, seg_steps / max(wall, 1e-9),
                       len(stats.returns), train_stats, ticks=ticks, best=best, interrupted=interrupted,
                       checkpoint=checkpoint, env_time_s=timer.seconds, scene=cfg.scene)



def _save_checkpoint(model, out: Path, settings: dict, replay_buffer: bool, keep: int | None = None) -> Path:
    """``checkpoints/model_<steps>_steps.zip`` with its settings file (and SAC's replay buffer),
    named as SB3's CheckpointCallback names them, so that :func:`_latest_checkpoint` finds it;
    then the older checkpoints beyond the newest ``keep`` are removed."""
    from agents.callbacks import prune_checkpoints, write_settings

    steps = int(model.num_timesteps)
    folder = out / "checkpoints"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"model_{steps}_steps.zip"
    model.save(path)
    write_settings(path, settings, steps=steps)
    if replay_buffer:
        model.save_replay_buffer(folder / f"model_replay_buffer_{steps}_steps.pkl")
    prune_checkpoints(folder, keep)
    return path


def model_settings(cfg: RunConfig) -> dict:
    """What a saved model means only with (``impact_env.policy.sb3.SETTINGS`` and its origin):
    written beside every model file, so that no saved model is ever evaluated without them."""
    return {"algo": cfg.algo, "observation": cfg.observation, "history": cfg.history, "scene": cfg.scene,
            "overrides": dict(cfg.overrides), "env_kwargs": dict(cfg.env_kwargs),
            "hold_ticks": cfg.hold_ticks, "residual": cfg.residual, "policy": cfg.policy}


def _restore_evaluations(cb, path: Path) -> None:
    """On --resume, EvalCallback starts from the evaluations (and best return) logged so far."""
    import numpy as np

    if not path.is_file():
        return
    d = np.load(path)
    cb.evaluations_timesteps = list(d["timesteps"])
    cb.evaluations_results = [list(r) for r in d["results"]]
    cb.evaluations_length = [list(r) for r in d["ep_lengths"]]
    if len(d["results"]):
        cb.best_mean_reward = float(np.max(np.mean(d["results"], axis=1)))


def _history(eval_cb) -> list[dict]:
    """Every evaluation of this segment: policy step, training wall time before it (the
    evaluations' own time excluded), the env's part of it, and the validation return."""
    if eval_cb is None:
        return []
    k = len(eval_cb.wall_s)
    steps = eval_cb.evaluations_timesteps[-k:] if k else []
    results = eval_cb.evaluations_results[-k:] if k else []
    return [{"step": int(st), "wall_s": round(w, 3), "env_s": round(e, 3),
             "return": round(float(sum(r) / len(r)), 4)}
            for st, w, e, r in zip(steps, eval_cb.wall_s, eval_cb.env_s, results, strict=True)]


def _law_return(cfg: RunConfig, tooling: Tooling) -> float:
    """Mean validation return of the residual's law alone: the evaluation env (the same drops, the
    same objective) with every action 0."""
    import numpy as np

    from agents.callbacks import FixedSeeds

    env = FixedSeeds(_vec_env(cfg, tooling.eval_episodes, evaluation=True), tooling.eval_seed)
    env.reset()
    total = np.zeros(env.num_envs)
    done = np.zeros(env.num_envs, dtype=bool)
    zero = np.zeros((env.num_envs, 1), dtype=np.float32)
    while not done.all():  # every validation episode runs the whole horizon (no termination)
        _, rewards, dones, _ = env.step(zero)
        total += np.where(done, 0.0, rewards)
        done |= dones
    env.close()
    return float(total.mean())


def _best(path: Path) -> dict:
    import numpy as np

    if not path.is_file():
        return {}
    d = np.load(path)
    if not len(d["results"]):
        return {}
    means = np.mean(d["results"], axis=1)
    k = int(np.argmax(means))
    return {"step": int(d["timesteps"][k]), "mean_reward": float(means[k]), "evaluations": int(len(means))}


def train(algo: str = "ppo", scene=None, overrides: dict | None = None, *, steps: int | None = None,
          envs: int | None = None, seed: int = 0, out, observation: str | None = None,
          history: int | None = None, env_kwargs: dict | None = None, hyperparameters: dict | None = None,
          options: dict | None = None, conf_file=None, tooling: Tooling | None = None, progress: bool = False,
          torch_threads: int | None = 1, verbose: int = 0) -> TrainResult:
    """Train ``algo`` into ``out``: the YAML entry of ``conf_file`` (default
    ``agents/hyperparams/ALGO.yml``) with these arguments overriding it (None: the file's value).
    ``env_kwargs`` go to ``ImpactCatch-v0``; ``options`` are more env kwargs (``hold_ticks``,
    ``residual``; kept for callers of the first version); ``hyperparameters`` override single
    hyperparameters or policy kwargs.
    Raises :class:`~impact_env.config.ConfigError` (a ValueError) on any bad value, before
    anything is created.  Default ``tooling``: evaluation every 100k steps, no checkpoints."""
    cfg = make_config(algo, conf_file, scene=scene, overrides=overrides, steps=steps, envs=envs, seed=seed,
                      observation=observation, history=history, env_kwargs=env_kwargs,
                      hyperparameters=hyperparameters, options=options)
    return run(cfg, out, tooling or Tooling(), progress=progress, torch_threads=torch_threads,
               verbose=verbose)


def make_config(algo, conf_file=None, *, env_id: str = ENV_ID, scene=None, overrides=None, steps=None,
                envs=None, seed=0, observation=None, history=None, env_kwargs=None, hyperparameters=None,
                options=None, policy=None, action_limit=None) -> RunConfig:
    """The :class:`RunConfig` of a YAML entry with these values overriding it (None: the file's)."""
    algo = str(algo).lower()
    if algo not in ALGOS:
        raise ConfigError(f"algo = {algo!r}; expected one of {', '.join(ALGOS)}")
    conf = Path(conf_file) if conf_file is not None else default_conf_file(algo)
    entry = read_conf(conf, env_id)
    env_over = dict(env_kwargs or {})
    if observation is not None:
        if observation not in OBSERVATIONS:
            raise ConfigError(f"observation = {observation!r}; expected one of {', '.join(OBSERVATIONS)}")
        env_over["observation"] = observation
    if history is not None:
        env_over["history"] = history
    env_over.update(options or {})
    if scene is not None and not isinstance(scene, str):
        raise ConfigError(f"scene = {scene!r}: give a preset name or a .toml path (it is recorded in "
                          "model.json)")
    if action_limit is not None:  # as the YAML's vec_env_wrapper would give it
        from agents.run_config import ACTION_LIMIT

        entry["vec_env_wrapper"] = [{ACTION_LIMIT: {"limit": action_limit}}]
    return resolve(algo, entry, seed=seed, n_timesteps=steps, n_envs=envs, hp_overrides=hyperparameters,
                   env_overrides=env_over, scene=scene, overrides=overrides, conf_file=str(conf),
                   policy=policy)



# -- command line ---------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    from impact_env.cli import add_scene_arguments

    p = argparse.ArgumentParser(prog="python -m agents.train", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="Hyperparameters: agents/hyperparams/*.yml (RL Zoo format).")
    p.add_argument("--algo", choices=ALGOS, help="ppo or sac (required unless --resume or --quick)")
    p.add_argument("--quick", action="store_true",
                   help="a first agent in about a minute: the YAML's settings with a budget of "
                        f"{QUICK_STEPS['ppo']:,} policy steps for PPO ({QUICK_STEPS['sac']:,} for SAC), "
                        f"evaluated every {QUICK_EVAL_EVERY['ppo']:,} (SAC {QUICK_EVAL_EVERY['sac']:,}); "
                        "--algo defaults to ppo and --out to the first free runs/quick[-N]; at the end "
                        "the run says whether it beats pd-penetration on the validation drops")
    p.add_argument("--teacher", default=None, metavar="law:NAME",
                   help="with --quick: no RL, a student on its sensor frame and the scene's Kalman filter's "
                        "estimate, imitating this compiled classic law by DAgger on rig (agents.distill; e.g. "
                        "law:mpc-state), with the budget QUICK_DAGGER")
    p.add_argument("--conf-file", default=None, metavar="YML",
                   help="RL-Zoo-style hyperparameters (default agents/hyperparams/ALGO.yml)")
    p.add_argument("--env", default=ENV_ID, help=f"entry of the YAML file (default {ENV_ID})")
    add_scene_arguments(p, default=None, default_text="the YAML's, rig")
    p.add_argument("--steps", type=int, default=None,
                   help="policy steps to train for (default: the YAML's n_timesteps; PPO trains whole "
                        "rollouts of n_steps x n_envs, so N is rounded up to one, and says so)")
    p.add_argument("--envs", type=int, default=None, help="rigs stepped together (default: n_envs)")
    p.add_argument("--seed", type=int, default=0, help="model seed; env i starts from seed + i (default 0)")
    p.add_argument("--out", metavar="DIR", help="run folder (required unless --resume)")
    p.add_argument("--label", default=None, metavar="NAME",
                   help="the run's name in reports (model.json; default ALGO[-priv]-sSEED)")
    p.add_argument("--policy", default=None,
                   help="MlpPolicy, or with --observation both the asymmetric actor-critic: "
                        "agents.policies.AsymmetricActorCriticPolicy (ppo) or "
                        "agents.policies.AsymmetricSACPolicy (sac): the actor reads the sensors, the critic "
                        "the true state too")
    p.add_argument("--observation", choices=OBSERVATIONS, default=None, help="default: the YAML's (sensors)")
    p.add_argument("--history", type=int, default=None, help="frames stacked in the observation")
    p.add_argument("--horizon", type=float, default=None, help="episode length, s (default: the scene's)")
    p.add_argument("--env-kwargs", action="append", default=[], metavar="KEY=VALUE",
                   help="an ImpactCatch-v0 argument or option (effort_weight=0.1, hold_ticks=4, "
                        "residual=pd-penetration, terminate_on_catch=False); repeatable")
    p.add_argument("--hp", action="append", default=[], metavar="KEY=VALUE",
                   help="override a hyperparameter (Python literal), e.g. --hp learning_rate=1e-4")
    p.add_argument("--action-limit", type=float, default=None, metavar="L",
                   help="the policy's action bounds +-L (fraction of the command scale, 0 < L <= 1; "
                        "default: the YAML's vec_env_wrapper ActionLimit, else +-1)")
    p.add_argument("--tensorboard", default=None, metavar="DIR", help="TensorBoard log folder")
    p.add_argument("--checkpoint-every", type=int, default=CHECKPOINT_EVERY, metavar="N",
                   help=f"save a checkpoint (and its settings file) every N policy steps, what --resume "
                        f"continues from (default {CHECKPOINT_EVERY}; 0: never)")
    p.add_argument("--keep-checkpoints", type=int, default=1, metavar="K",
                   help="keep the newest K checkpoints, removing older ones (default 1: what --resume "
                        "needs; 0: keep all)")
    p.add_argument("--eval-every", type=int, default=None, metavar="N",
                   help="evaluate on the validation drops every N policy steps, keep the best (0: never; "
                        "default 100000, with --quick the quick budget's)")
    p.add_argument("--eval-episodes", type=int, default=16, help="validation drops (default 16)")
    p.add_argument("--eval-seed", type=int, default=EVAL_SEED,
                   help=f"first validation seed (default {EVAL_SEED})")
    p.add_argument("--resume", metavar="DIR", default=None,
                   help="continue the run in DIR from its last checkpoint, with its settings")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="SB3's progress bar (tqdm + rich) in policy steps, ending where the budget "
                        "line says (default: on when stderr is a terminal; otherwise one line per "
                        "evaluation on stderr)")
    p.add_argument("--torch-threads", type=int, default=1, help="torch CPU threads (default 1)")
    p.add_argument("--verbose", type=int, default=0, help="SB3 verbosity (0, 1, 2)")
    return p


SETTING_FLAGS = ("algo", "policy", "conf_file", "scene", "set", "envs", "observation", "history", "horizon",
                 "env_kwargs", "hp", "tensorboard", "checkpoint_every", "out", "action_limit", "label")


def _from_args(args) -> tuple[RunConfig, Path, Tooling, bool]:
    from impact_env.cli import parse_overrides

    if args.resume is not None:
        given = [f"--{k.replace('_', '-')}" for k in SETTING_FLAGS if getattr(args, k) not in (None, [])
                 and k != "label"
                 and not (k == "checkpoint_every" and args.checkpoint_every == CHECKPOINT_EVERY)]
        if given:
            raise ConfigError(f"--resume takes the run's settings from {args.resume}/run.json; drop "
                              f"{', '.join(given)} (only --steps, --label, --progress, --torch-threads, "
                              "--verbose go with it)")
        out = Path(args.resume)
        if not (out / "run.json").is_file():
            raise ConfigError(f"--resume {args.resume!r}: no run.json there (not a run folder of "
                              "agents.train)")
        state = json.loads((out / "run.json").read_text())
        cfg = RunConfig.from_dict(state["config"])
        if args.steps is not None:
            if args.steps < 1:
                raise ConfigError(f"--steps {args.steps} must be >= 1")
            cfg.n_timesteps = args.steps
        tooling = Tooling(**state["tooling"])
        if args.label is not None:
            # a run continued to a longer budget is another run in reports (a copy of the folder
            # extended, say): it may take a new name; its settings stay the run's
            tooling = replace(tooling, label=args.label)
        return cfg, out, tooling, True
    if args.quick:
        args.algo = args.algo or "ppo"
        args.out = args.out or str(_free_folder(Path("runs") / "quick"))
        if args.steps is None:
            args.steps = QUICK_STEPS[args.algo]
        if args.eval_every is None:
            args.eval_every = QUICK_EVAL_EVERY[args.algo]
    if args.algo is None or args.out is None:
        raise ConfigError("--algo and --out are required (or --resume DIR, or --quick)")
    if args.eval_every is None:
        args.eval_every = EVAL_EVERY
    env_kwargs = _pairs(args.env_kwargs, "--env-kwargs")
    if args.horizon is not None:
        if not (args.horizon > 0 and math.isfinite(args.horizon)):
            raise ConfigError(f"--horizon {args.horizon} s must be a finite time > 0 s")
        env_kwargs["horizon"] = args.horizon
    cfg = make_config(args.algo, args.conf_file, env_id=args.env, scene=args.scene,
                      overrides=parse_overrides(args.set) or None, steps=args.steps, envs=args.envs,
                      seed=args.seed, observation=args.observation, history=args.history,
                      env_kwargs=env_kwargs, hyperparameters=_pairs(args.hp, "--hp"), policy=args.policy,
                      action_limit=args.action_limit)
    if args.keep_checkpoints < 0:
        raise ConfigError(f"--keep-checkpoints {args.keep_checkpoints} must be >= 0 (0: keep all)")
    tooling = Tooling(tensorboard=args.tensorboard, checkpoint_every=args.checkpoint_every or None,
                      keep_checkpoints=args.keep_checkpoints or None,
                      eval_every=args.eval_every or None, eval_episodes=args.eval_episodes,
                      eval_seed=args.eval_seed, label=args.label)
    return cfg, Path(args.out), tooling, False


def _free_folder(base: Path) -> Path:
    """``base`` if it holds no run, else the first ``base-N`` (N = 1, 2, ...) that holds none."""
    k, path = 0, base
    while path.exists() and any((path / name).exists() for name in ("run.json", "model.zip", "checkpoints")):
        k += 1
        path = base.with_name(f"{base.name}-{k}")
    return path


def steps_per_collection(cfg: RunConfig) -> int:
    """Policy steps SB3 collects between two looks at the budget: PPO a whole rollout (n_steps x
    n_envs), SAC train_freq vector steps of n_envs (1 for a train_freq counted in episodes)."""
    hp = cfg.hyperparameters
    if cfg.algo == "ppo":
        return int(hp.get("n_steps", 2048)) * cfg.n_envs
    freq = hp.get("train_freq", 1)
    if isinstance(freq, (list, tuple)):
        freq = freq[0] if freq[1] == "step" else 1
    return int(freq) * cfg.n_envs


def planned_steps(cfg: RunConfig, start_step: int = 0) -> int:
    """The policy step the run ends at: ``n_timesteps`` rounded up to whole collections from
    ``start_step`` (SB3 stops only between them)."""
    per = steps_per_collection(cfg)
    return start_step + -(-max(cfg.n_timesteps - start_step, 0) // per) * per


def budget_line(cfg: RunConfig, start_step: int = 0) -> str:
    """What the run will do, said before it starts: the budget, its rounding and the env."""
    total = planned_steps(cfg, start_step)
    per = steps_per_collection(cfg)
    what = (f"whole PPO rollouts of {cfg.hyperparameters.get('n_steps', 2048)} x {cfg.n_envs} envs"
            if cfg.algo == "ppo" else
            f"whole vector steps of {cfg.n_envs} envs x train_freq {per // cfg.n_envs}")
    rounding = (f" (--steps {cfg.n_timesteps} rounded up to {what} = {per} steps)"
                if total - start_step != cfg.n_timesteps - start_step else "")
    start = f" from step {start_step}" if start_step else ""
    return (f"agents.train: {cfg.algo} training {total - start_step} policy steps{start}, to step {total}"
            f"{rounding}; {(total - start_step) * cfg.hold_ticks} control periods "
            f"(hold_ticks {cfg.hold_ticks}), {cfg.n_envs} envs of {cfg.scene}")


def _missing_extra() -> list[str]:
    """The modules of the extra ``impact-env[sb3]`` that training needs and this install lacks."""
    import importlib.util

    return [m for m in ("stable_baselines3", "torch", "yaml") if importlib.util.find_spec(m) is None]


def quick_dagger(args) -> int:
    """``--quick --teacher law:NAME``: a student on its sensor frame and the filter's estimate,
    distilled from the law by DAgger on :data:`QUICK_SCENE` (unless ``--scene``)
    (:func:`agents.distill.distill` with :data:`QUICK_DAGGER`) into ``--out`` or the first free
    ``runs/quick[-N]``; its last line names the model to evaluate and the command that does."""
    from agents import law_teacher
    from agents.distill import distill, verdict_line

    if not args.quick:
        raise ConfigError("--teacher goes with --quick (or use python -m agents.distill)")
    given = [f"--{k.replace('_', '-')}" for k in ("algo", "steps", "envs", "observation", "history", "policy",
                                                   "conf_file", "hp", "resume", "action_limit")
             if getattr(args, k) not in (None, [])]
    if given:
        raise ConfigError(f"--quick --teacher trains a DAgger student with its own budget; drop "
                          f"{', '.join(given)}")
    if not law_teacher.is_law_teacher(args.teacher):
        raise ConfigError(f"--teacher {args.teacher!r}: choose {law_teacher.choices_text()}")
    law_teacher.parse_teacher(args.teacher)
    out = Path(args.out) if args.out else _free_folder(Path("runs") / "quick")
    meta = distill(args.teacher, out, seed=args.seed, eval_episodes=args.eval_episodes,
                   eval_seed=args.eval_seed, torch_threads=args.torch_threads, scene=args.scene or QUICK_SCENE,
                   env_kwargs=_pairs(args.env_kwargs, "--env-kwargs") or None, **QUICK_DAGGER)
    best = out / "best_model.zip"
    law = args.teacher[len(law_teacher.PREFIX):]
    print(verdict_line(meta, best))
    print(f"saved {out / 'model.zip'} (the last model); the model to evaluate is the best on the validation "
          f"drops, {best}")
    print(f"next: impact-env compare --scene rig --policies pd-penetration,{law},ppo:{best} --episodes 100 "
          f"--seed {TEST_SEED} --out {out / 'compare'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    missing = _missing_extra()
    if missing:  # the core install (pip install -e .): one line with the fix, not a deep traceback
        print(f"agents.train: training needs the extra 'sb3' ({', '.join(missing)} not installed): "
              "pip install 'impact-env[sb3]' (README: install torch's CPU build first)", file=sys.stderr)
        return 2
    try:
        if args.quick and args.resume is not None:
            raise ConfigError("--quick starts a new run; drop it with --resume")
        if args.teacher is not None:
            return quick_dagger(args)
        cfg, out, tooling, resume = _from_args(args)
        progress = sys.stderr.isatty() if args.progress is None else args.progress
        result = run(cfg, out, tooling, progress=progress, torch_threads=args.torch_threads,
                     verbose=args.verbose, resume=resume)
    except ConfigError as exc:
        print(f"agents.train: {exc}", file=sys.stderr)
        return 2
    print(result.summary())
    return 130 if result.interrupted else 0


if __name__ == "__main__":
    sys.exit(main())
