"""Accuracy per impact of the ``split`` integrator (and RK4 at 1 us, the former default) against
an independent reference: ``scipy.integrate.solve_ivp`` DOP853 at rtol 1e-12 with event restarts
(``tests/naive.py: reference_drop``), at plant parameters no test or tuning used.

Each case is a drop onto a suspended body 2 under a constant shaker force (held over 100 us
control periods, as on the rig), long enough for several bounces.  Per contact event it
compares the event time (s) and, at each separation, the relative exit speed divided by the
impact speed of that contact (the per-impact restitution); per run the largest penetration.
Errors are the worst over all events of all cases.  Cost: the plant's compiled loop alone on the
``rig`` scene's nominal drop (0.4 s, records every 100 us control period, no effects, minimum of
``--repeats`` runs after a compiling one), in us per control period.

    .venv/bin/python scripts/split_accuracy.py            # about 20 s
    .venv/bin/python scripts/split_accuracy.py --json docs/split_accuracy.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from naive import Params, reference_drop, sim_overrides  # noqa: E402

import impact_env  # noqa: E402
from impact_env.hardware.arrays import initial_state  # noqa: E402

# unseen parameters: none of them is a preset's, a test's or a tuning's value
CASES = [
    dict(plant_m1=0.0937, plant_m2=0.87, plant_c=3.3e6, plant_restitution=0.71,
         plant_suspension_stiffness=1.3e4, plant_suspension_damping=27.0,
         initial_drop_height=0.043, force=3.7),
    dict(plant_m1=0.117, plant_m2=1.21, plant_c=1.4e6, plant_restitution=0.86,
         plant_suspension_stiffness=7.1e3, plant_suspension_damping=13.0,
         initial_drop_height=0.061, force=-2.3),
    dict(plant_m1=0.061, plant_m2=0.64, plant_c=8.2e6, plant_restitution=1.0,
         plant_suspension_stiffness=2.2e4, plant_suspension_damping=0.0,
         initial_drop_height=0.022, force=0.0),
]
T_END = 0.25  # s
RATE = 1e4  # Hz: the rig's control rate; the force is held over each period
SETTINGS = [("rk4", dict(dt=1e-6)), ("split", dict(rtol=1e-9)), ("split", dict(rtol=1e-10)),
            ("split", dict(rtol=1e-11)), ("split", dict(rtol=1e-12)), ("split", dict(rtol=1e-13))]


def run(case: dict, method: str, knob: dict):
    kw = {k: v for k, v in case.items() if k != "force"}
    force = case["force"]
    ov = sim_overrides(method, control_rate=RATE, **knob, **kw)
    scene = impact_env.load_scene("ideal", ov)
    return impact_env.simulate(scene, controller=lambda t, y: force, t_end=T_END, record_rate=RATE)


def period_cost_us(method: str, knob: dict, repeats: int) -> float:
    ov = {"integrator.method": method, **{f"integrator.{k}": v for k, v in knob.items()}}
    best = float("inf")
    for _ in range(repeats + 1):
        tr = impact_env.simulate("rig", t_end=0.4, record_rate=RATE, overrides=ov, plant_only=True)
        best = min(best, tr.wall_time_s)
    return best / round(0.4 * RATE) * 1e6


def impact_errors(tr, ref) -> dict:
    ev, rv = tr.events, ref.events
    if ev[:, 1].tolist() != rv[:, 1].tolist():
        raise SystemExit(f"event sequences differ: {ev[:, 1].tolist()} vs {rv[:, 1].tolist()}")
    dt = float(np.abs(ev[:, 0] - rv[:, 0]).max())
    worst_e = 0.0
    for k in range(1, len(rv)):
        if rv[k, 1] < 0 and rv[k - 1, 1] > 0:  # a separation after its onset
            v_in = rv[k - 1, 3] - rv[k - 1, 5]
            e_ref = -(rv[k, 3] - rv[k, 5]) / v_in
            e_got = -(ev[k, 3] - ev[k, 5]) / (ev[k - 1, 3] - ev[k - 1, 5])
            worst_e = max(worst_e, abs(e_got - e_ref))
    return {"event_time_s": dt, "restitution": worst_e,
            "max_penetration_rel": abs(tr.metrics()["max_penetration_m"] / ref.max_penetration - 1.0),
            "n_events": len(rv)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", type=Path, help="write the table's numbers here")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    refs = []
    for case in CASES:
        kw = {k: v for k, v in case.items() if k != "force"}
        scene = impact_env.load_scene("ideal", sim_overrides("rk4", control_rate=RATE, **kw))
        y0, _ = initial_state(scene)
        refs.append(reference_drop(Params.from_array(impact_env.hardware.arrays.plant_params(scene)),
                                   y0, T_END, f2=case["force"], peak_samples=400))
    rows = []
    for method, knob in SETTINGS:
        worst = {"event_time_s": 0.0, "restitution": 0.0, "max_penetration_rel": 0.0, "n_events": 0}
        for case, ref in zip(CASES, refs):
            tr = run(case, method, knob)
            e = impact_errors(tr, ref)
            for k in ("event_time_s", "restitution", "max_penetration_rel"):
                worst[k] = max(worst[k], e[k])
            worst["n_events"] += e["n_events"]
        label = f"{method} " + ", ".join(f"{k} {v:g}" for k, v in knob.items())
        rows.append({"setting": label, **worst, "us_per_period": period_cost_us(method, knob, args.repeats)})
    print(f"{len(CASES)} drops, {T_END:g} s each, {rows[0]['n_events']} contact events; reference: "
          "solve_ivp DOP853 rtol 1e-12 with event restarts")
    print("| setting | event time error (s) | restitution error per impact | max penetration (rel) | "
          "plant cost on rig (us per 100 us period) |")
    print("| --- | --- | --- | --- | --- |")
    for r in rows:
        print(f"| {r['setting']} | {r['event_time_s']:.2g} | {r['restitution']:.2g} | "
              f"{r['max_penetration_rel']:.2g} | {r['us_per_period']:.3g} |")
    if args.json:
        args.json.write_text(json.dumps({"cases": CASES, "t_end_s": T_END, "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
