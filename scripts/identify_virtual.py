"""Identification on virtual rigs nobody tuned for, and the sim-to-rig gap before and after.

For each seed: a virtual rig whose hardware is ``rig``'s moved by up to +-40 %
(:func:`impact_env.ident.virtual.perturbed_physics`; the second seed with a tick of actuator
and of sensor delay), described to its target as ``rig``; the identification plan
(``impact-env rig identify``, the full plan unless ``--quick``) on loopback in lock-step; the
fit.  Prints (and writes to ``--out``) the true against the identified values with their
standard uncertainties and the deviation in uncertainties (z), the fit's wall time split into
simulation and the rest, and, with ``--gap``, compare's energy integral per policy on the rig
(``compare --rig``), in simulation on ``rig`` (before) and on the identified scene (after), on
the same seeds.  The rig keeps ``rig``'s benchmark drops (0.08-0.12 kg from 30-70 mm) for the
comparison; identification drops release its own body from the nominal height.

    python scripts/identify_virtual.py --seeds 21 22 --gap --out docs/results/identification
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from pathlib import Path

import numpy as np

from impact_env.ident import report
from impact_env.ident.experiments import load
from impact_env.ident.fit import Problem, identify
from impact_env.ident.plan import default_plan, run_plan
from impact_env.ident.virtual import perturbed_physics
from impact_env.rig.driver import VirtualRig
from impact_env.rig.host import RigClient
from impact_env.rig.target import Target, TargetConfig
from impact_env.scene import load_scene

AGENT = "compiled:agents/models/best/best.policy.json"
POLICIES = ("passive", "thesis-rig", "pd-penetration", AGENT)


def serve(physics, scene="rig"):
    """A lock-step target on loopback serving ``scene`` on a virtual rig whose hardware is
    ``physics``, in a thread: (target, thread)."""
    target = Target(VirtualRig(scene, physics), config=TargetConfig(lockstep=True))
    th = threading.Thread(target=target.serve, daemon=True)
    th.start()
    return target, th


SPREAD = 0.4  # each hardware field moved by up to +-40 %


def virtual_physics(seed: int, delays: tuple[int, int]):
    """(physics, truth) of the virtual rig of ``seed`` with ``delays`` (actuator, sensor periods):
    ``rig``'s hardware moved by up to :data:`SPREAD`, and ``rig``'s benchmark drops on it."""
    physics, truth = perturbed_physics("rig", seed, SPREAD, *delays)
    base = load_scene("rig")
    # the benchmark's drops on this rig, as rig draws them (identification drops use its own body)
    physics = physics.with_overrides({"randomize.m1": list(base.randomize.m1),
                                      "randomize.drop_height": list(base.randomize.drop_height)})
    return physics, truth


def one_rig(seed: int, delays: tuple[int, int], out: Path, quick: bool, gap: bool, episodes: int) -> dict:
    physics, truth = virtual_physics(seed, delays)
    d = out / f"seed{seed}"
    target, th = serve(physics)
    try:
        client = RigClient(target.address)
        t0 = time.perf_counter()
        files = run_plan(client, d / "logs", default_plan(quick=quick), progress=False)
        t_plan = time.perf_counter() - t0
        client.close()
        exps = load(files)
        sim = {"t": 0.0, "n": 0}
        orig = Problem.residuals_many

        def timed(self, X):  # the share of the fit's time spent replaying the hardware stage
            t = time.perf_counter()
            r = orig(self, X)
            sim["t"] += time.perf_counter() - t
            sim["n"] += X.shape[0]
            return r

        Problem.residuals_many = timed
        fit = identify(exps)
        Problem.residuals_many = orig
        (d / "identified.toml").write_text(report.scene_text(fit, "rig"))
        (d / "identification.json").write_text(json.dumps(report.to_json(fit), indent=1) + "\n")
        ticks = sum(e.n for e in exps if e.kind != "quiet")
        res = {"seed": seed, "delays": delays, "truth": truth, "fields": report.field_table(fit),
               "sensors": {k: vars(v) for k, v in fit.sensors.items()},
               "k_act": fit.k_act, "k_sens": fit.k_sens,
               "chi2_red": fit.chi2_red, "plan_s": t_plan, "fit_s": fit.wall_s, "sim_s": sim["t"],
               "candidate_replays": sim["n"], "replayed_ticks": ticks, "logs": len(files)}
        if gap:
            res["gap"] = gap_table(target.address, d / "identified.toml", episodes)
    finally:
        target.stop()
        th.join(10)
    return res


def gap_table(address: str, identified: Path, episodes: int) -> dict:
    from impact_env.eval.compare import compare
    from impact_env.eval.rig_compare import rig_compare

    _scene, on_rig = rig_compare(address, list(POLICIES), episodes=episodes, seed=1000, progress=False)
    before = compare("rig", list(POLICIES), episodes=episodes, seed=1000, progress=False)
    after = compare(load_scene(identified), list(POLICIES), episodes=episodes, seed=1000, progress=False)
    return {p: {"rig": on_rig[p].summary["energy_integral_ms"],
                "before": before[p].summary["energy_integral_ms"],
                "after": after[p].summary["energy_integral_ms"]} for p in POLICIES}


def markdown(res: dict) -> str:
    truth = res["truth"]
    out = [f"Rig seed {res['seed']} (delays: actuator {res['delays'][0]}, sensor {res['delays'][1]} ticks): "
           f"reduced chi-square {res['chi2_red']:.3f}; delays identified: actuator {res['k_act']}, sensor "
           f"{res['k_sens']} ticks; plan {res['plan_s']:.1f} s ({res['logs']} episodes, lock-step), fit "
           f"{res['fit_s']:.0f} s, of which {res['sim_s']:.0f} s replaying the hardware stage "
           f"({res['candidate_replays']} candidate replays of {res['replayed_ticks']} ticks).", "",
           "| field | base (`rig`) | true | identified +- 1 sigma | z | status |",
           "|---|---|---|---|---|---|"]
    for r in res["fields"]:
        t = truth.get(r["field"])
        z = math.log(r["value"] / t) / r["rel_sigma"] if t and r["rel_sigma"] > 0 else float("nan")
        sig = f"{r['sigma']:.3g}" if r["rel_sigma"] > 0 else "-"
        out.append(f"| `{r['field']}` | {r['base']:.6g} | {t:.6g} | {r['value']:.6g} +- {sig} | "
                   f"{z:+.1f} | {r['status']} |")
    for ch, s in res["sensors"].items():
        for key in ("offset", "noise_std"):
            t = truth[f"effects.sensors.{ch}.{key}"]
            se = s["offset_se" if key == "offset" else "noise_se"]
            out.append(f"| `effects.sensors.{ch}.{key}` | - | {t:.4g} | {s[key]:.4g} +- {se:.2g} | "
                       f"{(s[key] - t) / se:+.1f} | identified |")
    if "gap" in res:
        out += ["", "Energy integral (ms, mean over the same drops): on the virtual rig (`compare --rig`), "
                "in simulation on `rig` (before) and on the identified scene (after):", "",
                "| policy | rig | sim before | gap before | sim after | gap after |",
                "|---|---|---|---|---|---|"]
        for p, g in res["gap"].items():
            out.append(f"| {p} | {g['rig']:.2f} | {g['before']:.2f} | {g['before'] - g['rig']:+.2f} | "
                       f"{g['after']:.2f} | {g['after'] - g['rig']:+.2f} |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[21, 22])
    ap.add_argument("--quick", action="store_true", help="the quick plan")
    ap.add_argument("--gap", action="store_true", help="also compare on the rig, before and after")
    ap.add_argument("--episodes", type=int, default=30, help="drops per policy for --gap (default 30)")
    ap.add_argument("--out", default="docs/results/identification")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    text = []
    for i, seed in enumerate(args.seeds):
        res = one_rig(seed, (1, 1) if i % 2 else (0, 0), out, args.quick, args.gap, args.episodes)
        md = markdown(res)
        print(md, flush=True)
        text.append(md)
        (out / f"seed{seed}" / "result.json").write_text(json.dumps(res, indent=1, default=float) + "\n")
    cmd = "python scripts/identify_virtual.py " + " ".join(sys.argv[1:] if argv is None else argv)
    (out / "virtual_rigs.md").write_text(f"Written by `{cmd}`.\n\n" + "\n".join(text))
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
