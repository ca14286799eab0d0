"""``impact-env benchmark``: the command line of :mod:`impact_env.eval.benchmark`."""

from __future__ import annotations

import shlex
import sys

from impact_env.cli.args import add_format_argument, add_workers_arguments, output_dir
from impact_env.config import ConfigError
from impact_env.eval.benchmark import format_overall, run_benchmark, write_record
from impact_env.eval.compare import split_policies
from impact_env.eval.suite import SUITES, get_suite


def add_arguments(p) -> None:
    """``benchmark``'s arguments on its subparser (:data:`impact_env.cli.main.COMMANDS`)."""
    p.add_argument("policies", nargs="*", metavar="POLICY",
                   help="policy specs, as compare's --policies (several per argument, comma-separated; "
                        "passive, the suite's reference and the cached oracle are always added)")
    p.add_argument("--suite", default="catch-v1", choices=sorted(SUITES),
                   help="the frozen suite of held-out drops (default catch-v1; docs/benchmark.md)")
    p.add_argument("--out", metavar="DIR", default="benchmark",
                   help="write <suite>.json (the record) and <suite>_profile.png here (default ./benchmark)")
    p.add_argument("--drops", type=int, default=None,
                   help="only the first N drops of each set: a quick look, not a record the leaderboard "
                        "takes")
    p.add_argument("--oracle-cache", metavar="DIR", default=None,
                   help="the oracle's cache folder (default $IMPACT_ENV_CACHE, else ~/.cache/impact_env)")
    add_workers_arguments(p)
    add_format_argument(p, what="the profile plot's")
    p.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")
    p.set_defaults(func=cmd_benchmark)


def cmd_benchmark(args) -> int:
    suite = get_suite(args.suite)
    specs = [s for text in args.policies for s in split_policies(text)]
    if args.drops is not None and args.drops < 1:
        raise ConfigError(f"--drops {args.drops} must be an integer >= 1 (drops per set)")
    if getattr(args, "cluster", None):
        raise ConfigError("--cluster: the benchmark runs on local processes (use --workers)")
    out = output_dir(args.out)
    on_cli = sys.argv[1:2] == ["benchmark"]
    command = " ".join(shlex.quote(w) for w in ["impact-env", *sys.argv[1:]]) if on_cli else None
    record = run_benchmark(specs, suite, workers=args.workers, progress=not args.no_progress,
                           oracle_cache=args.oracle_cache, command=command, drops=args.drops)
    meta = record["meta"]
    n = sum(s["drops"] for s in record["sets"].values())
    print(f"suite {suite.name} (version {suite.version}): {len(record['sets'])} sets, {n} drops, "
          f"{len(record['overall'])} policies in {meta['wall_time_s']:.1f} s"
          + (f" (of which {meta['oracle_search_s']:.1f} s searching {meta['oracle_drops_searched']} "
             "oracle drops)" if meta["oracle_drops_searched"] else ""))
    print("* score: 100 (passive - policy) / (passive - oracle) per drop on the energy integral, mean over "
          "every drop (0 = passive, 100 = the per-drop oracle); 95 % stratified bootstrap intervals")
    print(format_overall(record))
    for name, s in record["sets"].items():
        for spec, why in s["left_out"].items():
            print(f"impact-env benchmark: {spec!r} left out of set {name!r}: {why}", file=sys.stderr)
    paths = write_record(record, out, fmt=args.format)
    print("written: " + ", ".join(str(p) for p in paths))
    return 0
