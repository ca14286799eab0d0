"""``impact-env compare``: policies side by side on the same seeded drops.

Every policy runs the same episodes: episode ``j`` is seeded ``seed + j`` (as env ``j`` of the
vector env reset with ``seed``), so drops and sensor noise are identical across policies and
across runs.  Episodes of a policy run batched (:func:`impact_env.eval.rollout.rollout`); policies
(and chunks of episodes, when there are more cores than policies) run in parallel processes.
Results are merged in episode order, so the table does not depend on the number of workers.
With ``cluster`` (``--cluster tcp://SCHEDULER:PORT``) the same tasks run on a Dask cluster's
workers instead (:mod:`impact_env.eval.parallel`), with the same results.

Policies are named policies (``passive``, ``thesis-rig:h01=2.3e6,h11=18``: the classic laws of
:mod:`baselines`, found through :mod:`impact_env.policy.registry`) or saved stable-baselines3
models (``PATH.zip``, ``ppo:PATH.zip``).

Aggregates (one row per policy; per-episode values in ``episodes.csv``):

* ``time_to_catch_median_s``, ``time_to_catch_q25_s``, ``time_to_catch_q75_s``,
  ``time_to_catch_iqr_s``: over episodes, an episode not caught within the horizon counting as
  infinitely long (so a median of ``inf``, printed as ``>H``, written as null in summary.json and
  as an empty cell in summary.csv, means that half the episodes or more were not caught);
  ``caught_fraction``.
* the means over episodes of every other per-episode metric of :mod:`impact_env.eval.rollout`
  (``residual_energy_50ms``, ``exit_speed_ratio``, ``bounces``, ``peak_force_N``, ...).
* ``episodes``, ``failed_episodes``, ``failures`` (episode, seed, time, error), ``wall_time_s``.

The oracle (:mod:`impact_env.eval.oracle`; a policy class with ``is_oracle = True``).  When one is
listed, the other policies run first and record the commands they issue on every episode; the
oracle runs after them, its episodes spread over all workers, and gets those commands as warm
starts (so no policy of the comparison can beat it on any drop).  Every row then has
``gap_to_oracle_ms``: the median over episodes of the policy's energy integral minus the
oracle's on the same episode (and ``gap_to_oracle_min_ms``, the smallest, which is >= 0), and the
oracle's row ``oracle_improvement_ms`` (median over drops of its gain on its best warm start)
and ``oracle_seconds_per_drop`` (mean CPU time of its optimisation per drop, one core each).

Statistics (:mod:`impact_env.eval.scores`; the primary score is the energy integral): every
row has its mean's 95 % bootstrap interval (``energy_integral_ms_ci95``, and ``<metric>_ci95``
for every other metric), the IQM with its interval, and with ``reference`` (a policy of the
comparison, added to it when absent) the paired difference and the probability of improvement
against it, each with its interval; the bootstrap's generator is seeded from ``seed``.

The cached oracle (``oracle="compute"`` or ``"auto"``, :mod:`impact_env.eval.oracle_cache`):
its per-drop commands, searched once per drop without the comparison's warm starts and kept on
disk, are replayed as the row ``oracle`` (``passive`` is added when absent), and every row gets
``score``, the oracle-normalised score (0 = passive, 100 = the oracle), with its interval.
``"auto"`` uses the cache when it holds every drop; ``"compute"`` searches the drops it lacks
first.  A listed ``oracle`` policy (warm-started by the comparison) serves as the ceiling instead.

Limits: ``workers`` must be >= 1, and a request whose memory or time is out of proportion is
refused before anything runs, with an estimate (:mod:`impact_env.eval.limits`).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from impact_env._threads import check_threads
from impact_env.config import ConfigError
from impact_env.eval.compare_plots import plot_catch_time, plot_energy, plot_force, plot_motion
from impact_env.eval.limits import check_cost, estimate, is_small
from impact_env.eval.oracle_cache import OracleCache
from impact_env.eval.parallel import prepare, report, run_tasks, session
from impact_env.eval.rollout import EPISODE_METRICS, rollout
from impact_env.eval.scores import PRIMARY, comparison_statistics, interval_text
from impact_env.policy.registry import (
    REGISTERED,
    check_spec,
    entry_point_policies,
    is_model_spec,
    make_policy,
    parse_spec,
    policy_class,
)
from impact_env.scene import load_scene

if TYPE_CHECKING:
    from impact_env.eval.parallel import Cluster
    from impact_env.scene import Scene

SUMMARY_KEYS = ("time_to_catch_median_s", "time_to_catch_q25_s", "time_to_catch_q75_s", "time_to_catch_iqr_s",
                "caught_fraction", "residual_vibration_mps", "residual_energy_10ms", "residual_energy_50ms",
                "residual_energy_100ms", "exit_speed_ratio", "exit_velocity_ratio", "bounces", "peak_force_N",
                "rms_force_N", "peak_demand_N", "energy_integral_ms", "energy_integral_ticks_ms",
                "contact_fraction", "saturation_time_s", "impact_speed_mps")
ENERGY_CURVE_RATE = 2000.0  # Hz, samples of the catch-energy curves kept for every episode
ORACLE_KEYS = ("gap_to_oracle_ms", "gap_to_oracle_min_ms", "oracle_improvement_ms", "oracle_seconds_per_drop")
ORACLE_ROW = "oracle"  # the cached oracle's row (and the name of the oracle policy)
ORACLE_MODES = ("off", "auto", "compute")
# summary.csv's statistics columns (an interval as two columns, _low and _high)
STAT_KEYS = (f"{PRIMARY}_ci95", f"{PRIMARY}_iqm", f"{PRIMARY}_iqm_ci95", f"{PRIMARY}_diff",
             f"{PRIMARY}_diff_ci95", "prob_improvement", "prob_improvement_ci95", "score", "score_ci95",
             "score_iqm", "score_iqm_ci95",
             "caught_fraction_ci95", "time_to_catch_median_s_ci95")


# -- policy lists ---------------------------------------------------------------------------------
def split_policies(text: str) -> list[str]:
    """``"passive,thesis-rig:h01=2.3e6,h11=18,pd-penetration"`` -> three specs.

    Items are separated by commas (or semicolons); an item ``KEY=VALUE`` without a ``:`` continues
    the previous policy's parameters."""
    specs: list[str] = []
    for item in (s.strip() for s in text.replace(";", ",").split(",")):
        if not item:
            continue
        if "=" in item and ":" not in item and specs:
            last = specs[-1]
            specs[-1] = last + ("" if last.endswith(":") else "," if ":" in last else ":") + item
        else:
            specs.append(item)
    return specs


# -- one job: a chunk of one policy's episodes (a process pool's unit of work) ----------------
@dataclass
class RolloutJob:
    spec: str
    scene: Scene
    episodes: list[int]
    seed: int
    horizon: float
    trace_rate: float
    record: bool = False  # keep the commands (an oracle is in the comparison)
    warm_starts: dict | None = None  # other policies' commands on these episodes (for an oracle)
    threads: int | str = 1  # the rollout's threads (rollout(threads=...); "auto"), in the worker that runs it
    open_loop: Any = None  # float64[n_steps, len(episodes)]: replay these commands (the cached oracle)


@dataclass
class PolicyRun:
    """One policy's merged results: per-episode metrics (float64[E] each), failures, the traces
    of the first episode (for the plots) and the catch-energy ratio of every episode."""

    spec: str
    episodes: Any  # int64[E]
    metrics: dict
    failures: list
    trace_t: Any
    trace0: dict | None
    t_touch0: float
    impact_energy0: float
    energy_t: Any
    energy_ratio: Any  # float64[T, E]
    control_period: float
    wall_time_s: float = 0.0
    summary: dict = field(default_factory=dict)
    commands: Any = None  # float64[n_steps, E] when recorded
    stats: dict = field(default_factory=dict)  # a prepared policy's per-episode figures (the oracle's)


def run_job(task: RolloutJob):
    """One job's episodes (in a worker): the rollout's results as plain data, or the error that
    kept its policy from being built."""
    seeds = [task.seed + j for j in task.episodes]
    try:
        if task.open_loop is not None:
            from impact_env.eval.oracle import Replay

            policy = Replay(task.open_loop)
        else:
            policy = make_policy(task.spec, task.scene)
    except Exception as exc:  # a policy that cannot be built fails its episodes, not the run
        n_steps = int(round(task.horizon / task.scene.control_period))
        report(n_steps)
        return {"error": f"{type(exc).__name__}: {exc}", "episodes": task.episodes, "seeds": seeds}
    # the plots need episode 0's traces and every episode's energy: only those are kept
    keep0 = 0 in task.episodes
    r = rollout(task.scene, policy, seeds, horizon=task.horizon, episodes=task.episodes,
                trace_rate=task.trace_rate, name=task.spec, progress=report,
                warm_starts=task.warm_starts, record_commands=task.record, threads=task.threads,
                trace_rows=[list(task.episodes).index(0)] if keep0 else [])
    stride = max(1, int(round(task.trace_rate / ENERGY_CURVE_RATE)))
    ratio = r.energy_trace[::stride] / r.impact_energy[None, :]
    return {"metrics": r.metrics, "failures": r.failures, "trace_t": r.trace_t,
            "trace0": {k: v[:, 0].copy() for k, v in r.traces.items()} if keep0 else None,
            "t_touch0": float(r.t_touch[0]), "impact_energy0": float(r.impact_energy[0]),
            "energy_t": r.trace_t[::stride], "energy_ratio": ratio.astype(np.float32),
            "control_period": r.control_period, "wall_time_s": r.wall_time_s, "episodes": task.episodes,
            "commands": r.extras.get("commands"), "stats": r.extras.get("policy_stats")}


# -- the comparison --------------------------------------------------------------------------------
def compare(scene, specs: list[str], episodes: int = 100, seed: int = 0, horizon: float | None = None,
            workers: int | None = None, progress: bool = True,
            trace_rate: float = 1.0e4, cluster: str | Cluster | None = None,
            threads: int | str | None = None, reference: str | None = None, oracle: str = "off",
            oracle_cache: str | Path | None = None, oracle_params: dict | None = None,
            allow_long: bool = False) -> dict[str, PolicyRun]:
    """Run every policy spec on ``episodes`` seeded drops of ``scene``; returns spec -> PolicyRun
    (with ``summary`` filled in).  Policies are validated before anything runs.

    ``reference``: the policy the paired statistics are taken against (added when not listed;
    None: none).  ``oracle``: "off", "auto" (the cached oracle's row and the score when the
    cache holds every drop) or "compute" (search the drops it lacks first); ``oracle_cache``:
    the cache's root folder (:mod:`impact_env.eval.oracle_cache`), ``oracle_params`` the cached
    oracle's budget (default: the oracle's defaults).  ``allow_long``: run a request
    estimated above a day (:mod:`impact_env.eval.limits`).

    ``cluster``: a Dask scheduler's ``tcp://HOST:PORT`` (or a connected
    :class:`~impact_env.eval.parallel.Cluster`) runs the tasks on its workers instead of local
    processes, with the same results; ``workers`` then defaults to the cluster's worker threads.

    ``threads``: each task's rollout runs its episodes in this many threads
    (:func:`~impact_env.eval.rollout.rollout`; None: 1; ``"auto"``: the CPUs the worker may use,
    one per few episodes at most); the results do not depend on it,
    bitwise.  The workers already fill the cores, so it pays with ``workers=1`` (one process,
    its episodes over the cores, no fork) or fewer workers than cores."""

    threads = check_threads(threads)
    scene = load_scene(scene)
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes = {episodes!r} must be an integer >= 1")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed = {seed!r} must be an integer >= 0")
    horizon = scene.episode.horizon if horizon is None else float(horizon)
    if not (horizon > 0 and math.isfinite(horizon)):
        raise ValueError(f"horizon = {horizon!r} s must be a finite time > 0 s")
    if not specs:
        raise ValueError("no policy given (e.g. --policies passive,thesis-rig)")
    if len(set(specs)) != len(specs):
        raise ValueError(f"policy listed twice: {specs}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers = {workers!r} must be an integer >= 1 (processes; the default: the "
                         "available cores)")
    if oracle not in ORACLE_MODES:
        raise ValueError(f"oracle = {oracle!r} must be one of {', '.join(ORACLE_MODES)}")
    specs = list(specs)
    listed_oracle = any(_is_oracle(s) for s in specs if not is_model_spec(s))
    if oracle == "compute" and listed_oracle:
        raise ConfigError("--oracle replays the cached oracle as the row 'oracle'; the listed oracle policy "
                          "already gives the score's ceiling: give one of the two")
    if reference is not None and reference not in specs:
        specs.append(reference)
    check_specs(specs, scene)
    if cluster is not None:
        check_cluster_specs(specs)
    seeds = [seed + j for j in range(episodes)]
    cache = None
    if oracle != "off" and not listed_oracle:
        cache = OracleCache.of(scene, horizon, oracle_params, root=oracle_cache)
        if oracle == "auto" and cache.missing(seeds):
            cache = None
    n_rows = len(specs) + (cache is not None) + (cache is not None and "passive" not in specs)
    with session(cluster, workers) as (cl, workers):
        if not is_small(scene, horizon, episodes, n_rows):
            check_cost(estimate(scene, horizon, episodes, n_rows, workers, trace_rate, ENERGY_CURVE_RATE,
                                record_commands=listed_oracle),
                       f"{n_rows} policies x {episodes} episodes of {horizon:g} s", allow_long)
        commands, cache_stats = None, None
        if cache is not None:
            if "passive" not in specs:
                specs.insert(0, "passive")
            cache.fill(seeds, workers=workers, progress=progress, cluster=cl)
            commands, cache_stats = cache.load(seeds)
            specs.append(ORACLE_ROW)
        runs = _compare(scene, specs, episodes, seed, horizon, workers, progress, trace_rate, cl, threads,
                        oracle_commands=commands)
    if cache_stats is not None:
        add_oracle_gaps(runs, ORACLE_ROW)
        runs[ORACLE_ROW].summary["oracle_seconds_per_drop"] = float(np.mean(cache_stats["cpu_seconds"]))
        runs[ORACLE_ROW].summary["oracle_improvement_ms"] = float(np.median(cache_stats["improvement_ms"]))
    add_statistics(runs, seed, reference)
    return runs


def add_statistics(runs: dict[str, PolicyRun], seed: int, reference: str | None) -> None:
    """Every row's statistics (:mod:`impact_env.eval.scores`) into its summary: intervals, IQM,
    against ``reference``, and the score when the comparison has ``passive`` and an oracle."""
    ceiling = next((s for s in runs if s == ORACLE_ROW or (not is_model_spec(s) and _is_oracle(s))), None)
    floor = "passive" if "passive" in runs else None
    stats = comparison_statistics({s: r.metrics for s, r in runs.items()}, seed=seed, reference=reference,
                                  passive=floor, oracle=ceiling)
    for spec, run in runs.items():
        run.summary.update(stats[spec])


def _compare(scene, specs, episodes, seed, horizon, workers, progress, trace_rate,
             cl, threads=1, oracle_commands=None) -> dict[str, PolicyRun]:

    replayed = ORACLE_ROW if oracle_commands is not None else None  # the cached oracle: a replay
    oracles = [s for s in specs if s != replayed and _is_oracle(s)]
    others = [s for s in specs if s not in oracles]
    # chunks of episodes so that every worker has work; results do not depend on the chunking
    per_policy = max(1, math.ceil(workers / max(len(others), 1))) if workers > 1 else 1
    tasks = [RolloutJob(spec, scene, chunk, seed, horizon, trace_rate, record=bool(oracles), threads=threads,
                        open_loop=oracle_commands[:, chunk[0]:chunk[-1] + 1] if spec == replayed else None)
             for spec in others for chunk in split_episodes(episodes, per_policy)]
    prepare(warm_up, scene, horizon, workers=workers, cluster=cl)
    n_steps = int(round(horizon / scene.control_period))
    t0 = time.perf_counter()
    outs = run_tasks(run_job, tasks, workers, total=n_steps * len(tasks),
                     desc=f"compare ({len(others)} policies x {episodes} episodes)",
                     progress=progress, cluster=cl) if tasks else []
    runs = {}
    for spec in others:
        runs[spec] = merge_runs(spec, [o for t, o in zip(tasks, outs, strict=True) if t.spec == spec], scene)
    if oracles:  # after the others, with their commands as warm starts, over every worker
        warm = {spec: run.commands for spec, run in runs.items() if run.commands is not None}
        tasks = [RolloutJob(spec, scene, chunk, seed, horizon, trace_rate,
                      warm_starts={k: u[:, chunk[0]:chunk[-1] + 1] for k, u in warm.items()},
                      threads=threads)
                 for spec in oracles for chunk in split_episodes(episodes, workers)]
        outs = run_tasks(run_job, tasks, workers, total=n_steps * len(tasks),
                         desc=f"compare: oracle optimising {episodes} drops", progress=progress, cluster=cl)
        for spec in oracles:
            parts = [o for t, o in zip(tasks, outs, strict=True) if t.spec == spec]
            runs[spec] = merge_runs(spec, parts, scene)
    wall = time.perf_counter() - t0
    runs = {spec: runs[spec] for spec in specs}
    for run in runs.values():
        run.summary = summarize(run)
        run.summary["wall_time_total_s"] = wall
    if oracles:
        add_oracle_gaps(runs, oracles[0])
    return runs


def split_episodes(episodes: int, parts: int) -> list[list[int]]:
    """Episodes ``0 .. episodes - 1`` in ``parts`` consecutive runs of near-equal length (the jobs)."""
    parts = max(1, min(parts, episodes))
    bounds = np.linspace(0, episodes, parts + 1).round().astype(int)
    return [list(range(bounds[c], bounds[c + 1])) for c in range(parts)]


def _is_oracle(spec: str) -> bool:
    if is_model_spec(spec) or spec.startswith("compiled:"):
        return False
    return bool(getattr(policy_class(parse_spec(spec)[0]), "is_oracle", False))


def add_oracle_gaps(runs: dict[str, PolicyRun], oracle: str) -> None:
    """Every run's ``gap_to_oracle_ms`` (median over episodes of its energy integral minus the
    oracle's) and ``gap_to_oracle_min_ms``; the oracle's improvement on its warm starts and time."""
    ref = runs[oracle].metrics["energy_integral_ms"]
    for run in runs.values():
        gap = run.metrics["energy_integral_ms"] - ref
        gap = gap[np.isfinite(gap)]
        run.summary["gap_to_oracle_ms"] = float(np.median(gap)) if gap.size else math.nan
        run.summary["gap_to_oracle_min_ms"] = float(np.min(gap)) if gap.size else math.nan
    for run in runs.values():
        st = run.stats
        if st:
            run.summary["oracle_improvement_ms"] = float(np.nanmedian(st["improvement_ms"]))
            run.summary["oracle_seconds_per_drop"] = float(np.nanmean(st["cpu_seconds"]))


def check_cluster_specs(specs, option: str = "--cluster") -> None:
    """What a cluster's workers cannot find: a policy registered in this process only
    (:func:`~impact_env.policy.registry.register_policy`; workers find policies through installed
    entry points) and a model or compiled file given by a relative path (workers run elsewhere:
    give absolute paths on a disk every worker sees).  ConfigError naming ``option``."""
    from pathlib import PurePath

    for spec in specs:
        if spec.startswith("compiled:") or is_model_spec(spec):
            compiled = spec.startswith("compiled:")
            head = spec.partition(":")[2] if compiled else spec.partition(".zip")[0] + ".zip"
            _algo, colon, rest = head.partition(":")
            path = rest if colon and not compiled else head  # ALGO:PATH.zip
            if not PurePath(path).is_absolute():
                raise ConfigError(f"{option}: policy {spec!r} names the file {path!r} by a relative path; "
                                  "the cluster's workers do not share this directory: give an absolute path "
                                  "on a disk every worker sees")
        else:
            name = parse_spec(spec)[0]
            if name in REGISTERED and name not in entry_point_policies():
                raise ConfigError(f"{option}: policy {name!r} is registered in this process only "
                                  "(register_policy); the cluster's workers find policies through installed "
                                  "entry points ([project.entry-points.\"impact_env.policies\"])")


def check_specs(specs, scene) -> None:
    """Every spec validated on ``scene`` before any job starts (ConfigError naming the bad one)."""
    for spec in specs:
        check_spec(spec, scene)  # a model's syntax and file only: loading waits for the worker


def warm_up(scene, horizon) -> None:
    """Compile (or load) the kernels once in the parent, so that forked workers inherit them.
    Two episodes, not one: a column of a one-row array is contiguous, of a wider one not, and
    numba compiles a kernel for each layout (each worker compiled the trace kernel again)."""

    rollout(scene, make_policy("passive", scene), [0, 1], horizon=2 * scene.control_period, trace_rate=0.0)


def merge_runs(spec, parts, scene) -> PolicyRun:
    """One policy's run from its jobs' results (:func:`run_job`), in episode order."""
    episodes = np.concatenate([np.asarray(p["episodes"], dtype=np.int64) for p in parts])
    metrics: dict = {}
    failures: list = []
    ratio_blocks = []
    energy_t = None
    trace_t, trace0, t_touch0, e00 = None, None, float("nan"), float("nan")
    wall = 0.0
    period = scene.control_period
    for p in parts:
        if "error" in p:
            n = len(p["episodes"])
            for key in EPISODE_METRICS:
                metrics.setdefault(key, []).append(np.full(n, np.nan))
            pairs = enumerate(zip(p["episodes"], p["seeds"], strict=True))
            failures += [{"policy": spec, "episode": int(j), "seed": int(s), "row": i, "t_s": 0.0,
                          "error": p["error"]} for i, (j, s) in pairs]
            continue
        for key in EPISODE_METRICS:
            metrics.setdefault(key, []).append(p["metrics"][key])
        failures += p["failures"]
        ratio_blocks.append(p["energy_ratio"])
        energy_t = p["energy_t"]
        trace_t = p["trace_t"]
        wall += p["wall_time_s"]
        period = p["control_period"]
        if p["trace0"] is not None:
            trace0, t_touch0, e00 = p["trace0"], p["t_touch0"], p["impact_energy0"]
    metrics = {k: np.concatenate(v) for k, v in metrics.items()}
    ratio = np.concatenate(ratio_blocks, axis=1) if ratio_blocks else None
    commands = None
    if parts and all(p.get("commands") is not None for p in parts):
        commands = np.concatenate([p["commands"] for p in parts], axis=1)
    stats: dict = {}
    if parts and all(p.get("stats") for p in parts):
        for key in parts[0]["stats"]:
            stats[key] = np.concatenate([np.asarray(p["stats"][key]) for p in parts])
    return PolicyRun(spec=spec, episodes=episodes, metrics=metrics, failures=failures, trace_t=trace_t,
                     trace0=trace0, t_touch0=t_touch0, impact_energy0=e00, energy_t=energy_t,
                     energy_ratio=ratio, control_period=period, wall_time_s=wall, commands=commands,
                     stats=stats)


def summarize(run: PolicyRun) -> dict:
    """The table's numbers for one policy (see the module doc)."""
    m = run.metrics
    ok = ~np.isnan(m["time_to_catch_s"])
    out: dict = {"episodes": int(len(run.episodes)), "failed_episodes": int((~ok).sum())}
    ttc = m["time_to_catch_s"][ok]
    if ttc.size:
        # not caught = inf; interpolating with inf gives NaN, so a huge stand-in is mapped back
        big = np.where(np.isinf(ttc), 1e300, ttc)
        q25, q50, q75 = (float(x) if x < 1e299 else math.inf for x in np.quantile(big, [0.25, 0.5, 0.75]))
        out.update(time_to_catch_median_s=q50, time_to_catch_q25_s=q25, time_to_catch_q75_s=q75,
                   time_to_catch_iqr_s=q75 - q25 if math.isfinite(q75) else math.inf,
                   caught_fraction=float(np.mean(np.isfinite(ttc))))
    else:
        keys = ("time_to_catch_median_s", "time_to_catch_q25_s", "time_to_catch_q75_s", "time_to_catch_iqr_s",
                "caught_fraction")
        out.update(dict.fromkeys(keys, math.nan))
    for key, v in m.items():
        if key.startswith("time_to_catch"):  # (times with inf: the quantiles above, not a mean)
            continue
        vals = v[ok & ~np.isnan(v)]
        out[key] = float(np.mean(vals)) if vals.size else math.nan
    out["wall_time_s"] = run.wall_time_s
    out["failures"] = run.failures
    return out


# -- output -----------------------------------------------------------------------------------------
def _fmt_time(x: float, horizon: float) -> str:
    if math.isnan(x):
        return "n/a"
    return f">{horizon:g}" if math.isinf(x) else f"{x:.3f}"


def format_table(runs: dict[str, PolicyRun], horizon: float) -> str:
    cols = ("policy", "catch s: median (IQR)", "caught", "vib mm/s", "E 10ms", "E 50ms", "E 100ms",
            "int E ms*", "exit v/v0", "bounces", "peak N", "RMS N", "contact", "sat ms", "failed")
    gaps = any("gap_to_oracle_ms" in run.summary for run in runs.values())
    if gaps:
        cols = (*cols[:8], "gap to oracle", *cols[8:])  # type: ignore[assignment]  # one more column
    rows = []
    for spec, run in runs.items():
        s = run.summary
        iqr = s["time_to_catch_iqr_s"]
        iqr_s = "inf" if math.isinf(iqr) else ("n/a" if math.isnan(iqr) else f"{iqr:.3f}")
        rows.append((spec, f"{_fmt_time(s['time_to_catch_median_s'], horizon)} ({iqr_s})",
                     f"{s['caught_fraction']:.0%}" if not math.isnan(s["caught_fraction"]) else "n/a",
                     f"{1e3 * s['residual_vibration_mps']:.2f}",
                     *(f"{s[k]:.4f}" for k in ("residual_energy_10ms", "residual_energy_50ms",
                                               "residual_energy_100ms")),
                     f"{s['energy_integral_ms']:.2f}",
                     *((f"{s.get('gap_to_oracle_ms', math.nan):.2f}",) if gaps else ()),
                     f"{s['exit_speed_ratio']:.3f}", f"{s['bounces']:.1f}",
                     f"{s['peak_force_N']:.1f}",
                     f"{s['rms_force_N']:.1f}", f"{s['contact_fraction']:.3f}",
                     f"{1e3 * s['saturation_time_s']:.2f}", f"{s['failed_episodes']}/{s['episodes']}"))
    return _columns(cols, rows)


def _columns(cols, rows) -> str:
    widths = [max(len(c), *(len(r[i]) for r in rows)) for i, c in enumerate(cols)]
    line = lambda r: "  ".join(x.ljust(w) if i == 0 else x.rjust(w)  # noqa: E731
                               for i, (x, w) in enumerate(zip(r, widths, strict=True)))
    return "\n".join([line(cols), line(tuple("-" * w for w in widths))] + [line(r) for r in rows])


def format_statistics(runs: dict[str, PolicyRun]) -> str:
    """The primary score's table: per policy its mean and IQM with 95 % bootstrap intervals, the
    oracle-normalised score (when the oracle's values are available) and, against the reference,
    the paired difference and the probability of improvement (:mod:`impact_env.eval.scores`)."""
    first = next(iter(runs.values())).summary
    reference = first.get("reference")
    scored = any(run.summary.get("score") is not None for run in runs.values())
    cols = ["policy", "int E ms* [95 % CI]", "IQM [95 % CI]"]
    if scored:
        cols.append("score [95 % CI]")
    if reference is not None:
        cols += [f"- {reference} [95 % CI]", f"P(better than {reference}) [95 % CI]"]
    rows = []
    for spec, run in runs.items():
        s = run.summary
        row = [spec + (" (reference)" if spec == reference else ""),
               interval_text(s.get(PRIMARY), s.get(f"{PRIMARY}_ci95")),
               interval_text(s.get(f"{PRIMARY}_iqm"), s.get(f"{PRIMARY}_iqm_ci95"))]
        if scored:
            row.append(interval_text(s.get("score"), s.get("score_ci95"), "{:.1f}"))
        if reference is not None:
            row += [interval_text(s.get(f"{PRIMARY}_diff"), s.get(f"{PRIMARY}_diff_ci95"), "{:+.2f}"),
                    interval_text(s.get("prob_improvement"), s.get("prob_improvement_ci95"))]
        rows.append(tuple(row))
    return _columns(tuple(cols), rows)


def statistics_legend(runs: dict[str, PolicyRun]) -> str:
    """The lines that say what :func:`format_statistics` shows."""
    first = next(iter(runs.values())).summary
    lines = ["* primary score: the energy integral (ms, lower is better); intervals: 95 % percentile "
             "bootstrap over the drops, paired (the same resampled drops for every policy)"]
    if any(run.summary.get("score") is not None for run in runs.values()):
        lines.append("score: 100 (passive - policy) / (passive - oracle) per drop, mean over drops "
                     "(0 = passive, 100 = the per-drop oracle)")
    if first.get("reference") is not None:
        lines.append(f"- {first['reference']}: mean over drops of the policy's energy integral minus the "
                     f"reference's; P(better): the share of drops on which it is lower (ties count half)")
    return "\n".join(lines)


def _json_value(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, list):
        return [_json_value(x) for x in v]
    return v


def _csv_value(v):
    """summary.csv's cell: an empty one where summary.json has null (a non-finite number)."""
    if isinstance(v, float) and not math.isfinite(v):
        return ""
    return "" if v is None else v


def summary_json(runs: dict[str, PolicyRun]) -> dict:
    """{policy: {metric: value}} with non-finite numbers as null."""
    out = {}
    for spec, run in runs.items():
        d = {}
        for k, v in run.summary.items():
            d[k] = [dict(f) for f in v] if k == "failures" else _json_value(v)
        out[spec] = d
    return out


def write_outputs(runs: dict[str, PolicyRun], out_dir: Path, scene, seed: int, horizon: float,
                  fmt: str = "png") -> list[Path]:
    """summary.csv, summary.json, episodes.csv and the plots (``fmt``: png, pdf or svg) into
    ``out_dir``; returns the paths."""
    import csv

    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    p = out_dir / "summary.csv"
    with open(p, "w", newline="") as fh:
        w = csv.writer(fh)
        keys = ["episodes", "failed_episodes", *SUMMARY_KEYS, "wall_time_s"]
        keys += [k for k in (*ORACLE_KEYS, *STAT_KEYS) if any(k in run.summary for run in runs.values())]
        header = [c for k in keys for c in ((f"{k}_low", f"{k}_high") if k.endswith("_ci95") else (k,))]
        w.writerow(["policy", *header, "reference"])
        for spec, run in runs.items():
            cells = []
            for k in keys:
                v = run.summary.get(k)
                pair = k.endswith("_ci95")
                cells += [_csv_value(x) for x in (v or [None, None])] if pair else [_csv_value(v)]
            w.writerow([spec, *cells, _csv_value(run.summary.get("reference"))])
    paths.append(p)
    p = out_dir / "summary.json"
    p.write_text(json.dumps({"scene": scene.name, "seed": seed, "horizon_s": horizon, "primary": PRIMARY,
                             "policies": summary_json(runs)}, indent=2))
    paths.append(p)
    p = out_dir / "episodes.csv"
    with open(p, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["policy", "episode", "seed", *EPISODE_METRICS])
        for spec, run in runs.items():
            for i, j in enumerate(run.episodes):
                w.writerow([spec, int(j), seed + int(j),
                            *(float(run.metrics[k][i]) for k in EPISODE_METRICS)])
    paths.append(p)
    paths.append(plot_energy(runs, out_dir / f"energy.{fmt}", scene))
    paths.append(plot_force(runs, out_dir / f"force.{fmt}", scene))
    paths.append(plot_motion(runs, out_dir / f"motion.{fmt}", scene))
    paths.append(plot_catch_time(runs, out_dir / f"catch_time.{fmt}", scene, horizon))
    return paths
