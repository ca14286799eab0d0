"""The mismatch map of docs/mismatch.md: the shipped agent, pd-penetration, thesis-rig and the two
MPC laws (``mpc`` on its filter's estimate, ``mpc-state`` on the true state) on the same drops of ``rig`` while one hardware parameter at a time departs from the scene
(``impact-env robustness``), over the parameters a real rig is most likely to get wrong.

    python scripts/mismatch_map.py --episodes 50 \
        --identified docs/results/identification/seed21/identification.json

``--cluster tcp://HOST:PORT`` runs the points on a Dask cluster's workers, with the same results
(docs/cluster.md; the shipped agent's file is then named by its absolute path, which every worker
must see).

Writes ``docs/figures/mismatch_<field>.png``, ``docs/results/mismatch.json`` and the tables of
``docs/mismatch.md`` between its markers.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from impact_env.eval.parallel import Cluster
from impact_env.eval.robustness import identified_bands, parse_vary, plot, robustness
from impact_env.scene import load_scene

POLICIES = ["compiled:agents/models/best/best.policy.json", "pd-penetration", "thesis-rig", "mpc", "mpc-state"]
NAMES = {POLICIES[0]: "shipped agent", "pd-penetration": "pd-penetration", "thesis-rig": "thesis-rig",
         "mpc": "mpc", "mpc-state": "mpc-state"}
GRIDS = [  # a factor 2 or more either way of the nominal, or the physical range
    "c=1e6:4e6:7", "restitution=0.6:0.95:8", "shaker_coil_inductance=25e-6:200e-6:7",
    "sensor_delay_s=0:5e-4", "command_gain=0.6:1.4:9", "m1=0.05:0.2:7", "noise_scale=0.25:8:7",
    # rig-randomized's two ranges that the MPC laws' models feel most beside those (0-0.1 ms and
    # 10-30 N s/m there)
    "actuator_delay_s=0:3e-4", "suspension_damping=10:40:7",
]
ROOT = Path(__file__).resolve().parent.parent


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--identified", default=None, help="an identification.json to mark")
    ap.add_argument("--only", nargs="*", default=None, help="fields to run (default all)")
    ap.add_argument("--cluster", default=None, metavar="tcp://HOST:PORT",
                    help="run on this Dask scheduler's workers (docs/cluster.md)")
    ap.add_argument("--render", action="store_true",
                    help="only rewrite docs/mismatch.md's tables from docs/results/mismatch.json")
    args = ap.parse_args(argv)
    out = ROOT / "docs" / "results" / "mismatch.json"
    if args.render:
        _write_doc(json.loads(out.read_text()), args)
        return 0
    cluster = Cluster(args.cluster) if args.cluster else None  # one connection for every grid
    # on a cluster the agent's file by its absolute path (the workers' directory is not this one)
    specs = [f"compiled:{ROOT / POLICIES[0].partition(':')[2]}" if cluster else POLICIES[0], *POLICIES[1:]]
    names = {spec: NAMES[p] for spec, p in zip(specs, POLICIES, strict=True)}
    scene = load_scene("rig")
    bands = identified_bands(args.identified, scene) if args.identified else {}
    figs = ROOT / "docs" / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    results = {}
    for grid in GRIDS:
        name, values = parse_vary(grid, scene.control_rate)
        if args.only and name not in args.only:
            continue
        res = robustness(scene, specs, [(name, values)], args.episodes, args.seed, args.workers,
                         progress=False, cluster=cluster)
        res.identified = bands
        plot(res, figs / f"mismatch_{name}.png", names)
        results[name] = {"values": values.tolist(), "nominal": res.nominal[name], "wall_s": res.wall_s,
                         "rows": [{p: row[spec] for spec, p in zip(specs, POLICIES, strict=True)}
                                  for row in res.summaries]}
        print(f"{name}: {res.wall_s:.0f} s", file=sys.stderr, flush=True)
    old = json.loads(out.read_text()) if out.exists() and args.only else {}
    old.update(results)
    out.write_text(json.dumps(old, indent=1, default=_json) + "\n")
    _write_doc(old, args)
    if cluster is not None:
        cluster.close()
    return 0


def _write_doc(results: dict, args) -> None:
    tables = render(results, args)
    doc = ROOT / "docs" / "mismatch.md"
    text = doc.read_text() if doc.exists() else "<!-- mismatch:start -->\n<!-- mismatch:end -->\n"
    a, b = text.index("<!-- mismatch:start -->"), text.index("<!-- mismatch:end -->")
    doc.write_text(text[:a] + "<!-- mismatch:start -->\n" + tables + text[b:])
    print(tables)


def _json(v):
    return None if isinstance(v, float) and not math.isfinite(v) else float(v)


def _f(v, scale=1.0, digits=2):
    if v is None or not math.isfinite(float(v)):
        return ">0.4" if scale == "catch" else "-"
    return f"{float(v):.3f}" if scale == "catch" else f"{float(v) * scale:.{digits}f}"


def _nominal_and_worst(r: dict, policy: str) -> str:
    """``nominal -> worst (at value)`` of one policy's energy integral over one parameter's grid:
    the nominal point is the grid's value nearest the scene's (the grids include it or straddle it)."""
    values = r["values"]
    energy = [row[policy].get("energy_integral_ms") for row in r["rows"]]
    energy = [float("inf") if e is None or not math.isfinite(float(e)) else float(e) for e in energy]
    at_nominal = min(range(len(values)), key=lambda i: abs(values[i] - r["nominal"]))
    worst = max(range(len(values)), key=lambda i: energy[i])
    return f"{_f(energy[at_nominal])} -> {_f(energy[worst])} ({values[worst]:.3g})"


def render(results: dict, args) -> str:
    cmd = "python scripts/mismatch_map.py --episodes {} {}".format(
        args.episodes, f"--identified {args.identified}" if args.identified else "").strip()
    out = [f"Written by `{cmd}` ({args.episodes} drops of `rig` per point and policy, seeds "
           f"{args.seed}-{args.seed + args.episodes - 1}; energy integral in ms, median catch time "
           "in s (>0.4: half the drops or more not caught), mean time at the 200 N limit in ms, "
           "mean bounces).", "",
           "Each policy's energy integral (ms) at the grid's point nearest the scene's value and its worst "
           "over the grid (at which value):", "",
           "| parameter (grid) | " + " | ".join(NAMES[p] for p in POLICIES) + " |",
           "|---|" + "---|" * len(POLICIES)]
    for name, r in results.items():
        out.append(f"| {name} ({min(r['values']):.3g}-{max(r['values']):.3g}) | "
                   + " | ".join(_nominal_and_worst(r, p) for p in POLICIES) + " |")
    out.append("")
    for name, r in results.items():
        out += [f"**{name}** (nominal {r['nominal']:g}; figure `docs/figures/mismatch_{name}.png`)", "",
                "| " + name + " | "
                + " | ".join(f"{NAMES[p]}: int E / catch / sat / bounces" for p in POLICIES) + " |",
                "|---|" + "---|" * len(POLICIES)]
        for v, row in zip(r["values"], r["rows"], strict=True):
            cells = []
            for p in POLICIES:
                s = row[p]
                cells.append(f"{_f(s.get('energy_integral_ms'))} / "
                             f"{_f(s.get('time_to_catch_median_s'), 'catch')} / "
                             f"{_f(s.get('saturation_time_s'), 1e3, 1)} / {_f(s.get('bounces'), 1.0, 1)}")
            out.append(f"| {v:.4g} | " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    sys.exit(main())
