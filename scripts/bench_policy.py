"""What a compiled policy costs per call, and what it buys in ``impact-env compare``.

    python scripts/bench_policy.py [--quick]

1. One ``act`` call (``impact_env.control.policy.act``) for the committed agent (PPO, a 64 x 64
   tanh MLP) and each classic law: p50 / p99 / p99.9 / max over many calls on observations of
   real rig episodes, timed inside compiled code with the CPU's cycle counter (LLVM's
   ``readcyclecounter``, rdtsc on x86) converted to ns by calibrating it against
   ``time.perf_counter_ns`` in the same run; the counter's own cost (an empty timed region) is
   reported and not subtracted.  Goal (issue "A rig-shaped core"): p99 <= 5 us for a 64 x 64 MLP.
   For scale, the same observations through SB3's ``model.predict`` and through one Python call
   of the compiled kernel (dispatch included).
2. Parity: max |compiled - reference| on those observations (SB3 ``predict(deterministic=True)``
   for the MLP; the baselines' float64 command for the laws, memory carried along).
3. ``compare``'s rollout of the committed agent on 16 rig drops of 0.4 s: the SB3 model through
   the Python loop against its compiled policy in the compiled loop; the speed-up is the ratio
   of the two wall times in this run (minimum of repeats).
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


@njit(cache=False)
def timed_calls(pi, pf, obs, mem, reps, out):
    """Cycle count of each of ``reps`` passes over the observation rows (one act per row)."""
    sink = 0.0
    k = 0
    for _ in range(reps):
        for i in range(obs.shape[0]):
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


def episode_obs(scene, observation: str, n_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Observations and episode starts of pd-penetration rig drops (thesis-ideal for privileged)."""
    from gymnasium.vector import AutoresetMode

    from impact_env.env.vector import ImpactCatchVectorEnv

    n_env = 8
    venv = ImpactCatchVectorEnv(n_env, scene, autoreset_mode=AutoresetMode.SAME_STEP, observation=observation,
                                horizon=0.1)
    drv = make_policy("pd-penetration" if observation == "sensors" else "thesis-ideal", scene)
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
             ("pd-penetration", "sensors"), ("thesis-ideal", "privileged")]
    for spec, observation in cases:
        obs_ep, starts = episode_obs(scene, observation, n_rows)
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
        mem = np.zeros(m)
        cyc = np.empty(flat.shape[0] * reps, dtype=np.uint64)
        timed_calls(pi, pf, flat, mem, 1, cyc[:flat.shape[0]])  # compile and warm up
        timed_calls(pi, pf, flat, mem, reps, cyc)
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
