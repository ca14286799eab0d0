"""``impact-env benchmark``: policies on a frozen suite of held-out drops, and the record it keeps.

For every drop set of the suite (:mod:`impact_env.eval.suite`) the policies run as
``compare`` runs them (:func:`impact_env.eval.compare.compare`: the same seeded drops for
every policy), together with ``passive`` (the score's floor), the suite's reference policy
(``thesis-rig``: the paired statistics) and the cached per-drop oracle (the score's ceiling;
its searches are made once per drop and kept, :mod:`impact_env.eval.oracle_cache`).  A policy
that cannot run on a set's scene (a channel it reads is missing) is left out of that set, and
the record says why.

The record (``<out>/<suite>.json``, :func:`run_benchmark`):

* ``suite``: the suite's definition (sets, scenes, overrides, seeds), its name and version;
* ``meta``: package versions, git commit (and whether the tree had changes), CPU, command line,
  date (UTC), wall time, and the oracle's cache (drops searched in this run, their time);
* ``sets``: per set, the seeds, the policies left out (and why) and per policy every metric per
  drop (``metrics``: name -> list over drops, null for a failed drop) and compare's summary
  (means, intervals, IQM, score, paired statistics against the reference);
* ``overall``: per policy, over every drop of the sets it ran, the statistics of
  :func:`impact_env.eval.scores.policy_statistics` with the stratified bootstrap (the sets are
  the strata): the score's mean and IQM, the probability of improvement on the reference, every
  metric's mean with its interval.

The plot (``<out>/<suite>_profile.png``): the performance profile of every policy, the share
of drops whose score exceeds a threshold, with 95 % stratified bootstrap bands
(:func:`impact_env.eval.benchmark_plots.plot_profiles`).
"""

from __future__ import annotations

import datetime
import json
import math
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from impact_env import __version__
from impact_env.config import ConfigError
from impact_env.eval.compare import ENERGY_CURVE_RATE, ORACLE_ROW, compare, summary_json
from impact_env.eval.oracle_cache import OracleCache
from impact_env.eval.scores import PRIMARY, normalized_score, policy_statistics
from impact_env.eval.suite import Suite, get_suite
from impact_env.policy.registry import check_spec

RECORD_VERSION = 1
PACKAGES = ("numpy", "scipy", "numba", "gymnasium", "stable-baselines3", "torch", "cma", "matplotlib")


def benchmark_specs(specs: list[str], suite: Suite) -> list[str]:
    """The policies a benchmark runs: ``passive`` and the suite's reference first, then the
    given ones (the oracle's row is added by compare)."""
    if ORACLE_ROW in specs:
        raise ConfigError("the oracle is always in a benchmark (cached per drop): do not list it")
    out = list(dict.fromkeys(["passive", suite.reference, *specs]))
    return out


def run_benchmark(specs: list[str], suite: str | Suite = "catch-v1", workers: int | None = None,
                  progress: bool = True, oracle_cache: str | Path | None = None, command: str | None = None,
                  drops: int | None = None) -> dict:
    """Run ``specs`` on every set of ``suite``; returns the record (module doc).  ``drops``:
    only the first ``drops`` drops of each set (a quick look; the record says so, and the
    leaderboard refuses it)."""
    suite = get_suite(suite) if isinstance(suite, str) else suite
    specs = benchmark_specs(specs, suite)
    t0 = time.perf_counter()
    sets: dict = {}
    oracle_searched, oracle_s = 0, 0.0
    for ds in suite.sets:
        scene = ds.build_scene()
        n = ds.drops if drops is None else min(int(drops), ds.drops)
        runnable, left_out = [], {}
        for spec in specs:
            try:
                check_spec(spec, scene)
            except (ConfigError, ValueError) as exc:
                left_out[spec] = str(exc)
                continue
            runnable.append(spec)
        if "passive" not in runnable:
            raise ConfigError(f"set {ds.name!r}: passive does not run on its scene: "
                              f"{left_out.get('passive')}")
        reference = suite.reference if suite.reference in runnable else None
        cache = OracleCache.of(scene, scene.episode.horizon, root=oracle_cache)
        missing = len(cache.missing(ds.seeds[:n]))
        t_set = time.perf_counter()
        if progress:
            print(f"benchmark {suite.name}: set {ds.name} ({n} drops of {scene.name}, seeds {ds.seed}.."
                  f"{ds.seed + n - 1}), {len(runnable)} policies"
                  + (f"; the oracle searches {missing} drops first (about 3 s of CPU each, cached afterwards)"
                     if missing else ""), file=sys.stderr)
        if missing:
            t_fill = time.perf_counter()
            cache.fill(ds.seeds[:n], workers=workers or _default_workers(), progress=progress)
            oracle_searched += missing
            oracle_s += time.perf_counter() - t_fill
        runs = compare(scene, runnable, episodes=n, seed=ds.seed, workers=workers, progress=progress,
                       trace_rate=ENERGY_CURVE_RATE, reference=reference, oracle="auto",
                       oracle_cache=oracle_cache)
        if ORACLE_ROW not in runs:  # pragma: no cover - the cache was just filled
            raise RuntimeError(f"set {ds.name!r}: the oracle's cache lacks drops after filling it")
        sets[ds.name] = {
            "seeds": [ds.seed, ds.seed + n - 1], "drops": n, "left_out": left_out, "reference": reference,
            "wall_time_s": time.perf_counter() - t_set,
            "policies": {spec: {"metrics": {k: _json_list(v) for k, v in run.metrics.items()},
                                "summary": summary_json({spec: run})[spec]}
                         for spec, run in runs.items()},
        }
    record = {"record_version": RECORD_VERSION, "suite": suite.describe(), "complete": drops is None,
              "primary": PRIMARY, "sets": sets}
    record["overall"] = overall_statistics(record)
    record["meta"] = run_meta(command, wall=time.perf_counter() - t0, oracle_searched=oracle_searched,
                              oracle_s=oracle_s)
    return record


def _default_workers() -> int:
    from impact_env.eval.parallel import default_workers

    return default_workers()


def _json_list(values) -> list:
    return [None if math.isnan(x) else float(x) for x in np.asarray(values, dtype=np.float64)]


def _array(values) -> np.ndarray:
    return np.array([np.nan if x is None else x for x in values], dtype=np.float64)


def per_drop(record: dict, spec: str, key: str = PRIMARY) -> tuple[np.ndarray, np.ndarray]:
    """(values, strata): ``spec``'s per-drop ``key`` over the sets it ran, and each drop's set index."""
    vals, strata = [], []
    for i, (_name, s) in enumerate(record["sets"].items()):
        if spec in s["policies"]:
            v = _array(s["policies"][spec]["metrics"][key])
            vals.append(v)
            strata.append(np.full(v.size, i))
    if not vals:
        return np.zeros(0), np.zeros(0, dtype=np.int64)
    return np.concatenate(vals), np.concatenate(strata)


def scores_per_drop(record: dict, spec: str) -> tuple[np.ndarray, np.ndarray]:
    """(scores, strata): ``spec``'s oracle-normalised score per drop over the sets it ran."""
    out, strata = [], []
    for i, s in enumerate(record["sets"].values()):
        pol = s["policies"]
        if spec in pol:
            x = _array(pol[spec]["metrics"][PRIMARY])
            sc = normalized_score(x, _array(pol["passive"]["metrics"][PRIMARY]),
                                  _array(pol[ORACLE_ROW]["metrics"][PRIMARY]))
            out.append(sc)
            strata.append(np.full(sc.size, i))
    if not out:
        return np.zeros(0), np.zeros(0, dtype=np.int64)
    return np.concatenate(out), np.concatenate(strata)


def overall_statistics(record: dict) -> dict:
    """Per policy: :func:`~impact_env.eval.scores.policy_statistics` over every drop of the sets
    it ran (the sets as strata), against the reference on the same drops."""
    sets = list(record["sets"].values())
    seed = record["suite"]["sets"][0]["seed"]
    specs = list(dict.fromkeys(spec for s in sets for spec in s["policies"]))
    reference = record["suite"]["reference"]
    out = {}
    for spec in specs:
        ran = [s for s in sets if spec in s["policies"]]
        keys = list(ran[0]["policies"][spec]["metrics"])
        metrics = {k: np.concatenate([_array(s["policies"][spec]["metrics"][k]) for s in ran]) for k in keys}
        strata = np.concatenate([np.full(s["drops"], i) for i, s in enumerate(ran)])
        both = all(reference in s["policies"] for s in ran)
        ref = ({PRIMARY: np.concatenate([_array(s["policies"][reference]["metrics"][PRIMARY]) for s in ran])}
               if both else None)
        floor = np.concatenate([_array(s["policies"]["passive"]["metrics"][PRIMARY]) for s in ran])
        top = np.concatenate([_array(s["policies"][ORACLE_ROW]["metrics"][PRIMARY]) for s in ran])
        st = policy_statistics(metrics, seed=seed, strata=strata, reference=ref, passive=floor, oracle=top)
        st = {k: ([_num(x) for x in v] if isinstance(v, list) else _num(v)) for k, v in st.items()}
        st["sets"] = [name for name, s in record["sets"].items() if spec in s["policies"]]
        st["drops"] = int(strata.size)
        st["reference"] = reference if both else None
        st[PRIMARY] = _num(float(np.nanmean(metrics[PRIMARY])))
        ttc = metrics["time_to_catch_s"]
        ok = ~np.isnan(ttc)
        st["caught_fraction"] = _num(float(np.mean(np.isfinite(ttc[ok])))) if ok.any() else None
        out[spec] = st
    return out


def _rank_key(st: dict) -> float:
    """Best score first; a policy without a score last."""
    return -st["score"] if st.get("score") is not None else math.inf


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def run_meta(command: str | None, wall: float, oracle_searched: int, oracle_s: float) -> dict:
    """Where and how a record was made (module doc)."""
    from importlib.metadata import PackageNotFoundError, version

    versions = {"python": platform.python_version(), "impact_env": __version__}
    for name in PACKAGES:
        try:
            versions[name] = version(name)
        except PackageNotFoundError:
            continue
    return {"versions": versions, "git": git_state(), "cpu": cpu_name(), "platform": platform.platform(),
            "command": command if command is not None else " ".join(sys.argv),
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "wall_time_s": wall, "oracle_drops_searched": oracle_searched, "oracle_search_s": oracle_s}


def git_state() -> dict:
    root = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                                check=True).stdout.strip()
        dirty = bool(subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                                    capture_output=True, text=True, check=True).stdout.strip())
    except (OSError, subprocess.CalledProcessError):
        return {"commit": None, "dirty": None}
    return {"commit": commit, "dirty": dirty}


def cpu_name() -> dict:
    """The CPU: its model name (/proc/cpuinfo) and the name LLVM compiles for."""
    model = platform.processor() or None
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        import llvmlite.binding as llvm

        llvm_cpu = str(llvm.get_host_cpu_name())
    except Exception:  # pragma: no cover - numba's llvmlite is a dependency
        llvm_cpu = None
    import os

    return {"model": model, "llvm": llvm_cpu, "cores": os.cpu_count()}


def write_record(record: dict, out_dir: Path, fmt: str = "png") -> list[Path]:
    """``<suite>.json`` and the performance profile into ``out_dir``; returns the paths."""
    from impact_env.eval.benchmark_plots import plot_profiles

    out_dir.mkdir(parents=True, exist_ok=True)
    name = record["suite"]["name"]
    p = out_dir / f"{name}.json"
    p.write_text(dumps_record(record))
    order = sorted(record["overall"], key=lambda k: _rank_key(record["overall"][k]))
    scores = {spec: scores_per_drop(record, spec) for spec in order}
    return [p, plot_profiles(record, scores, out_dir / f"{name}_profile.{fmt}")]


def dumps_record(record: dict) -> str:
    """The record as indented JSON with every list of numbers on one line (a drop per entry)."""
    import re

    text = json.dumps(record, indent=1)
    numbers = re.compile(r"\[\s*((?:-?[0-9.eE+-]+|null|Infinity|-Infinity|NaN)(?:,\s*(?:-?[0-9.eE+-]+|null|"
                         r"Infinity|-Infinity|NaN))*)\s*\]")
    return numbers.sub(lambda m: "[" + ", ".join(x.strip() for x in m.group(1).split(",")) + "]", text) + "\n"


def format_overall(record: dict) -> str:
    """The overall table, best score first."""
    from impact_env.eval.scores import interval_text

    rows = sorted(record["overall"].items(), key=lambda kv: _rank_key(kv[1]))
    ref = record["suite"]["reference"]
    head = ("policy", "score* [95 % CI]", "score IQM [95 % CI]", f"P(better than {ref}) [95 % CI]",
            "int E ms [95 % CI]", "caught", "sets")
    lines = []
    for spec, st in rows:
        lines.append((spec, interval_text(st.get("score"), st.get("score_ci95"), "{:.1f}"),
                      interval_text(st.get("score_iqm"), st.get("score_iqm_ci95"), "{:.1f}"),
                      interval_text(st.get("prob_improvement"), st.get("prob_improvement_ci95")),
                      interval_text(st.get(PRIMARY), st.get(f"{PRIMARY}_ci95")),
                      "n/a" if st.get("caught_fraction") is None else f"{st['caught_fraction']:.0%}",
                      str(len(st["sets"]))))
    widths = [max(len(h), *(len(r[i]) for r in lines)) for i, h in enumerate(head)]
    fmt = lambda r: "  ".join(x.ljust(w) if i == 0 else x.rjust(w)  # noqa: E731
                              for i, (x, w) in enumerate(zip(r, widths, strict=True)))
    return "\n".join([fmt(head), fmt(tuple("-" * w for w in widths)), *(fmt(r) for r in lines)])
