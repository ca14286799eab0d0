"""Restitution error of the fixed-step methods against the number of steps per contact.

One free collision (gravity 0, m1 = 0.1 kg, m2 = 1 kg, c = 2e6 N/m^1.5, 1 m/s) on a pad
calibrated to restitution e (1, 0.8, 0.3), taken with a fixed step dt = t_c / N, t_c the contact
time the stability module estimates (:func:`impact_env.hardware.stability.contact_scales`, the
scaled Tsuji collision).  The touch falls at several phases within a step (it matters at small
N); the table gives the worst |e_measured - e| over them.  The reference is e itself: the pad's
damping is solved to deliver it to about 1e-13 (``plant/restitution.py``).

This is the measurement behind ``integrator.min_steps_per_contact`` (default 8: RK4 within
about 1e-3) and behind the README's convergence figures for the damped pad (order 1.25 in dt
without the graded zone after the touch, see ``impact_env/plant/integrators.py``).

    python scripts/steps_per_contact.py                 # RK4, N = 4 .. 10000 (about a minute)
    python scripts/steps_per_contact.py --quick         # N = 4 .. 30
    python scripts/steps_per_contact.py --method euler
"""

from __future__ import annotations

import argparse
import dataclasses
import math

import numpy as np

import impact_env
from impact_env.hardware.stability import Drop, contact_scales
from impact_env.scene.scene import IntegratorConfig

STEPS = [4, 5, 6, 8, 10, 15, 20, 30, 100, 300, 1000, 3000, 10000]
STEPS_QUICK = [4, 5, 6, 8, 10, 15, 20, 30]
RESTITUTIONS = (1.0, 0.8, 0.3)
PHASES = np.linspace(0.05, 0.95, 7)  # where in a step the touch falls


def restitution_error(method: str, steps: float, e: float, phase: float, m1=0.1, m2=1.0, c=2e6,
                      v=1.0) -> float:
    """|e_measured - e| of one collision taken in ``steps`` steps of ``method`` per contact,
    the touch at ``phase`` (0..1) of a step."""
    drop = Drop(m1, m2, c, e, 0.0, 0.0, 0.0, v)
    tc = contact_scales(drop)["t_contact"]
    dt = tc / steps
    pre = 0.5 * tc + phase * dt
    n = math.ceil((pre + 1.5 * tc) / dt)
    ov = {"integrator.method": method, "integrator.dt": dt, "control.rate": 1.0 / dt,
          "plant.m1": m1, "plant.m2": m2, "plant.c": c, "plant.gravity": 0.0, "plant.restitution": e,
          "initial.impact_speed": v, "initial.pre_contact_time": pre}
    if "min_steps_per_contact" in {f.name for f in dataclasses.fields(IntegratorConfig)}:
        ov["integrator.min_steps_per_contact"] = 0.0  # this script measures what the check guards
    tr = impact_env.simulate("ideal", t_end=n * dt, record_rate=1.0 / dt, overrides=ov)
    got = tr.restitution()
    return math.inf if got is None else abs(got - e)


def worst_error(method: str, steps: float, e: float) -> float:
    return max(restitution_error(method, steps, e, ph) for ph in PHASES)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--method", default="rk4", choices=("rk4", "symplectic-euler", "euler"))
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    steps = STEPS_QUICK if args.quick else STEPS
    print(f"{args.method}: worst |e - e_requested| over {len(PHASES)} touch phases")
    print("steps/contact  " + "  ".join(f"e = {e:<8g}" for e in RESTITUTIONS))
    for n in steps:
        print(f"{n:13d}  " + "  ".join(f"{worst_error(args.method, n, e):10.2e}" for e in RESTITUTIONS))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
