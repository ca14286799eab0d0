"""Command line: ``impact-env drop | scenes | scene show | compare | sweep``.

Every command takes ``--set KEY=VALUE`` (repeatable) through :func:`add_scene_arguments` and
builds its scene with :func:`scene_from_args`; new commands should use the same two helpers.

Bad input (unknown scene, key or method, a value out of range) prints one line naming the
parameter to stderr and exits with code 2, before anything is simulated.
"""

from __future__ import annotations

import argparse
import json
import sys

from impact_env.config import ConfigError


def parse_overrides(pairs: list[str] | None) -> dict[str, str]:
    """``["a.b=1", ...]`` (the ``--set`` values) -> ``{"a.b": "1"}``; values are parsed as TOML
    when the scene is built.  ConfigError on an item without ``=``."""
    out: dict[str, str] = {}
    for item in pairs or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set expects KEY=VALUE (e.g. plant.m1=0.05), got {item!r}")
        out[key.strip()] = value.strip()
    return out


def add_scene_arguments(p: argparse.ArgumentParser, positional: bool = False, default: str | None = "ideal",
                        scene: bool = True) -> None:
    """Give a (sub)command the shared scene options: the scene (``--scene NAME|FILE.toml``, or a
    positional ``scene`` with ``positional=True``) and the repeatable ``--set KEY=VALUE``.
    Every command that builds a scene uses this and :func:`scene_from_args`, so ``--set`` works
    the same way everywhere.  ``scene=False`` adds ``--set`` only (commands over many scenes)."""
    if scene:
        if positional:
            p.add_argument("scene", help="preset name or path to a scene .toml")
        else:
            p.add_argument("--scene", default=default,
                           help=f"preset name or path to a scene .toml (default: {default})")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", default=[],
                   help="override a scene field, e.g. --set plant.m1=0.05 (repeatable; values are TOML, "
                        "e.g. --set 'randomize.m1=[0.08, 0.12]')")


def scene_from_args(args, scene: str | None = None):
    """The scene named by ``args.scene`` (or ``scene``) with ``args.set`` and the integrator
    options (``--method``, ``--dt``, ``--rtol``, where the command has them) applied."""
    from impact_env.scene import load_scene

    ov = parse_overrides(getattr(args, "set", None))
    if getattr(args, "method", None):
        ov["integrator.method"] = args.method
    if getattr(args, "dt", None) is not None:
        ov["integrator.dt"] = str(args.dt)
    if getattr(args, "rtol", None) is not None:
        ov["integrator.rtol"] = str(args.rtol)
    return load_scene(scene if scene is not None else args.scene, ov)


def cmd_drop(args) -> int:
    from impact_env.simulate import SimulationDiverged, simulate

    scene = scene_from_args(args)
    record_rate = args.record_rate
    drawn = None
    if args.seed is not None and scene.randomized:
        import numpy as np

        drawn = scene.draw(np.random.default_rng(args.seed))
        scene = scene.with_draws(drawn)
    try:
        traj = simulate(scene, t_end=args.t_end, record_rate=record_rate)
    except SimulationDiverged as exc:
        print(f"impact-env drop: {exc}", file=sys.stderr)
        return 3
    m = traj.metrics()
    if drawn is not None:
        m["drawn"] = drawn
    if args.json:
        print(json.dumps(m))
    else:
        print(f"scene {scene.name}: m1 {scene.plant.m1:g} kg, m2 {scene.plant.m2:g} kg, "
              f"c {scene.plant.c:g} N/m^1.5, impact speed {scene.impact_speed:g} m/s, "
              f"{scene.integrator.method}")
        for k, v in m.items():
            if isinstance(v, dict):
                v = ", ".join(f"{name} {x:.6g}" for name, x in v.items())
                print(f"  {k:28s} {v}")
            else:
                print(f"  {k:28s} {v if v is None else f'{v:.6g}'}")
    if args.plot:
        from impact_env.plots import plot_trajectory

        plot_trajectory(traj, args.plot)
        if not args.json:
            print(f"  plot written to {args.plot}")
    return 0


def cmd_scenes(args) -> int:
    """List the presets; with ``--set``, every preset with the overrides applied (each must
    accept them) and the overridden values shown."""
    from impact_env.config import to_dict
    from impact_env.presets import PRESETS

    ov = parse_overrides(args.set)
    for name in PRESETS:
        scene = scene_from_args(args, scene=name)
        line = f"{name:16s} {scene.description}"
        if ov:
            flat = to_dict(scene)
            shown = []
            for key in ov:
                v = flat
                for part in key.split("."):
                    v = v.get(part) if isinstance(v, dict) else None
                shown.append(f"{key}={v!r}" if not isinstance(v, dict) else f"{key}=(table)")
            line += "  [" + ", ".join(shown) + "]"
        print(line)
    return 0


def cmd_scene_show(args) -> int:
    scene = scene_from_args(args)
    print(scene.to_toml(), end="")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="impact-env", description="Catching a falling body with a shaker.")
    sub = ap.add_subparsers(dest="command", required=True)

    p = sub.add_parser("drop", help="simulate one uncontrolled drop and summarise it")
    add_scene_arguments(p)
    p.add_argument("--seed", type=int, default=None,
                   help="for a scene with [randomize] ranges: draw this drop's values with this seed "
                        "(default: the scene's nominal values); the JSON lists them under 'drawn'")
    p.add_argument("--method", help="euler | symplectic-euler | rk4 | dopri5")
    p.add_argument("--dt", type=float, help="fixed step, s")
    p.add_argument("--rtol", type=float, help="dopri5 relative tolerance")
    p.add_argument("--t-end", type=float, default=None, help="simulated time, s (default: episode.horizon)")
    p.add_argument("--record-rate", type=float, default=None,
                   help="samples per second (default: control.rate)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plot", metavar="FILE.png", help="write positions, velocities, forces and energies")
    p.set_defaults(func=cmd_drop)

    p = sub.add_parser("scenes", help="list the preset scenes (with --set: each with the overrides applied)")
    add_scene_arguments(p, scene=False)
    p.set_defaults(func=cmd_scenes)

    p = sub.add_parser("scene", help="scene tools")
    ssub = p.add_subparsers(dest="scene_command", required=True)
    q = ssub.add_parser("show", help="print a scene as TOML")
    add_scene_arguments(q, positional=True)
    q.set_defaults(func=cmd_scene_show)

    # policies and gains (impact_env.compare / impact_env.sweep import baselines only when run)
    from impact_env import compare, sweep

    compare.add_parser(sub, lambda p: add_scene_arguments(p, default="rig"))
    sweep.add_parser(sub, lambda p: add_scene_arguments(p, default="rig"))
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
