"""The ``mpc`` law's estimator on drops of a scene: its errors, its consistency and its
lost-track count, as a JSON record, and the figures of docs/mpc.md ("The estimator of
`mpc`", between the ``ekf-figures`` markers) written from it.

    python scripts/ekf_record.py [--scene rig] [--drops 20] [--out docs/results/ekf.json]

Each drop is driven open-loop (a pull of -150 N from 0.2 ms after the touch for 1.8 ms, then a
push of 80 N for 1.5 ms), so the record measures the estimator, not a controller.
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import re
import sys
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from impact_env.control.estimation.ekf import ekf_run
from impact_env.control.estimation.layout import MEMORY, N_STATE
from impact_env.control.estimation.model import constants_vector, ekf_constants
from impact_env.scene import load_scene
from impact_env.sim.simulator import Simulator

ROOT = Path(__file__).resolve().parents[1]
CHANNELS = ("accelerometer", "force", "potentiometer")


def demand(t: int) -> float:
    return -150.0 if 12 <= t < 30 else (80.0 if 30 <= t < 45 else 0.0)


def drops(scene, n, ticks, seed):
    sim = Simulator(scene, n)
    sim.reset([np.random.default_rng(seed + i) for i in range(n)])
    idx = [sim.layout.names.index(c) for c in CHANNELS]
    scales = sim.layout.scales[idx]
    frames, truth = np.zeros((n, ticks, 3)), np.zeros((n, ticks, 4))
    dem = np.array([demand(t) for t in range(ticks)])
    for t in range(ticks):
        frames[:, t] = sim.obs[:, idx].astype(np.float64) * scales
        truth[:, t] = sim.plant_state[:, :4]
        sim.step(np.full(n, np.clip(dem[t] / scene.effects.command_scale, -1.0, 1.0)))
    return frames, truth, dem, sim.plant_parameters[:, 0].copy()


def run(k, frames, dem):
    ticks = frames.shape[0]
    ox, st = np.zeros((ticks, N_STATE)), np.zeros((ticks, 6 + N_STATE))
    ekf_run(k, np.zeros(MEMORY), frames, dem, ox, st)
    return ox, st


def record(scene_name: str, n: int, ticks: int, seed: int) -> dict:
    scene = load_scene(scene_name)
    frames, truth, dem, m1 = drops(scene, n, ticks, seed)
    consts = ekf_constants(scene)
    k = constants_vector(consts)
    err, var, lost, m1_est = [], [], [], []
    for i in range(n):
        ox, st = run(k, frames[i], dem)
        err.append(ox[:, :4] - truth[i])
        var.append(st[:, 3:7])
        lost.append(st[-1, 1])
        m1_est.append(1.0 / ox[-1, 4])
    err, var = np.array(err), np.array(var)
    nees = np.sum(err**2 / var, axis=2)  # [drop, tick]
    wrong = constants_vector({**consts, "c": 4.0 * consts["c"]})
    lost_wrong = [run(wrong, frames[i], dem)[1][-1, 1] for i in range(n)]
    v0 = scene.impact_speed
    return {
        "command": f"python scripts/ekf_record.py --scene {scene_name} --drops {n} --ticks {ticks} "
                   f"--seed {seed}",
        "scene": scene_name, "drops": n, "ticks": ticks, "seed": seed,
        "x1_rms_um_tick12": float(1e6 * np.sqrt(np.mean(err[:, 12, 0] ** 2))),
        "x1_rms_um_tick50": float(1e6 * np.sqrt(np.mean(err[:, 50, 0] ** 2))),
        "v1_rms_pct_tick12": float(100 * np.sqrt(np.mean(err[:, 12, 1] ** 2)) / v0),
        "v1_rms_pct_tick50": float(100 * np.sqrt(np.mean(err[:, 50, 1] ** 2)) / v0),
        "m1_rms_pct_end": float(100 * np.sqrt(np.mean((np.array(m1_est) / m1 - 1.0) ** 2))),
        "nees_mean_after_touch": float(nees[:, 12:].mean()),
        "nees_interval_95": [float(x) for x in chi2.ppf([0.025, 0.975], 4 * n) / n],
        "lost_clean": int(sum(x > 0 for x in lost)),
        "lost_wrong_c": int(sum(x > 0 for x in lost_wrong)),
        "python": sys.version.split()[0], "machine": platform.machine(),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }


def block(r: dict) -> str:
    lo, hi = r["nees_interval_95"]
    return "\n".join([
        f"`{r['command']}`:", "",
        "| figure | value |", "| --- | --- |",
        f"| x1 error (RMS) 0.2 ms after the touch / at 5 ms | {r['x1_rms_um_tick12']:.1f} um / "
        f"{r['x1_rms_um_tick50']:.1f} um |",
        f"| v1 error (RMS, of the impact speed) 0.2 ms after the touch / at 5 ms | "
        f"{r['v1_rms_pct_tick12']:.1f} % / {r['v1_rms_pct_tick50']:.2f} % |",
        f"| m1 error (RMS) at the end | {r['m1_rms_pct_end']:.1f} % |",
        f"| NEES of (x1, v1, x2, v2), mean over drops and ticks after the touch | "
        f"{r['nees_mean_after_touch']:.2f} (95 % interval of a consistent filter, per tick: "
        f"{lo:.2f}-{hi:.2f}) |",
        f"| drops that lost track / of {r['drops']}: as drawn; with c four times too large | "
        f"{r['lost_clean']}; {r['lost_wrong_c']} |",
    ])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="rig")
    ap.add_argument("--drops", type=int, default=20)
    ap.add_argument("--ticks", type=int, default=600)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "ekf.json"))
    ap.add_argument("--doc", default=str(ROOT / "docs" / "mpc.md"))
    a = ap.parse_args(argv)
    r = record(a.scene, a.drops, a.ticks, a.seed)
    Path(a.out).write_text(json.dumps(r, indent=1) + "\n")
    doc = Path(a.doc)
    start, end = "<!-- ekf-figures:start -->", "<!-- ekf-figures:end -->"
    text = doc.read_text()
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
    if not pattern.search(text):
        raise SystemExit(f"{doc} lacks the markers {start} ... {end}")
    doc.write_text(pattern.sub(lambda _m: f"{start}\n{block(r)}\n{end}", text, count=1))
    print(json.dumps(r, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
