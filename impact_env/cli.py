"""Command line: ``impact-env drop | scenes | scene show``.

Bad input (unknown scene, key or method, a value out of range) prints one line naming the
parameter to stderr and exits with code 2, before anything is simulated.
"""

from __future__ import annotations

import argparse
import json
import sys

from impact_env.config import ConfigError


def _overrides(pairs: list[str] | None) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in pairs or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set expects KEY=VALUE (e.g. plant.m1=0.05), got {item!r}")
        out[key.strip()] = value.strip()
    return out


def _scene_from_args(args):
    from impact_env.scene import load_scene

    ov = _overrides(args.set)
    if getattr(args, "method", None):
        ov["integrator.method"] = args.method
    if getattr(args, "dt", None) is not None:
        ov["integrator.dt"] = str(args.dt)
    if getattr(args, "rtol", None) is not None:
        ov["integrator.rtol"] = str(args.rtol)
    return load_scene(args.scene, ov)


def cmd_drop(args) -> int:
    from impact_env.simulate import SimulationDiverged, simulate

    scene = _scene_from_args(args)
    record_rate = args.record_rate
    try:
        traj = simulate(scene, t_end=args.t_end, record_rate=record_rate)
    except SimulationDiverged as exc:
        print(f"impact-env drop: {exc}", file=sys.stderr)
        return 3
    m = traj.metrics()
    if args.json:
        print(json.dumps(m))
    else:
        print(f"scene {scene.name}: m1 {scene.plant.m1:g} kg, m2 {scene.plant.m2:g} kg, c {scene.plant.c:g} N/m^1.5, "
              f"impact speed {scene.impact_speed:g} m/s, {scene.integrator.method}")
        for k, v in m.items():
            print(f"  {k:28s} {v if v is None else f'{v:.6g}'}")
    if args.plot:
        from impact_env.plots import plot_trajectory

        plot_trajectory(traj, args.plot)
        if not args.json:
            print(f"  plot written to {args.plot}")
    return 0


def cmd_scenes(_args) -> int:
    from impact_env.presets import PRESETS

    for name, fn in PRESETS.items():
        print(f"{name:16s} {fn().description}")
    return 0


def cmd_scene_show(args) -> int:
    scene = _scene_from_args(args)
    print(scene.to_toml(), end="")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="impact-env", description="Catching a falling body with a shaker.")
    sub = ap.add_subparsers(dest="command", required=True)

    def scene_args(p, positional=False):
        if positional:
            p.add_argument("scene", help="preset name or path to a scene .toml")
        else:
            p.add_argument("--scene", default="ideal", help="preset name or path to a scene .toml (default: ideal)")
        p.add_argument("--set", action="append", metavar="KEY=VALUE",
                       help="override a scene field, e.g. --set plant.m1=0.05 (repeatable)")

    p = sub.add_parser("drop", help="simulate one uncontrolled drop and summarise it")
    scene_args(p)
    p.add_argument("--method", help="euler | symplectic-euler | rk4 | dopri5")
    p.add_argument("--dt", type=float, help="fixed step, s")
    p.add_argument("--rtol", type=float, help="dopri5 relative tolerance")
    p.add_argument("--t-end", type=float, default=None, help="simulated time, s (default: episode.horizon)")
    p.add_argument("--record-rate", type=float, default=None, help="samples per second (default: control.rate)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plot", metavar="FILE.png", help="write positions, velocities, forces and energies")
    p.set_defaults(func=cmd_drop)

    p = sub.add_parser("scenes", help="list the preset scenes")
    p.set_defaults(func=cmd_scenes)

    p = sub.add_parser("scene", help="scene tools")
    ssub = p.add_subparsers(dest="scene_command", required=True)
    q = ssub.add_parser("show", help="print a scene as TOML")
    scene_args(q, positional=True)
    q.set_defaults(func=cmd_scene_show)
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    try:
        return args.func(args)
    except (ConfigError, ValueError) as exc:
        print(f"impact-env {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
