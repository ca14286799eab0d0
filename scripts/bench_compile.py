"""What a user's first run pays to compile: the numba kernels of a cold cache, for the first
thing each user meets, in a fresh process with a fresh cache folder.

    python scripts/bench_compile.py [--rounds 1] [--other CHECKOUT] [--doc]

Per process (``PYTHONPATH`` = the checkout, ``NUMBA_CACHE_DIR`` = a new empty folder):

* ``env``: ``gymnasium.make("ImpactCatch-v0")``, ``reset``, one ``step`` (someone training an
  agent);
* ``compare``: then ``compare`` on 2 drops of ``rig`` with ``passive``, ``thesis-rig`` and
  ``mpc`` (someone benchmarking policies; 2 ms horizon, so the figure is the compile);

each as CPU seconds of the process (user + system: the compile is single-threaded, so this is
what it costs on an idle core, and it moves less with the machine's load than the wall time)
and wall seconds, and the number of project kernels compiled.  With ``--other`` the same probe
runs on another checkout too, alternating, and the table gives this / other.

Writes ``docs/results/compile.json`` (figures, command, versions, CPU, date); ``--doc`` also
rewrites the ``compile-cost`` block of docs/architecture.md from it.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / "docs" / "results" / "compile.json"
DOC = ROOT / "docs" / "architecture.md"
BLOCK = "compile-cost"
FIGURES = ("env_cpu_s", "compare_cpu_s", "env_wall_s", "compare_wall_s", "kernels")

PROBE = r'''
import json, resource, time
t0 = time.perf_counter()

def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime

import gymnasium as gym
import impact_env
from impact_env import _jit
from impact_env.eval.compare import compare
from impact_env.scene import load_scene
c0 = cpu()
env = gym.make("ImpactCatch-v0")
env.reset(seed=0)
env.step(env.action_space.sample())
out = {"env_cpu_s": cpu() - c0, "env_wall_s": time.perf_counter() - t0}
t1, c1 = time.perf_counter(), cpu()
compare(load_scene("rig"), ["passive", "thesis-rig", "mpc"], episodes=2, seed=0, horizon=0.002, workers=1,
        progress=False)
out.update(compare_cpu_s=cpu() - c1, compare_wall_s=time.perf_counter() - t1,
           kernels=len(_jit._PROGRESS.numbered), package=impact_env.__file__)
print(json.dumps(out))
'''


def probe(checkout: Path) -> dict:
    with tempfile.TemporaryDirectory(prefix="impact-env-cold-cache-") as cache:
        env = {**os.environ, "PYTHONPATH": str(checkout), "NUMBA_CACHE_DIR": cache,
               "IMPACT_ENV_NUMBA_CACHE": "1"}
        run = subprocess.run([sys.executable, "-c", PROBE], env=env, cwd=checkout, capture_output=True,
                             text=True, check=False)
    if run.returncode != 0:
        raise SystemExit(f"the probe failed in {checkout}:\n{run.stderr[-3000:]}")
    row = json.loads(run.stdout.strip().splitlines()[-1])
    if not row["package"].startswith(str(checkout)):
        raise SystemExit(f"the probe imported {row['package']}, not the checkout {checkout}")
    return row


def _median(rows: list[dict], key: str) -> float:
    return sorted(x[key] for x in rows)[len(rows) // 2]


def block(record: dict) -> str:
    this = record["median"]["this"]
    lines = [f"Cold compile on `{record['meta']['cpu']['model']}` ({record['meta']['date'][:10]}; "
             f"`{record['meta']['command']}`, median of {record['rounds']} round(s)):", "",
             "| first call | kernels compiled | CPU s | wall s |", "|---|---|---|---|",
             f"| `gym.make` + `reset` + `step` | | {this['env_cpu_s']:.0f} | {this['env_wall_s']:.0f} |",
             f"| then `compare` (passive, thesis-rig, mpc) | | {this['compare_cpu_s']:.0f} | "
             f"{this['compare_wall_s']:.0f} |",
             f"| both | {this['kernels']:.0f} | {this['env_cpu_s'] + this['compare_cpu_s']:.0f} | "
             f"{this['env_wall_s'] + this['compare_wall_s']:.0f} |"]
    if "other" in record["median"]:
        other = record["median"]["other"]
        ratio = (this["env_cpu_s"] + this["compare_cpu_s"]) / (other["env_cpu_s"] + other["compare_cpu_s"])
        lines += ["", f"Against `{record['other']}` in the same run, alternating: CPU time x{ratio:.2f}."]
    return "\n".join(lines)


def write_doc(record: dict) -> None:
    sys.path.insert(0, str(ROOT / "scripts"))
    from docs_tables import rewritten

    DOC.write_text(rewritten(DOC.read_text(), BLOCK, block(record)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--other", type=Path, help="another checkout, probed alternately")
    ap.add_argument("--doc", action="store_true", help="rewrite docs/architecture.md's block")
    ap.add_argument("--render", action="store_true", help="only rewrite the block from the record")
    args = ap.parse_args()
    if args.rounds < 1:
        raise SystemExit(f"--rounds = {args.rounds} must be >= 1")
    if not args.render:
        from impact_env.eval.benchmark import run_meta

        sides = {"this": ROOT} | ({"other": args.other.resolve()} if args.other else {})
        rows: dict[str, list[dict]] = {k: [] for k in sides}
        for r in range(args.rounds):
            # the side that runs first alternates: the first of a pair may meet a colder machine
            for k in (list(sides) if r % 2 == 0 else list(sides)[::-1]):
                rows[k].append(probe(sides[k]))
                print(k, json.dumps(rows[k][-1]), file=sys.stderr, flush=True)
        record = {"rounds": args.rounds, "other": str(args.other) if args.other else None, "runs": rows,
                  "median": {k: {f: _median(v, f) for f in FIGURES} for k, v in rows.items()},
                  "meta": run_meta("python scripts/bench_compile.py " + " ".join(sys.argv[1:]), 0.0, 0, 0.0)}
        RECORD.parent.mkdir(parents=True, exist_ok=True)
        RECORD.write_text(json.dumps(record, indent=1) + "\n")
    record = json.loads(RECORD.read_text())
    print(block(record))
    if args.doc or args.render:
        write_doc(record)
    return 0


if __name__ == "__main__":
    sys.exit(main())
