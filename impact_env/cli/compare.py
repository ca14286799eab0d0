"""``impact-env compare``: the command line of :mod:`impact_env.eval.compare`."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from impact_env.cli.args import (
    add_format_argument,
    add_scene_arguments,
    add_workers_arguments,
    cluster_from_args,
    output_dir,
    scene_from_args,
)
from impact_env.config import ConfigError
from impact_env.eval import rig_compare  # (called through the module: the rig tests stand in for it)
from impact_env.eval.compare import (
    compare,
    format_statistics,
    format_table,
    split_policies,
    statistics_legend,
    summary_json,
    write_outputs,
)
from impact_env.policy.export import export_policy
from impact_env.policy.registry import describe_policies, is_model_spec
from impact_env.rig import protocol
from impact_env.rig.auth import KeyFileError, load_key
from impact_env.rig.transport import RigError


# -- command line -------------------------------------------------------------------------------------
def add_arguments(p) -> None:
    """``compare``'s arguments on its subparser (:data:`impact_env.cli.main.COMMANDS`)."""
    add_scene_arguments(  # None: rig, or with --rig the rig's own
        p, default=None, default_text="rig; with --rig, the simulation beside it only when given")
    p.add_argument("--policies", action="append", metavar="LIST",
                   help="comma-separated policy specs (default passive,thesis-rig,pd-penetration): the "
                        "classic laws passive, thesis-ideal, thesis-rig, pd-penetration (with parameters, "
                        "e.g. thesis-rig:h01=2.3e6,h11=18; --list shows them), oracle (the per-drop "
                        "open-loop optimum, CMA-ES: needs pip install 'impact-env[oracle]'), a saved SB3 "
                        "model (PATH.zip, ppo:PATH.zip) or a compiled policy file "
                        "(compiled:FILE.policy.json, from impact-env export); repeatable")
    p.add_argument("--episodes", type=int, default=100, help="episodes per policy (default 100)")
    add_statistics_arguments(p)
    p.add_argument("--seed", type=int, default=0, help="episode j is seeded seed + j (default 0)")
    p.add_argument("--horizon", type=float, default=None, help="episode length, s (default: episode.horizon)")
    add_workers_arguments(p)
    p.add_argument("--threads", type=_threads_arg, default=None, metavar="K|auto",
                   help="threads per worker process: each runs its episodes in this many threads at once "
                        "(default 1; 'auto': the CPUs this process may use; the same results, bitwise).  "
                        "The workers already fill the cores: use it with --workers 1 (or fewer workers "
                        "than cores)")
    p.add_argument("--out", metavar="DIR", help="write summary.csv/json, episodes.csv and plots here")
    p.add_argument("--json", action="store_true", help="print one JSON object keyed by policy")
    add_format_argument(p, what="with --out, the plots'")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.add_argument("--list", action="store_true", help="list the baselines and their parameters, then exit")
    p.add_argument("--rig", metavar="udp://HOST:PORT",
                   help="measure on the rig behind this target (impact-env rig serve): classic and compiled "
                        "policies onboard, SB3 models in host mode; with --scene too, the simulation "
                        "beside it")
    p.add_argument("--on-host", action="store_true",
                   help="with --rig: run every policy on this host, compiled (SB3 models exported as "
                        "impact-env export does), in host mode: one COMMAND per policy step, each "
                        "observation answered in compiled code (fast enough for hold 1 in real time)")
    p.add_argument("--key", metavar="FILE",
                   help="with --rig: the session key file the target was started with (rig serve --key FILE)")
    p.add_argument("--allow-overruns", action="store_true",
                   help="with --rig and --scene: report the sim-to-rig gap even when more than 1 %% of a "
                        "policy's ticks were skipped by overruns (by default that is refused: exit 1)")
    p.set_defaults(func=cmd_compare)


def add_statistics_arguments(p) -> None:
    """``--reference``, ``--oracle``/``--no-oracle``, ``--oracle-cache`` and ``--allow-long``
    (compare and benchmark)."""
    p.add_argument("--reference", default=None, metavar="SPEC",
                   help="the policy the paired difference and the probability of improvement are taken "
                        f"against (default {DEFAULT_REFERENCE} when listed; a reference named here is added "
                        "to the run when not listed; 'none': no paired statistics)")
    oracle = p.add_mutually_exclusive_group()
    oracle.add_argument("--oracle", action="store_const", const="compute", dest="oracle", default="auto",
                        help="search the per-drop oracle on the drops the cache lacks (CMA-ES, about 3 s of "
                             "CPU per drop; needs pip install 'impact-env[oracle]'), then report its row and "
                             "every row's oracle-normalised score (by default both appear when the cache "
                             "holds every drop)")
    oracle.add_argument("--no-oracle", action="store_const", const="off", dest="oracle",
                        help="neither search nor read the oracle's cache: no oracle row, no score")
    p.add_argument("--oracle-cache", metavar="DIR", default=None,
                   help="the oracle's cache folder (default $IMPACT_ENV_CACHE, else ~/.cache/impact_env)")
    p.add_argument("--allow-long", action="store_true",
                   help="run a request estimated to take more than a day (refused by default)")


DEFAULT_REFERENCE = "thesis-rig"


def _threads_arg(text: str) -> int | str:
    """``--threads``: an integer (checked by cmd_compare, which names it) or ``auto``."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither an integer nor 'auto'") from None


def cmd_compare(args) -> int:
    if args.list:
        print(describe_policies())
        return 0
    texts = args.policies or ["passive,thesis-rig,pd-penetration"]
    specs = [s for text in texts for s in split_policies(text)]
    out_dir = output_dir(args.out) if args.out else None  # checked before anything runs

    if args.key and not args.rig:
        raise ConfigError("--key FILE is the rig's session key: it goes with --rig udp://HOST:PORT")
    if args.on_host and not args.rig:
        raise ConfigError("--on-host runs the policies on this host against a rig: it goes with --rig "
                          "udp://HOST:PORT")
    if args.allow_overruns and not args.rig:
        raise ConfigError("--allow-overruns goes with --rig udp://HOST:PORT")
    if args.seed < 0:
        raise ConfigError(f"--seed {args.seed} must be an integer >= 0 (episode j is seeded seed + j)")
    if args.threads is not None and args.threads != "auto" and args.threads < 1:
        raise ConfigError(f"--threads {args.threads} must be an integer >= 1 or 'auto'")
    cluster = cluster_from_args(args)
    if args.rig:
        if cluster is not None:
            raise ConfigError("--cluster runs simulations; it does not go with --rig (the rig runs its own "
                              "episodes)")
        return _compare_rig(args, specs)
    scene = scene_from_args(args, scene=args.scene or "rig")
    reference = reference_from_args(args, specs)
    runs = compare(scene, specs, episodes=args.episodes, seed=args.seed, horizon=args.horizon,
                   workers=args.workers, progress=not args.no_progress and not args.json, cluster=cluster,
                   threads=args.threads, reference=reference, oracle=args.oracle,
                   oracle_cache=args.oracle_cache, allow_long=args.allow_long)
    horizon = scene.episode.horizon if args.horizon is None else args.horizon
    if args.json:
        print(json.dumps(summary_json(runs)))
    else:
        wall = next(iter(runs.values())).summary["wall_time_total_s"]
        print(f"scene {scene.name}: {args.episodes} episodes of {horizon:g} s, seed {args.seed} "
              f"(episode j seeded {args.seed} + j), impact speed {scene.impact_speed:.3g} m/s"
              f"{' (nominal; drawn per episode)' if scene.randomized else ''}, "
              f"{len(specs)} policies in {wall:.1f} s")
        print(statistics_legend(runs))
        print(format_statistics(runs))
        print()
        print("E: body 1's catch energy over its impact value (mean); exit v/v0: body 1's speed at the located "
              "separation over the impact speed (mean); catch: body 1 at rest on the pad (its energy relative to "
              "body 2 below 1 % of the impact value, no bounce after); vib: body 2's RMS speed, last 50 ms")
        print(format_table(runs, horizon))
    failures = [f for run in runs.values() for f in run.failures]
    for f in failures[:20]:
        print(f"impact-env compare: policy {f['policy']!r} failed in episode {f['episode']} "
              f"(seed {f['seed']}) "
              f"at t = {f['t_s']:.6g} s: {f['error']}", file=sys.stderr)
    if len(failures) > 20:
        print(f"impact-env compare: ... and {len(failures) - 20} more failed episodes", file=sys.stderr)
    if out_dir is not None:
        paths = write_outputs(runs, out_dir, scene, args.seed, horizon, fmt=args.format)
        if not args.json:
            print("written: " + ", ".join(str(p) for p in paths))
    return all_failed(runs)


def reference_from_args(args, specs) -> str | None:
    """``--reference``: None for 'none'; by default thesis-rig when it is listed (the rows are
    the ones asked for), else none; a reference named explicitly joins the run."""
    ref = args.reference
    if ref is None:
        return DEFAULT_REFERENCE if DEFAULT_REFERENCE in specs else None
    return None if ref.strip().lower() == "none" else ref


def all_failed(runs) -> int:
    """1 (and a line on stderr) when some policy failed in every episode: its row is no result."""
    dead = [spec for spec, run in runs.items() if run.episodes is not None and len(run.failures) > 0
            and len(run.failures) >= len(run.episodes)]
    for spec in dead:
        print(f"impact-env compare: policy {spec!r} failed in every episode: no result for it (exit 1)",
              file=sys.stderr)
    return 1 if dead else 0


def _compare_rig(args, specs) -> int:
    """``--rig``: the rig's table, and with ``--scene`` the simulation's and the gap."""
    import tempfile

    try:
        key = load_key(args.key, "--key") if args.key else None
    except KeyFileError as exc:
        raise ConfigError(str(exc)) from None

    try:
        progress = not args.no_progress and not args.json
        rig_scene, rig_runs = rig_compare.rig_compare(args.rig, specs, episodes=args.episodes, seed=args.seed,
                                          horizon=args.horizon, progress=progress, key=key,
                                          on_host=args.on_host)
    except RigError as exc:  # a key on one side only, or another: the refusal names the option, no traceback
        if exc.code == protocol.ErrorCode.UNAUTHENTICATED:
            raise ConfigError(str(exc)) from None
        raise
    horizon = rig_scene.episode.horizon if args.horizon is None else args.horizon
    sim_runs = None
    if args.scene:
        scene = scene_from_args(args)
        with tempfile.TemporaryDirectory() as tmp:  # classic laws as the compiled policies the rig ran
            sim_specs = {}
            for k, spec in enumerate(specs):
                if is_model_spec(spec) and not args.on_host:  # --on-host: the rig ran its export
                    sim_specs[spec] = spec
                else:
                    path = export_policy(spec, scene).save(Path(tmp) / f"p{k}.policy.json")
                    sim_specs[spec] = f"compiled:{path}"
            runs = compare(scene, list(sim_specs.values()), episodes=args.episodes, seed=args.seed,
                           horizon=args.horizon, workers=args.workers, threads=args.threads,
                           progress=not args.no_progress and not args.json)
        sim_runs = {spec: runs[s] for spec, s in sim_specs.items()}
        for spec, run in sim_runs.items():
            run.spec = spec
    overrun = {spec: f for spec, run in rig_runs.items()
               if (f := run.summary.get("skipped_tick_fraction")) is not None and f > MAX_SKIPPED_FRACTION}
    refuse = bool(overrun) and sim_runs is not None and not args.allow_overruns
    if args.json:
        out = {"rig": summary_json(rig_runs)}
        if sim_runs is not None and not refuse:
            out["sim"] = summary_json(sim_runs)
        print(json.dumps(out))
    else:
        print(f"rig at {args.rig} (scene {rig_scene.name}): {args.episodes} episodes of {horizon:g} s, "
              f"seed {args.seed}")
        print(format_table(rig_runs, horizon))
        print("skipped ticks (overruns: the loop a period or more behind, the command held): "
              + ", ".join(f"{spec} {_pct(run.summary.get('skipped_tick_fraction'))}"
                          for spec, run in rig_runs.items()))
    if refuse:
        print("impact-env compare --rig: no sim-to-rig gap: "
              + ", ".join(f"{spec!r} skipped {_pct(f)} of its ticks" for spec, f in overrun.items())
              + f" (more than {_pct(MAX_SKIPPED_FRACTION)}), so the rig's numbers are not the episodes the "
              "simulator ran; run the target in lock-step (rig serve --lockstep) or on an idle core, or pass "
              "--allow-overruns (exit 1)", file=sys.stderr)
    if not args.json:
        if sim_runs is not None and not refuse:
            print(f"\nsimulation (scene {scene.name}), the same seeds and policies:")
            print(format_table(sim_runs, horizon))
            print("\nsim-to-rig gap (rig minus simulation):")
            for spec in specs:
                a, b = rig_runs[spec].summary, sim_runs[spec].summary
                gaps = ", ".join(_gap(k, a.get(k), b.get(k))
                                 for k in ("time_to_catch_median_s", "energy_integral_ms", "exit_speed_ratio",
                                           "rms_force_N"))
                print(f"  {spec}: {gaps}")
    for run in rig_runs.values():
        for f in run.failures[:5]:
            print(f"impact-env compare --rig: policy {f['policy']!r} failed in episode {f['episode']} "
                  f"(seed {f['seed']}): {f['error']}", file=sys.stderr)
    if args.out:
        paths = write_outputs(rig_runs, Path(args.out), rig_scene, args.seed, horizon, fmt=args.format)
        if not args.json:
            print("written: " + ", ".join(str(p) for p in paths))
    return 1 if refuse else 0


# above this share of skipped ticks a rig's episodes are not the simulator's: no gap is reported
MAX_SKIPPED_FRACTION = 0.01


def _pct(f) -> str:
    import math

    return "n/a" if f is None or not math.isfinite(f) else f"{100 * f:.3g} %"


def _gap(key: str, rig, sim) -> str:
    import math

    if rig is None or sim is None or not (math.isfinite(rig) and math.isfinite(sim)):
        return f"{key} {'same' if rig == sim else 'n/a'}"
    return f"{key} {rig - sim:+.4g}"
