"""What the ``mpc`` law costs per tick: the compiled tick on this machine (from
``scripts/bench_policy.py``'s record) and an ESTIMATE for a Cortex-M7 from the instruction count
of its C build; writes the M7 record and the block of docs/mpc.md between the
``mpc-cost`` markers.

    python scripts/bench_policy.py --laws mpc,mpc-state --json docs/results/mpc_cost.json
    python scripts/mpc_cost.py [--ticks 60]      # count, write docs/results/mpc_m7.json, render
    python scripts/mpc_cost.py --render          # render the block from the two records

The Cortex-M7 figure is counted, not timed: the tick (``impact_step`` of ``impact-env export mpc
--scene rig --c``, filter and solver included) is built with ``arm-none-eabi-gcc -mcpu=cortex-m7
-mfpu=fpv5-d16 -mfloat-abi=hard -mthumb -O2 -ffp-contract=off`` (plus ``-fno-short-enums``, so
that the object links into a Linux driver), linked with a small driver by
``arm-linux-gnueabihf-gcc -static``, and run by ``qemu-arm -singlestep -d exec,nochain``, which
logs every executed instruction's address: the instructions between two entries into
``impact_step`` are one tick's (the driver's loop adds a few dozen).  The readings are a drop of
``rig`` recorded from the virtual rig with the numba target in closed loop.  The cycles are then
ESTIMATED as one per instruction at 600 MHz, and apart from that the executed double-precision
divisions and square roots are counted (each takes many cycles on the M7's FPU, whose
double-precision arithmetic is not dual-issued): a board's cycle counter is the measurement this
estimate stands in for.
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

BENCH = ROOT / "docs" / "results" / "mpc_cost.json"
M7 = ROOT / "docs" / "results" / "mpc_m7.json"
DOC = ROOT / "docs" / "mpc.md"
M7_FLAGS = ("-mcpu=cortex-m7", "-mfpu=fpv5-d16", "-mfloat-abi=hard", "-mthumb", "-O2", "-std=c99", "-Wall",
            "-Wextra", "-Werror", "-ffp-contract=off", "-fno-short-enums")
CLOCK_HZ = 600e6  # a 600 MHz Cortex-M7 (STM32H7, i.MX RT1060 class)
DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include "impact_policy.h"
static impact_state st;
int main(int argc, char **argv) {
    FILE *f = fopen(argv[1], "rb");
    int n = atoi(argv[2]);
    double r[4];
    impact_real c = 0.0, fo;
    impact_init(&st);
    impact_reset(&st);
    for (int m = 0; m < n; m++) {
        if (fread(r, 8, 4, f) != 4) return 1;
        impact_step(&st, r, &c, &fo);
    }
    printf("%.17g\n", (double)c);
    return 0;
}
"""


def _need(tool: str) -> str:
    exe = shutil.which(tool)
    if exe is None:
        raise SystemExit(f"{tool} not found: install Debian's gcc-arm-none-eabi, gcc-arm-linux-gnueabihf and "
                         "qemu-user")
    return exe


def count(ticks: int, seed: int) -> dict:
    """Instructions executed per tick of the M7 build, counted under qemu-arm."""
    from impact_env.deploy import parity
    from impact_env.deploy.c_export import write_c
    from impact_env.policy.export import export_policy
    from impact_env.scene import load_scene

    scene = load_scene("rig")
    pol = export_policy("mpc", scene)
    with tempfile.TemporaryDirectory(prefix="mpc-m7-") as tmp:
        d = Path(tmp)
        write_c(pol, scene, d / "c")
        rec = parity.record(pol, scene, seed, ticks)
        rec.readings.astype("<f8").tofile(d / "r.f64")
        (d / "driver.c").write_text(DRIVER)
        subprocess.run([_need("arm-none-eabi-gcc"), *M7_FLAGS, "-c", "-o", str(d / "p.o"),
                        str(d / "c" / "impact_policy.c")], check=True)
        size = subprocess.run([_need("arm-none-eabi-size"), str(d / "p.o")], capture_output=True, text=True,
                              check=True).stdout.split("\n")[1].split()
        subprocess.run([_need("arm-linux-gnueabihf-gcc"), "-static", "-O2", f"-I{d / 'c'}", "-o",
                        str(d / "drv"), str(d / "driver.c"), str(d / "p.o"), "-lm", "-Wl,--no-warn-mismatch"],
                       check=True, capture_output=True)
        syms = subprocess.run(["arm-linux-gnueabihf-nm", str(d / "drv")], capture_output=True, text=True,
                              check=True).stdout
        entry = next(int(line.split()[0], 16) & ~1 for line in syms.splitlines()
                     if line.endswith(" impact_step"))
        dis = subprocess.run(["arm-linux-gnueabihf-objdump", "-d", str(d / "drv")], capture_output=True,
                             text=True, check=True).stdout
        mnemonic = {}
        for line in dis.splitlines():
            m = re.match(r"\s*([0-9a-f]+):\s+(?:[0-9a-f]{4}\s?){1,2}\s+(\S+)", line)
            if m:
                mnemonic[int(m.group(1), 16)] = m.group(2)
        proc = subprocess.Popen([_need("qemu-arm"), "-singlestep", "-d", "exec,nochain", str(d / "drv"),
                                 str(d / "r.f64"), str(ticks)], stderr=subprocess.PIPE,
                                stdout=subprocess.PIPE, text=True)
        per_tick, divs, sqrts = [], [], []
        n = nd = ns = 0
        started = False
        assert proc.stderr is not None
        pc_field = re.compile(r"\[[0-9a-f]+/([0-9a-f]+)/")
        for line in proc.stderr:
            m = pc_field.search(line)
            if not m:
                continue
            pc = int(m.group(1), 16)
            if pc == entry:
                if started:
                    per_tick.append(n)
                    divs.append(nd)
                    sqrts.append(ns)
                started, n, nd, ns = True, 0, 0, 0
            if started:
                n += 1
                op = mnemonic.get(pc, "")
                nd += op.startswith("vdiv.f64")
                ns += op.startswith("vsqrt.f64")
        proc.wait()
        last_command = float(proc.stdout.read()) if proc.stdout is not None else float("nan")
        if not np.isclose(last_command, rec.command[-1], rtol=0, atol=1e-12):
            raise SystemExit(f"the ARM build's last command {last_command!r} is not the numba target's "
                             f"{rec.command[-1]!r}: the count is not of the same computation")
    per = np.array(per_tick[1:], dtype=np.float64)  # tick 0 (the episode's start) apart; the last tick
    #                                                 ends with the driver's exit, not counted
    return {"ticks_counted": int(per.size), "seed": seed,
            "instructions_p50": float(np.percentile(per, 50)), "instructions_max": float(per.max()),
            "instructions_min": float(per.min()),
            "vdiv_f64_p50": float(np.percentile(divs[1:], 50)),
            "vsqrt_f64_p50": float(np.percentile(sqrts[1:], 50)),
            "object_bytes": {"text": int(size[0]), "data": int(size[1]), "bss": int(size[2])},
            "clock_hz": CLOCK_HZ, "flags": " ".join(M7_FLAGS)}


def block(bench: dict | None, m7: dict | None) -> str:
    rows = ["| figure | `mpc` | `mpc-state` |", "| --- | --- | --- |"]
    if bench:
        laws = bench["laws"]
        p50 = [f"{laws[k]['p50_ns'] / 1e3:.1f} us" if k in laws else "-" for k in ("mpc", "mpc-state")]
        p99 = [f"{laws[k]['p99_ns'] / 1e3:.1f} us" if k in laws else "-" for k in ("mpc", "mpc-state")]
        calls = laws.get("mpc", laws.get("mpc-state", {})).get("calls", 0)
        rows += [f"| compiled tick on this machine, p50 | {p50[0]} | {p50[1]} |",
                 f"| compiled tick on this machine, p99 (goal <= 50 us) | {p99[0]} | {p99[1]} |"]
    if m7:
        us = m7["instructions_p50"] / m7["clock_hz"] * 1e6
        rows += [f"| Cortex-M7 build: instructions per tick, p50 (max) | {m7['instructions_p50']:.0f} "
                 f"({m7['instructions_max']:.0f}) | (not exported: privileged) |",
                 f"| ... of which double divisions / square roots, p50 | {m7['vdiv_f64_p50']:.0f} / "
                 f"{m7['vsqrt_f64_p50']:.0f} | |",
                 f"| Cortex-M7 at {m7['clock_hz'] / 1e6:.0f} MHz, ESTIMATE at one instruction per cycle | "
                 f"{us:.0f} us | |",
                 f"| Cortex-M7 object: code and constants | {m7['object_bytes']['text']} B | |"]
    out = []
    if bench:
        out.append(f"* `{bench['command']}`: {calls} ticks per law, the observations of rig drops driven by "
                   "`mpc` itself (its filter replays its own demands; thesis-ideal for the privileged law), each drop "
                   "in order from its start;")
    if m7:
        out.append(f"* `{m7['command']}`: the M7 rows, counted by qemu-arm, not timed on a board "
                   "(the script's doc says how).")
    return "\n".join([*out, "", *rows])


def render() -> None:
    bench = json.loads(BENCH.read_text()) if BENCH.exists() else None
    m7 = json.loads(M7.read_text()) if M7.exists() else None
    text = DOC.read_text()
    start, end = "<!-- mpc-cost:start -->", "<!-- mpc-cost:end -->"
    if start not in text:
        raise SystemExit(f"{DOC}: no {start} marker")
    head, rest = text.split(start, 1)
    _old, tail = rest.split(end, 1)
    DOC.write_text(f"{head}{start}\n{block(bench, m7)}\n{end}{tail}")
    print(f"{DOC}: mpc-cost block written")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ticks", type=int, default=60,
                    help="ticks of the drop to run (default 60: the fall, the touch and the first contact)")
    ap.add_argument("--seed", type=int, default=0, help="the drop (a reset seed of the virtual rig)")
    ap.add_argument("--render", action="store_true", help="only rewrite the docs block from the records")
    args = ap.parse_args(argv)
    if not args.render:
        rec = count(args.ticks, args.seed)
        rec.update(command="python scripts/mpc_cost.py " + " ".join(sys.argv[1:] if argv is None else argv),
                   date_utc=datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M"),
                   host=platform.machine(), python=platform.python_version(),
                   qemu=subprocess.run(["qemu-arm", "--version"], capture_output=True,
                                       text=True).stdout.split("\n")[0],
                   gcc=subprocess.run(["arm-none-eabi-gcc", "--version"], capture_output=True,
                                      text=True).stdout.split("\n")[0])
        M7.write_text(json.dumps(rec, indent=1) + "\n")
        print(json.dumps(rec, indent=1))
    render()
    return 0


if __name__ == "__main__":
    sys.exit(main())
