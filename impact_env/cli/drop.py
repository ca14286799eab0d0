"""``impact-env drop``, ``scenes`` and ``scene show``: one uncontrolled drop, and the scenes."""

from __future__ import annotations

import json
import math
import sys
from typing import Any

from impact_env.cli.args import (
    add_format_argument,
    add_scene_arguments,
    output_figure_file,
    parse_overrides,
    scene_from_args,
)
from impact_env.config import ConfigError, to_dict
from impact_env.eval.plots import plot_trajectory
from impact_env.scene.presets import PRESETS
from impact_env.sim.drop import SimulationDiverged, simulate


def add_drop_arguments(p) -> None:
    """``drop``'s arguments on its subparser (:data:`impact_env.cli.main.COMMANDS`)."""
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


def add_scenes_arguments(p) -> None:
    """``scenes``'s arguments."""
    add_scene_arguments(p, scene=False)
    p.set_defaults(func=cmd_scenes)


def add_scene_tools(p) -> None:
    """``scene``'s subcommands (show)."""
    ssub = p.add_subparsers(dest="scene_command", required=True)
    q = ssub.add_parser("show", help="print a scene as TOML")
    add_scene_arguments(q, positional=True)
    q.set_defaults(func=cmd_scene_show)


def cmd_drop(args) -> int:
    scene = scene_from_args(args)
    plot = output_figure_file(args.plot, args.format, "--plot") if args.plot else None  # before simulating
    record_rate = args.record_rate
    if args.seed is not None and args.seed < 0:
        raise ConfigError(f"--seed {args.seed} must be an integer >= 0")
    if args.t_end is not None and args.t_end > 0 and math.isfinite(args.t_end):
        rate = record_rate or scene.control_rate
        n = round(args.t_end * rate)
        if n >= 1 and abs(n / rate - args.t_end) > 1e-9 * args.t_end:
            # simulate() runs whole record periods: say so rather than report another span silently
            print(f"impact-env drop: --t-end {args.t_end:g} s is not a whole number of record periods "
                  f"(1/{rate:g} s): simulating {n / rate:g} s ({n} records; --record-rate sets the grid)",
                  file=sys.stderr)
    drawn = None
    if args.seed is not None and scene.randomized:
        import numpy as np

        drawn = scene.draw(np.random.default_rng(args.seed))
        scene = scene.with_draws(drawn)
    if scene.effects.active:
        # the drop command shows the plant's physics; the effects need a policy and run in compare
        print(f"impact-env drop: scene {scene.name!r}: the bare plant, without its effects "
              f"{list(scene.effects.active)} (impact-env compare runs them)", file=sys.stderr)
    try:
        traj = simulate(scene, t_end=args.t_end, record_rate=record_rate, plant_only=True)
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
            if k == "warnings":
                continue
            if isinstance(v, dict):
                v = ", ".join(f"{name} {x:.6g}" for name, x in v.items())
                print(f"  {k:28s} {v}")
            else:
                print(f"  {k:28s} {v if v is None else f'{v:.6g}'}")
        for w in m["warnings"]:
            print(f"  warning: {w}")
    if plot is not None:
        plot_trajectory(traj, str(plot))
        if not args.json:
            print(f"  plot written to {plot}")
    return 0


def cmd_scenes(args) -> int:
    """List the presets; with ``--set``, every preset with the overrides applied (each must
    accept them) and the overridden values shown."""

    ov = parse_overrides(args.set)
    for name in PRESETS:
        scene = scene_from_args(args, scene=name)
        line = f"{name:16s} {scene.description}"
        if ov:
            flat = to_dict(scene)
            shown = []
            for key in ov:
                v: Any = flat
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
