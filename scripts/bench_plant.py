"""Benchmark the plant kernels: substeps per second and wall time at equal accuracy.

1. Throughput: each fixed-step method (with and without event location) over a long passive
   run (the ideal drop from 5 cm, bouncing on a free body 2), timed
   two ways: calling the kernel ``impact_env.plant.integrators.advance`` directly on one
   span, and through ``impact_env.simulate`` on a prebuilt Scene (its ``wall_time_s``: the
   compiled loop only, and the whole call).  The run is recorded 10 times, so recording
   costs nothing.  dopri5 is reported per simulated second.
2. Equal accuracy: for one elastic collision (gravity 0, the ideal rig: m1 = 0.1 kg,
   m2 = 1 kg, c = 2e6 N/m^1.5, 1 m/s) the cheapest setting of rk4+events (dt), dopri5 (rtol)
   and scipy's ``solve_ivp`` DOP853 with event restarts (rtol; ``impact_env/plant/reference.py``) that
   delivers |e - 1| <= target (default 1e-8), and the wall-time ratios, all in this process.

Timings are the minimum over repeats after a warm-up call (numba compiles on first use).
The issue's goal is RK4 >= 40 M substeps/s on one core; this script reports what it measures.

    .venv/bin/python scripts/bench_plant.py            # about 5 s
    .venv/bin/python scripts/bench_plant.py --quick    # a few seconds
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

import impact_env  # noqa: E402
from impact_env.hardware.arrays import METHOD_CODES, initial_state, plant_params  # noqa: E402
from impact_env.plant.hertz import contact_time  # noqa: E402
from impact_env.plant.integrators import PlantCarry, PlantConsts, advance  # noqa: E402
from impact_env.plant.layout import AUTO, FREE, N_EVENT_COLS, OK, V1, V2, X1, X2  # noqa: E402
from impact_env.plant.reference import Params, free_fall_start, reference_drop, sim_overrides  # noqa: E402

FIXED = [("euler", True), ("euler", False), ("symplectic-euler", True), ("symplectic-euler", False),
         ("rk4", True), ("rk4", False)]


def best_of(fn, repeats: int) -> tuple[float, object]:
    """Minimum wall time (s) of ``repeats`` calls of fn (after one warm-up call) and the last result."""
    out = fn()
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def throughput(t_sim: float, dt: float, repeats: int) -> list[dict]:
    """Substeps/s of each fixed-step method on a passive bouncing drop of t_sim seconds."""
    scene = impact_env.load_scene("ideal", sim_overrides("rk4", dt=dt))
    p = plant_params(scene)
    y0, _ = initial_state(scene)
    n_steps = 10 * round(t_sim / dt / 10)
    rows = []
    for method, events in FIXED:
        code = METHOD_CODES[method]

        ev = np.zeros((10_000, N_EVENT_COLS))
        evn = np.zeros(1, dtype=np.int64)
        scale, hstate, peak = np.ones(6), np.zeros(1), np.zeros(1)

        def direct(code=code, events=events, ev=ev, evn=evn, scale=scale, hstate=hstate, peak=peak):
            y = y0.copy()
            evn[0] = 0
            mode = FREE if events else AUTO
            status, _ = advance(mode, 0.0, 0.0, n_steps * dt, PlantConsts(p, scale, code, dt, 1e-9),
                                PlantCarry(y, hstate, ev, evn, peak))
            assert status == OK, status
            return int(evn[0])

        t_direct, n_ev = best_of(direct, repeats)
        scene_m = impact_env.load_scene("ideal", sim_overrides(method, dt=dt, events=events))
        kernel = math.inf

        def via_simulate(scene_m=scene_m):
            nonlocal kernel
            tr = impact_env.simulate(scene_m, t_end=n_steps * dt, record_rate=10.0 / t_sim)
            kernel = min(kernel, tr.wall_time_s)
            return tr

        t_call, _tr = best_of(via_simulate, repeats)
        rows.append(dict(method=method + ("+events" if events else " (no events)"), steps=n_steps,
                         events=n_ev, direct=n_steps / t_direct, kernel=n_steps / kernel,
                         call=n_steps / t_call))
    # dopri5: no fixed substeps; wall per simulated second
    scene_d = impact_env.load_scene("ideal", sim_overrides("dopri5", rtol=1e-9, control_rate=10.0 / t_sim))
    t_call, tr = best_of(lambda: impact_env.simulate(scene_d, t_end=t_sim), repeats)
    rows.append(dict(method="dopri5 rtol 1e-9", steps=None, events=len(tr.events), direct=None,
                     kernel=t_sim / tr.wall_time_s, call=t_sim / t_call))
    return rows


def collision_error(method: str, knob: float) -> tuple[float, float, float, float]:
    """One elastic ideal collision (gravity 0, 1 m/s): |e - 1|, the relative contact-time
    error, the compiled loop's time and the whole call's time (s).

    The kernels get a prebuilt Scene (building one from overrides costs milliseconds of
    Python, reported separately) and record once, at the end, so that records do not cut
    dopri5's steps; solve_ivp restarts at each contact event (``impact_env/plant/reference.py``)."""
    m = 0.1 / 1.1
    tc = contact_time(m, 2e6, 1.0)
    n = math.ceil((1e-4 + 1.2 * tc) / 1e-5)
    if method == "solve_ivp":
        p = Params(g=0.0)
        y0 = free_fall_start(1.0, 0.0, 1e-4)
        t0 = time.perf_counter()
        ref = reference_drop(p, y0, n * 1e-5, rtol=knob, peak_samples=0)
        wall = time.perf_counter() - t0
        return abs(ref.restitution() - 1.0), abs(ref.first_contact_duration() / tc - 1), wall, wall
    scene = _collision_scene(method, knob)
    t0 = time.perf_counter()
    tr = impact_env.simulate(scene, t_end=n * 1e-5, record_rate=1.0 / (n * 1e-5))
    wall = time.perf_counter() - t0
    return (abs(tr.restitution() - 1.0), abs(tr.first_contact_duration() / tc - 1), tr.wall_time_s,
            wall)


def _collision_scene(method, knob):
    dt = knob if method == "rk4" else 1e-6
    return impact_env.load_scene("ideal", sim_overrides(
        method, dt=dt, rtol=knob, control_rate=1e5, plant_gravity=0.0, initial_impact_speed=1.0,
        initial_pre_contact_time=1e-4))


def equal_accuracy(target: float, repeats: int) -> list[dict]:
    sweeps = {
        "rk4": [1e-5, 5e-6, 2e-6, 1e-6, 5e-7, 2e-7, 1e-7, 5e-8, 2e-8, 1e-8],
        "dopri5": [10.0**-k for k in range(3, 15)],
        "solve_ivp": [10.0**-k for k in range(3, 14)],
    }
    rows = []
    for method, knobs in sweeps.items():
        collision_error(method, knobs[0])  # warm-up (compile)
        chosen = None
        for knob in knobs:  # coarse to fine: the first that meets the target is the cheapest
            err, tc_err, _, _ = collision_error(method, knob)
            if err <= target:
                chosen = knob
                break
        if chosen is None:
            rows.append(dict(method=method, knob=None, err=err, tc_err=tc_err, kernel=math.nan,
                             call=math.nan))
            continue
        best_k = best_c = math.inf
        for _ in range(repeats):
            err, tc_err, k, c = collision_error(method, chosen)
            best_k, best_c = min(best_k, k), min(best_c, c)
        rows.append(dict(method=method, knob=chosen, err=err, tc_err=tc_err, kernel=best_k, call=best_c))
    return rows


def minimal_rk4_rate(n: int, repeats: int) -> float:
    """Substeps/s of the leanest RK4 loop over the same right-hand side (``plant.dynamics.deriv``,
    4 states, no ledger, no event or divergence checks): the bound the stage chain's latency
    sets for one trajectory, against which advance()'s figure is read."""
    from impact_env._jit import jit
    from impact_env.plant.dynamics import coefs, deriv

    @jit(cache=False)
    def loop(y, n, h, p):
        pc = coefs(p)
        x1, v1, x2, v2 = y[X1], y[V1], y[X2], y[V2]
        hh, h6 = 0.5 * h, h / 6.0
        for _ in range(n):
            a = deriv(x1, v1, x2, v2, AUTO, 0.0, pc)
            q = deriv(x1 + hh * a[X1], v1 + hh * a[V1], x2 + hh * a[X2], v2 + hh * a[V2], AUTO, 0.0, pc)
            r = deriv(x1 + hh * q[X1], v1 + hh * q[V1], x2 + hh * q[X2], v2 + hh * q[V2], AUTO, 0.0, pc)
            s = deriv(x1 + h * r[X1], v1 + h * r[V1], x2 + h * r[X2], v2 + h * r[V2], AUTO, 0.0, pc)
            x1 += h6 * (a[X1] + 2.0 * (q[X1] + r[X1]) + s[X1])
            v1 += h6 * (a[V1] + 2.0 * (q[V1] + r[V1]) + s[V1])
            x2 += h6 * (a[X2] + 2.0 * (q[X2] + r[X2]) + s[X2])
            v2 += h6 * (a[V2] + 2.0 * (q[V2] + r[V2]) + s[V2])
        y[X1], y[V1], y[X2], y[V2] = x1, v1, x2, v2

    scene = impact_env.load_scene("ideal")
    p = plant_params(scene)
    y0, _ = initial_state(scene)
    best, _ = best_of(lambda: loop(y0.copy(), n, 1e-6, p), repeats)
    return n / best


def scene_build_time(repeats: int) -> float:
    """Wall time (s) of building a Scene from a preset and seven dotted overrides."""
    return best_of(lambda: _collision_scene("rk4", 1e-6), repeats)[0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short runs, fewer repeats")
    ap.add_argument("--target", type=float, default=1e-8, help="|e - 1| to reach (default 1e-8)")
    ap.add_argument("--seconds", type=float, default=None, help="simulated seconds per throughput run")
    args = ap.parse_args(argv)
    t_sim = args.seconds or (0.05 if args.quick else 1.0)
    repeats = 2 if args.quick else 5
    print(f"impact_env {impact_env.__version__}, python {platform.python_version()}, "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} cpus "
          f"(numba threads unused: kernels are serial)")

    print(f"\n1. Throughput: passive bouncing drop (ideal preset, 5 cm), {t_sim:g} s simulated "
          f"at dt = 1 us, 10 records; best of {repeats}")
    print(f"{'method':28s} {'substeps':>9s} {'events':>6s} {'advance()':>11s} {'sim kernel':>11s} "
          f"{'sim call':>11s}   (M substeps/s)")
    rows = throughput(t_sim, 1e-6, repeats)
    for r in rows:
        if r["steps"] is None:
            print(f"{r['method']:28s} {'-':>9s} {r['events']:>6d} {'-':>11s} {r['kernel']:>10.1f}x "
                  f"{r['call']:>10.1f}x   (simulated s per wall s)")
        else:
            print(f"{r['method']:28s} {r['steps']:>9d} {r['events']:>6d} {r['direct'] / 1e6:>11.1f} "
                  f"{r['kernel'] / 1e6:>11.1f} {r['call'] / 1e6:>11.1f}")
    rk4 = next(r for r in rows if r["method"] == "rk4 (no events)")
    rk4e = next(r for r in rows if r["method"] == "rk4+events")
    print(f"RK4 goal >= 40 M substeps/s: measured {rk4['direct'] / 1e6:.1f} M (no events), "
          f"{rk4e['direct'] / 1e6:.1f} M (events) via advance() -> "
          f"{'met' if rk4['direct'] >= 40e6 else 'NOT met'}")
    bound = minimal_rk4_rate(round(t_sim / 1e-6), repeats)
    print(f"latency bound: the leanest 4-state RK4 loop on the same deriv (no ledger, events or "
          f"checks) runs {bound / 1e6:.1f} M substeps/s on this machine")

    print(f"\n2. Equal accuracy: one elastic collision (gravity 0, 1 m/s), cheapest setting with "
          f"|e - 1| <= {args.target:g}; one record; best of {repeats}")
    print(f"{'method':12s} {'setting':>14s} {'|e-1|':>9s} {'|tc err|':>9s} {'kernel s':>10s} "
          f"{'call s':>10s} {'call / solve_ivp':>17s}")
    acc = equal_accuracy(args.target, repeats)
    ref = next(r for r in acc if r["method"] == "solve_ivp")
    for r in acc:
        knob = "-" if r["knob"] is None else (f"dt {r['knob']:.0e}" if r["method"] == "rk4"
                                               else f"rtol {r['knob']:.0e}")
        print(f"{r['method']:12s} {knob:>14s} {r['err']:>9.1e} {r['tc_err']:>9.1e} {r['kernel']:>10.2e} "
              f"{r['call']:>10.2e} {r['call'] / ref['call']:>17.4f}")
    for name in ("dopri5", "rk4"):
        r = next(x for x in acc if x["method"] == name)
        print(f"{name} / solve_ivp wall-time ratio at equal accuracy: {r['call'] / ref['call']:.4f} "
              f"(simulate() call on a prebuilt scene; compiled loop alone {r['kernel'] / ref['call']:.4f})")
    build_ms = scene_build_time(repeats) * 1e3
    print(f"(building the Scene from the preset and 7 overrides adds {build_ms:.1f} ms "
          "per call when simulate() is given overrides)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
