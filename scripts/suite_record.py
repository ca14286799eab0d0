"""The test suite's pass rate and wall time, the whole suite and the fast subset, optionally with
a CPU-bound process beside it.

    python scripts/suite_record.py [--runs 3] [--fast-runs 1] [--beside-cpu-bound] [--doc]

Each run is README's test command (``python -m pytest -q -n auto``; the fast subset adds
``-m "not slow and not training"``) in a fresh pytest process of this checkout, with pytest's
cache off; its counts come from a JUnit XML report.  ``--beside-cpu-bound`` starts one process
that spins on a core for the whole of every run (what a newcomer's machine has when a build or a
browser is busy): the suite must pass beside it, because no test asserts on this machine's
timing.  The first run of a cold numba cache compiles the kernels; the record says how many were
compiled in each run, so a warm run's wall time is not read as a cold one's.

Writes ``docs/results/suite.json`` (figures, command, versions, CPU, date); ``--doc`` also
rewrites the ``suite-runs`` block of docs/getting-started.md from it.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import re
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ElementTree
from pathlib import Path

from docs_tables import write_block

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / "docs" / "results" / "suite.json"
DOC = ROOT / "docs" / "getting-started.md"
BLOCK = "suite-runs"
FAST = "not slow and not training"
COMPILED = re.compile(r"impact_env: compiled (\d+) numba kernels")


def _spin() -> None:
    while True:
        pass


def run_once(fast: bool) -> dict:
    """One pytest run of the suite (or the fast subset); its counts and wall time."""
    with tempfile.TemporaryDirectory(prefix="impact-env-suite-") as tmp:
        report = Path(tmp) / "junit.xml"
        command = [sys.executable, "-m", "pytest", "-q", "-n", "auto", "-p", "no:cacheprovider",
                   f"--junitxml={report}"] + (["-m", FAST] if fast else [])
        t0 = time.perf_counter()
        run = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, check=False)
        wall = time.perf_counter() - t0
        if not report.exists():
            raise SystemExit(f"pytest wrote no report (exit {run.returncode}):\n{run.stdout[-3000:]}"
                             f"{run.stderr[-3000:]}")
        suite = ElementTree.parse(report).getroot()
        suite = suite if suite.tag == "testsuite" else suite.find("testsuite")
        assert suite is not None
    failed, why = [], {}
    for case in suite.iter("testcase"):
        fault = case.find("failure") if case.find("failure") is not None else case.find("error")
        if fault is not None:
            name = case.get("classname", "") + "::" + case.get("name", "")
            failed.append(name)
            # the assertion's own line, so that a failure seen once can be diagnosed from the record
            why[name] = (fault.get("message") or "").strip()[:500]
    skipped = sum(1 for case in suite.iter("testcase") if case.find("skipped") is not None)
    total = int(suite.get("tests", 0))
    compiled = sum(int(n) for n in COMPILED.findall(run.stdout + run.stderr))
    return {"subset": "fast" if fast else "whole", "exit": run.returncode, "wall_s": round(wall, 1),
            "tests": total, "failed": len(failed), "failed_tests": failed, "failure_messages": why,
            "skipped_or_xfailed": skipped,
            "passed": total - len(failed) - skipped, "kernels_compiled": compiled}


def block(record: dict) -> str:
    meta = record["meta"]
    beside = "with a CPU-bound process beside each run" if record["beside_cpu_bound"] else "alone"
    lines = [f"On `{meta['cpu']['model']}`, {record['cpus']} CPUs ({meta['date'][:10]}; `{meta['command']}`, "
             f"{beside}):", "",
             "| run | subset | tests | passed | failed | skipped or xfailed | kernels compiled | wall s |",
             "|---|---|---|---|---|---|---|---|"]
    for i, row in enumerate(record["runs"], 1):
        lines.append(f"| {i} | {row['subset']} | {row['tests']} | {row['passed']} | {row['failed']} | "
                     f"{row['skipped_or_xfailed']} | {row['kernels_compiled']} | {row['wall_s']:.0f} |")
    failures = sorted({t for row in record["runs"] for t in row["failed_tests"]})
    for subset in ("whole", "fast"):
        rows = [row for row in record["runs"] if row["subset"] == subset]
        if rows:
            clean = sum(row["failed"] == 0 and row["exit"] == 0 for row in rows)
            lines += ["", f"Runs of the {subset} {'suite' if subset == 'whole' else 'subset'} that passed: "
                          f"{clean} of {len(rows)}."]
    if failures:
        lines += ["", "Failed at least once: " + ", ".join(f"`{t}`" for t in failures) + "."]
    return "\n".join(lines)



def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="runs of the whole suite (default 3)")
    ap.add_argument("--fast-runs", type=int, default=1, help="runs of the fast subset, after (default 1)")
    ap.add_argument("--beside-cpu-bound", action="store_true", help="one spinning process beside every run")
    ap.add_argument("--doc", action="store_true", help="rewrite docs/getting-started.md's block")
    ap.add_argument("--render", action="store_true", help="only rewrite the block from the record")
    args = ap.parse_args()
    for name, runs in (("--runs", args.runs), ("--fast-runs", args.fast_runs)):
        if not 0 <= runs <= 10:
            raise SystemExit(f"{name} = {runs} must be in [0, 10] "
                             "(a whole-suite run takes 10-30 min on 2 CPUs)")
    if not args.render:
        from impact_env.eval.benchmark import run_meta

        # the whole suite first: it compiles what it needs
        plan = [False] * args.runs + [True] * args.fast_runs
        spinner = None
        if args.beside_cpu_bound:
            spinner = multiprocessing.get_context("spawn").Process(target=_spin, daemon=True)
            spinner.start()
        t0 = time.perf_counter()
        rows: list[dict] = []
        RECORD.parent.mkdir(parents=True, exist_ok=True)
        try:
            for fast in plan:
                rows.append(run_once(fast))
                print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
                # after every run, so that a long series stopped early keeps what it measured
                record = {"runs": rows, "planned_runs": len(plan), "beside_cpu_bound": args.beside_cpu_bound,
                          "cpus": os.cpu_count(),
                          "meta": run_meta("python scripts/suite_record.py " + " ".join(sys.argv[1:]),
                                           time.perf_counter() - t0, 0, 0.0)}
                RECORD.write_text(json.dumps(record, indent=1) + "\n")
        finally:
            if spinner is not None:
                spinner.terminate()
    record = json.loads(RECORD.read_text())
    print(block(record))
    if args.doc or args.render:
        write_block(DOC, BLOCK, block(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())
