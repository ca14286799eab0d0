"""A/B of the env's speed between this checkout and another one (e.g. a revision before a
refactor), in alternating fresh processes on the same machine, each process measuring its own
reference env too: the ratios are what compares, the microseconds move with the machine's load.

    git worktree add /tmp/before 91a44ce      # the revision to compare with
    python scripts/bench_env_ab.py --other /tmp/before [--rounds 5]

Per process: one ``step`` of ``gymnasium.make("ImpactCatch-v0", scene="rig")`` against
``MountainCarContinuous-v0`` (min over repeats), and the native vector env at N = 1024 against
Gymnasium's ``CartPoleVectorEnv`` (env-steps/s), every env on the nominal drop.  Reported: the
median over rounds of each ratio, the minimum step time and the maximum vector rate, per checkout.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# run in the other checkout's package (PYTHONPATH); bench_env's timer comes from this checkout's
# scripts/ (given as argv[1]), which imports whichever impact_env is first on the path
PROBE = r'''
import json, sys, time
import gymnasium as gym, numpy as np
import impact_env
sys.path.insert(1, sys.argv[1])
from bench_env import per_step_us as per_step

def vec_rate(env, n, steps, reps):
    rng = np.random.default_rng(0)
    space = env.single_action_space
    acts = rng.uniform(-1, 1, (steps, n) + space.shape).astype(space.dtype)
    if space.dtype.kind == "i":
        acts = rng.integers(0, 2, (steps, n))
    env.reset(seed=0)
    env.step(acts[0])
    best = np.inf
    for _ in range(reps):
        t0 = time.perf_counter()
        for a in acts:
            env.step(a)
        best = min(best, time.perf_counter() - t0)
    return n * steps / best

rng = np.random.default_rng(0)
a = rng.uniform(-1, 1, (2000, 1)).astype(np.float32)
mc = gym.make("MountainCarContinuous-v0")
rig = gym.make("ImpactCatch-v0", scene="rig")
per_step(rig, a[:200], 1)
m = min(per_step(mc, a, 3) for _ in range(3))
r = min(per_step(rig, a, 3) for _ in range(3))
from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv
cp = vec_rate(CartPoleVectorEnv(num_envs=1024), 1024, 100, 5)
# the nominal drop in every env: the same work on both sides (a checkout whose rig draws drops per
# episode takes the overrides; an older one, whose rig had one drop, refuses them and needs none)
try:
    venv = gym.make_vec("ImpactCatch-v0", num_envs=1024, vectorization_mode="vector_entry_point", scene="rig",
                        overrides={"randomize.m1": [], "randomize.drop_height": []})
except Exception:
    venv = gym.make_vec("ImpactCatch-v0", num_envs=1024, vectorization_mode="vector_entry_point", scene="rig")
v = vec_rate(venv, 1024, 100, 5)
print(json.dumps({"package": impact_env.__file__, "mc_us": m, "rig_us": r, "step_ratio": r / m,
                  "vec_rate": v, "cartpole_rate": cp, "vec_ratio": v / cp}))
'''


def probe(checkout: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(checkout))
    out = subprocess.run([sys.executable, "-c", PROBE, str(ROOT / "scripts")], cwd=checkout, env=env,
                         capture_output=True, text=True, timeout=900)
    if out.returncode != 0:
        raise SystemExit(f"probe in {checkout} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _median(rows: list[dict], key: str) -> float:
    return sorted(x[key] for x in rows)[len(rows) // 2]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--other", required=True, type=Path, help="another checkout of the project")
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    sides = {"this": ROOT, "other": args.other.resolve()}
    rows = {k: [] for k in sides}
    order = list(sides)
    for r in range(args.rounds):
        # which side runs first alternates: run for run, the first of a pair came out a few per
        # cent slower here whichever checkout it was (both orders of two checkouts, 7 rounds each)
        for k in order if r % 2 == 0 else order[::-1]:
            rows[k].append(probe(sides[k]))
    print("| checkout | rig step us (min) | step / MountainCarContinuous (median) | "
          "vector N=1024 env-steps/s (max) | vector / CartPoleVectorEnv (median) |")
    print("|---|---|---|---|---|")
    for k, d in sides.items():
        r = rows[k]
        print(f"| {k} ({d}) | {min(x['rig_us'] for x in r):.2f} | {_median(r, 'step_ratio'):.2f} | "
              f"{max(x['vec_rate'] for x in r):.3g} | {_median(r, 'vec_ratio'):.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
