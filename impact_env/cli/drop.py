"""``impact-env drop``, ``scenes`` and ``scene show``: one uncontrolled drop, and the scenes."""

from __future__ import annotations

import json
import math
import sys
from typing import Any

from impact_env.cli.args import output_figure_file, parse_overrides, scene_from_args


def cmd_drop(args) -> int:
    from impact_env.sim.drop import SimulationDiverged, simulate

    scene = scene_from_args(args)
    plot = output_figure_file(args.plot, args.format, "--plot") if args.plot else None  # before simulating
    record_rate = args.record_rate
    if args.seed is not None and args.seed < 0:
        from impact_env.config import ConfigError

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
        from impact_env.eval.plots import plot_trajectory

        plot_trajectory(traj, str(plot))
        if not args.json:
            print(f"  plot written to {plot}")
    return 0


def cmd_scenes(args) -> int:
    """List the presets; with ``--set``, every preset with the overrides applied (each must
    accept them) and the overridden values shown."""
    from impact_env.config import to_dict
    from impact_env.scene.presets import PRESETS

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
