"""``mpc`` on rigs drawn from ``rig-randomized``'s hardware ranges, with and without their
calibration: the record and the generated block of docs/mpc-calibrated.md.

``rig-randomized`` draws a new rig's hardware for every drop and tells the controller none of
it, so ``mpc``'s model is the nominal rig's and its filter hands over to ``pd-penetration``.  A
rig on the bench is one rig, and ``impact-env identify`` measures it (on virtual rigs every value
within 0.1 % of the truth: docs/identification.md).  This script draws ``--rigs`` rigs from the
hardware ranges of ``rig-randomized`` (one ``np.random.default_rng([seed, rig]).random()`` per
ranged field, in the scene's field order, mapped by the scene's own rule; the drop's m1 and
height stay ranged) and runs ``mpc``, ``mpc-state`` and ``pd-penetration`` on ``--drops`` drops
of each (seeds ``1000 + drops * rig ..``), under two descriptions of the same hardware:

* **calibrated**: every hardware field a one-point range listed in ``control.known_hardware``,
  as a calibrated scene file marks its identified values
  (:func:`impact_env.scene.randomize.known_hardware` gives the model-based laws their model from
  them; the delays included);
* **not calibrated**: the same one-point ranges, not listed: the same hardware and drops, bit for
  bit, with the nominal rig's model, as on ``rig-randomized``.

Then the same three laws on the scene files ``impact-env identify`` wrote for the two virtual
rigs of docs/identification.md (``docs/results/identification/seed*/identified.toml``, the
second with a period of actuator and of sensor delay): in simulation on each identified scene,
``--identified-drops`` drops (seeds 1000 ..); and on each virtual rig itself (its hardware rebuilt
as ``scripts/identify_virtual.py`` builds it, a target in lock-step on loopback, ``compare
--rig``), ``--rig-drops`` drops, with the target serving ``rig`` and then serving the identified
scene (``impact-env rig serve --scene myrig/identified.toml``): the policies onboard are built
from the scene the target serves.

Then, per hardware field, ``mpc`` on the same rigs and drops told every value but that one (the
field's range still one point, not listed): which calibration ``mpc`` can do without.
``pd-penetration``'s drops are the calibrated run's, bit for bit (its gains take no model).

Per description: each policy's mean energy integral over all drops with its 95 % bootstrap
interval (drops resampled within their rig), and the paired difference ``mpc`` minus
``pd-penetration`` (:mod:`impact_env.eval.paired`); ``mpc`` is better where the interval lies
below 0.  Writes docs/results/mpc/calibrated.json (figures, per-drop values, each rig's hardware,
the command, versions, CPU, date) and the block between the ``mpc-calibrated`` markers of
docs/mpc-calibrated.md.

    python scripts/mpc_calibrated.py [--rigs 10] [--drops 10] [--seed 0]
    python scripts/mpc_calibrated.py --render          # the block from the record
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mpc_record import OUT, _table_head, at_least_two, meta, record_and_block  # noqa: E402

MARKERS = ("<!-- mpc-calibrated:start -->", "<!-- mpc-calibrated:end -->")
PAGE = OUT.parents[2] / "docs" / "mpc-calibrated.md"
RECORD = OUT / "calibrated.json"
POLICIES = ("mpc", "mpc-state", "pd-penetration")
IDENTIFIED = sorted((OUT.parents[1] / "results" / "identification").glob("seed*/identified.toml"))
DESCRIPTIONS = ("calibrated", "not calibrated")


def draw_rigs(rigs: int, seed: int) -> list[dict[str, float]]:
    """Each rig's hardware values: ``rig-randomized``'s hardware ranges at one uniform draw each."""
    from impact_env.scene import load_scene
    from impact_env.scene.randomize import DROP_FIELDS

    scene = load_scene("rig-randomized")
    rz = scene.randomize
    out = []
    for rig in range(rigs):
        u = np.random.default_rng([seed, rig]).random(len(rz.ranged()))
        values = rz.values_at(u, scene.control_rate)
        out.append({name: v for name, v in values.items() if name not in DROP_FIELDS})
    return out


def description(hardware: dict[str, float], calibrated: bool) -> dict:
    """The overrides of ``rig-randomized`` that give its hardware ``hardware``, told to the controller
    or not."""
    out: dict = {f"randomize.{name}": [v, v] for name, v in hardware.items()}
    if calibrated:
        out["control.known_hardware"] = list(hardware)
    return out


def measure_identified(drops: int) -> dict:
    """Each identified scene file: the three laws' mean energy integral and per-drop values."""
    from impact_env.eval.compare import compare
    from impact_env.scene import load_scene

    out = {}
    for path in IDENTIFIED:
        runs = compare(load_scene(path), list(POLICIES), episodes=drops, seed=1000, progress=False,
                       reference=None)
        out[str(path.relative_to(OUT.parents[2]))] = {
            p: [float(v) for v in runs[p].metrics["energy_integral_ms"]] for p in POLICIES}
    return out


def measure_on_rigs(drops: int) -> dict:
    """Each identified virtual rig in lock-step: mpc and pd-penetration onboard, the target
    serving ``rig`` and then the identified scene."""
    from identify_virtual import serve, virtual_physics

    from impact_env.eval.rig_compare import rig_compare

    out = {}
    for path in IDENTIFIED:
        res = json.loads((path.parent / "result.json").read_text())
        physics, _truth = virtual_physics(int(res["seed"]), tuple(res["delays"]))
        rows = {}
        for served in ("rig", str(path.relative_to(OUT.parents[2]))):
            target, th = serve(physics, OUT.parents[2] / served if served != "rig" else served)
            try:
                _scene, runs = rig_compare(target.address, ["mpc", "pd-penetration"], episodes=drops,
                                           seed=1000, progress=False)
            finally:
                target.stop()
                th.join(10)
            rows[served] = {p: [float(v) for v in runs[p].metrics["energy_integral_ms"]] for p in runs}
        out[f"seed {res['seed']}, delays {res['delays']}"] = rows
    return out


def measure(rigs: int, drops: int, seed: int, identified_drops: int, rig_drops: int) -> dict:
    from impact_env.eval.compare import compare
    from impact_env.scene import load_scene

    hardware = draw_rigs(rigs, seed)
    energies = {d: {p: [] for p in POLICIES} for d in DESCRIPTIONS}
    t0 = time.perf_counter()
    for rig, hw in enumerate(hardware):
        for d in DESCRIPTIONS:
            scene = load_scene("rig-randomized", description(hw, d == "calibrated"))
            runs = compare(scene, list(POLICIES), episodes=drops, seed=1000 + drops * rig, progress=False,
                           reference=None)
            for p in POLICIES:
                energies[d][p] += [float(v) for v in runs[p].metrics["energy_integral_ms"]]
        print(f"rig {rig + 1}/{rigs}: " + ", ".join(
            f"{d}: " + " ".join(f"{p} {np.mean(energies[d][p][-drops:]):.2f}" for p in POLICIES)
            for d in DESCRIPTIONS), file=sys.stderr)
    all_but = {field: [] for field in hardware[0]}
    for field in all_but:
        for rig, hw in enumerate(hardware):
            told = description(hw, True)
            told["control.known_hardware"] = [name for name in hw if name != field]
            runs = compare(load_scene("rig-randomized", told), ["mpc"], episodes=drops,
                           seed=1000 + drops * rig, progress=False, reference=None)
            all_but[field] += [float(v) for v in runs["mpc"].metrics["energy_integral_ms"]]
        print(f"told all but {field}: mpc {np.mean(all_but[field]):.2f}", file=sys.stderr)
    command = ["python", "scripts/mpc_calibrated.py", "--rigs", str(rigs), "--drops", str(drops),
               "--seed", str(seed), "--identified-drops", str(identified_drops),
               "--rig-drops", str(rig_drops)]
    identified = measure_identified(identified_drops)
    on_rigs = measure_on_rigs(rig_drops)
    return {**meta(command), "wall_s": round(time.perf_counter() - t0, 1), "rigs": rigs, "drops": drops,
            "seed": seed, "hardware": hardware, "energy_integral_ms": energies, "told_all_but": all_but,
            "identified_drops": identified_drops, "identified": identified, "rig_drops": rig_drops,
            "on_rigs": on_rigs}


def render(rec: dict) -> str:
    from impact_env.eval.paired import bootstrap, mean, mean_difference

    strata = np.repeat(np.arange(rec["rigs"]), rec["drops"])
    lines = _table_head(
        f"`{rec['command']}` ({rec['rigs']} rigs drawn from `rig-randomized`'s hardware ranges, "
        f"{rec['drops']} drops each; energy integral, ms: the mean over all drops and its 95 % bootstrap "
        "interval, drops resampled within their rig; paired: `mpc` minus `pd-penetration` per drop):",
        ["the controller's description of the rig", *(f"`{p}`" for p in POLICIES),
         "`mpc` - `pd-penetration`, paired [95 % CI]", "`mpc` better"])
    for d in DESCRIPTIONS:
        e = {p: np.asarray(rec["energy_integral_ms"][d][p]) for p in POLICIES}
        cells = []
        for p in POLICIES:
            m = bootstrap(mean, e[p], strata=strata)
            cells.append(f"{m.value:.2f} [{m.low:.2f}, {m.high:.2f}]")
        diff = bootstrap(mean_difference, e["mpc"], e["pd-penetration"], strata=strata)
        verdict = "yes" if diff.high < 0 else ("no: worse" if diff.low > 0 else "not separated")
        name = ("calibrated: the rig's values, as `impact-env identify` writes them" if d == "calibrated"
                else "not calibrated: the nominal rig's values (as on `rig-randomized`)")
        lines.append(f"| {name} | " + " | ".join(cells)
                     + f" | {diff.value:.2f} [{diff.low:.2f}, {diff.high:.2f}] | {verdict} |")
    if rec.get("told_all_but"):
        pd = np.asarray(rec["energy_integral_ms"]["calibrated"]["pd-penetration"])
        lines += [""] + _table_head(
            "The same rigs and drops, `mpc` told every value but one (that field's range still one "
            "point, not listed in `control.known_hardware`; `pd-penetration` as above):",
            ["the one value not told", "`mpc`", "`mpc` - `pd-penetration`, paired [95 % CI]", "`mpc` better"])
        for field, values in rec["told_all_but"].items():
            e = np.asarray(values)
            m = bootstrap(mean, e, strata=strata)
            diff = bootstrap(mean_difference, e, pd, strata=strata)
            verdict = "yes" if diff.high < 0 else ("no: worse" if diff.low > 0 else "not separated")
            lines.append(f"| `{field}` | {m.value:.2f} [{m.low:.2f}, {m.high:.2f}] | "
                         f"{diff.value:.2f} [{diff.low:.2f}, {diff.high:.2f}] | {verdict} |")
    if rec.get("identified"):
        lines += [""] + _table_head(
            f"The scene files `impact-env identify` wrote for the virtual rigs of "
            f"[identification.md](identification.md), in simulation on each ({rec['identified_drops']} drops "
            "from seed 1000; energy integral, ms, mean and 95 % bootstrap interval):",
            ["identified scene", *(f"`{p}`" for p in POLICIES), "`mpc` - `pd-penetration`, paired [95 % CI]"])
        for path, e in rec["identified"].items():
            cells = [f"{m.value:.2f} [{m.low:.2f}, {m.high:.2f}]"
                     for m in (bootstrap(mean, np.asarray(e[p])) for p in POLICIES)]
            diff = bootstrap(mean_difference, np.asarray(e["mpc"]), np.asarray(e["pd-penetration"]))
            lines.append(f"| `{path}` | " + " | ".join(cells)
                         + f" | {diff.value:.2f} [{diff.low:.2f}, {diff.high:.2f}] |")
    if rec.get("on_rigs"):
        lines += [""] + _table_head(
            f"On those virtual rigs themselves (lock-step, `compare --rig`, {rec['rig_drops']} drops from "
            "seed 1000; the laws onboard, built from the scene the target serves):",
            ["virtual rig", "the target serves", "`mpc`", "`pd-penetration`",
             "`mpc` - `pd-penetration`, paired [95 % CI]"])
        for rig, rows in rec["on_rigs"].items():
            for served, e in rows.items():
                cells = [f"{m.value:.2f} [{m.low:.2f}, {m.high:.2f}]"
                         for m in (bootstrap(mean, np.asarray(e[p])) for p in ("mpc", "pd-penetration"))]
                diff = bootstrap(mean_difference, np.asarray(e["mpc"]), np.asarray(e["pd-penetration"]))
                lines.append(f"| {rig} | `{served}` | " + " | ".join(cells)
                             + f" | {diff.value:.2f} [{diff.low:.2f}, {diff.high:.2f}] |")
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rigs", type=int, default=10, help="rigs drawn from rig-randomized's hardware ranges")
    ap.add_argument("--drops", type=int, default=10, help="drops per rig")
    ap.add_argument("--seed", type=int, default=0, help="seeds the rigs' draws")
    ap.add_argument("--identified-drops", type=int, default=30, help="drops on each identified scene file")
    ap.add_argument("--rig-drops", type=int, default=10, help="drops on each virtual rig, per served scene")
    ap.add_argument("--render", action="store_true", help="only rewrite the block from the record")
    args = ap.parse_args()
    at_least_two(ap, args, ("rigs", "drops", "identified_drops", "rig_drops"))
    run = None if args.render else lambda: measure(args.rigs, args.drops, args.seed, args.identified_drops,
                                                   args.rig_drops)
    text = record_and_block(RECORD, run, render, MARKERS, PAGE)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
