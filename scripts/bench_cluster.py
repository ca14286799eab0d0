"""``compare`` on a Dask cluster against the local process pool, on this machine (docs/cluster.md).

    python scripts/bench_cluster.py [--rounds 3] [--episodes 100] [--oracle-drops 8] \\
        [--out docs/results/cluster_bench.json]

Starts a real cluster on loopback (impact_env/eval/local_cluster.py: ``python -m dask scheduler`` and
``python -m dask worker --nworkers 2 --nthreads 1``, a worker process per core), connects once,
loads the kernels everywhere, then times two workloads in one process, alternating the ways of
running them round by round (so a slow spell of the machine falls on all of them):

* ``classic``: ``compare --scene rig --policies passive,thesis-rig,pd-penetration --episodes E``;
* ``oracle``: ``compare --scene rig --policies pd-penetration,oracle:generations=20 --episodes D``;

each run serially (``--workers 1``), on the local pool (``--workers 2``) and on the cluster
(``--cluster``, 2 worker processes).  Reported: the median wall time of each and the ratios
(speed-up of the cluster over the local pool, of the pool over one process), the CPU time of the
processes (less inflated by other jobs than the wall time), with the cluster's
overheads (start, connection, a task's round trip, the first load of the kernels in a fresh
worker), the sizes of what travels (a task, a result per drop) and a rollout's CPU time against
its number of drops (a task's fixed cost).  Every cluster run's metrics are
checked bitwise against the local pool's (and the serial run's).  The machine's load average
before and after is recorded: on a shared machine, other jobs on the same cores skew every figure.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pickle
import platform
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def _process_cpu() -> float:
    import psutil

    t = psutil.Process().cpu_times()
    return t.user + t.system


def _cpu_seconds(cluster) -> float:
    """CPU time so far of this process, its ended children (the local pool's workers), the
    cluster's worker processes and its scheduler (which tick over while idle too).  Other jobs on
    the cores inflate it less than the wall time (through caches and clocks, not waiting)."""
    import resource

    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    workers = sum(cluster.client.run(_process_cpu).values())
    return (time.process_time() + ch.ru_utime + ch.ru_stime + workers
            + cluster.client.run_on_scheduler(_process_cpu))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=100,
                    help="episodes of the classic workload (default 100)")
    ap.add_argument("--oracle-drops", type=int, default=8, help="drops of the oracle workload (default 8)")
    ap.add_argument("--out", default=None, help="write the figures as JSON here")
    ap.add_argument("--doc", default=None,
                    help="rewrite the table between <!-- bench:start --> and <!-- bench:end --> of this file")
    args = ap.parse_args()

    import distributed
    import numba
    import numpy as np

    from impact_env.eval.compare import RolloutJob, compare, run_job
    from impact_env.eval.local_cluster import local_cluster
    from impact_env.eval.parallel import Cluster, run_tasks
    from impact_env.scene import load_scene

    scene = load_scene("rig")
    workloads = {
        "classic": (["passive", "thesis-rig", "pd-penetration"], args.episodes),
        "oracle": (["pd-penetration", "oracle:generations=20"], args.oracle_drops),
    }
    # the kernels compiled (or loaded) in this process before anything is timed
    compare(scene, ["passive", "oracle:generations=2,popsize=4"], episodes=1, horizon=0.01, workers=1,
            progress=False)

    # a task's fixed cost: one batched rollout's CPU time against its number of drops (the per-step
    # overhead is paid once per batch, so a chunk of few drops costs nearly as much as one of many)
    from impact_env.eval.rollout import rollout
    from impact_env.policy.registry import make_policy

    batch_cpu = {}
    for n in (1, 5, 25, 50, 100):
        best = math.inf
        for _ in range(2):
            c0 = time.process_time()
            rollout(scene, make_policy("pd-penetration", scene), list(range(n)), trace_rate=1.0e4)
            best = min(best, time.process_time() - c0)
        batch_cpu[n] = round(best, 3)
        print(f"rollout of {n:3d} drops: {best:.3f} s CPU", flush=True)

    load_before = os.getloadavg()
    t0 = time.perf_counter()
    with local_cluster(workers=2, threads=1, lifetime_s=3 * 3600.0) as address:
        start_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        cluster = Cluster(address)
        connect_s = time.perf_counter() - t0
        try:
            # a fresh worker's first task loads numba's cached kernels (and the imports)
            t0 = time.perf_counter()
            compare(scene, ["passive", "oracle:generations=2,popsize=4"], episodes=2, horizon=0.01,
                    progress=False, cluster=cluster)
            first_load_s = time.perf_counter() - t0
            # a task's round trip: 200 trivial tasks over the 2 workers
            t0 = time.perf_counter()
            run_tasks(math.sqrt, [float(i) for i in range(200)], 2, total=200, desc="", progress=False,
                      cluster=cluster)
            round_trip_ms = 1e3 * (time.perf_counter() - t0) / 200 * 2  # per task, per worker
            # what travels: a task of 50 drops and its result
            task = RolloutJob("pd-penetration", scene, list(range(50)), 0, scene.episode.horizon, 1.0e4,
                        record=True)
            task_bytes = len(pickle.dumps(task))
            result_bytes = len(pickle.dumps(run_job(task))) / 50
            task.record = False
            result_plain_bytes = len(pickle.dumps(run_job(task))) / 50

            modes = {"serial": {"workers": 1}, "pool": {"workers": 2}, "cluster": {"cluster": cluster}}
            walls: dict = {w: {m: [] for m in modes} for w in workloads}
            cpus: dict = {w: {m: [] for m in modes} for w in workloads}
            for r in range(args.rounds):
                for name, (specs, episodes) in workloads.items():
                    order = list(modes) if r % 2 == 0 else list(reversed(modes))
                    results = {}
                    for mode in order:
                        c0, t0 = _cpu_seconds(cluster), time.perf_counter()
                        results[mode] = compare(scene, specs, episodes=episodes, seed=1000, progress=False,
                                                **modes[mode])
                        walls[name][mode].append(time.perf_counter() - t0)
                        cpus[name][mode].append(_cpu_seconds(cluster) - c0)
                        print(f"round {r + 1} {name:8s} {mode:8s} {walls[name][mode][-1]:7.2f} s", flush=True)
                    for spec in specs:  # the cluster's results are the pool's, bitwise
                        for key, v in results["pool"][spec].metrics.items():
                            np.testing.assert_array_equal(v, results["cluster"][spec].metrics[key],
                                                          err_msg=f"{name} {spec} {key}")
                            np.testing.assert_array_equal(v, results["serial"][spec].metrics[key],
                                                          err_msg=f"{name} {spec} {key}")
        finally:
            cluster.close()

    out = {"script": "scripts/bench_cluster.py", "json": args.out,
           "command": " ".join(["python", "scripts/bench_cluster.py", *sys.argv[1:]]),
           "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()), "cpu": _cpu(),
           "cores": len(os.sched_getaffinity(0)), "python": platform.python_version(),
           # the machine's load (1, 5, 15 min) before and after: other jobs on these cores skew every figure
           "loadavg_before": [round(x, 2) for x in load_before],
           "loadavg_after": [round(x, 2) for x in os.getloadavg()],
           "dask": distributed.__version__, "numba": numba.__version__,
           "cluster": "1 scheduler + 2 worker processes x 1 thread, loopback "
                      "(impact_env/eval/local_cluster.py)",
           "overheads": {"cluster_start_s": round(start_s, 2), "connect_s": round(connect_s, 3),
                         "first_call_fresh_workers_s": round(first_load_s, 2),
                         "task_round_trip_ms": round(round_trip_ms, 2)},
           "rollout_cpu_s_by_drops": batch_cpu,
           "sizes": {"task_bytes": task_bytes, "result_bytes_per_drop": round(result_bytes),
                     "result_bytes_per_drop_without_commands": round(result_plain_bytes)},
           "workloads": {}}
    for name, (specs, episodes) in workloads.items():
        med = {m: statistics.median(v) for m, v in walls[name].items()}
        out["workloads"][name] = {
            "policies": specs, "episodes": episodes, "rounds": args.rounds,
            "wall_s": {m: [round(x, 3) for x in v] for m, v in walls[name].items()},
            "median_s": {m: round(v, 3) for m, v in med.items()},
            "cpu_s": {m: [round(x, 3) for x in v] for m, v in cpus[name].items()},
            "median_cpu_s": {m: round(statistics.median(v), 3) for m, v in cpus[name].items()},
            "cluster_speedup_over_pool": round(med["pool"] / med["cluster"], 3),
            "pool_speedup_over_serial": round(med["serial"] / med["pool"], 3),
            "cluster_speedup_over_serial": round(med["serial"] / med["cluster"], 3)}
    text = json.dumps(out, indent=1)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    if args.doc:
        doc = Path(args.doc)
        page = doc.read_text()
        i, j = page.index("<!-- bench:start -->"), page.index("<!-- bench:end -->")
        doc.write_text(page[:i] + "<!-- bench:start -->\n" + render(out) + page[j:])
    return 0


def render(out: dict) -> str:
    """docs/cluster.md's table of one run."""
    o, sz = out["overheads"], out["sizes"]
    rounds = next(iter(out["workloads"].values()))["rounds"]
    lines = [f"Written by `{out['command']}` ({out['date_utc']} UTC, {out['cpu']}, {out['cores']} cores, "
             f"Dask {out['dask']}, numba {out['numba']}; load average {out['loadavg_before'][0]:g} before "
             f"and {out['loadavg_after'][0]:g} after, from other jobs on the same cores; the figures are in "
             f"`{out.get('json') or 'the JSON the script writes'}`).  Wall time of the whole `compare` "
             f"call, median of {rounds} alternating rounds, and beside it the CPU time of the processes "
             "(this one, the pool's workers once ended, the cluster's two workers and its scheduler, which "
             "also tick over while idle), which other jobs on the cores inflate less than the wall time; the "
             "cluster is 1 scheduler and 2 worker processes of 1 thread on loopback, already started and "
             "connected.",
             "", "| workload | one process (`--workers 1`) | local pool (`--workers 2`) | "
             "cluster (`--cluster`) | cluster / pool speed-up | pool / one process |",
             "|---|---|---|---|---|---|"]
    for name, w in out["workloads"].items():
        m, c = w["median_s"], w["median_cpu_s"]
        what = f"`{','.join(w['policies'])}`, {w['episodes']} drops"
        lines.append(f"| {name}: {what} | {m['serial']:.2f} s (CPU {c['serial']:.2f} s) | {m['pool']:.2f} s "
                     f"(CPU {c['pool']:.2f} s) | {m['cluster']:.2f} s (CPU {c['cluster']:.2f} s) | "
                     f"{w['cluster_speedup_over_pool']:.2f} | {w['pool_speedup_over_serial']:.2f} |")
    lines += ["", f"Overheads: starting the cluster {o['cluster_start_s']:.1f} s; connecting "
              f"{1e3 * o['connect_s']:.0f} ms; the first `compare` on fresh workers (imports and loading "
              f"the cached kernels in each worker process) {o['first_call_fresh_workers_s']:.1f} s; a "
              f"trivial task's round trip {o['task_round_trip_ms']:.1f} ms of a worker's time.  Sizes: a "
              f"task (the rig scene and 50 drops) {sz['task_bytes'] / 1e3:.1f} kB pickled; a result "
              f"{sz['result_bytes_per_drop_without_commands'] / 1e3:.1f} kB per drop and policy, "
              f"{sz['result_bytes_per_drop'] / 1e3:.1f} kB with the commands kept for the oracle's warm "
              "starts.", "", "A task's fixed cost: one batched rollout of `pd-penetration` over the full "
              "horizon takes " + ", ".join(f"{v:.2f} s of CPU for {k} drop{'s' if int(k) > 1 else ''}"
                                           for k, v in out["rollout_cpu_s_by_drops"].items())
              + " (best of 2): the per-step overhead is paid once per batch.", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
