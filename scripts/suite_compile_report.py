"""Where a cold-cache test run spends its compile time, from the log the tests' conftest writes
when ``IMPACT_ENV_COMPILE_LOG`` is set.

    IMPACT_ENV_COMPILE_LOG=/tmp/compile.jsonl NUMBA_CACHE_DIR=$(mktemp -d) python -m pytest -q -n auto
    python scripts/suite_compile_report.py /tmp/compile.jsonl [--top 30]

Prints the outermost compiles' CPU seconds (a kernel's callees compile inside it) per worker and in
all, the tests that compiled most, the kernels compiled most often (each signature is a compile
of its own), and the compiles repeated in more than one worker (each worker has its own process,
so a kernel that two workers first need at the same time is compiled twice).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter, defaultdict
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--top", type=int, default=30)
    args = ap.parse_args()
    lines = [json.loads(line) for line in args.log.read_text().splitlines() if line.strip()]
    rows = [r for r in lines if r.get("kind", "compile") == "compile"]
    tests = [r for r in lines if r.get("kind") == "test"]
    for r in rows:  # CPU seconds where the log has them (they move less with the load than wall seconds)
        r["s"] = r.get("cpu_s", r["s"])
    outer = [r for r in rows if r["depth"] == 0]
    per_pid: Counter = Counter()
    per_test: Counter = Counter()
    for r in outer:
        per_pid[r["pid"]] += r["s"]
        per_test[r["test"]] += r["s"]
    print(f"{len(rows)} compiles, {len(outer)} outermost, {sum(per_pid.values()):.0f} s of compiling in "
          f"{len(per_pid)} processes")
    for pid, s in per_pid.most_common():
        print(f"  pid {pid}: {s:.0f} s")
    test_cpu = {r["test"]: r["cpu_s"] for r in tests}
    if tests:
        total = sum(test_cpu.values())
        print(f"{len(tests)} tests, {total:.0f} CPU s in the workers' processes, of which compiling "
              f"{sum(per_pid.values()):.0f} s ({100 * sum(per_pid.values()) / max(total, 1e-9):.0f} %)")
    print(f"\nthe {args.top} tests that compiled most (outermost compiles' seconds; the test's own CPU s):")
    for test, s in per_test.most_common(args.top):
        print(f"  {s:7.1f} s  {test_cpu.get(test, float('nan')):7.1f} s  {test}")
    if tests:
        print(f"\nthe {args.top} tests with the most CPU s (compiling included):")
        for test, s in sorted(test_cpu.items(), key=lambda kv: -kv[1])[:args.top]:
            print(f"  {s:7.1f} s  {per_test.get(test, 0.0):7.1f} s compiling  {test}")
    per_kernel: dict[str, list] = defaultdict(list)
    for r in rows:
        per_kernel[r["kernel"]].append(r)
    print(f"\nthe {args.top} kernels with the most compile seconds (outermost only) and signatures:")
    ranked = sorted(per_kernel.items(), key=lambda kv: -sum(r["s"] for r in kv[1] if r["depth"] == 0))
    for kernel, rs in ranked[:args.top]:
        sigs = {r["args"] for r in rs}
        print(f"  {sum(r['s'] for r in rs if r['depth'] == 0):7.1f} s  {len(rs):3d} compiles  "
              f"{len(sigs):3d} signatures  {kernel}")
    repeated = defaultdict(set)
    for r in outer:
        repeated[(r["kernel"], r["args"])].add(r["pid"])
    twice = {k: pids for k, pids in repeated.items() if len(pids) > 1}
    wasted = sum(r["s"] for r in outer if (r["kernel"], r["args"]) in twice) * 0.5
    print(f"\n{len(twice)} outermost compiles repeated in more than one process "
          f"(about {wasted:.0f} s of compiling spent twice):")
    for (kernel, _), pids in sorted(twice.items(), key=lambda kv: kv[0][0])[:args.top]:
        print(f"  {len(pids)} processes  {kernel}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
