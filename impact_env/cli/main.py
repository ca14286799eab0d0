"""Command line: ``impact-env drop | scenes | scene show | compare | benchmark | sweep | export | rig |
identify | robustness``.

Every command takes ``--set KEY=VALUE`` (repeatable) through
:func:`impact_env.cli.args.add_scene_arguments` and builds its scene with
:func:`impact_env.cli.args.scene_from_args`; new commands should use the same two helpers, and
a line in :data:`COMMANDS`.

Bad input (unknown scene, key or method, a value out of range) prints one line naming the
parameter to stderr and exits with code 2, before anything is simulated.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from impact_env import __version__
from impact_env.config import ConfigError

DESCRIPTION = ("Catching a falling body with a shaker: simulate drops, compare control policies on the same "
               "seeded drops, export a policy, run it on a rig.")
EPILOG = """examples:
  impact-env compare --scene rig --policies passive,thesis-rig,pd-penetration,thesis-ideal \\
      --episodes 100 --seed 5000000 --out results
                                                 README's main job: a table, CSV/JSON and plots
  impact-env compare --list                      the named policies and their parameters
  impact-env benchmark pd-penetration --out bench
                                                 a policy on the frozen suite catch-v1 (a record)
  impact-env drop --scene rig --plot drop.png    one uncontrolled drop, summarised and plotted
  impact-env scenes                              the preset scenes
  impact-env scene show rig                      a scene as TOML (a scene file: base = "rig" + changes)
  impact-env export pd-penetration --out pd.policy.json
                                                 a compiled policy (compare --policies compiled:FILE)
  impact-env rig serve --virtual --port 5600     a virtual rig's target (compare --rig udp://...)
  impact-env COMMAND --help                      a command's options

The first run compiles the numba kernels (a progress line on stderr; cached afterwards).
Docs: README.md and docs/ in the source tree (baselines.md: compare, sweep and the policies;
scenes.md: scenes and --set; env.md: the Gymnasium env; rig/: the rig; plant.md: the model)."""


#: every command: name -> (the function that adds its arguments, as "module:function", its one-line
#: help).  A command's module is imported only when that command is parsed: the modules import
#: their machinery (numba, scipy, the rig) at their top, and ``impact-env --help`` and
#: ``--version`` import none of it.
COMMANDS = {
    "drop": ("impact_env.cli.drop:add_drop_arguments", "simulate one uncontrolled drop and summarise it"),
    "scenes": ("impact_env.cli.drop:add_scenes_arguments",
               "list the preset scenes (with --set: each with the overrides applied)"),
    "scene": ("impact_env.cli.drop:add_scene_tools", "scene tools"),
    "compare": ("impact_env.cli.compare:add_arguments",
                "run policies on the same seeded drops and tabulate catch metrics"),
    "benchmark": ("impact_env.cli.benchmark:add_arguments",
                  "run policies on a frozen suite of held-out drops and keep a record (score, intervals, "
                  "profile)"),
    "sweep": ("impact_env.cli.sweep:add_arguments",
              "sweep a baseline's two gains over a grid (thesis fig 4.4)"),
    "export": ("impact_env.cli.export:add_arguments",
               "write a policy as a compiled policy file (runs without Python; optionally also ONNX)"),
    "rig": ("impact_env.cli.rig:add_arguments", "the rig: serve a target (real or virtual), make a session "
            "key, run the identification plan, summarise an episode log (serve | keygen | identify | log)"),
    "identify": ("impact_env.cli.identify:add_arguments",
                 "calibrate a scene to a rig from its identification logs (offline)"),
    "robustness": ("impact_env.cli.robustness:add_arguments", "map where each policy breaks as the rig's "
                   "hardware departs from the scene (energy integral, catch time, peak force, saturation)"),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The command line's parser, with the arguments of ``command`` (the others by name and help
    only: their modules stay unimported)."""
    ap = argparse.ArgumentParser(prog="impact-env", description=DESCRIPTION, epilog=EPILOG,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--version", action="version", version=f"impact-env {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    for name, (where, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == command:
            module, _, function = where.partition(":")
            getattr(importlib.import_module(module), function)(p)
    return ap


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    command = next((a for a in argv if not a.startswith("-")), None)
    ap = build_parser(command)
    args = ap.parse_args(argv)
    try:
        return args.func(args)
    except (ConfigError, ValueError) as exc:
        print(f"impact-env {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
