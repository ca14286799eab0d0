"""How ``mpc``'s filter allows for the model's error on hardware it is not told: the search that
chose :data:`impact_env.control.laws.mpc.MODEL_ERROR`, as a record and as the generated block of
docs/mpc-calibrated.md.

``rig-randomized`` draws each drop's pad, suspension, noise, shaker gain and response and delays
and tells the controller none of them (``impact_env.scene.randomize.untold_hardware``).  The
filter then adds ``MODEL_ERROR`` to each reading's noise and to body 2's white acceleration.  This
script runs ``mpc`` on ``--drops`` validation drops of ``rig-randomized`` (seeds 900000 on, apart
from the held-out 1000 on and the suite's) for every combination of the grid below (each value a
standard deviation: accelerometer m/s^2, force N, potentiometer m, body 2's acceleration m/s^2,
the last in quadrature with ``q_a2``), then the shipped values and ``untold_error=0`` (the nominal
model taken as exact) with ``pd-penetration`` on ``--check-drops`` further drops (seeds 950000
on).  Per row: the mean energy integral, its median and its largest drop (ms); the check rows
with their 95 % bootstrap interval and the paired difference to ``pd-penetration``.

    python scripts/mpc_model_error.py [--drops 40] [--check-drops 80]
    python scripts/mpc_model_error.py --render

Writes docs/results/mpc/model_error.json (figures, command, versions, CPU, date) and the block
between the ``mpc-model-error`` markers of docs/mpc-calibrated.md.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mpc_record import OUT, _table_head, at_least_two, meta, record_and_block  # noqa: E402

MARKERS = ("<!-- mpc-model-error:start -->", "<!-- mpc-model-error:end -->")
PAGE = OUT.parents[2] / "docs" / "mpc-calibrated.md"
RECORD = OUT / "model_error.json"
GRID = {"acc": (30.0, 100.0, 160.0), "force": (5.0, 20.0, 40.0), "pot": (0.0, 1e-4), "q_a2": (0.0, 30.0)}
SEARCH_SEED, CHECK_SEED = 900000, 950000


def _energies(policies: list[str], drops: int, seed: int, model_error: dict | None = None) -> dict:
    from impact_env.control.laws import mpc
    from impact_env.eval.compare import compare
    from impact_env.scene import load_scene

    shipped = dict(mpc.MODEL_ERROR)
    try:
        mpc.MODEL_ERROR.update(model_error or {})
        runs = compare(load_scene("rig-randomized"), policies, episodes=drops, seed=seed, progress=False,
                       reference=None)
    finally:
        mpc.MODEL_ERROR.update(shipped)
    return {p: [float(v) for v in runs[p].metrics["energy_integral_ms"]] for p in policies}


def measure(drops: int, check_drops: int) -> dict:
    from impact_env.control.laws import mpc

    t0 = time.perf_counter()
    search = []
    for values in itertools.product(*GRID.values()):
        error = dict(zip(GRID, values, strict=True))
        e = _energies(["mpc"], drops, SEARCH_SEED, error)["mpc"]
        search.append({"model_error": error, "energy_integral_ms": e})
        print(f"{error}: {np.mean(e):.2f} ms", file=sys.stderr)
    check = _energies(["mpc", "mpc:untold_error=0", "pd-penetration"], check_drops, CHECK_SEED)
    command = ["python", "scripts/mpc_model_error.py", "--drops", str(drops),
               "--check-drops", str(check_drops)]
    return {**meta(command), "wall_s": round(time.perf_counter() - t0, 1), "drops": drops,
            "search_seed": SEARCH_SEED, "check_drops": check_drops, "check_seed": CHECK_SEED,
            "shipped": dict(mpc.MODEL_ERROR), "search": search, "check": check}


def render(rec: dict) -> str:
    from impact_env.eval.paired import bootstrap, mean, mean_difference

    shipped = rec["shipped"]
    lines = _table_head(
        f"`{rec['command']}`: the search, {rec['drops']} validation drops of `rig-randomized` (seeds "
        f"{rec['search_seed']} on) per row, the five best rows and the shipped one (energy integral, ms):",
        ["accelerometer, m/s^2", "force, N", "potentiometer, m", "body 2, m/s^2", "mean", "median",
         "largest drop", "shipped"])
    rows = sorted(rec["search"], key=lambda r: np.mean(r["energy_integral_ms"]))
    picked = rows[:5] + [r for r in rows[5:] if r["model_error"] == shipped]
    for r in picked:
        e, err = np.asarray(r["energy_integral_ms"]), r["model_error"]
        lines.append(f"| {err['acc']:g} | {err['force']:g} | {err['pot']:g} | {err['q_a2']:g} | "
                     f"{e.mean():.2f} | {np.median(e):.2f} | {e.max():.1f} | "
                     f"{'yes' if err == shipped else ''} |")
    worst = np.mean(rows[-1]["energy_integral_ms"])
    lines.append(f"| (of {len(rows)} rows) | | | | {worst:.2f} at the worst | | | |")
    labels = {"acc": "accelerometer, m/s^2", "force": "force, N", "pot": "potentiometer, m",
              "q_a2": "body 2, m/s^2"}
    lines += [""] + _table_head(
        "Each value held, the best of the rows with it (mean, ms, and that row's largest drop):",
        ["allowance", "value: best mean (largest drop)"])
    for key, values in GRID.items():
        cells = []
        for value in values:
            best = min((r for r in rows if r["model_error"][key] == value),
                       key=lambda r: np.mean(r["energy_integral_ms"]))
            e = np.asarray(best["energy_integral_ms"])
            cells.append(f"{value:g}: {e.mean():.2f} ({e.max():.1f})")
        lines.append(f"| {labels[key]} | " + "; ".join(cells) + " |")
    pd = np.asarray(rec["check"]["pd-penetration"])
    lines += [""] + _table_head(
        f"Checked on {rec['check_drops']} further drops (seeds {rec['check_seed']} on; mean and 95 % "
        "bootstrap interval; paired: minus `pd-penetration` per drop):",
        ["policy", "energy integral, ms [95 % CI]", "largest drop, ms",
         "- `pd-penetration`, paired [95 % CI]"])
    names = {"mpc": "`mpc` (the model's error allowed for)",
             "mpc:untold_error=0": "`mpc:untold_error=0` (the nominal model taken as exact)",
             "pd-penetration": "`pd-penetration`"}
    for policy, name in names.items():
        e = np.asarray(rec["check"][policy])
        m = bootstrap(mean, e)
        cell = "" if policy == "pd-penetration" else "{0.value:.2f} [{0.low:.2f}, {0.high:.2f}]".format(
            bootstrap(mean_difference, e, pd))
        lines.append(f"| {name} | {m.value:.2f} [{m.low:.2f}, {m.high:.2f}] | {e.max():.1f} | {cell} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--drops", type=int, default=40, help="validation drops per row of the search")
    ap.add_argument("--check-drops", type=int, default=80, help="further drops for the shipped values")
    ap.add_argument("--render", action="store_true", help="only rewrite the block from the record")
    args = ap.parse_args()
    at_least_two(ap, args, ("drops", "check_drops"))
    run = None if args.render else lambda: measure(args.drops, args.check_drops)
    text = record_and_block(RECORD, run, render, MARKERS, PAGE)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
