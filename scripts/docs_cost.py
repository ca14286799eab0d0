"""What the documentation costs to check: the site's build and each tutorial's run.

    python scripts/docs_cost.py [--doc]

* the site: ``sphinx-build -W --keep-going -q -b html docs <a fresh folder>``, as ``.ci/run`` builds
  it (the generated reference pages are rewritten first, by ``docs/_ext``), its wall time;
* the tutorials: ``tests/test_docs.py``'s ``test_tutorial_*``, each in one pytest process, with
  each test's own duration from pytest's report (the numba cache as it is: a run on a cold cache
  includes the compile, and the record counts the kernels compiled).

Writes ``docs/results/docs_cost.json`` (figures, command, versions, CPU, date); ``--doc`` also
rewrites the ``docs-cost`` block of docs/tooling.md from it.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ElementTree
from pathlib import Path

from docs_tables import write_block

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / "docs" / "results" / "docs_cost.json"
DOC = ROOT / "docs" / "tooling.md"
BLOCK = "docs-cost"
COMPILED = re.compile(r"impact_env: compiled (\d+) numba kernels")


def site_build() -> float:
    with tempfile.TemporaryDirectory(prefix="impact-env-site-") as out:
        t0 = time.perf_counter()
        command = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html", "docs", out]
        run = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, check=False)
        wall = time.perf_counter() - t0
    if run.returncode != 0:
        raise SystemExit(f"the site did not build:\n{run.stderr[-3000:]}")
    return wall


def tutorials() -> tuple[dict[str, float], int]:
    with tempfile.TemporaryDirectory(prefix="impact-env-tutorials-") as tmp:
        report = Path(tmp) / "junit.xml"
        command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--junitxml={report}",
                   "tests/test_docs.py", "-k", "test_tutorial_"]
        run = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, check=False)
        if run.returncode != 0 or not report.exists():
            raise SystemExit(f"the tutorials failed (exit {run.returncode}):\n{run.stdout[-3000:]}")
        cases = ElementTree.parse(report).getroot().iter("testcase")
        times = {case.get("name", ""): float(case.get("time", "nan")) for case in cases}
    return times, sum(int(n) for n in COMPILED.findall(run.stdout + run.stderr))


def block(record: dict) -> str:
    meta = record["meta"]
    lines = [f"On `{meta['cpu']['model']}` ({meta['date'][:10]}; `{meta['command']}`):", "",
             "| what | wall s |", "|---|---|",
             f"| the site, `sphinx-build -W` from scratch | {record['site_s']:.0f} |"]
    for name, s in record["tutorials_s"].items():
        page = name.removeprefix("test_tutorial_").replace("_", "-")
        lines.append(f"| tutorial `{page}`, run by `tests/test_docs.py::{name}` | {s:.0f} |")
    lines += ["", f"Numba kernels the tutorials compiled in this run: {record['tutorial_kernels_compiled']} "
                  "(0: every kernel came from the cache)."]
    return "\n".join(lines)



def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--doc", action="store_true", help="rewrite docs/tooling.md's block")
    ap.add_argument("--render", action="store_true", help="only rewrite the block from the record")
    args = ap.parse_args()
    if not args.render:
        from impact_env.eval.benchmark import run_meta

        t0 = time.perf_counter()
        site = site_build()
        times, compiled = tutorials()
        record = {"site_s": round(site, 1), "tutorials_s": {k: round(v, 1) for k, v in sorted(times.items())},
                  "tutorial_kernels_compiled": compiled,
                  "meta": run_meta("python scripts/docs_cost.py " + " ".join(sys.argv[1:]),
                                   time.perf_counter() - t0, 0, 0.0)}
        RECORD.parent.mkdir(parents=True, exist_ok=True)
        RECORD.write_text(json.dumps(record, indent=1) + "\n")
    record = json.loads(RECORD.read_text())
    print(block(record))
    if args.doc or args.render:
        write_block(DOC, BLOCK, block(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())
