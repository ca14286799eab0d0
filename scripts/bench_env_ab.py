"""A/B of what users feel of the env's speed, between this checkout and another one (e.g. the
revision before a refactor), in alternating fresh processes on the same machine: the ratios
between the two sides are what compares; the absolute figures move with the machine's load.

    mkdir /tmp/before && git archive REV | tar -x -C /tmp/before   # the revision to compare with
    python scripts/bench_env_ab.py --other /tmp/before [--rounds 3] [--threads 1]

Per process (``PYTHONPATH`` = the checkout), the figures a user feels:

* ``ppo_single``: SB3 PPO's training steps/s on one ``ImpactCatch-v0`` (rig), SB3's default
  PPO settings but ``n_steps`` 1024, one torch thread, 2048 steps (collection and updates);
* ``ppo_vector``: the same on the native vector env through its SB3 adapter (64 envs, ``n_steps``
  32, batch 1024), 4096 steps;
* ``compare_s``: ``compare``'s wall time on 100 drops x 4 policies (rig, one worker);
* ``vec_1024``, ``vec_16384``: the native vector env's env-steps/s at N = 1024 and 16384 (rig,
  every env on the nominal drop, random actions; best of a few repeats);
* ``step_us``: one single-env step (min over repeats), for reference.

``--quick``: only ``step_us``, ``vec_1024`` and ``compare10_s`` (``compare`` on 10 drops x 2
laws, after a first call that compiles), a few minutes a round.

Reported: per checkout, the median over rounds of every figure, and the ratio this / other.
``--threads`` is the vector env's ``threads`` (1: serial, the default of the env).  ``--json
FILE`` also writes the record: every round's figures, the medians, and where and how it was
made (command, versions, git commit, CPU, date: :func:`impact_env.eval.benchmark.run_meta`, as
every other benchmark's record has it).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

PROBE = r'''
import json, sys, time
import gymnasium as gym, numpy as np, torch
import impact_env
threads = int(sys.argv[1])
quick = sys.argv[2] == "1"
torch.set_num_threads(1)
out = {"package": impact_env.__file__}

def vec_rate(n, steps, reps):
    venv = gym.make_vec("ImpactCatch-v0", num_envs=n, vectorization_mode="vector_entry_point", scene="rig",
                        overrides={"randomize.m1": [], "randomize.drop_height": []}, threads=threads)
    acts = np.random.default_rng(0).uniform(-1, 1, (steps, n, 1)).astype(np.float32)
    venv.reset(seed=0)
    venv.step(acts[0])
    best = np.inf
    for _ in range(reps):
        t0 = time.perf_counter()
        for a in acts:
            venv.step(a)
        best = min(best, time.perf_counter() - t0)
    return n * steps / best

env = gym.make("ImpactCatch-v0", scene="rig")
acts = np.random.default_rng(0).uniform(-1, 1, (2000, 1)).astype(np.float32)
best = np.inf
for _ in range(4):
    env.reset(seed=0)
    t0 = time.perf_counter()
    for a in acts:
        _, _, te, tr, _ = env.step(a)
        if te or tr:
            env.reset()
    best = min(best, time.perf_counter() - t0)
out["step_us"] = best / len(acts) * 1e6
out["vec_1024"] = vec_rate(1024, 100, 3)
if quick:
    from impact_env.eval.compare import compare
    from impact_env.scene import load_scene
    compare(load_scene("rig"), ["thesis-rig"], episodes=1, seed=0, workers=1, progress=False)  # compiled
    t0 = time.perf_counter()
    compare(load_scene("rig"), ["thesis-rig", "pd-penetration"], episodes=10, seed=0, workers=1,
            progress=False)
    out["compare10_s"] = time.perf_counter() - t0
    print(json.dumps(out))
    sys.exit(0)
out["vec_16384"] = vec_rate(16384, 10, 2)

from stable_baselines3 import PPO
from impact_env.env.sb3_vecenv import make_sb3_vec_env
model = PPO("MlpPolicy", gym.make("ImpactCatch-v0", scene="rig"), n_steps=1024, device="cpu", seed=0)
t0 = time.perf_counter(); model.learn(2048); out["ppo_single"] = 2048 / (time.perf_counter() - t0)
model = PPO("MlpPolicy", make_sb3_vec_env("rig", num_envs=64), n_steps=32, batch_size=1024, device="cpu",
            seed=0)
t0 = time.perf_counter(); model.learn(4096); out["ppo_vector"] = 4096 / (time.perf_counter() - t0)

from impact_env.eval.compare import compare
from impact_env.scene import load_scene
t0 = time.perf_counter()
compare(load_scene("rig"), ["passive", "thesis-rig", "pd-penetration", "thesis-ideal"], episodes=100, seed=0,
        workers=1, progress=False)
out["compare_s"] = time.perf_counter() - t0
print(json.dumps(out))
'''

FIGURES = ("ppo_single", "ppo_vector", "compare_s", "vec_1024", "vec_16384", "step_us")
QUICK_FIGURES = ("compare10_s", "vec_1024", "step_us")


def probe(checkout: Path, threads: int, quick: bool = False) -> dict:
    env = dict(os.environ, PYTHONPATH=str(checkout))
    out = subprocess.run([sys.executable, "-c", PROBE, str(threads), "1" if quick else "0"], cwd=checkout,
                         env=env,
                         capture_output=True, text=True, timeout=1800)
    if out.returncode != 0:
        raise SystemExit(f"probe in {checkout} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _median(rows: list[dict], key: str) -> float:
    return sorted(x[key] for x in rows)[len(rows) // 2]


def record(argv: list[str], other: Path, threads: int, quick: bool, rows: dict[str, list[dict]],
           wall: float) -> dict:
    """The run's record: its settings, every round's figures per side, each side's medians, and
    ``meta`` (run_meta: command, versions, git, CPU, date, the run's wall time in s)."""
    from impact_env.eval.benchmark import run_meta

    figures = QUICK_FIGURES if quick else FIGURES
    return {"other": str(other), "threads": threads, "quick": quick, "rounds": rows,
            "median": {k: {f: _median(v, f) for f in figures} for k, v in rows.items()},
            "meta": run_meta("python scripts/bench_env_ab.py " + " ".join(argv), wall, 0, 0.0)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--other", required=True, type=Path, help="another checkout of the project")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1, help="the vector env's threads")
    ap.add_argument("--json", type=Path, help="also write every round's figures here")
    ap.add_argument("--quick", action="store_true",
                    help="only step_us, vec_1024 and compare10_s (10 drops x 2 laws, compiled first)")
    args = ap.parse_args()
    sides = {"this": ROOT, "other": args.other.resolve()}
    rows: dict[str, list[dict]] = {k: [] for k in sides}
    order = list(sides)
    t0 = time.perf_counter()
    for r in range(args.rounds):
        # which side runs first alternates: the first of a pair may run on a colder machine
        for k in order if r % 2 == 0 else order[::-1]:
            rows[k].append(probe(sides[k], args.threads, args.quick))
            print(k, json.dumps(rows[k][-1]), file=sys.stderr, flush=True)
    if args.json:
        out = record(sys.argv[1:], sides["other"], args.threads, args.quick, rows, time.perf_counter() - t0)
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    print("| figure | " + " | ".join(f"{k} ({d})" for k, d in sides.items()) + " | this / other |")
    print("|---|---|---|---|")
    for f in QUICK_FIGURES if args.quick else FIGURES:
        a, b = _median(rows["this"], f), _median(rows["other"], f)
        print(f"| {f} | {a:.4g} | {b:.4g} | {a / b:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
