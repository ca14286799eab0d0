"""The MPC's record: ``mpc-state`` beside the classic laws and the per-drop oracle on ``rig``'s
held-out drops, and its tick cost, as JSON and as the generated block of docs/mpc.md.

    python scripts/mpc_record.py                       # compare (20 drops) + tick cost + block
    python scripts/mpc_record.py --episodes 100        # the full-size record (a quiet machine)
    python scripts/mpc_record.py --render              # rewrite the block from the records

1. ``impact-env compare --scene rig --policies mpc-state,mpc,pd-penetration,thesis-rig,oracle
   --episodes N --seed 1000 --json``: each policy's mean energy integral (ms) with its 95 %
   bootstrap interval (compare's statistics, :mod:`impact_env.eval.scores`), its ratio to the
   oracle's mean, the share caught and the median catch time; written to
   docs/results/mpc/compare.json with the command, versions, CPU and date.
2. The tick cost, from ``scripts/bench_policy.py --laws mpc-state --json
   docs/results/mpc/tick.json`` (run here unless ``--no-tick``): p50 / p99 of one compiled
   ``act`` call of ``mpc-state`` on the observations of rig drops, in order per drop (the warm
   start as in an episode).
3. The block between ``<!-- mpc-record:start -->`` and ``<!-- mpc-record:end -->`` of
   docs/mpc.md, written from the two records.
4. The block between the ``mpc-robustness`` markers of docs/mpc.md, from the benchmark record
   ``docs/results/benchmark/mpc/catch-v1.json`` (``impact-env benchmark mpc-state mpc
   pd-penetration --out docs/results/benchmark/mpc``): per held-out set, ``mpc``'s and
   ``pd-penetration``'s mean energy integral over the oracle's, and their paired difference
   (``mpc`` minus ``pd-penetration``, per drop) with its 95 % paired bootstrap interval
   (:func:`impact_env.eval.paired.paired_difference`); ``mpc`` is better where the whole
   interval is below 0.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "results" / "mpc"
DOC = ROOT / "docs" / "mpc.md"
START, END = "<!-- mpc-record:start -->", "<!-- mpc-record:end -->"
ROBUSTNESS = ("<!-- mpc-robustness:start -->", "<!-- mpc-robustness:end -->")
BENCHMARK = ROOT / "docs" / "results" / "benchmark" / "mpc" / "catch-v1.json"
POLICIES = "mpc-state,mpc,pd-penetration,thesis-rig,oracle"


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def meta(command: list[str]) -> dict:
    import numba
    import numpy

    import impact_env

    return {"command": " ".join(command), "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
            "cpu": _cpu(), "cores": len(os.sched_getaffinity(0)), "python": platform.python_version(),
            "numpy": numpy.__version__, "numba": numba.__version__, "impact_env": impact_env.__version__}


def run_compare(episodes: int, seed: int, workers: str) -> dict:
    cmd = ["impact-env", "compare", "--scene", "rig", "--policies", POLICIES, "--episodes", str(episodes),
           "--seed", str(seed), "--json"]
    if workers:
        cmd += ["--workers", workers]
    t0 = time.perf_counter()
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    wall = time.perf_counter() - t0
    table = json.loads(out[out.index("{"):])
    rows = {}
    oracle = table["oracle"]["energy_integral_ms"]
    for name in POLICIES.split(","):
        s = table[name]
        rows[name] = {"energy_integral_ms": s["energy_integral_ms"],
                      "energy_integral_ms_ci95": s.get("energy_integral_ms_ci95"),
                      "ratio_to_oracle": s["energy_integral_ms"] / oracle,
                      "caught_fraction": s.get("caught_fraction"),
                      "time_to_catch_median_s": s.get("time_to_catch_median_s"),
                      "peak_force_N": s.get("peak_force_N")}
    return {**meta(cmd), "wall_s": round(wall, 1), "episodes": episodes, "seed": seed, "policies": rows}


def run_tick(quick: bool) -> dict:
    cmd = [sys.executable, "scripts/bench_policy.py", "--laws", "mpc-state", "--json", str(OUT / "tick.json")]
    if quick:
        cmd.append("--quick")
    subprocess.run(cmd, check=True, cwd=ROOT)
    return json.loads((OUT / "tick.json").read_text())


def _table_head(intro: str, columns: list[str]) -> list[str]:
    """A generated table's opening: its sentence, a blank line, the header row and the rule."""
    return [intro, "", "| " + " | ".join(columns) + " |", "|" + " --- |" * len(columns)]


def render(compare: dict | None, tick: dict | None) -> str:
    lines = []
    if compare is not None:
        lines += _table_head(f"`{compare['command']}` ({compare['episodes']} drops; energy integral: mean "
                             "and its 95 % bootstrap interval over the drops; ratio: the mean over the "
                             "oracle's mean):",
                             ["policy", "energy integral, ms [95 % CI]", "ratio to the oracle", "caught",
                              "catch, median s"])
        for name, r in compare["policies"].items():
            ci = r["energy_integral_ms_ci95"]
            ci_text = f" [{ci[0]:.2f}, {ci[1]:.2f}]" if ci else ""
            caught = r["caught_fraction"]
            ttc = r["time_to_catch_median_s"]
            ratio = r["ratio_to_oracle"]
            lines.append(f"| `{name}` | {r['energy_integral_ms']:.2f}{ci_text} | {ratio:.2f} | "
                         f"{'' if caught is None else f'{100 * caught:.0f} %'} | "
                         f"{'' if ttc is None else ('> horizon' if ttc == float('inf') else f'{ttc:.3f}')} |")
        lines.append("")
    if tick is not None:
        row = tick["laws"]["mpc-state"]
        lines += [f"Tick cost (`{tick['command']}`; one compiled `act` call of `mpc-state`, "
                  f"{row['calls']} calls on rig drops in order, cycle counter, no pinning or other set-up): "
                  f"p50 {row['p50_ns'] / 1e3:.1f} us, p99 {row['p99_ns'] / 1e3:.1f} us, "
                  f"max {row['max_ns'] / 1e3:.1f} us (goal: p99 <= 50 us).", ""]
    return "\n".join(lines)


def render_robustness(record: dict) -> str:
    """Per set of the benchmark record: mpc and pd-penetration over the oracle, and their paired
    difference on the energy integral."""
    from impact_env.eval.paired import paired_difference

    drops = ", ".join(f"{name} {st['drops']}" for name, st in record["sets"].items())
    lines = _table_head(f"`{record['meta']['command']}` ({drops} drops; x oracle: the set's mean energy "
                        "integral over the oracle's; paired: `mpc` minus `pd-penetration` per drop, mean and "
                        "its 95 % paired bootstrap interval):",
                        ["set", "`mpc`, x oracle", "`pd-penetration`, x oracle",
                         "`mpc` - `pd-penetration`, paired, ms [95 % CI]", "`mpc` better"])
    for name, st in record["sets"].items():
        pols = st["policies"]
        best = pols["oracle"]["summary"]["energy_integral_ms"]
        a = pols["mpc"]["metrics"]["energy_integral_ms"]
        b = pols["pd-penetration"]["metrics"]["energy_integral_ms"]
        d = paired_difference(a, b)
        verdict = "yes" if d.high < 0 else ("no: worse" if d.low > 0 else "not separated")
        lines.append(f"| {name} | {pols['mpc']['summary']['energy_integral_ms'] / best:.2f}x | "
                     f"{pols['pd-penetration']['summary']['energy_integral_ms'] / best:.2f}x | "
                     f"{d.difference:.2f} [{d.low:.2f}, {d.high:.2f}] | {verdict} |")
    return "\n".join(lines) + "\n"


def write_block(text: str, markers: tuple[str, str] = (START, END), doc: Path = DOC) -> None:
    start, end = markers
    page = doc.read_text()
    i, j = page.index(start), page.index(end)
    doc.write_text(page[:i] + start + "\n" + text + page[j:])


def at_least_two(ap: argparse.ArgumentParser, args: argparse.Namespace, names: tuple[str, ...]) -> None:
    """Refuse a count below 2, naming its flag: the records' intervals resample them."""
    for name in names:
        if getattr(args, name) < 2:
            ap.error(f"--{name.replace('_', '-')} = {getattr(args, name)} must be at least 2 (the intervals "
                     "resample them)")


def record_and_block(record: Path, measure, render, markers: tuple[str, str], doc: Path) -> str:
    """``measure()``'s record written to ``record`` (``measure`` None: the kept record), then
    ``render`` of it written as the block between ``markers`` of ``doc``; returns the block."""
    if measure is not None:
        record.parent.mkdir(parents=True, exist_ok=True)
        record.write_text(json.dumps(measure(), indent=1) + "\n")
    text = render(json.loads(record.read_text()))
    write_block(text, markers, doc)
    return text


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=20, help="drops (episodes) of rig")
    ap.add_argument("--seed", type=int, default=1000, help="first drop's seed (held-out: 1000 on)")
    ap.add_argument("--workers", default="", help="compare's --workers (default: compare's)")
    ap.add_argument("--render", action="store_true", help="only rewrite the block from the records")
    ap.add_argument("--no-tick", action="store_true", help="keep the tick record as it is")
    ap.add_argument("--quick", action="store_true", help="bench_policy --quick for the tick cost")
    args = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    cpath, tpath = OUT / "compare.json", OUT / "tick.json"
    if not args.render:
        rec = run_compare(args.episodes, args.seed, args.workers)
        cpath.write_text(json.dumps(rec, indent=1) + "\n")
        if not args.no_tick:
            run_tick(args.quick)
    compare = json.loads(cpath.read_text()) if cpath.exists() else None
    tick = json.loads(tpath.read_text()) if tpath.exists() else None
    write_block(render(compare, tick))
    print(render(compare, tick))
    if BENCHMARK.exists():
        text = render_robustness(json.loads(BENCHMARK.read_text()))
        write_block(text, ROBUSTNESS)
        print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
