"""How good is the oracle for its budget?  Energy integral against CMA-ES generations on N drops.

Runs the oracle's optimiser (:func:`impact_env.eval.oracle.search_drop`) on drops ``seed0 ..
seed0 + N - 1`` for the largest number of generations asked, keeping the best sequence found
after each listed number of generations; every kept sequence is then rolled out over the full
horizon on the full scene (as ``compare`` would), and the oracle's choice at that budget is the
better of it and the drop's best warm start.  Prints, per budget: candidate evaluations, median
energy integral over the drops, median improvement on the best warm start, and the CPU seconds
per drop the optimisation took so far (process time: a shared machine does not inflate it).

    python scripts/oracle_budget.py --scene rig --seed 1000 --drops 10 --generations 25,50,100,200,400 \
        [--popsize 12 --basis 12 --window 0.03 --first-knot 2.5e-4 --sigma 0.3] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from impact_env.eval import oracle
from impact_env.scene import load_scene


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="rig")
    p.add_argument("--seed", type=int, default=1000, help="first drop's seed")
    p.add_argument("--drops", type=int, default=10)
    p.add_argument("--horizon", type=float, default=None, help="s (default: the scene's)")
    p.add_argument("--generations", default="25,50,100,200,400", help="budgets to report (comma-separated)")
    for key in ("popsize", "basis", "window", "first_knot", "sigma"):
        p.add_argument("--" + key.replace("_", "-"), type=float, default=None, help=oracle.PARAMS[key].doc)
    p.add_argument("--json", metavar="OUT", help="write the figures here")
    args = p.parse_args(argv)
    scene = load_scene(args.scene)
    horizon = scene.episode.horizon if args.horizon is None else args.horizon
    n_steps = int(round(horizon / scene.control_period))
    gens = sorted({int(g) for g in args.generations.split(",")})
    params = {k: getattr(args, k) for k in ("popsize", "basis", "window", "first_knot", "sigma")
              if getattr(args, k) is not None}
    budget = oracle.Budget.from_params(generations=max(gens), **params)
    seeds = list(range(args.seed, args.seed + args.drops))

    t0 = time.perf_counter()
    warm = oracle.classic_warm_starts(scene, seeds, horizon)
    names = list(warm)
    ref = oracle.replay(scene, [s for s in seeds for _ in names],
                   np.stack([warm[k][:, i] for i in range(len(seeds)) for k in names], axis=1), horizon)
    warm_ei = ref.metrics["energy_integral_ms"].reshape(len(seeds), len(names))
    best_warm = warm_ei.min(axis=1)
    cols, cpu, objective = [], np.zeros((len(seeds), len(gens))), np.zeros(len(seeds))
    for i, seed in enumerate(seeds):
        s = oracle.search_drop(scene, seed, {k: v[:, i] for k, v in warm.items()}, n_steps, budget,
                          checkpoints=gens)
        for j, g in enumerate(gens):
            u, c = s.checkpoints.get(g, s.checkpoints[max(s.checkpoints)])
            cols.append(u)
            cpu[i, j] = c
        objective[i] = s.objective
        print(f"drop {seed}: best warm {names[int(np.argmin(warm_ei[i]))]} {best_warm[i]:.3f} ms, "
              f"window objective {s.objective:.3f} ms, {s.cpu_seconds:.1f} s CPU", file=sys.stderr,
              flush=True)
    r = oracle.replay(scene, [s for s in seeds for _ in gens], np.stack(cols, axis=1), horizon)
    ei = r.metrics["energy_integral_ms"].reshape(len(seeds), len(gens))
    chosen = np.minimum(ei, best_warm[:, None])
    rows = []
    for j, g in enumerate(gens):
        rows.append({"generations": g, "evaluations": len(names) + g * budget.popsize,
                     "energy_integral_median_ms": float(np.median(chosen[:, j])),
                     "energy_integral_max_ms": float(np.max(chosen[:, j])),
                     "search_only_median_ms": float(np.median(ei[:, j])),
                     "improvement_median_ms": float(np.median(best_warm - chosen[:, j])),
                     "cpu_s_per_drop": float(np.mean(cpu[:, j]))})
    pd = (f" (pd-penetration {np.median(warm_ei[:, names.index('pd-penetration')]):.3f} ms)"
          if "pd-penetration" in names else "")
    print(f"scene {scene.name}, drops {seeds[0]}..{seeds[-1]}, horizon {horizon:g} s, "
          f"popsize {budget.popsize}, basis {budget.basis}, window {budget.window:g} s, "
          f"first knot {budget.first_knot:g} s, sigma {budget.sigma:g}; "
          f"best warm start: median {np.median(best_warm):.3f} ms{pd}")
    print(f"{'gens':>5} {'evals':>6} {'EI median ms':>13} {'EI max ms':>10} {'improvement ms':>15} "
          f"{'CPU s/drop':>11}")
    for row in rows:
        print(f"{row['generations']:>5} {row['evaluations']:>6} {row['energy_integral_median_ms']:>13.3f} "
              f"{row['energy_integral_max_ms']:>10.3f} {row['improvement_median_ms']:>15.3f} "
              f"{row['cpu_s_per_drop']:>11.2f}")
    print(f"wall {time.perf_counter() - t0:.0f} s")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"scene": scene.name, "seeds": seeds, "horizon_s": horizon, "budget": vars(budget),
                       "best_warm_ms": best_warm.tolist(), "warm_names": names,
                       "warm_ms": warm_ei.tolist(), "rows": rows}, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
