"""What the effects cost: per control step, relative to the bare plant, and compile times.

    .venv/bin/python scripts/bench_effects.py            # about a minute (3 cold compiles)
    .venv/bin/python scripts/bench_effects.py --quick    # fewer repeats, one cold compile

1. Kernel cost per control step.  For each scene a compiled loop calls the two stages of the
   signal path, the hardware (``impact_env.hardware.stage.hardware_tick``) and the controller's
   front end (``impact_env.control.front_end.condition``), for one env with action 0 once per
   control period; the *bare plant* is the same loop calling only the plant's integrator
   ``impact_env.plant.integrators.advance`` over the period (what ``simulate`` and
   ``run_periods`` do).  Both run the same drop over the same span (ideal: 10 ms at 1 us
   control; rig plant: 100 ms at 10 kHz, 100 RK4 substeps per period, with the first impact),
   from the same start each repeat; the figure is the minimum over repeats after a warm-up, and
   the ratios are to the bare plant of the same plant measured in this run.  Goals (issue
   "Effects and scenes"): ``ideal`` (every effect off) within 5 % of the bare plant, full ``rig``
   at most 2x.  Each effect alone is the rig's plant with only that effect on (the detector
   needs the sensors, so it is measured as sensors + detector, and its own share is the
   difference).
2. Whole ``Simulator.step`` per control step (Python layer: noise draw, argument passing to the
   kernel) for 1 and 64 envs, for scale: an RL step pays this, not just the kernel.
3. Compile time per scene: a fresh Python process builds ``Simulator(scene, 1)``, resets and
   steps once, with an empty ``NUMBA_CACHE_DIR`` (cold: numba compiles the kernel and every
   callee) and again with the cache that run left (warm: loaded from disk).  Every scene uses
   the same single compiled specialisation of the kernel (checked: its ``signatures`` has one
   entry after all scenes ran here), so a second scene in a process compiles nothing.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from impact_env.control.front_end import condition  # noqa: E402
from impact_env.hardware.stage import hardware_tick  # noqa: E402
from impact_env.plant.integrators import PlantCarry, PlantConsts, advance  # noqa: E402
from impact_env.scene import load_scene  # noqa: E402
from impact_env.sim.simulator import Simulator  # noqa: E402
from impact_env.sim.step import sim_step  # noqa: E402

RIG_EFFECTS = ("shaker", "saturation", "sensors", "filters", "detector")


@numba.njit(cache=False)
def bare_loop(n, y, mode, f2, period, p, method, dt, rtol, scale, hstate, ev, evn):
    peak = np.zeros(1)
    for _ in range(n):
        peak[0] = 0.0
        status, mode = advance(mode, f2, 0.0, period, PlantConsts(p, scale, method, dt, rtol),
                               PlantCarry(y, hstate, ev, evn, peak))
    return mode


@numba.njit(cache=False)
def pipeline_loop(n, hw_p, hw_s, fe_p, fe_s):
    cursor = hw_s.noise.cursor
    for _ in range(n):
        cursor[0] = 0  # the same noise sample every step (drawing noise is the Python layer's job)
        hardware_tick(0, 0.0, hw_p, hw_s)
        condition(0, hw_s.out.raw, fe_p, fe_s)


STATE = ("Y", "modes", "EV", "EVN", "ST", "H", "raw", "info", "t")


def _pipeline_runner(sim: Simulator, n: int):
    hw = sim.hw
    start = {k: getattr(hw, k).copy() for k in STATE}
    fe_start = [a.copy() for a in sim.fe.state]
    z = np.random.default_rng(0).standard_normal((1, 1, 4))
    noise = type(hw.state.noise)(z, np.zeros(1, dtype=np.int64))
    hw_s = hw.state._replace(noise=noise)

    def run():
        for k, v in start.items():
            getattr(hw, k)[...] = v
        for a, v in zip(sim.fe.state, fe_start, strict=True):
            a[...] = v
        pipeline_loop(n, hw.params, hw_s, sim.fe.params, sim.fe.state)
        return hw.plant_state[0].copy()
    return run


def _bare_runner(sim: Simulator, n: int):
    y0, mode0 = sim.plant_state[0].copy(), int(sim.hw.modes[0])
    y = np.empty_like(y0)
    ev = np.zeros_like(sim.hw.events[0])
    evn = np.zeros(1, dtype=np.int64)
    hstate = np.zeros(1)

    def run():
        y[:] = y0
        evn[0] = 0
        hstate[0] = 0.0
        bare_loop(n, y, mode0, 0.0, sim.period, sim.plant_parameters[0], sim.hw.method,
                  sim.scene.integrator.dt,
                  sim.scene.integrator.rtol, sim.hw.scale[0], hstate, ev, evn)
        return y.copy()
    return run


def best_of(fn, repeats: int) -> float:
    fn()
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def interleaved_best(fns: list, repeats: int) -> list[float]:
    """Minimum wall time of each function, timing them in turn (one round = each once), so that
    a load that comes and goes on a shared machine hits every case alike."""
    for fn in fns:
        fn()
    best = [math.inf] * len(fns)
    for _ in range(repeats):
        for j, fn in enumerate(fns):
            t0 = time.perf_counter()
            fn()
            best[j] = min(best[j], time.perf_counter() - t0)
    return best


def kernel_costs(repeats: int) -> list[tuple[str, float, float, str]]:
    """Rows (label, ns per control step, ratio to the bare plant, note)."""
    rig_plant = {"effects.active": []}
    cases = [
        ("ideal: bare plant", "ideal", None, 0.01),
        ("ideal: pipeline, every effect off", "ideal", {}, 0.01),
        ("rig plant: bare plant", "rig", None, 0.1),
        ("rig plant: pipeline, every effect off", "rig", rig_plant, 0.1),
        ("  actuator_delay alone (1 period)", "rig", {"effects.active": ["actuator_delay"],
                                                      "effects.delay.actuator_s": 1e-4}, 0.1),
        ("  shaker alone", "rig", {"effects.active": ["shaker"]}, 0.1),
        ("  shaker with back-EMF", "rig", {"effects.active": ["shaker"],
                                           "effects.shaker.back_emf": True}, 0.1),
        ("  saturation alone", "rig", {"effects.active": ["saturation"]}, 0.1),
        ("  sensors alone", "rig", {"effects.active": ["sensors"]}, 0.1),
        ("  filters alone", "rig", {"effects.active": ["filters"]}, 0.1),
        ("  sensor_delay alone (2 periods)", "rig", {"effects.active": ["sensor_delay"],
                                                     "effects.delay.sensor_s": 2e-4}, 0.1),
        ("  sensors + detector", "rig", {"effects.active": ["sensors", "detector"]}, 0.1),
        ("rig (full scene)", "rig", {}, 0.1),
        ("rig-randomized (one draw)", "rig-randomized", {}, 0.1),
    ]
    runners, steps, notes = [], [], []
    for _label, name, ov, span in cases:
        scene = load_scene(name, {"effects.active": []} if ov is None else ov)
        sim = Simulator(scene, 1)
        sim.reset([np.random.default_rng(0)])
        n = int(round(span / sim.period))
        runners.append(_bare_runner(sim, n) if ov is None else _pipeline_runner(sim, n))
        steps.append(n)
        notes.append(f"{n} periods of {sim.period * 1e6:g} us" if ov is None else "")
    best = interleaved_best(runners, repeats)
    rows = []
    bare = {}
    for (label, name, ov, _span), t, n, note in zip(cases, best, steps, notes, strict=True):
        if ov is None:
            bare[name] = t
        ref = bare["rig" if name.startswith("rig") else name]
        rows.append((label, 1e9 * t / n, t / ref, note))
    return rows


def simulator_step_costs(repeats: int) -> list[tuple[str, float]]:
    rows = []
    for name in ("ideal", "rig"):
        for n_env in (1, 64):
            sim = Simulator(name, n_env)
            sim.reset([np.random.default_rng(i) for i in range(n_env)])
            a = np.zeros(n_env)
            steps = 2000 if name == "rig" else 20000
            steps = max(steps // n_env, 50)

            def run(sim=sim, a=a, steps=steps):
                for _ in range(steps):
                    sim.step(a)
            t = best_of(run, repeats)
            rows.append((f"Simulator('{name}', {n_env}).step", 1e6 * t / steps, 1e6 * t / steps / n_env))
    return rows


CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
import numpy as np
from impact_env.sim.simulator import Simulator
from impact_env.sim.step import sim_step
t1 = time.perf_counter()
sim = Simulator(sys.argv[1], 1)
sim.reset([np.random.default_rng(0)])
sim.step(np.zeros(1))
t2 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "first_step_s": t2 - t1,
                  "signatures": len(sim_step.signatures)}))
"""


def compile_time(scene: str, cache_dir: str) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir, IMPACT_ENV_NUMBA_CACHE="1")
    out = subprocess.run([sys.executable, "-c", CHILD, scene], env=env, cwd=str(ROOT), capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="3 repeats, cold compile of 'rig' only")
    ap.add_argument("--repeats", type=int, default=None,
                    help="timed repeats after warm-up (default 15, quick 5)")
    ap.add_argument("--no-compile", action="store_true", help="skip the compile-time subprocesses")
    args = ap.parse_args(argv)
    repeats = args.repeats or (5 if args.quick else 15)
    print(f"bench_effects: {platform.processor() or platform.machine()}, numba {numba.__version__}, "
          f"numpy {np.__version__}, min of {repeats} repeats after warm-up")

    t0 = time.perf_counter()
    rows = kernel_costs(repeats)
    print("\n1. kernel cost per control step (compiled loop, 1 env, action 0)")
    print(f"  {'case':40s} {'ns/step':>10s} {'x bare':>8s}")
    for label, ns, ratio, note in rows:
        print(f"  {label:40s} {ns:10.1f} {ratio:8.3f}  {note}")
    r = {label.strip(): ratio for label, _ns, ratio, _ in rows}
    ns = {label.strip(): v for label, v, _r, _ in rows}
    ideal, full = r["ideal: pipeline, every effect off"], r["rig (full scene)"]
    print(f"  goals: ideal {ideal:.3f}x (<= 1.05: {'met' if ideal <= 1.05 else 'MISSED'}), "
          f"full rig {full:.3f}x (<= 2: {'met' if full <= 2.0 else 'MISSED'})")
    extra = ns["ideal: pipeline, every effect off"] - ns["ideal: bare plant"]
    extra_rig = ns["rig plant: pipeline, every effect off"] - ns["rig plant: bare plant"]
    print(f"  fixed cost of a pipeline call with every effect off: {extra:.0f} ns (ideal), "
          f"{extra_rig:.0f} ns (rig plant) per control step")
    print(f"  kernel specialisations after every scene above: {len(sim_step.signatures)}")

    print("\n2. whole Simulator.step (Python layer + kernel)")
    print(f"  {'case':40s} {'us/step':>10s} {'us/env-step':>12s}")
    for label, us, per_env in simulator_step_costs(max(2, repeats // 3)):
        print(f"  {label:40s} {us:10.2f} {per_env:12.3f}")

    if not args.no_compile:
        print("\n3. compile time per scene (fresh process: Simulator(scene, 1), reset, one step)")
        print(f"  {'scene':16s} {'cold s':>8s} {'warm s':>8s} {'import s':>9s}  specialisations")
        scenes = ["rig"] if args.quick else ["ideal", "rig", "rig-randomized"]
        for name in scenes:
            with tempfile.TemporaryDirectory(prefix="numba-cache-") as cache:
                cold = compile_time(name, cache)
                warm = compile_time(name, cache)
            print(f"  {name:16s} {cold['first_step_s']:8.2f} {warm['first_step_s']:8.2f} "
                  f"{warm['import_s']:9.2f}  {cold['signatures']}")
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
