"""The sensor plausibility check (impact_env.control.plausibility) measured on closed-loop drops:
its false alarms on clean, noisy drops and its detection delay per fault kind and channel.

    python scripts/fault_detection.py                      # 10^4 drops of rig-randomized
    python scripts/fault_detection.py --drops 2000         # fewer (a loaded machine)
    python scripts/fault_detection.py --table-only         # rewrite the docs' table from the record

Every drop runs the rig target's compiled tick (the controller, onboard, with its plausibility
check, safety layer and front end) on the virtual rig's hardware stage, all in compiled code
(:class:`impact_env.eval.sensor_faults.DropRunner`; bitwise the virtual rig's per-tick loop).

* False alarms: ``--drops`` drops of ``--scene`` (seeds 0 .. drops - 1, the policies taking turns),
  ``--ticks`` ticks each (0.4 s at 10 kHz: the whole episode); a drop is a false alarm when any
  tick's status has a SENSOR_* bit.  The same for ``rig`` with a tenth of the drops.
* Detection: for each channel (accelerometer, force transducer, potentiometer) and kind (an
  in-range spike, a step offset, a stuck reading, a dropout to 0), ``--fault-drops`` drops of
  ``--scene`` with the fault at a tick drawn uniformly over the first 0.25 s, each beside the clean
  drop of the same seed: whether it was flagged, the delay in ticks from its first tick to the
  first tick flagged, and the largest difference between the force the faulty readings drove and
  the clean drop's over the fault's ticks before the flag (a spike's one, a dropout's five, a
  step's or a stuck reading's first UNSEEN_TICKS): what the fault made of the drive unseen.
  Then the audit's three cases before the touch (tick 5), under thesis-rig.

The record (docs/results/fault_detection.json) holds the figures, the command, the versions, the
CPU and the date; the table between ``<!-- fault-detection:start -->`` and ``<!-- fault-detection:end
-->`` in docs/rig/faults.md is written from it.
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import re
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from impact_env.control import plausibility  # noqa: E402
from impact_env.eval.sensor_faults import DropRunner, Fault, first_flag  # noqa: E402
from impact_env.policy.export import export_policy  # noqa: E402
from impact_env.scene import load_scene  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
RECORD = ROOT / "docs" / "results" / "fault_detection.json"
DOC = ROOT / "docs" / "rig" / "faults.md"
CHANNEL_NAMES = ("accelerometer", "force", "potentiometer")
UNITS = ("m/s^2", "N", "m")
# in-range sizes below each channel's jump bound (max_step + noise), so that only the physics
# checks can see them: (spike, step) per channel
SIZES = {0: (100.0, 50.0), 1: (50.0, 20.0), 2: (3e-4, 3e-4)}
DROPOUT_TICKS = 5
UNSEEN_TICKS = 20


def unseen_drive(clean, faulty, fault: Fault, flag: int) -> float:
    """The largest |force difference| (N) over the fault's ticks before ``flag`` (-1: none)."""
    span = {"spike": 1, "dropout": fault.length}.get(fault.kind, UNSEEN_TICKS)
    end = min(fault.tick + span, flag if flag >= 0 else len(faulty.force), len(clean.force))
    if end <= fault.tick:
        return 0.0
    return float(np.abs(faulty.force[fault.tick : end] - clean.force[fault.tick : end]).max())


def false_alarms(scene_name: str, policies: list[str], drops: int, ticks: int) -> dict:
    scene = load_scene(scene_name)
    runners = [DropRunner(export_policy(p, scene), scene, ticks) for p in policies]
    flagged, flagged_ticks, t0 = [], 0, time.perf_counter()
    for seed in range(drops):
        d = runners[seed % len(runners)].run(seed)
        bad = np.flatnonzero(d.status & plausibility.SENSOR_BITS)
        if bad.size:
            flagged.append(
                {
                    "seed": seed,
                    "policy": policies[seed % len(runners)],
                    "first_tick": int(bad[0]),
                    "status": int(d.status[bad[0]]),
                }
            )
            flagged_ticks += int(bad.size)
    return {
        "scene": scene_name,
        "policies": policies,
        "drops": drops,
        "ticks_per_drop": ticks,
        "drops_flagged": len(flagged),
        "ticks_flagged": flagged_ticks,
        "flagged": flagged[:20],
        "seconds": round(time.perf_counter() - t0, 1),
    }


def detection(scene_name: str, policy: str, drops: int, ticks: int) -> list[dict]:
    scene = load_scene(scene_name)
    run = DropRunner(export_policy(policy, scene), scene, ticks)
    rng = np.random.default_rng(12345)
    last = int(0.25 * scene.control_rate)
    rows = []
    for ch in range(3):
        for kind in ("spike", "step", "stuck", "dropout"):
            size = {"spike": SIZES[ch][0], "step": SIZES[ch][1]}.get(kind, 0.0)
            delays, drive, missed = [], [], 0
            for seed in range(drops):
                tick = int(rng.integers(1, last))
                clean = run.run(seed)
                fault = Fault(ch, kind, tick, size, DROPOUT_TICKS)
                d = run.run(seed, fault)
                hit = first_flag(d.status, plausibility.SENSOR_FAULT, tick)
                drive.append(unseen_drive(clean, d, fault, hit))
                if hit < 0:
                    missed += 1
                else:
                    delays.append(hit - tick)
            rows.append(
                {
                    "channel": CHANNEL_NAMES[ch],
                    "kind": kind,
                    "size": size,
                    "unit": UNITS[ch],
                    "drops": drops,
                    "detected": drops - missed,
                    "delay_ticks_median": float(np.median(delays)) if delays else None,
                    "delay_ticks_max": int(max(delays)) if delays else None,
                    "unseen_drive_N_max": round(max(drive), 3),
                }
            )
    return rows


def audit_cases(ticks: int) -> list[dict]:
    """The audit's cases, before the touch (tick 5) under thesis-rig on rig: the clean drop's
    force there and the faulty one's."""
    scene = load_scene("rig")
    run = DropRunner(export_policy("thesis-rig", scene), scene, ticks)
    ph = plausibility.plausibility_params(scene).phys
    # the steady drive's threshold, N
    arm = ph[plausibility.PH.tol_arm] + ph[plausibility.PH.per_tick] + ph[plausibility.PH.tail]
    a_thr = arm / ph[plausibility.PH.lower_mass]
    cases = [
        ("accelerometer spike +450 m/s^2", Fault(0, "spike", 5, 450.0)),
        ("force transducer step +300 N", Fault(1, "step", 5, 300.0)),
        ("accelerometer stuck at -0.0", Fault(0, "stuck_at", 5, -0.0)),
        (
            f"accelerometer spike +{0.95 * a_thr:.1f} m/s^2 (0.95 x its threshold)",
            Fault(0, "spike", 5, 0.95 * a_thr),
        ),
        (
            f"force transducer spike +{0.95 * arm:.1f} N (0.95 x its threshold)",
            Fault(1, "spike", 5, 0.95 * arm),
        ),
    ]
    out = []
    for name, fault in cases:
        clean, d = run.run(0), run.run(0, fault)
        hit = first_flag(d.status, plausibility.SENSOR_FAULT, fault.tick)
        flagged = np.flatnonzero(d.status & plausibility.SENSOR_FAULT)
        out.append(
            {
                "case": name,
                "first_flag_tick": hit,
                "delay_ticks": hit - fault.tick if hit >= 0 else None,
                "timeout_tick": first_flag(d.status, plausibility.SENSOR_TIMEOUT),
                "force_N_on_flagged_ticks_max": float(np.abs(d.force[flagged]).max())
                if flagged.size
                else None,
                "unseen_drive_N_max": unseen_drive(clean, d, fault, hit),
            }
        )
    return out


def constants_table(scenes=("rig", "rig-randomized")) -> str:
    """What the check derives from each scene (impact_env.control.plausibility): computed, not
    measured."""
    rows = [
        ("`tol_sign`: m2' a2 + T may read this far below 0", "N", lambda p: p.phys[plausibility.PH.tol_sign]),
        (
            "`tol_arm`: noise and rounding of the armature residual's change",
            "N",
            lambda p: p.phys[plausibility.PH.tol_arm],
        ),
        (
            "`per_tick`: its change per tick the drive does not explain",
            "N",
            lambda p: p.phys[plausibility.PH.per_tick],
        ),
        (
            "`drive_gain`: per N of the demand's largest change in the last 16 ticks",
            "",
            lambda p: p.phys[plausibility.PH.drive_gain],
        ),
        (
            "accelerometer threshold, steady drive: (tol_arm + per_tick) / (m2 - m2')",
            "m/s^2",
            lambda p: (
                (
                    p.phys[plausibility.PH.tol_arm]
                    + p.phys[plausibility.PH.per_tick]
                    + p.phys[plausibility.PH.tail]
                )
                / p.phys[plausibility.PH.lower_mass]
            ),
        ),
        (
            "force transducer threshold, steady drive: tol_arm + per_tick",
            "N",
            lambda p: (
                p.phys[plausibility.PH.tol_arm]
                + p.phys[plausibility.PH.per_tick]
                + p.phys[plausibility.PH.tail]
            ),
        ),
        (
            "potentiometer threshold: its jump check's max_step + tol",
            "mm",
            lambda p: 1e3 * (p.ch[2, plausibility.CC.max_jump] + p.ch[2, plausibility.CC.tol]),
        ),
        (
            "stuck after this many exact repeats: accelerometer / force / potentiometer",
            "ticks",
            lambda p: " / ".join(str(int(v)) for v in p.ch[:3, plausibility.CC.repeat]),
        ),
    ]
    params = [plausibility.plausibility_params(load_scene(name)) for name in scenes]
    lines = [
        "| derived | unit | " + " | ".join(f"`{n}`" for n in scenes) + " |",
        "|---|---|" + "---:|" * len(scenes),
    ]
    for name, unit, f in rows:
        vals = [f(p) for p in params]
        lines.append(
            f"| {name} | {unit} | " + " | ".join(v if isinstance(v, str) else f"{v:.3g}" for v in vals) + " |"
        )
    return "\n".join(lines)


def table(rec: dict) -> str:
    fa = rec["false_alarms"]
    lines = [
        constants_table(),
        "",
        "| scene | policies | drops | drops with a false alarm |",
        "|---|---|---:|---:|",
    ]
    for r in fa:
        lines.append(f"| `{r['scene']}` | {', '.join(r['policies'])} | {r['drops']} | {r['drops_flagged']} |")
    lines += [
        "",
        f"Detection on `{rec['detection_scene']}` under {rec['detection_policy']}, "
        f"{rec['detection'][0]['drops']} drops per row, the fault at a random tick of the first 0.25 s:",
        "",
        "| channel | fault | size | detected | delay, ticks (median / max) | unseen drive, N (max) |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for r in rec["detection"]:
        size = (
            f"{r['size']:g} {r['unit']}"
            if r["kind"] in ("spike", "step")
            else ("0 for 5 ticks" if r["kind"] == "dropout" else "")
        )
        delay = (
            "-"
            if r["delay_ticks_median"] is None
            else f"{r['delay_ticks_median']:g} / {r['delay_ticks_max']}"
        )
        lines.append(
            f"| {r['channel']} | {r['kind']} | {size} | {r['detected']}/{r['drops']} | {delay} | "
            f"{r['unseen_drive_N_max']:g} |"
        )
    lines += [
        "",
        "The audit's cases on `rig` under thesis-rig, at tick 5 (before the touch):",
        "",
        "| case | flagged after, ticks | SENSOR_TIMEOUT at tick | force on flagged ticks, N | "
        "unseen drive, N |",
        "|---|---:|---:|---:|---:|",
    ]
    for r in rec["audit"]:
        timeout = "never" if r["timeout_tick"] < 0 else r["timeout_tick"]
        delay = "not flagged" if r["delay_ticks"] is None else r["delay_ticks"]
        on_flagged = (
            "-" if r["force_N_on_flagged_ticks_max"] is None else f"{r['force_N_on_flagged_ticks_max']:g}"
        )
        lines.append(f"| {r['case']} | {delay} | {timeout} | {on_flagged} | {r['unseen_drive_N_max']:g} |")
    lines += ["", f"Command: `{rec['command']}`"]
    return "\n".join(lines)


def write_table(rec: dict, doc: Path = DOC) -> None:
    text = doc.read_text()
    block = f"<!-- fault-detection:start -->\n{table(rec)}\n<!-- fault-detection:end -->"
    new, n = re.subn(
        r"<!-- fault-detection:start -->.*?<!-- fault-detection:end -->", block, text, flags=re.S
    )
    if n != 1:
        raise SystemExit(f"{doc}: no fault-detection block")
    doc.write_text(new)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--drops", type=int, default=10_000, help="clean drops of --scene (false alarms)")
    ap.add_argument("--scene", default="rig-randomized")
    ap.add_argument("--policies", default="thesis-rig,pd-penetration")
    ap.add_argument("--ticks", type=int, default=4000, help="ticks per drop (4000: 0.4 s at 10 kHz)")
    ap.add_argument("--fault-drops", type=int, default=20, help="drops per fault kind and channel")
    ap.add_argument("--out", type=Path, default=RECORD)
    ap.add_argument("--table-only", action="store_true", help="rewrite the docs' table from --out")
    args = ap.parse_args(argv)
    if args.table_only:
        write_table(json.loads(args.out.read_text()))
        return 0
    import numba

    policies = args.policies.split(",")
    t0 = time.perf_counter()
    fa = [
        false_alarms(args.scene, policies, args.drops, args.ticks),
        false_alarms("rig", policies, max(1, args.drops // 10), args.ticks),
    ]
    det = detection(args.scene, policies[0], args.fault_drops, args.ticks)
    rec = {
        "false_alarms": fa,
        "detection_scene": args.scene,
        "detection_policy": policies[0],
        "detection": det,
        "audit": audit_cases(args.ticks),
        "command": " ".join(
            ["python scripts/fault_detection.py", *(argv if argv is not None else sys.argv[1:])]
        ),
        "versions": {
            "python": platform.python_version(),
            "numpy": np.__version__,
            "numba": numba.__version__,
        },
        "cpu": platform.processor() or platform.machine(),
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "seconds": round(time.perf_counter() - t0, 1),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rec, indent=1) + "\n")
    print(table(rec))
    if args.out == RECORD:
        write_table(rec)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
