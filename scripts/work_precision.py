"""Work-precision study of the plant's integrators.

For each method (explicit Euler, symplectic Euler, RK4 with and without event location, all
over a sweep of the step dt; dopri5 and split, the default, over a sweep of rtol) it measures five errors against a
reference, and the wall time of the compiled loop (``Trajectory.wall_time_s``, the minimum of
the repeats after a warm-up call that compiles):

``restitution``        |e - 1| of one elastic collision, gravity 0 (the ideal rig: m1 = 0.1 kg,
                       m2 = 1 kg, c = 2e6 N/m^1.5, 1 m/s); reference: e = 1 exactly.
``restitution_damped`` |e - e_ref| of the same collision with the pad calibrated to e = 0.6;
                       reference: solve_ivp (DOP853 rtol 1e-12, event restarts,
                       impact_env/plant/reference.py).
``contact_time``       |t_c / t_c,Hertz - 1| of the elastic collision (closed form).
``peak_force``         |F_max / F_Hertz - 1| of the elastic collision (closed form).
``three_bounces``      max scaled state error (positions / 2 mm, velocities / impact speed)
                       midway through the flight after the third bounce of a 2 mm drop on a
                       suspended body 2 (k2 = 1e4 N/m), gravity on, elastic; reference: solve_ivp.
``energy_drift``       |E(t_end) / E(0) - 1| after 100 elastic bounces of body 1 (drop 10 um,
                       c = 2e8) on a 1000 t body 2 that barely moves; reference: 0 (conservative).

Each run records once, at its end, so that records do not cut dopri5's steps (the peak force
is then the largest at step ends, as the plant tracks it).  Writes ``docs/results/work_precision.csv``
and ``docs/work_precision.png`` (``--format pdf|svg``: that file type instead) and prints a
summary table.

    .venv/bin/python scripts/work_precision.py            # about a minute on one core
    .venv/bin/python scripts/work_precision.py --quick    # a few seconds
"""

from __future__ import annotations

import argparse
import csv
import math
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

import impact_env  # noqa: E402
from impact_env import SimulationDiverged  # noqa: E402
from impact_env.config import ConfigError  # noqa: E402
from impact_env.figstyle import DPI, FORMATS, save_figure  # noqa: E402
from impact_env.hardware.arrays import initial_state, plant_params  # noqa: E402
from impact_env.plant import hertz  # noqa: E402
from impact_env.plant.reference import Params, reference_drop, sim_overrides  # noqa: E402

DTS = [1e-5, 5e-6, 2e-6, 1e-6, 5e-7, 2e-7, 1e-7, 5e-8, 2e-8, 1e-8]
DTS_QUICK = [1e-5, 2e-6, 1e-6, 2e-7]
RTOLS = [10.0**-k for k in range(4, 14)]
RTOLS_QUICK = [1e-4, 1e-6, 1e-8, 1e-10]
GRID = 1e-5  # every t_end is a multiple of this, so of every dt in the sweep
SERIES = [  # (label, method, event location, knob)
    ("euler", "euler", True, "dt"),
    ("symplectic-euler", "symplectic-euler", True, "dt"),
    ("rk4+events", "rk4", True, "dt"),
    ("rk4 (no events)", "rk4", False, "dt"),
    ("dopri5", "dopri5", True, "rtol"),
    ("split (default)", "split", True, "rtol"),
]
METRICS = ["restitution", "restitution_damped", "contact_time", "peak_force", "three_bounces",
           "energy_drift"]
G = 9.81


def on_grid(t: float) -> float:
    return round(t / GRID) * GRID


# --------------------------------------------------------------------------------------------
# problems: scenes, end times and references
# --------------------------------------------------------------------------------------------

def collision_overrides(restitution: float) -> dict:
    return dict(plant_gravity=0.0, initial_impact_speed=1.0, initial_pre_contact_time=1.0333333e-4,
                plant_restitution=restitution)


BOUNCE3 = dict(initial_drop_height=2e-3, plant_suspension_stiffness=1e4)
DRIFT = dict(plant_m2=1e6, plant_c=2e8, initial_drop_height=1e-5)


class Problems:
    """The references, computed once."""

    def __init__(self, n_bounces: int):
        m = 0.1 / 1.1
        self.tc = hertz.contact_time(m, 2e6, 1.0)
        self.fmax = hertz.peak_force(m, 2e6, 1.0)
        self.t_collision = on_grid(1.1e-4 + 1.2 * self.tc)
        t0 = time.perf_counter()
        # damped collision: solve_ivp's restitution for the calibrated pad
        sc = impact_env.load_scene("ideal", sim_overrides("rk4", **collision_overrides(0.6)))
        y0, _ = initial_state(sc)
        self.e_damped = reference_drop(Params.from_array(plant_params(sc)), y0, self.t_collision,
                                       peak_samples=0).restitution()
        # three bounces: end midway between the third separation and the fourth touch
        sc = impact_env.load_scene("ideal", sim_overrides("rk4", **BOUNCE3))
        p = Params.from_array(plant_params(sc))
        y0, _ = initial_state(sc)
        first = reference_drop(p, y0, 0.2, peak_samples=0)
        off = first.events[first.events[:, 1] < 0]
        on = first.events[first.events[:, 1] > 0]
        self.t_bounce3 = on_grid(0.5 * (off[2, 0] + on[3, 0]))
        self.ref_bounce3 = reference_drop(p, y0, self.t_bounce3, peak_samples=0).y_end
        self.v_bounce3 = math.sqrt(2 * G * 2e-3)
        # energy drift: end midway through the flight after the n-th bounce (from an rk4 run)
        sc = impact_env.load_scene("ideal", sim_overrides("rk4", control_rate=1e3, **DRIFT))
        tr = impact_env.simulate(sc, t_end=0.01 * (n_bounces + 5), record_rate=1e3)
        off = tr.separations()
        on = tr.onsets()
        self.t_drift = on_grid(0.5 * (off[n_bounces - 1, 0] + on[n_bounces, 0]))
        self.n_bounces = n_bounces
        # solve_ivp's own drift over the same run, for comparison
        y0, _ = initial_state(sc)
        p = Params.from_array(plant_params(sc))
        ref = reference_drop(p, y0, self.t_drift, peak_samples=0)
        e0 = _energy(y0, p)
        self.ref_drift = abs(_energy(ref.y_end, p) / e0 - 1.0)
        self.ref_seconds = time.perf_counter() - t0


def _energy(y, p: Params) -> float:
    d = max(y[0] - y[2], 0.0)
    return (0.5 * p.m1 * y[1] ** 2 + 0.5 * p.m2 * y[3] ** 2 - p.m1 * p.g * y[0]
            + 0.4 * p.c * d * d * math.sqrt(d) + 0.5 * p.k2 * y[2] ** 2)


# --------------------------------------------------------------------------------------------
# one setting of one method: all errors and timings
# --------------------------------------------------------------------------------------------

def run_timed(scene, t_end: float, repeats: int):
    """simulate() with one record at t_end; the trajectory and the best compiled-loop time."""
    best = math.inf
    tr = None
    for _ in range(repeats):
        tr = impact_env.simulate(scene, t_end=t_end, record_rate=1.0 / t_end)
        best = min(best, tr.wall_time_s)
    return tr, best


def measure(method: str, events: bool, knob: str, value: float, pr: Problems, repeats: int) -> list[dict]:
    dt = value if knob == "dt" else 1e-6
    rtol = value if knob == "rtol" else 1e-9

    def scene(**kw):
        return impact_env.load_scene("ideal", sim_overrides(method, dt=dt, rtol=rtol, events=events,
                                                             control_rate=1.0 / GRID, **kw))

    rows = []

    def add(metric, err, wall, note=""):
        rows.append(dict(metric=metric, error=err, wall_s=wall, note=note))

    def guarded(metrics, fn):
        try:
            fn()
        except SimulationDiverged:
            for mt in metrics:
                add(mt, math.nan, math.nan, "diverged")
        except ConfigError as exc:  # a step refused up front (unstable, or too few steps a contact)
            if "integrator.dt" not in str(exc):
                raise
            for mt in metrics:
                add(mt, math.nan, math.nan, "refused")

    def elastic():
        sc = scene(**collision_overrides(1.0))
        impact_env.simulate(sc, t_end=pr.t_collision, record_rate=1.0 / pr.t_collision)  # warm-up
        tr, wall = run_timed(sc, pr.t_collision, repeats)
        mt = tr.metrics()
        add("restitution", abs(mt["restitution"] - 1.0), wall)
        add("contact_time", abs(mt["first_contact_duration_s"] / pr.tc - 1.0), wall)
        add("peak_force", abs(mt["peak_contact_force_N"] / pr.fmax - 1.0), wall)

    def damped():
        sc = scene(**collision_overrides(0.6))
        tr, wall = run_timed(sc, pr.t_collision, repeats)
        add("restitution_damped", abs(tr.restitution() - pr.e_damped), wall)

    def bounce3():
        sc = scene(**BOUNCE3)
        tr, wall = run_timed(sc, pr.t_bounce3, repeats)
        y = np.array([tr.x1[-1], tr.v1[-1], tr.x2[-1], tr.v2[-1]])
        v = pr.v_bounce3
        err = np.abs(y - pr.ref_bounce3[:4]) / np.array([2e-3, v, 2e-3, v])
        add("three_bounces", float(err.max()), wall)

    def drift():
        sc = scene(**DRIFT)
        tr, wall = run_timed(sc, pr.t_drift, repeats)
        e = tr.energies()["total"]
        add("energy_drift", abs(e[-1] / e[0] - 1.0), wall, f"{len(tr.onsets())} bounces")

    guarded(["restitution", "contact_time", "peak_force"], elastic)
    guarded(["restitution_damped"], damped)
    guarded(["three_bounces"], bounce3)
    guarded(["energy_drift"], drift)
    return rows


# --------------------------------------------------------------------------------------------
# output
# --------------------------------------------------------------------------------------------

def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(15, 9))
    markers = dict(zip([s[0] for s in SERIES], "osD^v*", strict=True))
    for ax, metric in zip(axes.flat, METRICS, strict=True):
        for label, *_ in SERIES:
            pts = [(r["wall_s"], r["error"], r["value"]) for r in rows
                   if r["series"] == label and r["metric"] == metric and r["error"] == r["error"]]
            if not pts:
                continue
            pts.sort(key=lambda q: q[2], reverse=True)
            w, e, _v = zip(*pts, strict=True)
            e = [max(x, 1e-17) for x in e]  # exact results (0) at the floor of the plot
            ax.loglog(w, e, marker=markers[label], label=label)
        title, ylabel = PANELS[metric]
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("wall time of the compiled loop, s")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
        if metric == "restitution_damped":
            p = damped_order(rows)
            ax.text(0.97, 0.97, f"rk4+events: error ~ dt^{p:.2f} here (fit);\nthe pad's d^0.25 at the touch "
                    "limits it to order 1.25,\nthe graded steps after the touch\nmake its constant small",
                    transform=ax.transAxes, fontsize=8, va="top", ha="right")
    axes.flat[0].legend(fontsize=8)
    fig.suptitle("impact_env plant: work-precision (fixed-step methods: dt 1e-5..1e-8 s; "
                 "dopri5 and split: rtol 1e-4..1e-12)")
    fig.tight_layout()
    save_figure(fig, path)


PANELS = {  # metric -> (title, y label): what is measured, as a quantity
    "restitution": ("elastic collision: restitution", "|e - 1|"),
    "restitution_damped": ("damped pad (e = 0.6): restitution", "|e - e_ref| (e_ref: solve_ivp)"),
    "contact_time": ("elastic collision: contact time", "|t_c / t_c,Hertz - 1|"),
    "peak_force": ("elastic collision: peak force", "|F_max / F_Hertz - 1|"),
    "three_bounces": ("three bounces, suspended body 2: state", "max |state error| / (2 mm, v0)"),
    "energy_drift": ("100 elastic bounces: energy drift", "|E(end) / E(0) - 1|"),
}


def damped_order(rows: list[dict]) -> float:
    """Slope of log error against log dt of rk4+events on the damped collision (least squares
    over the steps whose error is above 1e-12, clear of the reference's own error)."""
    pts = [(r["value"], r["error"]) for r in rows if r["series"] == "rk4+events"
           and r["metric"] == "restitution_damped" and r["error"] == r["error"] and r["error"] > 1e-12]
    if len(pts) < 2:
        return math.nan
    x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def summary(rows: list[dict], pr: Problems) -> None:
    print(f"\nreferences: t_c = {pr.tc * 1e3:.4f} ms, F_max = {pr.fmax:.4f} N (Hertz); damped "
          f"e_ref = {pr.e_damped:.12f}; three bounces end at {pr.t_bounce3 * 1e3:.2f} ms; "
          f"{pr.n_bounces} bounces end at {pr.t_drift:.4f} s, solve_ivp's own drift there "
          f"{pr.ref_drift:.1e} (references took {pr.ref_seconds:.1f} s)")
    head = f"{'series':18s} {'setting':>11s}" + "".join(f" {m[:13]:>13s}" for m in METRICS) + \
        f" {'wall (s)':>9s}"
    print(head)
    print("-" * len(head))
    for label, _m, _e, knob in SERIES:
        values = sorted({r["value"] for r in rows if r["series"] == label}, reverse=True)
        for v in values:
            sel = {r["metric"]: r for r in rows if r["series"] == label and r["value"] == v}
            cells = []
            for m in METRICS:
                r = sel.get(m)
                if r is None or r["error"] != r["error"]:
                    cells.append(f" {(r['note'] if r else '-'):>13s}")
                else:
                    cells.append(f" {r['error']:>13.2e}")
            wall = sum(r["wall_s"] for r in sel.values() if r["wall_s"] == r["wall_s"])
            print(f"{label:18s} {knob + ' ' + format(v, '.0e'):>11s}" + "".join(cells) + f" {wall:>9.4f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer settings, one repeat, 20 bounces")
    ap.add_argument("--repeats", type=int, default=None, help="timing repeats (default 3, quick 1)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs", help="output folder (default docs/)")
    ap.add_argument("--format", default="png", choices=FORMATS,
                    help=f"the figure's file format (default png, {DPI} dpi; impact_env.figstyle)")
    args = ap.parse_args(argv)
    repeats = args.repeats or (1 if args.quick else 3)
    dts = DTS_QUICK if args.quick else DTS
    rtols = RTOLS_QUICK if args.quick else RTOLS
    # compile the kernels (or load them from numba's cache) before anything is timed
    impact_env.simulate("ideal", t_end=1e-3, overrides=sim_overrides("rk4", control_rate=1e3))
    impact_env.simulate("ideal", t_end=1e-3, overrides=sim_overrides("dopri5", control_rate=1e3))
    t_start = time.perf_counter()
    pr = Problems(n_bounces=20 if args.quick else 100)
    rows: list[dict] = []
    for label, method, events, knob in SERIES:
        for v in (dts if knob == "dt" else rtols):
            for r in measure(method, events, knob, v, pr, repeats):
                rows.append(dict(series=label, method=method, event_location=events, knob=knob, value=v, **r))
            print(f"  {label:18s} {knob} {v:.0e} done ({time.perf_counter() - t_start:.0f} s)", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results").mkdir(exist_ok=True)  # the record; the figure goes to args.out
    csv_path = args.out / "results" / "work_precision.csv"
    with open(csv_path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["series", "method", "event_location", "knob", "value", "metric",
                                           "error", "wall_s", "note"])
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{r[k]:.6e}" if isinstance(r[k], float) else r[k]) for k in w.fieldnames})
    png_path = args.out / f"work_precision.{args.format}"
    plot(rows, png_path)
    summary(rows, pr)
    print(f"rk4+events on the damped pad: error ~ dt^{damped_order(rows):.2f} (least-squares slope)")
    print(f"\nwrote {csv_path} and {png_path} in {time.perf_counter() - t_start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
