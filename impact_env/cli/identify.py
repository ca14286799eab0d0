"""``impact-env identify LOGS...`` (offline) and ``impact-env rig identify`` (run the plan on a
target, then fit): a scene calibrated to a rig from its own logs (:mod:`impact_env.ident`)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from impact_env.cli.args import add_format_argument
from impact_env.config import ConfigError
from impact_env.ident import report
from impact_env.ident.experiments import ExperimentError, load
from impact_env.ident.fit import identify
from impact_env.ident.plan import default_plan, run_plan
from impact_env.rig.host import RigClient
from impact_env.scene import PRESETS, load_scene


def add_identify_arguments(p) -> None:
    p.add_argument("--base", default=None, metavar="SCENE",
                   help="the scene to calibrate (preset or .toml; default: the scene the logs were recorded "
                        "with, i.e. the target's)")
    p.add_argument("--ranges", type=float, default=None, metavar="K",
                   help="write [randomize] ranges of +-K standard uncertainties around each identified value "
                        "(for training on the identified rig with its uncertainty); default: one-point "
                        "ranges for the fields the controller reads, fixed values for the others")

    add_format_argument(p, what="the report's figures'")
    p.add_argument("--json", action="store_true", help="print the identification as one JSON object")


def add_arguments(p) -> None:
    """``identify``'s arguments on its subparser (:data:`impact_env.cli.main.COMMANDS`)."""
    p.add_argument("logs", nargs="+", help="episode logs (.h5) or folders of them: quiet, shaker and "
                                           "identification-drop episodes (impact-env rig identify)")
    p.add_argument("--out", required=True, metavar="FILE.toml", help="the calibrated scene file to write")
    p.add_argument("--report", metavar="DIR", default=None,
                   help="write report.md, identification.json and figures here (default: the folder "
                        "FILE-report beside --out)")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    add_identify_arguments(p)
    p.set_defaults(func=cmd_identify)


def _check_out(out: Path, force: bool) -> None:
    if out.suffix != ".toml":
        raise ConfigError(f"--out {str(out)!r} must be a .toml scene file")
    if out.exists() and not force:
        raise ConfigError(f"--out {str(out)!r} exists; give --force to overwrite it")


def _base(args, exps):
    if args.base is None:
        scene = exps[0].scene
        ref = scene.name if scene.name in PRESETS and scene == load_scene(scene.name) else None
        return scene, ref
    scene = load_scene(args.base)
    first = exps[0]
    if abs(scene.control_rate - first.rate) > 1e-9 * first.rate:
        raise ExperimentError(f"--base {args.base!r} runs at control.rate = {scene.control_rate:g} Hz; "
                              f"the logs were recorded at {first.rate:g} Hz")
    for name in ("accelerometer", "force", "potentiometer", "body1_displacement"):
        a, b = getattr(scene.effects.sensors, name), getattr(first.scene.effects.sensors, name)
        if (a.enabled, a.gain, a.adc_bits, a.adc_range) != (b.enabled, b.gain, b.adc_bits, b.adc_range):
            raise ExperimentError(f"--base {args.base!r} describes other sensors than the logs' "
                                  f"(effects.sensors.{name}: enabled, gain or ADC differ): calibrate "
                                  f"the scene the logs were recorded with")
    if not isinstance(args.base, str):
        raise ConfigError("--base must name a preset or a scene file")
    return scene, (args.base if args.base in PRESETS else str(Path(args.base).resolve()))


def run_identification(args, paths, out: Path, report_dir: Path) -> int:
    if args.ranges is not None and not 0 < args.ranges <= 10:
        raise ConfigError(f"--ranges {args.ranges!r} must be > 0 and <= 10 standard uncertainties")
    exps = load(paths)
    base, ref = _base(args, exps)
    fit = identify(exps, base, progress=lambda s: print(f"identify: {s} ...", file=sys.stderr, flush=True))
    report_dir.mkdir(parents=True, exist_ok=True)
    if ref is None:  # the logs' own scene is no preset: keep it beside the calibrated file
        base_file = out.with_name(out.stem + ".base.toml")
        base_file.write_text(fit.base_toml)
        ref = base_file.name
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(report.scene_text(fit, ref, args.ranges))

    load_scene(out)  # what was written loads (and validates)
    data = report.to_json(fit)
    (report_dir / "identification.json").write_text(json.dumps(data, indent=1) + "\n")
    figs = report.plot(fit, exps, report_dir, args.format)
    (report_dir / "report.md").write_text(report.markdown(fit, str(out)) + "\n" + "".join(
        f"![{f.stem}]({f.name})\n\n" for f in figs))
    if args.json:
        print(json.dumps(data, indent=1))
    else:
        print(report.markdown(fit, str(out)))
        print(f"wrote {out}, {report_dir / 'report.md'}, {report_dir / 'identification.json'} and "
              f"{', '.join(f.name for f in figs)}")
    return 0


def cmd_identify(args) -> int:
    out = Path(args.out)
    _check_out(out, args.force)
    report = Path(args.report) if args.report else out.with_name(out.stem + "-report")
    return run_identification(args, args.logs, out, report)


def cmd_rig_identify(args) -> int:
    """Run the identification plan on the target at --rig, then fit (unless --no-fit)."""

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {str(out)!r} is a file; give a folder "
                          "(logs, the scene file and the report go in it)")
    if out.exists() and any(out.iterdir()) and not args.force:
        raise ConfigError(f"--out {str(out)!r} exists and is not empty; give --force to add to it")
    if args.drops is not None and not 2 <= args.drops <= 100:
        raise ConfigError(f"--drops {args.drops} must be 2 to 100 (the fit needs two at least)")
    plan = default_plan(quick=args.quick, drops=args.drops)
    client = RigClient(args.rig, key=args.key)
    try:
        files = run_plan(client, out / "logs", plan, seed=args.seed)
    finally:
        client.close()
    print(f"identify: {len(files)} episode logs in {out / 'logs'}", file=sys.stderr)
    if args.no_fit:
        return 0
    scene_file = out / "identified.toml"
    _check_out(scene_file, True)
    return run_identification(args, [out / "logs"], scene_file, out)
