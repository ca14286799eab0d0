"""``impact-env robustness``: the command line of :mod:`impact_env.eval.robustness`."""

from __future__ import annotations

import sys

from impact_env.cli.args import (
    add_format_argument,
    add_scene_arguments,
    add_workers_arguments,
    cluster_from_args,
    output_dir,
    scene_from_args,
)
from impact_env.config import ConfigError
from impact_env.eval.compare import split_policies
from impact_env.eval.robustness import (
    format_table,
    identified_bands,
    parse_vary,
    robustness,
    write_outputs,
)


def add_arguments(p) -> None:
    """``robustness``'s arguments on its subparser (:data:`impact_env.cli.main.COMMANDS`)."""
    add_scene_arguments(p, default="rig")
    p.add_argument("--policies", required=True,
                   help="comma-separated policies, as compare takes them (e.g. pd-penetration,thesis-rig,"
                        "compiled:agents/models/best/best.policy.json)")
    p.add_argument("--vary", action="append", required=True, metavar="FIELD=LO:HI[:N]",
                   help="a [randomize] field moved over LO..HI in N points (default 7; geometric for "
                        "log-uniform fields, whole control periods for delays); once or twice, e.g. "
                        "--vary c=1e6:4e6:9 --vary sensor_delay_s=0:5e-4")
    p.add_argument("--identified", metavar="identification.json", default=None,
                   help="mark the identified values and their 95 %% bands (impact-env identify's output)")
    p.add_argument("--episodes", type=int, default=50, help="drops per grid point and policy (default 50)")
    p.add_argument("--seed", type=int, default=0, help="drop j is seeded seed + j (default 0)")
    add_workers_arguments(p)
    p.add_argument("--out", metavar="DIR", default="robustness",
                   help="where robustness.csv/.json and the figure go (default ./robustness)")
    add_format_argument(p, what="the figure's")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.set_defaults(func=cmd_robustness)


def cmd_robustness(args) -> int:
    if args.seed < 0:
        raise ConfigError(f"--seed {args.seed} must be >= 0")
    cluster = cluster_from_args(args)
    scene = scene_from_args(args)
    out = output_dir(args.out, "--out")
    axes = [parse_vary(v, scene.control_rate) for v in args.vary]
    bands = identified_bands(args.identified, scene) if args.identified else {}
    res = robustness(scene, split_policies(args.policies), axes, args.episodes, args.seed, args.workers,
                     progress=not args.no_progress, cluster=cluster)
    res.identified = bands
    files = write_outputs(res, out, args.format)
    print(format_table(res))
    print(f"{res.wall_s:.1f} s; wrote {', '.join(str(f) for f in files)}", file=sys.stderr)
    return 0
