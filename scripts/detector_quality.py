"""How well the eq-4.4 contact detector sees the true contact on the rig.

    python scripts/detector_quality.py [--seeds 5] [--quick] [--set effects.detector.threshold_n=3]

For each case, drops are simulated with :class:`impact_env.sim.simulator.Simulator` over the scene's
horizon (0.4 s: the whole uncontrolled decay) and the detector's channel (``info[:, I_DETECTED]``,
computed from the filtered, noisy, quantised accelerometer and force-transducer readings) is
scored per control period against the true contact (contact force > 0 at the sample) with
:func:`impact_env.effects.detector.score_detection`:

* false contact: share of the no-contact samples that read "contact"; false onsets: detected
  onsets that match no true onset (spurious detections), out of all detected onsets;
* late detection: detected onset minus true onset (ms), mean and max over the true onsets that
  were found, and the same for the first impact alone; missed onsets: true onsets not found;
* missed contact: share of the contact samples that read "no contact" (includes body 1 resting on
  the pad, which eq 4.4 with its 2 N threshold reports as no contact, as on the rig).

Cases: ``rig`` uncontrolled; ``rig`` with a 50 Hz, 40 N shaker drive (the transducer then carries
the shaker's force, which eq 4.4 must cancel); ``rig-randomized`` uncontrolled (one draw per seed).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from impact_env.cli import add_scene_arguments, scene_from_args  # noqa: E402
from impact_env.effects.detector import score_detection  # noqa: E402
from impact_env.hardware.stage import HW_INFO  # noqa: E402
from impact_env.sim.simulator import Simulator  # noqa: E402


def run(scene, seeds, n_steps, drive_n=0.0, drive_hz=50.0):
    """(true contact [S, n], detected [S, n], contact force [S, n]) for one env per seed."""
    sim = Simulator(scene, len(seeds))
    sim.reset([np.random.default_rng(s) for s in seeds])
    true = np.zeros((len(seeds), n_steps), bool)
    det = np.zeros_like(true)
    phi = np.zeros((len(seeds), n_steps))
    scale = sim.hw.command_scale
    for k in range(n_steps):
        f = drive_n * math.sin(2 * math.pi * drive_hz * k * sim.period)
        sim.step(np.full(sim.n, f) / scale)
        phi[:, k] = sim.info[:, HW_INFO.contact_force]
        det[:, k] = sim.detected > 0.5
    true[:] = phi > 0.0
    return true, det, phi


def summarise(true, det, rate):
    scores = [score_detection(t, d, rate) for t, d in zip(true, det, strict=True)]
    first = []
    for t, d in zip(true, det, strict=True):
        on = np.flatnonzero(t)
        if on.size:
            i = on[0]
            dj = np.flatnonzero(d[i:])
            first.append(dj[0] / rate if dj.size else math.nan)
    n_on = sum(s.n_onsets for s in scores)
    n_det = sum(s.n_detected_onsets for s in scores)
    return {
        "false_contact_fraction": float(np.mean([s.false_contact_fraction for s in scores])),
        "false_onsets": sum(s.false_onsets for s in scores),
        "detected_onsets": n_det,
        "true_onsets": n_on,
        "missed_onsets": sum(s.missed_onsets for s in scores),
        "onset_late_mean_ms": 1e3 * float(np.nanmean([s.onset_lateness_mean_s for s in scores])),
        "onset_late_max_ms": 1e3 * float(np.nanmax([s.onset_lateness_max_s for s in scores])),
        "first_impact_late_max_ms": 1e3 * float(np.nanmax(first)) if first else math.nan,
        "release_late_mean_ms": 1e3 * float(np.nanmean([s.release_lateness_mean_s for s in scores])),
        "missed_contact_fraction": float(np.mean([s.missed_contact_fraction for s in scores])),
    }


def per_impact(true, det, phi, rate, limit=12):
    """Rows (onset ms, peak force N, detected late ms or None) of one run's true contacts."""
    t = true.astype(np.int8)
    on = np.flatnonzero(np.diff(t) == 1) + 1
    if t[0]:
        on = np.concatenate([[0], on])
    off = np.flatnonzero(np.diff(t) == -1) + 1
    rows = []
    for i in on[:limit]:
        j = off[off > i]
        end = j[0] if j.size else t.size
        hit = np.flatnonzero(det[i:end])
        rows.append((1e3 * i / rate, float(phi[i:end].max()), 1e3 * hit[0] / rate if hit.size else None))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="drops per case (default 5)")
    ap.add_argument("--quick", action="store_true", help="2 seeds, 0.2 s")
    add_scene_arguments(ap, scene=False)
    args = ap.parse_args(argv)
    seeds = list(range(2 if args.quick else args.seeds))
    t0 = time.perf_counter()
    cases = [("rig, uncontrolled", "rig", 0.0), ("rig, 50 Hz 40 N drive", "rig", 40.0),
             ("rig-randomized, uncontrolled", "rig-randomized", 0.0)]
    print(f"eq 4.4 detector vs true contact, {len(seeds)} seeds per case, control rate 10 kHz")
    keys = None
    first_run = None
    for label, name, drive in cases:
        scene = scene_from_args(args, scene=name)
        n_steps = int(round((0.2 if args.quick else scene.episode.horizon) * scene.control_rate))
        true, det, phi = run(scene, seeds, n_steps, drive_n=drive)
        if first_run is None:
            first_run = (true[0], det[0], phi[0], scene.control_rate)
        m = summarise(true, det, scene.control_rate)
        if keys is None:
            keys = list(m)
        print(f"\n{label} ({n_steps} steps):")
        for k in keys:
            v = m[k]
            print(f"  {k:28s} {v:.4g}" if isinstance(v, float) else f"  {k:28s} {v}")
    print("\nrig, seed 0, uncontrolled: each true contact (onset ms, peak N, detected after ms)")
    for on, pk, late in per_impact(*first_run):
        print(f"  {on:8.1f} {pk:8.2f}  {'missed' if late is None else f'{late:.1f}'}")
    print(f"\n({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
