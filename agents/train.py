"""Train a PPO or SAC agent (stable-baselines3) on ``ImpactCatch-v0`` and save it for the comparison.

    python -m agents.train --algo ppo --scene rig --steps 2000000 --envs 16 --seed 0 \\
        --out agents/models/ppo_rig [--set plant.m1=0.05] [--observation sensors --history 4] \\
        [--horizon 0.2] [--hp learning_rate=1e-4 --hp net_arch=[32,32]]

The vector env is the native one (:func:`impact_env.env.sb3.make_sb3_vec_env`, all ``--envs``
rigs stepped in one compiled call) wrapped in SB3's ``VecMonitor`` for episode statistics.  It is
**not** normalised (no ``VecNormalize``): the env already divides every observation by a reference
scale so that it is of order one, and the reward is ``-(E/E0) * T / 1 ms``, 0.1 per step at most
on ``rig``; leaving normalisation out means a saved ``model.zip`` is the whole policy and
``impact-env compare`` evaluates exactly what was trained.

Writes ``OUT/model.zip`` and ``OUT/model.json`` (read by :mod:`baselines.sb3`: ``observation``,
``history``; plus ``algo``, ``scene``, ``overrides``, ``steps``, ``envs``, ``seed``,
``wall_time_s``, the hyperparameters and the last episodes' statistics).  Evaluate with
``impact-env compare --scene rig --policies passive,ppo:OUT/model.zip --seed 1000`` (pick
seeds that training did not use: its env i starts from seed ``seed + i`` and then draws its
next episodes from its own generator).

Seeding: ``seed`` goes to the model (``torch``, ``numpy``, ``random`` and the action sampling)
and to the env (env i reset with ``seed + i``), so a run is reproducible on the same machine and
thread count.
"""

from __future__ import annotations

import argparse
import ast
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

ALGOS = ("ppo", "sac")
OBSERVATIONS = ("sensors", "privileged", "both")

# Hyperparameters and why.  A step is one control period (100 us on ``rig``); an episode is up to
# 4000 steps (0.4 s), and a caught drop ends earlier.
PPO_DEFAULTS: dict = {
    # 256 steps x envs per rollout (4096 with 16 envs): about one episode's length of experience per
    # update, so updates come often on a CPU budget while GAE still sees whole contact events.
    "n_steps": 256,
    # big minibatches: fewer optimiser calls per sample, which is what costs on 2 CPU cores.
    "batch_size": 1024,
    # 5 passes over each rollout (SB3 default 10): half the gradient cost, little loss per sample
    # with a dense reward.
    "n_epochs": 5,
    # discount 0.995 = a horizon of ~200 steps = 20 ms: one contact lasts ~1-2 ms but its
    # consequence (the next bounce) comes 10-30 ms later; 0.99 (10 ms) would not see it.
    "gamma": 0.995,
    "gae_lambda": 0.95,  # SB3 default: bias/variance trade-off of the advantage
    "learning_rate": 3e-4,  # SB3 / Adam default, known to work for small MLPs
    "clip_range": 0.2,  # SB3 default
    "ent_coef": 0.0,  # exploration comes from the Gaussian's own std (below)
    # a small MLP: the observation has 4 x history entries; two layers of 64 cost little per step.
    "net_arch": [64, 64],
    # initial action std exp(-1) = 0.37 (SB3 default 1.0): with std 1 half of all commands would
    # saturate at +-200 N, shaking the rig so hard that the passive drop's return (-65) is never
    # approached early on.
    "log_std_init": -1.0,
    # generalised state-dependent exploration with a tanh-squashed mean (``--hp use_sde=True --hp
    # squash_output=True``): off by default (SB3's); the Gaussian's mean is otherwise unbounded and
    # can drift past the +-1 clip, where the env gives it no gradient back.
    "use_sde": False,
    "squash_output": False,
    "max_grad_norm": 0.5,  # SB3 default; clips the joint actor-critic gradient
}
SAC_DEFAULTS: dict = {
    "buffer_size": 300_000,  # ~75 full episodes; 2.4 MB per 100k transitions with a 4-entry obs
    "learning_starts": 10_000,  # a few episodes of random actions before the first update
    "batch_size": 256,  # SB3 default
    "gamma": 0.995,  # as PPO: ~20 ms horizon, the time to the next bounce
    "tau": 0.005,  # SB3 default target smoothing
    "learning_rate": 3e-4,  # SB3 default
    # one gradient step per vector step of all envs: the update-to-data ratio is 1/envs, which
    # keeps SAC's per-sample cost near PPO's on a CPU; raise it for sample efficiency.
    "train_freq": 1,
    "gradient_steps": 1,
    "ent_coef": "auto",  # SAC's target-entropy tuning
    "net_arch": [64, 64],  # as PPO
    "log_std_init": -1.0,  # as PPO: start with moderate commands (SB3's SAC default is -3)
}
POLICY_KWARGS = ("net_arch", "log_std_init", "squash_output")  # go to policy_kwargs, not the algorithm


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

    def summary(self) -> str:
        s = self.stats
        lines = [f"{self.algo}: {self.steps} env-steps in {self.wall_time_s:.1f} s "
                 f"({self.steps_per_s:.0f} steps/s), {self.episodes} episodes finished"]
        if s.get("episodes_last"):
            lines.append(f"last {s['episodes_last']} episodes: return {s['return_mean']:.2f} "
                         f"(min {s['return_min']:.2f}, max {s['return_max']:.2f}), length "
                         f"{s['length_mean_s'] * 1e3:.1f} ms, caught {100 * s['caught_fraction']:.0f} %, "
                         f"diverged {s['diverged']}")
        if s.get("return_first_mean") is not None:
            lines.append(f"first {s['episodes_first']} episodes: return {s['return_first_mean']:.2f}")
        lines.append(f"saved {self.model_path} and {self.meta_path}")
        return "\n".join(lines)


def _hyperparameters(algo: str, overrides: dict | None) -> tuple[dict, dict]:
    """(algorithm kwargs, policy_kwargs) from the defaults with ``overrides`` applied."""
    defaults = PPO_DEFAULTS if algo == "ppo" else SAC_DEFAULTS
    hp = dict(defaults)
    for key, value in (overrides or {}).items():
        if key not in defaults:
            raise ValueError(f"unknown {algo} hyperparameter {key!r}; valid: {', '.join(defaults)}")
        hp[key] = value
    policy_kwargs = {k: hp.pop(k) for k in POLICY_KWARGS if k in hp}
    if algo == "ppo":
        arch = list(policy_kwargs["net_arch"])
        policy_kwargs["net_arch"] = {"pi": arch, "vf": list(arch)}  # separate actor and critic
    return hp, policy_kwargs


def _stats_callback(window: int):
    from stable_baselines3.common.callbacks import BaseCallback

    class EpisodeStats(BaseCallback):
        """Collects the return, length, caught and diverged flags of every finished episode."""

        def __init__(self):
            super().__init__()
            self.returns: list[float] = []
            self.lengths: list[int] = []
            self.caught: list[bool] = []
            self.diverged = 0

        def _on_step(self) -> bool:
            for info in self.locals.get("infos", ()):
                ep = info.get("episode")
                if ep is not None:
                    self.returns.append(float(ep["r"]))
                    self.lengths.append(int(ep["l"]))
                    self.caught.append(bool(info.get("caught", False)))
                    self.diverged += bool(info.get("diverged", False))
            return True

        def stats(self, period: float) -> dict:
            import numpy as np

            n = min(window, len(self.returns))
            if n == 0:
                return {"episodes_last": 0}
            r = np.asarray(self.returns[-n:])
            m = min(window, len(self.returns) - n) or n  # the first episodes, apart from the last ones
            return {"episodes_last": n, "return_mean": float(r.mean()), "return_min": float(r.min()),
                    "return_max": float(r.max()),
                    "length_mean_s": float(np.mean(self.lengths[-n:]) * period),
                    "caught_fraction": float(np.mean(self.caught[-n:])), "diverged": int(self.diverged),
                    "episodes_first": m, "return_first_mean": float(np.mean(self.returns[:m]))}

    return EpisodeStats()


def train(algo: str = "ppo", scene="rig", overrides: dict | None = None, *, steps: int, envs: int = 16,
          seed: int = 0, out, observation: str = "sensors", history: int = 1, env_kwargs: dict | None = None,
          hyperparameters: dict | None = None, torch_threads: int | None = 1,
          verbose: int = 0) -> TrainResult:
    """Train ``algo`` for ``steps`` env-steps on ``envs`` rigs of ``scene`` (+ ``overrides``) and
    save ``out/model.zip`` and ``out/model.json``.  ``env_kwargs`` go to ``ImpactCatch-v0``
    (``horizon``, ``effort_weight``, ...); ``hyperparameters`` override :data:`PPO_DEFAULTS` /
    :data:`SAC_DEFAULTS`; ``torch_threads`` caps torch's CPU threads (None: torch's default)."""
    algo = str(algo).lower()
    if algo not in ALGOS:
        raise ValueError(f"algo = {algo!r}; expected one of {', '.join(ALGOS)}")
    for name, v, lo in (("steps", steps, 1), ("envs", envs, 1), ("seed", seed, 0), ("history", history, 1)):
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise ValueError(f"{name} = {v!r} must be an integer >= {lo}")
    if observation not in OBSERVATIONS:
        raise ValueError(f"observation = {observation!r}; expected one of {', '.join(OBSERVATIONS)}")
    env_kwargs = dict(env_kwargs or {})
    for key in ("observation", "history", "overrides"):
        if key in env_kwargs:
            raise ValueError(f"env_kwargs must not hold {key!r}: pass it as train()'s own argument")
    hp, policy_kwargs = _hyperparameters(algo, hyperparameters)

    import torch
    from stable_baselines3 import PPO, SAC

    from impact_env.env.sb3 import make_sb3_vec_env
    from impact_env.scene import Scene

    if torch_threads is not None:
        torch.set_num_threads(int(torch_threads))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    venv = make_sb3_vec_env(scene, num_envs=envs, overrides=overrides, observation=observation,
                            history=history, **env_kwargs)  # in a VecMonitor
    period = venv.get_attr("scene")[0].control_period
    venv.seed(seed)
    cls = PPO if algo == "ppo" else SAC
    model = cls("MlpPolicy", venv, seed=seed, device="cpu", policy_kwargs=policy_kwargs, verbose=verbose,
                **hp)
    callback = _stats_callback(window=100)
    t0 = time.perf_counter()
    model.learn(total_timesteps=steps, callback=callback, progress_bar=False)
    wall = time.perf_counter() - t0
    done_steps = int(model.num_timesteps)
    model_path = out / "model.zip"
    model.save(model_path)
    venv.close()
    stats = callback.stats(period)
    scene_name = scene.name if isinstance(scene, Scene) else scene if isinstance(scene, str) else None
    meta = {"algo": algo, "observation": observation, "history": history, "scene": scene_name,
            "overrides": {k: v for k, v in (overrides or {}).items()}, "env_kwargs": env_kwargs,
            "steps": done_steps, "envs": envs, "seed": seed, "wall_time_s": round(wall, 2),
            "steps_per_s": round(done_steps / wall, 1), "control_period_s": period,
            "hyperparameters": {**hp, **policy_kwargs}, "episodes": len(callback.returns),
            "train_stats_last_episodes": stats,
            "versions": _versions()}
    meta_path = out / "model.json"
    meta_path.write_text(json.dumps(meta, indent=2, default=str) + "\n")
    return TrainResult(model_path, meta_path, algo, done_steps, wall, done_steps / wall,
                       len(callback.returns), stats)


def _versions() -> dict:
    import gymnasium
    import stable_baselines3
    import torch

    return {"python": sys.version.split()[0], "stable_baselines3": stable_baselines3.__version__,
            "torch": torch.__version__, "gymnasium": gymnasium.__version__}


def _literal(text: str):
    """A ``--hp`` value: a Python literal (``3e-4``, ``[32, 32]``, ``'auto'``) or a bare word."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def _pairs(items: list[str], what: str) -> dict:
    out = {}
    for item in items:
        key, eq, value = item.partition("=")
        if not eq or not key.strip() or not value.strip():
            raise SystemExit(f"agents.train: {what} {item!r} must be KEY=VALUE")
        out[key.strip()] = value.strip()
    return out


def build_parser() -> argparse.ArgumentParser:
    from impact_env.cli import add_scene_arguments

    p = argparse.ArgumentParser(prog="python -m agents.train", description=__doc__.split("\n\n")[0])
    p.add_argument("--algo", choices=ALGOS, required=True, help="ppo or sac")
    add_scene_arguments(p, default="rig")
    p.add_argument("--steps", type=int, required=True, help="env-steps (control periods) to train for")
    p.add_argument("--envs", type=int, default=16, help="rigs stepped together (default 16)")
    p.add_argument("--seed", type=int, default=0, help="seed of the model and env i = seed + i (default 0)")
    p.add_argument("--out", required=True, metavar="DIR", help="writes DIR/model.zip and DIR/model.json")
    p.add_argument("--observation", choices=OBSERVATIONS, default="sensors", help="default sensors")
    p.add_argument("--history", type=int, default=1, help="frames stacked in the observation (default 1)")
    p.add_argument("--horizon", type=float, default=None, help="episode length, s (default: the scene's)")
    p.add_argument("--hp", action="append", default=[], metavar="KEY=VALUE",
                   help="override a hyperparameter (Python literal), e.g. --hp learning_rate=1e-4")
    p.add_argument("--torch-threads", type=int, default=1, help="torch CPU threads (default 1)")
    p.add_argument("--verbose", type=int, default=0, help="SB3 verbosity (0, 1, 2)")
    return p


def main(argv: list[str] | None = None) -> int:
    from impact_env.cli import parse_overrides
    from impact_env.config import ConfigError

    args = build_parser().parse_args(argv)
    hp = {k: _literal(v) for k, v in _pairs(args.hp, "--hp").items()}
    env_kwargs = {}
    if args.horizon is not None:
        if not (args.horizon > 0 and math.isfinite(args.horizon)):
            raise SystemExit(f"agents.train: --horizon {args.horizon} s must be a finite time > 0 s")
        env_kwargs["horizon"] = args.horizon
    try:
        result = train(args.algo, args.scene, parse_overrides(args.set) or None, steps=args.steps,
                       envs=args.envs, seed=args.seed, out=args.out, observation=args.observation,
                       history=args.history, env_kwargs=env_kwargs, hyperparameters=hp,
                       torch_threads=args.torch_threads, verbose=args.verbose)
    except (ValueError, ConfigError) as exc:
        print(f"agents.train: {exc}", file=sys.stderr)
        return 2
    print(result.summary())
    return 0


if __name__ == "__main__":
    sys.exit(main())
