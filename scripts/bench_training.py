"""Env-step throughput of the training paths, as ratios against the native SB3 adapter in the same
process (absolute figures depend on what else shares the cores).

    python scripts/bench_training.py [--envs 16] [--ticks 20000]

Rows (random actions, ``rig``, 16 envs, control periods per second of wall time):

* ``native``: :func:`impact_env.env.sb3_vecenv.make_sb3_vec_env`, what ``agents.train`` steps (reference);
* ``dummy``: SB3's ``DummyVecEnv`` of ``gymnasium.make("ImpactCatch-v0")``, what ``rl_zoo3.train``
  steps;
* ``hold4``, ``hold4+residual``: the native adapter with the env's own ``hold_ticks=4`` (and
  ``residual="pd-penetration"``: the compiled law evaluated every period inside the step).
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np


def _rate(venv, ticks_per_step: int, ticks: int, n: int) -> float:
    rng = np.random.default_rng(0)
    venv.seed(0)
    venv.reset()
    steps = max(1, ticks // ticks_per_step)
    acts = rng.uniform(-0.2, 0.2, (steps, n, 1)).astype(np.float32)
    venv.step(acts[0])  # warm-up (compilation, noise blocks)
    t0 = time.perf_counter()
    for k in range(steps):
        venv.step(acts[k])
    return steps * ticks_per_step * n / (time.perf_counter() - t0)


def main(argv=None) -> int:
    from stable_baselines3.common.vec_env import DummyVecEnv

    import impact_env  # noqa: F401
    from impact_env.env.sb3_vecenv import make_sb3_vec_env

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", type=int, default=16)
    p.add_argument("--ticks", type=int, default=20000, help="control periods per env and row")
    a = p.parse_args(argv)
    n = a.envs
    rows = {
        "native": (make_sb3_vec_env("rig", num_envs=n), 1),
        "dummy": (DummyVecEnv([lambda: gym.make("ImpactCatch-v0", scene="rig") for _ in range(n)]), 1),
        "hold4": (make_sb3_vec_env("rig", num_envs=n, hold_ticks=4), 4),
        "hold4+residual": (make_sb3_vec_env("rig", num_envs=n, hold_ticks=4, residual="pd-penetration"), 4),
    }
    ref = None
    print(f"{'path':16s} {'periods/s':>10s} {'ratio':>6s}")
    for name, (venv, k) in rows.items():
        r = _rate(venv, k, a.ticks if name != "dummy" else a.ticks // 4, n)
        ref = ref or r
        print(f"{name:16s} {r:10.0f} {r / ref:6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
