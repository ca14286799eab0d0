"""Why the README says ``torch.set_num_threads(1)``: PPO on one env with 1 and with 2 torch threads.

The same PPO run (``MlpPolicy``, one ``rig`` env from ``make_sb3_vec_env``, ``learn(2000)``,
seed 0) is timed for each thread count in a fresh process (torch's intra-op thread pool keeps
the size of its first parallel region, so one process cannot time both), after a warm-up
``learn(256)`` in that process (numba kernels loaded, torch initialised); best of ``--repeats``.
Prints the wall times, their ratio and the machine's load (other processes on the cores make
the extra threads spin-wait, which is where the cost comes from).

    python scripts/bench_torch_threads.py [--steps 2000] [--repeats 2]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

CHILD = """
import sys, time, torch
threads, steps, repeats = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
torch.set_num_threads(threads)
from stable_baselines3 import PPO
from impact_env.env.sb3_vecenv import make_sb3_vec_env

def run(n):
    env = make_sb3_vec_env("rig", num_envs=1)
    model = PPO("MlpPolicy", env, seed=0, device="cpu", verbose=0)
    t0 = time.perf_counter()
    model.learn(n)
    return time.perf_counter() - t0

run(256)
print(min(run(steps) for _ in range(repeats)))
"""


def timed(threads: int, steps: int, repeats: int) -> float:
    out = subprocess.run([sys.executable, "-c", CHILD, str(threads), str(steps), str(repeats)],
                         capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args(argv)
    walls = {}
    t0 = time.perf_counter()
    for threads in (1, 2):
        walls[threads] = timed(threads, args.steps, args.repeats)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"PPO MlpPolicy, 1 rig env, learn({args.steps}), best of {args.repeats}, a fresh process per "
          f"thread count ({os.cpu_count()} cores, load average {load:.1f}; {time.perf_counter() - t0:.0f} s)")
    for threads, wall in walls.items():
        print(f"  torch.set_num_threads({threads}): {wall:.2f} s  ({wall / walls[1]:.1f}x the 1-thread time)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
