"""Where a compiled workload spends its time, by numba function: ``perf`` samples, named by ``gdb``.

    python scripts/perf_kernels.py [--workload sim|rollout] [--effects] [--seconds 5] [--top 25]

``perf record`` alone cannot name numba's functions: they live in memory that the JIT (or the
cache loader) mapped, with no perf map and no jitdump.  This script runs the workload in a child
process, samples it with ``perf record -p`` for ``--seconds`` once it is warm (compiled and
stepping), then asks ``gdb`` (attached to the same, still running, process) which function each
sampled JIT address lies in, and prints the samples per function: numba functions by their
Python name, shared libraries' by their symbol (glibc's ``pow``, numba's ``NRT_incref``/
``NRT_decref``, numpy's random generators, CPython's interpreter).  Functions that numba inlined
(``inline="always"``) count in their caller.

Workloads (one thread, ``rig``, zero commands):

* ``sim``: ``Simulator("rig", 400)`` stepped from ``reset`` over whole episodes;
* ``rollout``: compare's rollout of ``passive`` on ``rig`` at N = 400, as
  ``scripts/bench_env.py --only period`` times it.

``--no-effects`` runs the bare plant (``effects.active = []``) instead of ``rig`` as it is.
Needs Linux ``perf`` (with permission to sample a process: root, or ``perf_event_paranoid`` <= 1)
and ``gdb``; on a machine without them it says so and exits 2.  Output is a benchmark's: sample
shares on this machine, under its load, not a test.
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

WORKLOAD = r'''
import sys, time, numpy as np, impact_env
from impact_env.config import with_overrides
kind, effects = sys.argv[1], sys.argv[2] == "1"
scene = impact_env.load_scene("rig")
if not effects:
    scene = with_overrides(scene, {"effects.active": []})
if kind == "sim":
    from impact_env.sim.simulator import Simulator
    sim = Simulator(scene, 400)
    z = np.zeros(400)
    def once():
        sim.reset([np.random.default_rng(s) for s in range(400)])
        for _ in range(4000):
            sim.step(z)
else:
    from impact_env.eval.rollout import rollout
    from impact_env.policy.registry import make_policy
    pol = make_policy("passive", scene)
    def once():
        rollout(scene, pol, range(400), horizon=4000 * scene.control_period, trace_rate=1e4)
once()
print("warm", flush=True)
while True:
    once()
'''


def _need(tool: str) -> str:
    path = shutil.which(tool)
    if path is None:
        print(f"perf_kernels: {tool!r} not found on PATH (Debian: apt-get install linux-perf gdb)",
              file=sys.stderr)
        sys.exit(2)
    return path


REPORT_LINE = re.compile(r"\s*(\d+)\s+(\[JIT\] tid \d+|\S+)\s+\[[.k]\]\s+(.+?)(?:\s{2,}.*)?$")


def parse_report(text: str) -> collections.Counter:
    """Samples per (object, symbol or address) from the text of ``perf report --stdio -F
    sample,dso,symbol``: lines "  COUNT  DSO  [.] SYMBOL   -   -", where the symbol ends at the
    two spaces that start the IPC columns (a C++ symbol may hold single spaces)."""
    counts: collections.Counter = collections.Counter()
    for line in text.splitlines():
        m = REPORT_LINE.match(line)
        if m:
            counts[(m.group(2), m.group(3))] += int(m.group(1))
    return counts


def function_name(info_symbol: str) -> str:
    """The function in one answer of gdb's ``info symbol ADDR``: "NAME + OFFSET in section S of
    ...", NAME a numba function's mangled name (``_ZN`` and the length-prefixed parts of its
    Python path, then numba's ABI tags) or a plain symbol; numba's path comes back joined by
    "::".  An address gdb cannot name: "(unnamed JIT code)"."""
    if " in section " not in info_symbol:
        return "(unnamed JIT code)"
    name = re.sub(r" \+ \d+$", "", info_symbol.split(" in section ")[0])
    name = name.split("[abi")[0]
    if name.startswith("_ZN"):
        parts, rest = [], name[3:]
        while rest and rest[0].isdigit():
            digits = re.match(r"\d+", rest).group(0)  # type: ignore[union-attr]
            n = int(digits)
            rest = rest[len(digits):]
            parts.append(rest[:n])
            rest = rest[n:]
        name = "::".join(parts) or name
    return name


def _samples(perf: str, data: Path) -> collections.Counter:
    out = subprocess.run([perf, "report", "-i", str(data), "--no-children", "--sort", "dso,symbol",
                          "--stdio", "-F", "sample,dso,symbol"], capture_output=True, text=True).stdout
    return parse_report(out)


def _name_jit(gdb: str, pid: int, addrs: list[str]) -> dict[str, str]:
    """Function names of JIT addresses, from gdb attached to the live process."""
    script = "\n".join(f"info symbol {a}" for a in addrs)
    with tempfile.NamedTemporaryFile("w", suffix=".gdb", delete=False) as f:
        f.write(script + "\n")
    out = subprocess.run([gdb, "-p", str(pid), "-batch", "-x", f.name], capture_output=True, text=True,
                         timeout=300).stdout
    os.unlink(f.name)
    answers = [ln for ln in out.splitlines() if " in section " in ln or ln.startswith("No symbol matches")]
    return {a: function_name(ln) for a, ln in zip(addrs, answers, strict=False)}  # (one answer per line)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workload", choices=("sim", "rollout"), default="sim")
    ap.add_argument("--effects", action=argparse.BooleanOptionalAction, default=True)
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--top", type=int, default=25)
    args = ap.parse_args()
    perf, gdb = _need("perf"), _need("gdb")
    child = subprocess.Popen([sys.executable, "-c", WORKLOAD, args.workload, "1" if args.effects else "0"],
                             stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert child.stdout is not None
        if child.stdout.readline().strip() != "warm":
            print("perf_kernels: the workload did not start", file=sys.stderr)
            return 2
        time.sleep(1.0)
        with tempfile.TemporaryDirectory() as tmp:
            data = Path(tmp) / "perf.data"
            rec = subprocess.run([perf, "record", "-q", "-p", str(child.pid), "-o", str(data), "--", "sleep",
                                  str(args.seconds)], capture_output=True, text=True)
            if rec.returncode != 0 or not data.exists():
                print(f"perf_kernels: perf record failed: {rec.stderr.strip()[:300]}", file=sys.stderr)
                return 2
            counts = _samples(perf, data)
        jit = [sym for (dso, sym) in counts if dso.startswith("[JIT]") and sym.startswith("0x")]
        names = _name_jit(gdb, child.pid, jit) if jit else {}
    finally:
        child.kill()
        child.wait()
    by: collections.Counter = collections.Counter()
    for (dso, sym), n in counts.items():
        by[names.get(sym, sym) if dso.startswith("[JIT]") else f"{sym} ({Path(dso).name})"] += n
    total = sum(by.values())
    print(f"## Samples per function: {args.workload}, rig, effects {'on' if args.effects else 'off'}, "
          f"{total} samples in {args.seconds:g} s (load average {os.getloadavg()[0]:.2f})\n")
    print("| share | function |")
    print("|---|---|")
    for name, n in by.most_common(args.top):
        print(f"| {100.0 * n / total:.1f} % | {name} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
