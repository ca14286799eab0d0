"""``impact-env sweep``: the command line of :mod:`impact_env.eval.sweep`."""

from __future__ import annotations

import json

from impact_env.cli.args import (
    add_format_argument,
    add_scene_arguments,
    add_workers_arguments,
    cluster_from_args,
    output_dir,
    scene_from_args,
)
from impact_env.config import ConfigError
from impact_env.eval.sweep import DEFAULT_AXES, parse_grid, plot, sweep, write_csv
from impact_env.policy.registry import parse_spec


# -- command line ------------------------------------------------------------------------------------
def add_arguments(p) -> None:
    """``sweep``'s arguments on its subparser (:data:`impact_env.cli.main.COMMANDS`)."""
    add_scene_arguments(p, default="rig")
    p.add_argument("--policy", default="thesis-rig",
                   help="baseline whose gains are swept (default thesis-rig)")
    p.add_argument("--h01", metavar="LO:HI:N", help="grid of h01, 1/s^2 (thesis-rig default 1e5:5e6:20)")
    p.add_argument("--h11", metavar="LO:HI:N", help="grid of h11, 1/s (thesis-rig default 1:1000:20)")
    p.add_argument("--grid", action="append", metavar="NAME=LO:HI:N",
                   help="grid of any parameter of the policy (two axes in all, with --h01/--h11)")
    p.add_argument("--fixed", metavar="K=V,...", default="",
                   help="other parameters of the policy, e.g. dref=6e-5")
    p.add_argument("--log", action="store_true", help="geometric grids instead of linear")
    p.add_argument("--t-end", type=float, default=0.02,
                   help="simulated time per pair, s (default 0.02: the first contact)")
    p.add_argument("--limit", choices=("none", "scene"), default="none",
                   help="none (default, as the thesis): no saturation, pairs marked against the scene's "
                        "limit; scene: the scene's force limits act")
    p.add_argument("--objective", default="exit_speed_ratio", help="metric the best pair minimises")
    p.add_argument("--seed", type=int, default=0, help="seed of the drop (the same for every pair)")
    add_workers_arguments(p)
    p.add_argument("--out", metavar="DIR", default=".",
                   help="where sweep.csv and sweep.FORMAT go (default .)")
    add_format_argument(p, what="the plot's")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.set_defaults(func=cmd_sweep)


def axes_from_args(args) -> tuple:
    items = []
    if args.h01:
        items.append(("h01", args.h01))
    if args.h11:
        items.append(("h11", args.h11))
    for g in args.grid or []:
        name, sep, spec = g.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"--grid expects NAME=LO:HI:N, got {g!r}")
        items.append((name.strip(), spec.strip()))
    if not items and args.policy in DEFAULT_AXES:
        items = list(DEFAULT_AXES[args.policy])
    elif len(items) == 1 and args.policy in DEFAULT_AXES:
        items += [ax for ax in DEFAULT_AXES[args.policy] if ax[0] != items[0][0]][:1]
    if len(items) != 2:
        raise ValueError(f"sweep needs exactly two grid axes (got {len(items)}): give --h01 and --h11, "
                         "or --grid NAME=LO:HI:N twice")
    return tuple((name, parse_grid(name, spec, args.log)) for name, spec in items)


def cmd_sweep(args) -> int:
    cluster = cluster_from_args(args)
    scene = scene_from_args(args)
    out = output_dir(args.out)  # checked before anything runs
    axes = axes_from_args(args)
    _, fixed = parse_spec(f"{args.policy}:{args.fixed}") if args.fixed else (None, {})
    if args.seed < 0:
        raise ConfigError(f"--seed {args.seed} must be an integer >= 0")
    res = sweep(scene, args.policy, axes, fixed, seed=args.seed, t_end=args.t_end, limit=args.limit,
                objective=args.objective, workers=args.workers, progress=not (args.no_progress or args.json),
                cluster=cluster)
    csv_path = write_csv(res, out / "sweep.csv")
    png_path = plot(res, out / f"sweep.{args.format}", args.log)
    if args.json:
        print(json.dumps(res.to_json()))
        return 0
    print(f"scene {scene.name}: {res.policy}, {len(res.x)} x {len(res.y)} pairs of "
          f"({res.x_name}, {res.y_name}), "
          f"{res.t_end:g} s each, force {'unlimited' if res.limit == 'none' else 'limited by the scene'}; "
          f"{int(res.within_limit.sum())} pairs peak within {res.force_limit_N:g} N; {res.wall_time_s:.1f} s")
    if res.best is None:
        print(f"  no pair stays within {res.force_limit_N:g} N")
    else:
        b = res.best
        print(f"  best within the limit: {res.x_name} = {b[res.x_name]:.4g}, "
              f"{res.y_name} = {b[res.y_name]:.4g}: exit speed {b['exit_speed_ratio']:.3f} of the impact "
              f"speed, peak force {b['peak_force_N']:.1f} N, "
              f"{res.objective} = {b[res.objective]:.4g}")
    for f in res.failures[:10]:
        print(f"  failed: {res.x_name}={f[res.x_name]:.4g}, {res.y_name}={f[res.y_name]:.4g} at "
              f"t = {f['t_s']:.4g} s: {f['error']}")
    print(f"written: {csv_path}, {png_path}")
    return 0
