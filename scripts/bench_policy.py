"""What a compiled policy costs per call, and what it buys in ``impact-env compare``.

    python scripts/bench_policy.py [--quick]

1. One ``act`` call (``impact_env.control.policy.act``) for the committed agent (PPO, a 64 x 64
   tanh MLP) and each classic law: p50 / p99 / p99.9 / max over many calls on observations of
   real rig episodes, timed inside compiled code with the CPU's cycle counter (LLVM's
   ``readcyclecounter``, rdtsc on x86) converted to ns by calibrating it against
   ``time.perf_counter_ns`` in the same run; the counter's own cost (an empty timed region) is
   reported and not subtracted.  Goal (issue "A rig-shaped core"): p99 <= 5 us for a 64 x 64 MLP.
   For scale, the same observations through SB3's ``model.predict`` and through one Python call
   of the compiled kernel (dispatch included).  ``mpc-state`` and ``mpc`` (goal p99 <= 50 us)
   are timed on each drop's ticks in order, from its start, since their memory holds the warm
   start (and mpc's filter).  ``--laws mpc,mpc-state --json PATH`` times only the named policies
   and writes their figures as a JSON record.
2. Parity: max |compiled - reference| on those observations (SB3 ``predict(deterministic=True)``
   for the MLP; the baselines' float64 command for the laws, memory carried along).
3. ``compare``'s rollout of the committed agent on 16 rig drops of 0.4 s: the SB3 model through
   the Python loop against its compiled policy in the compiled loop; the speed-up is the ratio
   of the two wall times in this run (minimum of repeats).
4. The generated C step (``impact-env export --c``, :mod:`impact_env.deploy`): one
   ``impact_step`` (the whole tick: filters, detector, observation, policy, hold, residual,
   safety) for the shipped agent and each deployable classic law, double and float32 builds
   (gcc -O2 -ffp-contract=off), timed in C with ``clock_gettime(CLOCK_MONOTONIC)`` around each
   call on readings recorded from the virtual rig (the timer's own cost printed beside, not
   subtracted); goal p99 <= 2 us for the 64 x 64 MLP.  Then the operation count of one tick
   (multiply-adds, transcendental calls) and, as an estimate only, its cycles on a 600 MHz
   Cortex-M7.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from baselines import make_policy  # noqa: E402
from impact_env.control.policy import act, act_batch  # noqa: E402
from impact_env.eval.rollout import rollout  # noqa: E402
from impact_env.policy.export import export_policy  # noqa: E402
from impact_env.rig.cycles import cycles, ns_per_cycle  # noqa: E402
from impact_env.scene import load_scene  # noqa: E402

MODEL = "ppo:agents/models/ppo_rig/model.zip"
IN_ORDER = ("mpc-state", "mpc")  # laws whose memory carries the warm start (and mpc's filter) tick to tick


@njit(cache=False)
def timed_calls(pi, pf, obs, starts, mem, reps, out):
    """Cycle count of each of ``reps`` passes over the observation rows (one act per row); the
    memory is zeroed (untimed) before each row that ``starts`` an episode, as a rollout does."""
    sink = 0.0
    k = 0
    for _ in range(reps):
        for i in range(obs.shape[0]):
            if starts[i]:
                mem[:] = 0.0
            t0 = cycles()
            sink += act(pi, pf, obs[i], mem)
            t1 = cycles()
            out[k] = t1 - t0
            k += 1
    return sink


@njit(cache=False)
def timed_empty(n, out):
    for k in range(n):
        t0 = cycles()
        t1 = cycles()
        out[k] = t1 - t0


def episode_obs(scene, observation: str, n_rows: int,
                driver: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Observations and episode starts of rig drops driven by ``driver`` (default pd-penetration,
    thesis-ideal for privileged).  ``mpc`` is timed on its own closed loop: its filter replays its
    own demands, so on drops another law drove it would see forces it did not command, report
    its model wrong and hand over to pd-penetration, whose cost is not the one asked for."""
    from gymnasium.vector import AutoresetMode

    from impact_env.env.vector import ImpactCatchVectorEnv

    n_env = 8
    venv = ImpactCatchVectorEnv(n_env, scene, autoreset_mode=AutoresetMode.SAME_STEP, observation=observation,
                                horizon=0.1)
    drv = make_policy(driver or ("pd-penetration" if observation == "sensors" else "thesis-ideal"), scene)
    obs, _ = venv.reset(seed=100)
    starts = np.ones(n_env, dtype=bool)
    out, st = [], []
    while len(out) * n_env < n_rows:
        out.append(obs.copy())
        st.append(starts.copy())
        a, _ = drv.predict(obs, episode_start=starts)
        obs, _r, te, tr, _i = venv.step(a)
        starts = te | tr
    return np.array(out), np.array(st)


def pct(x: np.ndarray) -> tuple[float, ...]:
    return tuple(float(np.percentile(x, q)) for q in (50, 99, 99.9)) + (float(x.max()),)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer calls and repeats")
    ap.add_argument("--laws", default="", help="only these policies of part 1-2 (comma-separated names, e.g. "
                    "mpc-state), and no parts 3-4")
    ap.add_argument("--json", default="", help="also write part 1-2's figures to this JSON record")
    args = ap.parse_args()
    scene = load_scene("rig")
    n_rows = 4000 if args.quick else 20_000
    reps = 5 if args.quick else 25
    nspc = ns_per_cycle()
    empty = np.empty(100_000, dtype=np.uint64)
    timed_empty(empty.size, empty)
    print(f"cycle counter: {nspc:.4f} ns per cycle; an empty timed region costs p50 "
          f"{np.median(empty) * nspc:.1f} ns")
    print()
    print(f"## 1-2. One act call ({n_rows} observations of rig drops x {reps} passes)")
    print()
    print("| policy | p50 ns | p99 ns | p99.9 ns | max ns | Python call of the kernel, p50 us | "
          "reference predict, p50 us | parity: max abs diff |")
    print("|---|---|---|---|---|---|---|---|")
    cases = [(MODEL, "sensors"), ("passive", "sensors"), ("thesis-rig", "sensors"),
             ("pd-penetration", "sensors"), ("thesis-ideal", "privileged"), ("mpc-state", "privileged"),
             ("mpc", "sensors")]
    if args.laws:
        wanted = args.laws.split(",")
        cases = [c for c in cases if c[0] in wanted]
    record: dict = {"command": "python scripts/bench_policy.py " + " ".join(sys.argv[1:]),
                    "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()), "ns_per_cycle": nspc,
                    "laws": {}}
    for spec, observation in cases:
        obs_ep, starts = episode_obs(scene, observation, n_rows, driver="mpc" if spec == "mpc" else None)
        comp = export_policy(spec, scene)
        pi, pf, m = comp.arrays()
        flat = np.ascontiguousarray(obs_ep.reshape(-1, obs_ep.shape[-1]))
        # parity (laws carry memory: replay the episodes in order, as in tests/test_compiled_policy.py)
        ref = make_policy(spec, scene)
        mem_b = np.zeros((obs_ep.shape[1], m))
        worst = 0.0
        state = None
        for k in range(obs_ep.shape[0]):
            mem_b[starts[k]] = 0.0
            got = act_batch(pi, pf, obs_ep[k], mem_b, np.empty(obs_ep.shape[1]))
            if spec == MODEL:
                want = ref.model.predict(obs_ep[k], deterministic=True)[0][:, 0]
            else:
                want, state = ref.command(obs_ep[k], state, starts[k])
            worst = max(worst, float(np.max(np.abs(got - want))))
        flat_starts = np.zeros(flat.shape[0], dtype=np.bool_)
        if spec in IN_ORDER:
            # the memory is the warm start (and mpc's filter): time each drop's ticks in order, from
            # its start, as an episode runs them
            flat = np.ascontiguousarray(obs_ep.transpose(1, 0, 2).reshape(-1, obs_ep.shape[-1]))
            flat_starts = np.ascontiguousarray(starts.T.reshape(-1))
        mem = np.zeros(m)
        cyc = np.empty(flat.shape[0] * reps, dtype=np.uint64)
        timed_calls(pi, pf, flat, flat_starts, mem, 1, cyc[:flat.shape[0]])  # compile and warm up
        timed_calls(pi, pf, flat, flat_starts, mem, reps, cyc)
        p50, p99, p999, mx = pct(cyc.astype(np.float64) * nspc)
        sub = flat[:500]
        single = np.zeros((1, m))
        t0 = time.perf_counter()
        for row in sub:
            act_batch(pi, pf, row[None, :], single, np.empty(1))
        py_call = (time.perf_counter() - t0) / len(sub) * 1e6
        t0 = time.perf_counter()
        for row in sub:
            ref.predict(row, deterministic=True)
        ref_call = (time.perf_counter() - t0) / len(sub) * 1e6
        name = "PPO agent (64x64 tanh MLP)" if spec == MODEL else spec
        print(f"| {name} | {p50:.0f} | {p99:.0f} | {p999:.0f} | {mx:.0f} | {py_call:.2f} | {ref_call:.1f} | "
              f"{worst:.2e} |")
        record["laws"][spec] = {"p50_ns": p50, "p99_ns": p99, "p99.9_ns": p999, "max_ns": mx,
                                "calls": int(cyc.size), "parity_max_abs": worst}
    if args.json:
        import json
        import platform

        from impact_env.eval.benchmark import cpu_name

        record.update(cpu=cpu_name(), python=platform.python_version())
        Path(args.json).write_text(json.dumps(record, indent=1) + "\n")
    if args.laws:
        return 0
    print()
    print("## 3. compare's rollout of the committed agent: SB3 in the Python loop vs compiled "
          "(16 drops x 0.4 s)")
    print()
    seeds = list(range(1000, 1016))
    sb3 = make_policy(MODEL, scene)
    comp = export_policy(MODEL, scene)
    rollout(scene, comp, seeds[:2], horizon=0.01)  # compile
    rollout(scene, sb3, seeds[:2], horizon=0.01)
    times = {"python": [], "compiled": []}
    for _ in range(1 if args.quick else 3):
        for key, pol in (("python", sb3), ("compiled", comp)):
            t0 = time.perf_counter()
            rollout(scene, pol, seeds, trace_rate=0.0)
            times[key].append(time.perf_counter() - t0)
    tp, tc = min(times["python"]), min(times["compiled"])
    print(f"SB3 predict in the Python loop: {tp:.2f} s; compiled policy in the compiled loop: {tc:.2f} s; "
          f"speed-up {tp / tc:.1f}x")
    c_step(scene, args.quick)
    return 0


C_BENCH = r"""
#define _GNU_SOURCE
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "impact_policy.h"
static impact_state st;
static int cmp(const void *a, const void *b) { long x = *(const long *)a, y = *(const long *)b; return (x > y) - (x < y); }
static long now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec * 1000000000L + t.tv_nsec; }
int main(int argc, char **argv) {
    if (argc < 3) return 2;
    FILE *f = fopen(argv[1], "rb"); int reps = atoi(argv[2]);
    fseek(f, 0, SEEK_END); long n = ftell(f) / 32; fseek(f, 0, SEEK_SET);
    double *r = malloc(n * 32); if (fread(r, 8, n * 4, f) != (size_t)(n * 4)) return 1; fclose(f);
    long *dt = malloc(sizeof(long) * n * reps), *e = malloc(sizeof(long) * n); long k = 0; double sink = 0;
    impact_init(&st);
    for (int p = 0; p < reps; p++) {
        impact_reset(&st);
        for (long m = 0; m < n; m++) {
            impact_real x[4] = {(impact_real)r[4 * m], (impact_real)r[4 * m + 1], (impact_real)r[4 * m + 2],
                                (impact_real)r[4 * m + 3]};
            impact_real c, fo;
            long t0 = now(); impact_step(&st, x, &c, &fo); long t1 = now();
            dt[k++] = t1 - t0; sink += c;
        }
    }
    for (long m = 0; m < n; m++) { long t0 = now(); long t1 = now(); e[m] = t1 - t0; }
    qsort(dt, k, sizeof(long), cmp); qsort(e, n, sizeof(long), cmp);
    printf("%ld %ld %ld %ld %ld %g\n", dt[k / 2], dt[(long)(0.99 * (k - 1))], dt[(long)(0.999 * (k - 1))], dt[k - 1],
           e[n / 2], sink);
    return 0;
}
"""


def op_count(pol) -> tuple[int, int]:
    """(multiply-adds, transcendental calls) of one tick at a policy step: the filters (5
    products and 4 sums per section and channel, counted as 5 multiply-adds), the detector, the
    policy (a law: a few dozen; an MLP: its weights), the residual law and the safety layer."""
    from impact_env.control.front_end import FrontEnd

    fe = FrontEnd(load_scene("rig"), pol.layout, 1)
    macs = 5 * fe.sos.shape[0] * fe.sos.shape[1] + 2 + pol.layout.size + 4
    trans = 1  # the safety layer's square root (on a clamped tick)
    for p in [pol] + ([pol.residual_policy()] if pol.residual is not None else []):
        if p.mlp is not None:
            for ly in p.mlp["layers"]:
                w = np.asarray(ly["weight"])
                macs += w.size
                trans += w.shape[0] if ly.get("activation") in ("tanh", "elu") else 0
            trans += 1 if p.mlp["output"] == "squash" else 0
        elif p.law["name"] != "passive":
            macs += 20
            trans += 1  # the penetration's power 2/3
    return macs, trans


def c_step(scene, quick: bool) -> None:
    import subprocess
    import tempfile

    from impact_env.deploy import parity
    from impact_env.deploy.c_export import write_c

    print()
    print("## 4. The generated C step (impact-env export --c): one impact_step, the whole tick")
    print()
    print("| policy | build | p50 ns | p99 ns | p99.9 ns | max ns | the timer alone, p50 ns |")
    print("|---|---|---|---|---|---|---|")
    specs = [("shipped agent (64x64 tanh MLP + pd residual)", "compiled:agents/models/best/best.policy.json"),
             ("passive", "passive"), ("thesis-rig", "thesis-rig"), ("pd-penetration", "pd-penetration")]
    counts = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name, spec in specs:
            pol = export_policy(spec, scene)
            d = tmp / name.split()[0]
            write_c(pol, scene, d)
            (d / "bench.c").write_text(C_BENCH)
            rec = parity.record(pol, scene, 0, 4000)
            rec.readings.astype("<f8").tofile(d / "r.f64")
            sizes = []
            for f32 in (False, True):
                try:
                    arm = parity.build_arm(d, d / f"arm{int(f32)}.o", f32)["text"]
                except Exception as exc:  # no cross-compiler here: say so in the table
                    arm = f"n/a ({str(exc).splitlines()[0][:40]})"
                lib = parity.CPolicy(parity.build_shared(d, d / f"lib{int(f32)}.so", f32), f32)
                sizes.append((arm, int(lib.lib.impact_state_bytes())))
            counts.append((name, *op_count(pol), sizes))
            for f32 in (False, True):
                exe = d / ("bench32" if f32 else "bench64")
                subprocess.run([parity.find_cc(), *parity.CFLAGS, *(["-DIMPACT_FLOAT32"] if f32 else []), f"-I{d}",
                                "-o", str(exe), str(d / "bench.c"), str(d / "impact_policy.c"), "-lm"], check=True)
                out = subprocess.run([str(exe), str(d / "r.f64"), "3" if quick else "25"], capture_output=True,
                                     text=True, check=True).stdout.split()
                p50, p99, p999, mx, timer = (int(x) for x in out[:5])
                print(f"| {name} | {'float32' if f32 else 'double'} | {p50} | {p99} | {p999} | {mx} | {timer} |")
    print()
    print("Operation count of one tick at a policy step, and a Cortex-M7 estimate (600 MHz; ESTIMATE: "
          "about 2 cycles per float32 multiply-add with -ffp-contract=off (VMUL + VADD, single-issue "
          "for the FPU) and 4 per double one, about 100 cycles per float32 transcendental and 200 per "
          "double one in newlib's libm, memory from tightly coupled RAM; not measured on a board):")
    print()
    print("| policy | multiply-adds | transcendental calls | est. float32 us | est. double us | Cortex-M7 "
          "code+constants B (double / float32) | state B (double / float32) |")
    print("|---|---|---|---|---|---|---|")
    for name, macs, trans, sizes in counts:
        f32 = (2 * macs + 100 * trans) / 600.0
        f64 = (4 * macs + 200 * trans) / 600.0
        print(f"| {name} | {macs} | {trans} | {f32:.1f} | {f64:.1f} | {sizes[0][0]} / {sizes[1][0]} | "
              f"{sizes[0][1]} / {sizes[1][1]} |")


if __name__ == "__main__":
    sys.exit(main())
