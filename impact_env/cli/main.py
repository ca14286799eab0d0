"""Command line: ``impact-env drop | scenes | scene show | compare | sweep | export | rig | identify |
robustness``.

Every command takes ``--set KEY=VALUE`` (repeatable) through :func:`add_scene_arguments` and
builds its scene with :func:`scene_from_args`; new commands should use the same two helpers.

Bad input (unknown scene, key or method, a value out of range) prints one line naming the
parameter to stderr and exits with code 2, before anything is simulated.
"""

from __future__ import annotations

import argparse
import sys

from impact_env.cli import compare, export, identify, rig, robustness, sweep
from impact_env.cli.args import add_format_argument, add_scene_arguments
from impact_env.cli.drop import cmd_drop, cmd_scene_show, cmd_scenes
from impact_env.config import ConfigError

DESCRIPTION = ("Catching a falling body with a shaker: simulate drops, compare control policies on the same "
               "seeded drops, export a policy, run it on a rig.")
EPILOG = """examples:
  impact-env compare --scene rig --policies passive,thesis-rig,pd-penetration,thesis-ideal \\
      --episodes 100 --seed 0 --out results      README's main job: a table, CSV/JSON and plots
  impact-env compare --list                      the named policies and their parameters
  impact-env drop --scene rig --plot drop.png    one uncontrolled drop, summarised and plotted
  impact-env scenes                              the preset scenes
  impact-env scene show rig                      a scene as TOML (a scene file: base = "rig" + changes)
  impact-env export pd-penetration --out pd.policy.json
                                                 a compiled policy (compare --policies compiled:FILE)
  impact-env rig serve --virtual --port 5600     a virtual rig's target (compare --rig udp://...)
  impact-env COMMAND --help                      a command's options

The first run compiles the numba kernels (a progress line on stderr; cached afterwards).
Docs: README.md and docs/ in the source tree (baselines.md: compare, sweep and the policies;
scenes.md: scenes and --set; env.md: the Gymnasium env; rig.md: the rig; plant.md: the model)."""


def build_parser() -> argparse.ArgumentParser:
    from impact_env import __version__

    ap = argparse.ArgumentParser(prog="impact-env", description=DESCRIPTION, epilog=EPILOG,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--version", action="version", version=f"impact-env {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)

    p = sub.add_parser("drop", help="simulate one uncontrolled drop and summarise it")
    add_scene_arguments(p, default_text="ideal, the thesis's ch. 3 drop without the rig's effects; "
                                        "compare, sweep and the envs default to rig")
    p.add_argument("--seed", type=int, default=None,
                   help="for a scene with [randomize] ranges: draw this drop's values with this seed "
                        "(default: the scene's nominal values); the JSON lists them under 'drawn'")
    p.add_argument("--method", help="split (default: exact free flight, dopri5 in contact) | euler | "
                                    "symplectic-euler | rk4 | dopri5")
    p.add_argument("--dt", type=float, help="fixed step, s")
    p.add_argument("--rtol", type=float, help="dopri5 relative tolerance")
    p.add_argument("--t-end", type=float, default=None, help="simulated time, s (default: episode.horizon)")
    p.add_argument("--record-rate", type=float, default=None,
                   help="samples per second (default: control.rate)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plot", metavar="FILE.png", help="write positions, velocities, forces and energies "
                                                      "(the suffix picks png, pdf or svg)")
    add_format_argument(p, default=None, what="--plot's")
    p.set_defaults(func=cmd_drop)

    p = sub.add_parser("scenes", help="list the preset scenes (with --set: each with the overrides applied)")
    add_scene_arguments(p, scene=False)
    p.set_defaults(func=cmd_scenes)

    p = sub.add_parser("scene", help="scene tools")
    ssub = p.add_subparsers(dest="scene_command", required=True)
    q = ssub.add_parser("show", help="print a scene as TOML")
    add_scene_arguments(q, positional=True)
    q.set_defaults(func=cmd_scene_show)

    compare.add_parser(sub, lambda p: add_scene_arguments(  # None: rig, or with --rig the rig's own
        p, default=None, default_text="rig; with --rig, the simulation beside it only when given"))
    sweep.add_parser(sub, lambda p: add_scene_arguments(p, default="rig"))
    export.add_parser(sub, lambda p: add_scene_arguments(p, default="rig"))
    rig.add_parser(sub, lambda p: add_scene_arguments(p, default="rig"))
    identify.add_parser(sub)
    robustness.add_parser(sub, lambda p: add_scene_arguments(p, default="rig"))
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
