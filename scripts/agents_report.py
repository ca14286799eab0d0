"""The agents' results: trained runs next to the classic laws and the oracle on
held-out drops of ``rig`` and ``rig-randomized``, with bootstrap 95 % intervals; writes the
results of ``docs/agents-results.md``, a figure, and ships the best agent.

    python scripts/agents_report.py --runs runs/ppo_s0 runs/ppo_s100 runs/ppo_s200 runs/sac_s0 ... \\
        [--episodes 100] [--seed 1000] [--scenes rig,rig-randomized] [--oracle oracle:warm=given] \\
        [--workers 2] [--out runs/report] [--reuse] [--doc docs/agents-results.md] \\
        [--figure docs/figures/agents_results.png] [--format png|pdf|svg] [--ship agents/models/best]

What it does:

* every run's ``best_model.zip`` (the evaluation callback's pick on the validation drops
  900000..900015) is exported to a compiled policy (``best_model.policy.json`` next to it,
  :func:`impact_env.policy.export.export_policy`: the network, its hold and its residual law);
* for each scene one :func:`impact_env.eval.compare.compare` on drops ``seed .. seed + episodes - 1``
  (seeds apart from training's, ``seed + envs``, and validation's, checked by ``agents.train``):
  ``passive``, ``thesis-rig``, ``pd-penetration``, every agent, and the oracle last, which gets
  every other policy's commands on each drop (its final choice includes them, so no policy can
  beat it on any drop; with ``warm=given`` they are also the bases of its search).  Per-episode
  metrics are kept in ``OUT/SCENE.npz`` (``--reuse`` reads them instead of running again);
* intervals: percentile bootstrap over drops (``--resamples`` 10000, ``numpy.random.default_rng``
  seeded ``--boot-seed``), the same resampled drops for every policy, of the median time to catch
  (an episode not caught within the horizon counts as infinitely long, as in ``compare``) and of
  the mean energy integral (ms: ``compare``'s ``int E ms``); the gap to the oracle is the mean
  over drops of the policy's energy integral minus the oracle's on the same drop, with its own
  paired interval;
* every run on the sensors is checked as the C export would run it on a board without a double
  FPU: its compiled policy in the export's float32 build against the double target, readings of
  drops 0..9 of each scene replayed through both (:mod:`impact_env.deploy.parity`, the bound of
  docs/rig/c-export.md's "How it is checked"; kept in ``report.json``, skipped without a C compiler);
* the agent shipped is the run on the sensors whose best model has the best validation return
  (the validation drops, not the test drops, choose it) among those whose float32 build stays
  within that bound on every drop checked; it is copied to ``--ship`` with its ``model.json``,
  its compiled policy ``best.policy.json`` and ``best.onnx``.  The best sensor policy by
  validation, shipped or not, is the one the gap to the oracle is decomposed for.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import shlex
import shutil
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from impact_env.eval.paired import PairedDifference, paired_difference  # noqa: E402
from impact_env.figstyle import DPI, FORMATS, output_figure, save_figure  # noqa: E402

BASELINES = ("passive", "thesis-rig", "pd-penetration")
METRICS = ("energy_integral_ms", "time_to_catch_s", "bounces", "rms_force_N", "peak_force_N")  # kept per drop
BEGIN, END = "<!-- agents_report:begin -->", "<!-- agents_report:end -->"
DEFAULT_FIGURE = Path("docs/figures/agents_results.png")


# -- runs ---------------------------------------------------------------------------------------------
ASYMMETRIC = ("agents.policies.AsymmetricActorCriticPolicy", "agents.policies.AsymmetricSACPolicy")


def run_info(d: Path) -> dict:
    """A run folder of agents.train (or a shipped folder): its label, best model and settings.  The
    label is ``ALGO-sSEED``, with ``-priv`` for a run on the privileged observation (the true state:
    a yardstick, never shipped)."""
    meta = json.loads((d / "model.json").read_text())
    best = (meta.get("validation") or {}).get("best") or {}
    model = d / "best_model.zip" if (d / "best_model.zip").is_file() else d / "model.zip"
    priv = meta.get("observation") == "privileged"
    label = (meta.get("shipped_from") or {}).get("label") or meta.get("label") or \
        f"{meta['algo']}{'-priv' if priv else ''}-s{meta['seed']}"
    return {"dir": d, "label": label, "algo": meta["algo"], "seed": meta["seed"],
            "model": model, "meta": meta, "val_best": best.get("mean_reward", -math.inf),
            "val_best_step": best.get("step"), "privileged": priv}


def deployable(info: dict) -> Path:
    """The model file that acts as the run's controller: the best model itself, or for an
    asymmetric actor-critic (its critic read the true state) the plain sensor model of its actor
    (:func:`agents.policies.sensor_actor_model`, written beside it as ``*.sensors.zip``)."""
    if info["meta"].get("policy") not in ASYMMETRIC:
        return info["model"]
    from agents.policies import deployable as actor

    src = info["model"]
    meta_src = src.with_suffix(".json")
    settings = json.loads((meta_src if meta_src.is_file() else info["dir"] / "model.json").read_text())
    return actor(src, settings)


F32_DROPS, F32_TICKS = 10, 2500  # the float32 check: drops 0..9 of each scene, 0.25 s each


def c_float32_check(info: dict, scenes: list[str], drops: int = F32_DROPS) -> dict | None:
    """The run's compiled policy in the C export's float32 build against the double target (the numba
    kernels), readings of drops ``0 .. drops - 1`` of each scene replayed through both
    (:func:`impact_env.deploy.parity.check`, judged by :meth:`ParityReport.verdict`, the bounds of
    docs/rig/c-export.md): ``{"bound", "drops", "failed", "max_same"}`` (the largest command difference where
    the builds decide alike, in full scale), or None without a C compiler."""
    import tempfile

    from impact_env.config import ConfigError
    from impact_env.deploy import parity
    from impact_env.deploy.c_export import write_c
    from impact_env.policy.export import export_policy
    from impact_env.scene import load_scene

    try:
        parity.find_cc()
    except ConfigError:
        return None
    model = deployable(info)
    failed, worst, n = [], 0.0, 0
    for name in scenes:
        scene = load_scene(name)
        pol = export_policy(f"{info['algo']}:{model}", scene)
        with tempfile.TemporaryDirectory(prefix="agents-report-c-") as tmp:
            write_c(pol, scene, Path(tmp), force=True)
            reports = parity.check(pol, scene, Path(tmp), seeds=range(drops), ticks=F32_TICKS, float32=True)
        for seed, r in enumerate(reports):
            n += 1
            worst = max(worst, r.max_abs_same)
            if not r.verdict(True)[0]:
                failed.append(f"{name}:{seed}")
    return {"bound": parity.F32_BOUND, "drops": n, "failed": failed, "max_same": worst}


def c_ok(info: dict) -> bool:
    """Shippable as far as the float32 check goes (not checked: yes)."""
    c = info.get("c_float32")
    return c is None or not c["failed"]


def export(info: dict, scene) -> str:
    from impact_env.policy.export import export_policy

    shipped = sorted(info["dir"].glob("*.policy.json"))
    if info["model"].name == "model.zip" and shipped:  # a shipped folder: its own compiled policy
        return f"compiled:{shipped[0]}"
    model = deployable(info)
    out = model.with_suffix(".policy.json")
    export_policy(f"{info['algo']}:{model}", scene).save(out)
    return f"compiled:{out}"


# -- evaluation -----------------------------------------------------------------------------------------
def evaluate_scene(scene_name: str, infos: list[dict], args) -> dict:
    """{label: {metric: float64[E]}} plus the oracle's per-drop source, from one compare."""
    from impact_env.eval.compare import compare
    from impact_env.scene import load_scene

    scene = load_scene(scene_name)
    specs = {b: b for b in BASELINES}
    for info in infos:
        specs[info["label"]] = export(info, scene)
    if args.oracle != "none":
        specs["oracle"] = args.oracle
    t0 = time.perf_counter()
    runs = compare(scene, list(specs.values()), episodes=args.episodes, seed=args.seed, workers=args.workers,
                   progress=False, trace_rate=2000.0)
    wall = time.perf_counter() - t0
    out = {"labels": list(specs), "specs": list(specs.values()), "wall_time_s": wall}
    for label, spec in specs.items():
        r = runs[spec]
        for key in METRICS:
            out[f"{label}|{key}"] = np.asarray(r.metrics[key], dtype=np.float64)
        out[f"{label}|failed"] = np.array(len(r.failures))
    if "oracle" in specs:
        from impact_env.eval.oracle import classic_law_names

        st = runs[args.oracle].stats
        out["oracle|source"] = np.asarray(st.get("source", []), dtype=str)
        out["oracle|cpu_seconds"] = np.asarray(st.get("cpu_seconds", []), dtype=np.float64)
        out["oracle|joined"] = np.asarray(classic_law_names(), dtype=str)  # its final choice saw them all
    return out


def unseen_laws(d: dict) -> list[str]:
    """The classic laws a kept oracle row's final choice did not see (none without an oracle row)."""
    from impact_env.eval.oracle import classic_law_names

    if "oracle" not in d["labels"]:
        return []
    seen = {str(x) for x in d.get("oracle|joined", [])} | set(d["labels"])
    return [name for name in classic_law_names() if name not in seen]


def join_classic_laws(d: dict, scene_name: str, episodes: int, seed: int, workers: int) -> list[str]:
    """Bring a kept oracle row to the oracle of today, whose final choice on each drop includes every
    classic law's commands (:func:`impact_env.eval.oracle.classic_law_names`): the laws that row's
    choice did not see (neither in its comparison nor joined before) run on the same drops, and on
    a drop where one is strictly better it becomes the oracle's sequence there, the first such law
    in the registry's order on a tie.  That is the choice the oracle makes itself, exactly: its
    search (its bases) is unchanged, these laws come after every earlier candidate, and a recorded
    sequence replays its episode bitwise, so the law's own episode is what the choice scores.
    Returns the laws run; ``d`` is changed in place.  ValueError (before anything is changed) when a
    classic law the row holds no longer scores as kept: the row was made by another simulator or
    metric, and joining today's laws into it would mix the two."""
    from impact_env.eval.compare import compare
    from impact_env.eval.oracle import classic_law_names
    from impact_env.scene import load_scene

    missing = unseen_laws(d)
    if missing:
        # exact only on the simulator and metrics the row was made with: a kept law row must come
        # out again drop for drop, bitwise
        check = next(label for label in d["labels"] if label in classic_law_names())
        runs = compare(load_scene(scene_name), [check, *missing], episodes=episodes, seed=seed,
                       workers=workers, progress=False, trace_rate=2000.0)
        again = np.asarray(runs[check].metrics["energy_integral_ms"], dtype=np.float64)
        if not np.array_equal(again, d[f"{check}|energy_integral_ms"]):
            worst = float(np.max(np.abs(again - d[f"{check}|energy_integral_ms"])))
            raise ValueError(f"{scene_name}: {check} on the kept drops differs from the kept row (by up to "
                             f"{worst:.3g} ms): the results were made by another simulator or metric, so "
                             "the laws cannot be joined; evaluate the runs again (--runs)")
        source = np.array([str(x) for x in d["oracle|source"]], dtype=object)
        for name in missing:
            law = {key: np.asarray(runs[name].metrics[key], dtype=np.float64) for key in METRICS}
            energy = np.where(np.isnan(law["energy_integral_ms"]), np.inf, law["energy_integral_ms"])
            better = energy < d["oracle|energy_integral_ms"]
            for key in METRICS:
                d[f"oracle|{key}"] = np.where(better, law[key], d[f"oracle|{key}"])
            source[better] = name
        d["oracle|source"] = source.astype(str)
    d["oracle|joined"] = np.asarray(classic_law_names(), dtype=str)
    return missing


def save(path: Path, data: dict) -> None:
    np.savez(path, **{k: (np.asarray(v) if not isinstance(v, (str, float)) else np.array(v))
                      for k, v in data.items() if k not in ("labels", "specs")},
             labels=np.array(data["labels"]), specs=np.array(data["specs"]))


def load(path: Path) -> dict:
    z = np.load(path)
    d = {k: z[k] for k in z.files}
    d["labels"] = [str(x) for x in z["labels"]]
    d["specs"] = [str(x) for x in z["specs"]]
    d["wall_time_s"] = float(z["wall_time_s"])
    return d


# -- statistics -------------------------------------------------------------------------------------------
def median_catch(ttc: np.ndarray) -> float:
    """compare's median: not caught (inf) counts as infinitely long."""
    return float(np.median(np.where(np.isnan(ttc), np.inf, ttc)))


def bootstrap(values: np.ndarray, stat, idx: np.ndarray) -> tuple[float, float]:
    """2.5 and 97.5 percentiles of ``stat`` over the resampled drops ``idx`` (int[B, E])."""
    reps = np.array([stat(values[i]) for i in idx]) if stat is not np.mean else values[idx].mean(axis=1)
    lo, hi = np.percentile(np.where(np.isinf(reps), 1e300, reps), [2.5, 97.5])
    return (float(lo) if lo < 1e299 else math.inf), (float(hi) if hi < 1e299 else math.inf)


def scene_stats(d: dict, args) -> dict:
    n = len(d[f"{d['labels'][0]}|energy_integral_ms"])
    idx = np.random.default_rng(args.boot_seed).integers(0, n, (args.resamples, n))
    has_oracle = "oracle" in d["labels"]
    oracle = d["oracle|energy_integral_ms"] if has_oracle else None
    out = {}
    for label in d["labels"]:
        e = d[f"{label}|energy_integral_ms"]
        t = d[f"{label}|time_to_catch_s"]
        gap = e - oracle if has_oracle else np.full_like(e, np.nan)
        out[label] = {
            "median_catch_s": median_catch(t), "median_catch_ci": bootstrap(t, median_catch, idx),
            "caught": float(np.mean(np.isfinite(t))),
            "energy_ms": float(np.mean(e)), "energy_ci": bootstrap(e, np.mean, idx),
            "gap_ms": float(np.mean(gap)),
            "gap_ci": bootstrap(gap, np.mean, idx) if has_oracle else (math.nan, math.nan),
            "gap_median_ms": float(np.median(gap)), "gap_min_ms": float(np.min(gap)),
            "bounces": float(np.mean(d[f"{label}|bounces"])),
            "rms_N": float(np.mean(d[f"{label}|rms_force_N"])),
            "failed": int(d[f"{label}|failed"]),
        }
    # the agents against pd-penetration on the same drops: paired differences (impact_env.eval.paired)
    out["_paired"] = {label: {"energy": paired_difference(d[f"{label}|energy_integral_ms"],
                                                          d["pd-penetration|energy_integral_ms"], "mean",
                                                          resamples=args.resamples, seed=args.boot_seed),
                              "catch": paired_difference(d[f"{label}|time_to_catch_s"],
                                                         d["pd-penetration|time_to_catch_s"], "median_catch",
                                                         resamples=args.resamples, seed=args.boot_seed)}
                      for label in d["labels"] if label not in ("pd-penetration", "oracle")}
    out["_oracle"] = {"episodes": n}
    if has_oracle:
        src = [str(s) for s in d["oracle|source"]]
        out["_oracle"].update(sources={s: src.count(s) for s in sorted(set(src))},
                              cpu_s_per_drop=float(np.mean(d["oracle|cpu_seconds"])))
    return out


def _json(o):
    if isinstance(o, PairedDifference):
        return dataclasses.asdict(o)
    return list(o)


# -- output ---------------------------------------------------------------------------------------------
def _t(x: float) -> str:
    return ">0.4" if math.isinf(x) else f"{x:.3f}"


def _ci(ci, fmt="{:.3f}", t=False) -> str:
    f = _t if t else (lambda x: fmt.format(x))
    return f"[{f(ci[0])}, {f(ci[1])}]"


def scene_table(stats: dict) -> str:
    oracle = "oracle" in stats
    gap_head = " gap to oracle ms, mean [95 % CI] (median) |" if oracle else ""
    paired = stats.get("_paired", {})
    rows = ["| policy | median catch s [95 % CI] | caught | energy integral ms [95 % CI] |" + gap_head +
            " energy integral - pd-penetration's, paired, ms [95 % CI] | bounces | RMS N |",
            "| --- | --- | --- | --- |" + (" --- |" if oracle else "") + " --- | --- | --- |"]
    for label, s in stats.items():
        if label.startswith("_"):
            continue
        gap = (f" {s['gap_ms']:.2f} {_ci(s['gap_ci'], '{:.2f}')} ({s['gap_median_ms']:.2f}) |"
               if oracle else "")
        pe = paired.get(label, {}).get("energy")
        diff = (f"{pe.difference:.2f} [{pe.low:.2f}, {pe.high:.2f}]" + (" better" if pe.a_better else "")
                if pe is not None else "")
        rows.append(f"| {label} | {_t(s['median_catch_s'])} {_ci(s['median_catch_ci'], t=True)} | "
                    f"{100 * s['caught']:.0f} % | {s['energy_ms']:.2f} {_ci(s['energy_ci'], '{:.2f}')} |"
                    f"{gap} {diff} | {s['bounces']:.1f} | {s['rms_N']:.1f} |")
    return "\n".join(rows)


def _what(m: dict) -> str:
    obs = m.get("observation", "sensors")
    asym = m.get("policy") in ASYMMETRIC
    hist = f" x {m['history']}" if (m.get("history") or 1) > 1 else ""
    how = " (DAgger from the true-state run)" if m.get("distilled_from") else ""
    if m.get("past_commands"):
        hist += " + its past commands"
    return (f"{obs}{hist}{' (critic: + true state)' if asym else ''}{how}, hold {m.get('hold_ticks', 1)}, "
            f"{m.get('envs', '?')} envs")


def training_table(infos: list[dict]) -> str:
    rows = ["| run | actor reads, hold, envs | policy steps | wall s (CPU s) | steps/s | env share | first "
            "beats pd-penetration on validation: step, s | best validation (step, s) |",
            "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for i in infos:
        m = i["meta"]
        first = m.get("first_beats_law")
        beats = f"{first['step']:,}, {first['wall_s']:.0f}" if first else ("never" if m.get("law") else "")
        at = f", {m['best_wall_s']:.0f}" if m.get("best_wall_s") is not None else ""
        share = f"{100 * m['env_share']:.0f} %" if m.get("env_share") is not None else ""
        cpu = f" ({m['cpu_time_s']:.0f})" if m.get("cpu_time_s") is not None else ""
        rows.append(f"| {i['label']} | {_what(m)} | {m['steps']:,} | {m['wall_time_s']:.0f}{cpu} | "
                    f"{m['steps'] / m['wall_time_s']:.0f} | {share} | {beats} | "
                    f"{i['val_best']:.2f} ({i['val_best_step'] or 0:,}{at}) |")
    return "\n".join(rows)


def figure(all_stats: dict, path: Path, shipped: str) -> Path:
    import matplotlib.pyplot as plt

    scenes = list(all_stats)
    fig, axes = plt.subplots(len(scenes), 2, figsize=(11, 3.2 + 2.2 * len(scenes)), squeeze=False)
    for r, scene in enumerate(scenes):
        st = {k: v for k, v in all_stats[scene].items() if not k.startswith("_")}
        labels = list(st)[::-1]
        y = np.arange(len(labels))
        panels = (("median_catch_s", "median_catch_ci", "median time to catch, s",
                   "median time to catch, s (right of 0.4: not caught)"),
                  ("energy_ms", "energy_ci", "energy integral, ms (mean)",
                   "mean energy integral, ms (log scale)"))
        for c, (key, ci, title, xlabel) in enumerate(panels):
            ax = axes[r, c]
            v = np.array([min(st[k][key], 0.45) if c == 0 else st[k][key] for k in labels])
            lo = np.array([min(st[k][ci][0], 0.45) if c == 0 else st[k][ci][0] for k in labels])
            hi = np.array([min(st[k][ci][1], 0.45) if c == 0 else st[k][ci][1] for k in labels])
            colors = ["tab:red" if k == shipped else "tab:gray" if k in BASELINES
                      else "black" if k == "oracle" else "tab:green" if k.startswith("sac") else "tab:blue"
                      for k in labels]
            for yi, vi, li, hii, ci_ in zip(y, v, lo, hi, colors, strict=True):  # one ecolor per call
                ax.errorbar([vi], [yi], xerr=[[vi - li], [hii - vi]], fmt="none", ecolor=ci_, capsize=3)
            ax.scatter(v, y, c=colors, zorder=3)
            ax.set_yticks(y, labels)
            if c == 0:
                ax.axvline(0.4, color="0.7", ls=":")
                ax.set_xlim(0, 0.46)
            ax.set_xscale("linear" if c == 0 else "log")
            if c == 1:  # plain numbers at a few ticks, no crowded minor labels
                from matplotlib.ticker import NullFormatter, ScalarFormatter

                ticks = (2, 3, 5, 10, 20, 50, 100)
                ax.set_xticks([t for t in ticks if lo.min() / 1.5 <= t <= hi.max() * 1.5])
                ax.xaxis.set_major_formatter(ScalarFormatter())
                ax.xaxis.set_minor_formatter(NullFormatter())
            ax.set_title(f"{scene}: {title}", fontsize=10)
            ax.set_xlabel(xlabel)
            ax.grid(axis="x", alpha=0.3)
    fig.suptitle("Held-out drops: values with bootstrap 95 % intervals (0.4 s = not caught within the "
                 "horizon)", fontsize=10)
    from matplotlib.lines import Line2D  # a key for every colour used

    key = [("tab:red", "the shipped agent"), ("tab:blue", "other PPO runs"),
           ("tab:green", "SAC runs"),
           ("tab:gray", "classic laws"), ("black", "oracle (per-drop optimum)")]
    fig.legend([Line2D([], [], marker="o", ls="", color=c) for c, _ in key], [t for _, t in key],
               loc="lower center", ncol=len(key), fontsize=8, frameon=False, bbox_to_anchor=(0.5, -0.02))
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    return save_figure(fig, path)


def ship(info: dict, dest: Path, stem: str = "best") -> dict:
    """Copy a run's best model with its model.json; write its compiled policy ``STEM.policy.json``
    and ``STEM.onnx`` next to it (a folder shipped before, given as a run, is re-exported in place)."""
    from impact_env.policy.export import export_policy, write_onnx

    dest.mkdir(parents=True, exist_ok=True)
    meta_src = info["model"].with_suffix(".json")
    meta = json.loads((info["dir"] / "model.json").read_text())  # the run's, then the best model's own
    if meta_src.is_file() and meta_src != info["dir"] / "model.json":
        meta.update(json.loads(meta_src.read_text()))
    if info["model"].resolve() == (dest / "model.zip").resolve():
        return meta  # the shipped agent itself, evaluated again: already there with its files
    model = deployable(info)
    if model != info["model"]:  # an asymmetric actor-critic: its actor as a sensor model
        meta = json.loads(model.with_suffix(".json").read_text())
        meta = {**json.loads((info["dir"] / "model.json").read_text()), **{
            k: meta[k] for k in ("observation", "env_kwargs", "policy", "converted_from")}}
    shutil.copyfile(model, dest / "model.zip")
    meta["shipped_from"] = {"run": str(info["dir"]), "model": info["model"].name, "label": info["label"]}
    (dest / "model.json").write_text(json.dumps(meta, indent=2, default=str) + "\n")
    pol = export_policy(f"{info['algo']}:{dest / 'model.zip'}", meta["scene"])
    pol.save(dest / f"{stem}.policy.json")
    write_onnx(pol, dest / f"{stem}.onnx")
    return meta


def best_sensor_run(infos: list[dict]) -> dict:
    """The best validation return among the runs on the sensors (a privileged run is a yardstick: a
    rig has no true state to give it)."""
    return max((i for i in infos if not i.get("privileged")), key=lambda i: i["val_best"])


def shipped_run(infos: list[dict]) -> dict:
    """The run shipped: the best validation return among the runs on the sensors whose float32 C build
    stays within the export's bound (:func:`c_float32_check`)."""
    ok = [i for i in infos if not i.get("privileged") and c_ok(i)]
    if not ok:
        raise SystemExit("no run on the sensors passes the C export's float32 check: nothing to ship")
    return max(ok, key=lambda i: i["val_best"])


def c_check_line(infos: list[dict], settings: dict) -> str:
    """What the float32 check found, run by run."""
    checked = [i for i in infos if i.get("c_float32")]
    if not checked:
        return ""
    c0 = checked[0]["c_float32"]
    parts = []
    for i in checked:
        c = i["c_float32"]
        over = (f" (**over the bound on {len(c['failed'])} of {c['drops']}**: {', '.join(c['failed'])})"
                if c["failed"] else "")
        parts.append(f"{i['label']} {c['max_same']:.2e}{over}")
    return ("The C export's float32 build against the double target, readings of drops 0.."
            f"{c0['drops'] // len(settings['scenes']) - 1} of each scene ({F32_TICKS} ticks) replayed "
            "through "
            f"both (`impact_env.deploy.parity.check`; bound {c0['bound']:.1e} of full scale where the builds "
            "decide alike, docs/rig/c-export.md), the largest command difference: " + "; ".join(parts) + ".")


def write_doc(doc: Path, text: str) -> None:
    old = doc.read_text()
    if BEGIN not in old or END not in old:
        raise SystemExit(f"{doc}: no {BEGIN} ... {END} markers; add them where the results go")
    head, _, rest = old.partition(BEGIN)
    _, _, tail = rest.partition(END)
    doc.write_text(head + BEGIN + "\n" + text.strip() + "\n" + END + tail)


def unseen_in_report(settings: dict) -> list[str]:
    """The classic laws the oracle of any of the report's scenes did not see (``build`` keeps
    each scene's :func:`unseen_laws` in ``settings['_unseen']``)."""
    return sorted({law for laws in settings.get("_unseen", {}).values() for law in laws})


def oracle_scope(settings: dict) -> str:
    """Which classic laws the oracle's final choice saw: every one, or (kept results made before
    it joined them all) the comparison's only, naming those it lacked."""
    unseen = unseen_in_report(settings)
    if not unseen:
        return ("its final choice on each drop includes every classic law's commands, whether or not "
                "the table has the law" + (f" (the laws outside this comparison joined by `python "
                                           f"scripts/agents_report.py {settings['laws_joined_by']}`)."
                                           if settings.get("laws_joined_by") else "."))
    text = ("**an older oracle**: its final choice saw only this comparison's policies, not "
            + ", ".join(f"`{law}`" for law in unseen) + "'s commands (today's oracle joins every classic "
            "law), so its ratios are lower than today's oracle would give.")
    if settings.get("join_refused"):
        return (text + f"  `--join-laws` cannot bring these kept results up to date: "
                f"{settings['join_refused']}")
    return text + (f"  `python scripts/agents_report.py --join-laws --results {settings['results']}` brings "
                   "them up to date.")


def report_text(infos, all_stats, shipped, settings, walls, data=None, best=None) -> str:
    """The results section, from the kept per-drop results alone (``settings``: the evaluation's
    settings and the command that made it, from ``RESULTS/report.json``)."""
    lines = [f"*Written by `python scripts/agents_report.py` from the per-drop results kept in "
             f"`{settings['results']}` (made by `python scripts/agents_report.py {settings['command']}`); "
             "do not edit by hand.*", ""]
    oracle = settings["oracle"]
    lines += [f"Test drops: seeds {settings['seed']}..{settings['seed'] + settings['episodes'] - 1} of each "
              "scene (training used seeds below 1000 and draws from their Generators; validation "
              "900000-900015). Intervals: percentile bootstrap over drops, "
              f"{settings['resamples']} resamples "
              f"(`numpy.random.default_rng({settings['boot_seed']})`), the same resamples for every policy; "
              "paired differences: `scipy.stats.bootstrap(paired=True)` (:mod:`impact_env.eval.paired`), "
              "\"better\" when the whole interval is below 0. "
              + (f"Oracle: `{oracle}`; " + oracle_scope(settings) if oracle != "none"
                 else "No oracle in this evaluation (`--oracle none`)."),
              ""]
    lines += ["### Training runs", "", training_table(infos), "",
              "Wall times are each run's own (`model.json`: the training, evaluations excluded, until the "
              "evaluation that first beat `pd-penetration`'s validation return and until the best one; "
              "the env share is the time inside the vector env's reset and step); the record "
              "(`report.json`) keeps the machine's state each ran in.", "",
              (f"Best validation return among the sensor runs: **{shipped}** (shipped)."
               if best in (None, shipped) else
               f"Best validation return among the sensor runs: **{best}**, not shipped: its float32 C "
               f"build exceeds the export's bound (below).  Shipped: **{shipped}**, the best of those "
               "within it."), ""]
    check = c_check_line(infos, settings)
    if check:
        lines += [check, ""]
    diag = Path(settings.get("_dir", settings["results"])) / "diag26"
    if diag.is_dir():
        lines += ["### Diagnostic runs of the shipped agent's recipe", "",
                  f"One change at a time, seed 0, `{settings['results']}/diag26/run.sh NAME \"OPTIONS\"` "
                  f"(each run's figures kept in `{settings['results']}/diag26/NAME.json` by its "
                  "`collect.py`, "
                  "the raw log in `series.log`); validation: the 16 drops 900000-900015, on which "
                  "`pd-penetration` scores -13.04 on `rig-randomized`.", "", diag_table(diag), ""]
    goals = goal_lines(all_stats, infos, shipped, best)
    if goals:
        lines += ["### The shipped agent's goals", ""] + goals + [""]
    for scene, st in all_stats.items():
        o = st["_oracle"]
        lines += [f"### `{scene}`, {o['episodes']} held-out drops", "", scene_table(st), ""]
        if "sources" in o:
            src = ", ".join(f"{k} {v}" for k, v in o["sources"].items())
            lines += [f"Oracle: {o['cpu_s_per_drop']:.1f} s of CPU per drop; its sequence per drop came "
                      "from: "
                      f"{src} (a name other than `cma`: that policy's own recorded commands were the best "
                      "found).", ""]
        lines += [f"Evaluation wall time {walls[scene]:.0f} s.", ""]
        if data is not None:
            boot = argparse.Namespace(resamples=settings["resamples"], boot_seed=settings["boot_seed"])
            dec = decomposition(data[scene], st, infos, best or shipped, boot, shipped=shipped)
            if dec:
                lines += [f"The gap to the oracle on `{scene}`, decomposed:", ""] + dec
        for label in [k for k in st if not k.startswith("_") and k not in BASELINES and k != "oracle"]:
            pd, ag = st["pd-penetration"], st[label]
            pe, pt = st["_paired"][label]["energy"], st["_paired"][label]["catch"]
            share = ""
            if "oracle" in st and pd["energy_ms"] > st["oracle"]["energy_ms"]:
                frac = (pd["energy_ms"] - ag["energy_ms"]) / (pd["energy_ms"] - st["oracle"]["energy_ms"])
                share = (f"; it closes {100 * frac:.0f} % of pd-penetration's gap to the oracle "
                         f"({pd['gap_ms']:.2f} ms -> {ag['gap_ms']:.2f} ms)")
            lines += [f"* {label} against pd-penetration: median catch {_t(ag['median_catch_s'])} against "
                      f"{_t(pd['median_catch_s'])} s (paired difference {pt.text('s')}: "
                      f"{'better' if pt.a_better else 'NOT shown better'}); energy integral "
                      f"{ag['energy_ms']:.2f} against {pd['energy_ms']:.2f} ms (paired difference "
                      f"{pe.text('ms', '{:.2f}')}: "
                      f"{'better' if pe.a_better else 'NOT shown better'}){share}."]
        lines.append("")
        if "oracle" in st:
            worst = min((v["gap_min_ms"], k) for k, v in st.items()
                        if not k.startswith("_") and k != "oracle")
            lines += [f"No policy beats the oracle on any drop: the smallest per-drop gap is "
                      f"{worst[0]:.3f} ms ({worst[1]})." if worst[0] >= 0 else
                      f"**{worst[1]} beats the oracle on a drop (gap {worst[0]:.3f} ms): the optimiser is "
                      "too weak.**", ""]
    return "\n".join(lines)


def diag_table(folder: Path) -> str:
    """The diagnostic runs (``RESULTS/diag26/NAME.json``, kept by its ``collect.py``): what each
    changed (its options) and what it reached on the validation drops, how fast."""
    rows = ["| run | options | validation return: first, best (step, training s), last | first beats "
            "pd-penetration: step, s | steps/s | env share |",
            "| --- | --- | --- | --- | --- | --- |"]
    for path in sorted(folder.glob("*.json"), key=lambda q: (json.loads(q.read_text())["algo"], q.stem)):
        r = json.loads(path.read_text())
        val = r.get("validation") or {}
        hist, best = val.get("history") or [], val.get("best") or {}
        if not hist:
            continue
        b = max(hist, key=lambda h: h["return"])
        first = best.get("first_beats_law")
        beats = f"{first['step']:,}, {first['wall_s']:.0f}" if first else "never"
        opts = (r.get("options") or "").replace("--checkpoint-every 0 ", "")
        rows.append(f"| {r['name']} | `{opts}` | {hist[0]['return']:.2f}, **{b['return']:.2f}** "
                    f"({b['step']:,}, {b['wall_s']:.0f}), {hist[-1]['return']:.2f} ({hist[-1]['step']:,}) | "
                    f"{beats} | "
                    f"{r['steps_per_s']:.0f} | {100 * r['env_share']:.0f} % |")
    return "\n".join(rows)


GOALS = {"rig": 1.2, "rig-randomized": 1.3}  # issue 26: the shipped agent's energy integral / the oracle's


def decomposition(d: dict, st: dict, infos: list[dict], best: str, args,
                  shipped: str | None = None) -> list[str]:
    """The gap to the oracle on one scene, decomposed: the oracle (open loop, privileged, per drop),
    the best feedback policy on the true state (a privileged run), the best sensor policy (``best``,
    by validation; ``shipped`` says whether it is the one shipped); the share of the sensor policy's
    gap that the privileged one closes is the information's share.  Intervals from the same
    bootstrap resamples as the tables."""
    name = ("shipped agent" if shipped in (None, best) else "best sensor policy")
    priv = [i for i in infos if i.get("privileged") and i["label"] in st]
    if "oracle" not in st or best not in st:
        return []
    n = len(d["oracle|energy_integral_ms"])
    idx = np.random.default_rng(args.boot_seed).integers(0, n, (args.resamples, n))
    e = {k: d[f"{k}|energy_integral_ms"] for k in st if not k.startswith("_")}
    mean = {k: v[idx].mean(axis=1) for k, v in e.items()}  # the resampled means

    def ratio(k):
        r = mean[k] / mean["oracle"]
        lo, hi = np.percentile(r, [2.5, 97.5])
        return f"{e[k].mean() / e['oracle'].mean():.2f} [{lo:.2f}, {hi:.2f}]"

    rows = ["| policy | information | energy integral ms [95 % CI] | / oracle's [95 % CI] |",
            "| --- | --- | --- | --- |"]
    best_priv = max(priv, key=lambda i: i["val_best"])["label"] if priv else None
    runs = {i["label"]: i for i in infos}
    others = [(k, "the sensors" + (f", last {runs[k]['meta'].get('history')} frames"
                                   if (runs[k]["meta"].get("history") or 1) > 1 else "")
               + (" (shipped agent)" if k == shipped else ""))
              for k in st if k in runs and k not in (best_priv, best) and not runs[k].get("privileged")]
    for k, what in (("oracle", "the drop (seed) before it starts: open loop, optimised per drop"),
                    (best_priv, "the true state x1, v1, x2, v2, feedback"),
                    (best, f"the sensors ({name})"), *others,
                    ("pd-penetration", "the sensors (classic law)")):
        if k is None:
            continue
        rows.append(f"| {k} | {what} | {st[k]['energy_ms']:.2f} {_ci(st[k]['energy_ci'], '{:.2f}')} | "
                    f"{ratio(k)} |")
    lines = rows + [""]
    if best_priv is not None:
        gap = mean[best] - mean["oracle"]
        share = np.where(gap > 0, (mean[best] - mean[best_priv]) / np.where(gap > 0, gap, 1.0), np.nan)
        lo, hi = np.nanpercentile(share, [2.5, 97.5])
        point = (e[best].mean() - e[best_priv].mean()) / (e[best].mean() - e["oracle"].mean())
        total = e[best].mean() - e["oracle"].mean()
        lines += [f"Of the {name}'s gap to the oracle ({best}, {total:.2f} ms), "
                  f"{100 * point:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}] is closed by seeing the true state "
                  f"({best_priv}): the information's share; the rest "
                  f"({e[best_priv].mean() - e['oracle'].mean():.2f} ms) lies between feedback on the true "
                  "state "
                  "and the per-drop open-loop optimum.", ""]
    return lines


def goal_lines(all_stats: dict, infos: list[dict], shipped: str, best: str | None = None) -> list[str]:
    """The shipped agent's goals, each with its measured figure and met or not (for the shipped agent; the best
    sensor policy, where it is not the one shipped, with what it would give)."""
    lines = []
    sac = [i["label"] for i in infos if i["algo"] == "sac" and not i.get("privileged")]
    for label in sac:
        parts, ok = [], True
        for scene, st in all_stats.items():
            pe = st["_paired"].get(label, {}).get("energy")
            if pe is None:
                continue
            ok &= bool(pe.a_better)
            parts.append(f"{scene} {pe.difference:.2f} [{pe.low:.2f}, {pe.high:.2f}] ms")
        lines.append(f"* {label} better than pd-penetration on the paired energy integral on every scene: "
                     f"{'**met**' if ok else '**NOT met**'} ({'; '.join(parts)}).")
    for scene, st in all_stats.items():
        if "oracle" in st and shipped in st and scene in GOALS:
            r = st[shipped]["energy_ms"] / st["oracle"]["energy_ms"]
            verdict = "**met**" if r <= GOALS[scene] else "**NOT met**"
            lines.append(f"* The shipped agent ({shipped}) within {GOALS[scene]}x of the oracle's mean "
                         f"energy integral on `{scene}`: {r:.3f}x ({st[shipped]['energy_ms']:.3f} against "
                         f"{st['oracle']['energy_ms']:.3f} ms): {verdict}.")
            if best not in (None, shipped) and best in st:
                rb = st[best]["energy_ms"] / st["oracle"]["energy_ms"]
                lines.append(f"  The best sensor policy ({best}; not shipped, its float32 C build exceeds "
                             "the "
                             f"export's bound): {rb:.3f}x ({st[best]['energy_ms']:.3f} ms), "
                             f"{'within' if rb <= GOALS[scene] else 'outside'} {GOALS[scene]}x.")
    return lines


README_BEGIN, README_END = "<!-- agents_report:readme:begin -->", "<!-- agents_report:readme:end -->"


def readme_table(all_stats: dict, infos: list[dict], shipped: str, settings: dict,
                 extra: list[str] | None = None, best: str | None = None) -> str:
    """The README's agent table: per scene pd-penetration, the shipped agents, the best privileged
    run and the oracle, with the command that made the figures."""
    sac = [i for i in infos if i["algo"] == "sac" and not i.get("privileged") and c_ok(i)]
    sac_label = max(sac, key=lambda i: i["val_best"])["label"] if sac else None
    priv = [i for i in infos if i.get("privileged")]
    priv_label = max(priv, key=lambda i: i["val_best"])["label"] if priv else None
    rows = ["| scene | policy | median catch s [95 % CI] | caught | energy integral ms [95 % CI] | "
            "/ oracle's |",
            "|---|---|---|---|---|---|"]
    for scene, st in all_stats.items():
        oracle = st.get("oracle", {}).get("energy_ms")
        for label, name in (("pd-penetration", "pd-penetration"),
                            (shipped, f"**shipped agent** (`agents/models/best`, {shipped})"),
                            (best if best != shipped else None,
                             f"best sensor policy ({best}; not shipped: float32 C build out of bounds)"),
                            (sac_label, f"SAC agent (`agents/models/sac`, {sac_label})"),
                            (priv_label, f"feedback on the true state ({priv_label}, not deployable)"),
                            ("oracle", "oracle (per drop, open loop)")):
            if label is None or label not in st or (label == sac_label and sac_label == shipped):
                continue
            x = st[label]
            ratio = f"{x['energy_ms'] / oracle:.2f}" if oracle else ""
            catch = f"{_t(x['median_catch_s'])} {_ci(x['median_catch_ci'], t=True)}"
            rows.append(f"| `{scene}` | {name} | {catch} | "
                        f"{100 * x['caught']:.0f} % | {x['energy_ms']:.2f} {_ci(x['energy_ci'], '{:.2f}')} | "
                        f"{ratio} |")
    head = (f"*Written by `python scripts/agents_report.py` from `{settings['results']}` (made by "
            f"`python scripts/agents_report.py {settings['command']}`); 100 held-out drops per scene "
            f"(seeds {settings['seed']}..{settings['seed'] + settings['episodes'] - 1}), bootstrap 95 % "
            "intervals; the paired comparisons and every run are in docs/agents-results.md.*")
    unseen = unseen_in_report(settings)
    if unseen:
        head += ("  \n*This table's oracle saw only its comparison's policies, not "
                 + ", ".join(f"`{law}`" for law in unseen) + "'s commands, so the ratios to it are lower "
                 "than to today's oracle (docs/agents-results.md says why these kept results cannot be re-based); the "
                 "[leaderboard](docs/leaderboard.md) ranks the shipped agents against today's oracle.*")
    return head + "\n\n" + "\n".join(rows) + ("\n\n" + "\n".join(extra) if extra else "")


def write_readme(readme: Path, text: str) -> bool:
    """Replace the README's agent table between its markers (False: no markers, nothing written)."""
    if not readme.is_file():
        return False
    old = readme.read_text()
    if README_BEGIN not in old or README_END not in old:
        return False
    head, _, rest = old.partition(README_BEGIN)
    _, _, tail = rest.partition(README_END)
    readme.write_text(head + README_BEGIN + "\n" + text.strip() + "\n" + README_END + tail)
    return True


def _run_record(info: dict) -> dict:
    """What the report needs of a run, kept in RESULTS/report.json (with the load average at its start
    and end: wall times on a shared machine mean little without it)."""
    m = info["meta"]
    best = (m.get("validation") or {}).get("best") or {}
    rec = {k: m.get(k) for k in ("scene", "steps", "ticks", "wall_time_s", "observation", "policy",
                                 "hold_ticks", "envs", "env_share", "steps_per_s", "torch_threads",
                                 "cpu_time_s", "history", "distilled_from")}
    rec["past_commands"] = bool((m.get("hyperparameters") or {}).get("past_commands"))
    rec.update(first_beats_law=best.get("first_beats_law"), best_wall_s=best.get("wall_s"),
               law=best.get("residual_law_return"),
               validation_history=(m.get("validation") or {}).get("history"))
    la = m.get("load_average")
    rec["load"] = f"{la[0]:.1f}-{la[1]:.1f}" if la and None not in la else None
    return {"label": info["label"], "algo": info["algo"], "seed": info["seed"], "dir": str(info["dir"]),
            "model": str(info["model"]), "val_best": info["val_best"], "val_best_step": info["val_best_step"],
            "privileged": info.get("privileged", False), "c_float32": info.get("c_float32"), "meta": rec}


def build(results: Path, doc: Path, figure_path: Path, resamples_override=None,
          readme: Path | None = None) -> tuple[str, Path]:
    """The doc's results section and the figure, from RESULTS/report.json and RESULTS/SCENE.npz."""
    rep = json.loads((results / "report.json").read_text())
    settings = {**rep["settings"], "_dir": str(results)}
    args = argparse.Namespace(resamples=settings["resamples"], boot_seed=settings["boot_seed"])
    infos = rep["runs"]
    all_stats, walls, data = {}, {}, {}
    for scene in settings["scenes"]:
        d = load(results / f"{scene}.npz")
        settings.setdefault("_unseen", {})[scene] = unseen_laws(d)
        walls[scene] = d["wall_time_s"]
        data[scene] = d
        all_stats[scene] = scene_stats(d, args)
    shipped = shipped_run(infos)["label"]
    best = best_sensor_run(infos)["label"]
    fig = figure(all_stats, figure_path, shipped)
    text = report_text(infos, all_stats, shipped, settings, walls, data, best=best)
    text += f"\n![results]({figure_path.relative_to(doc.parent)})\n"
    write_doc(doc, text)
    if readme is not None:
        # the card gives the figures and what limits the agent; the goals and their verdicts are in
        # the doc's section (report_text)
        extra: list[str] = []
        boot = argparse.Namespace(resamples=settings["resamples"], boot_seed=settings["boot_seed"])
        for scene in settings["scenes"]:
            dec = decomposition(data[scene], all_stats[scene], infos, best, boot, shipped=shipped)
            extra += [f"* `{scene}`: {line[0].lower()}{line[1:]}" for line in dec
                      if line.startswith("Of the")]
        write_readme(readme, readme_table(all_stats, infos, shipped, settings, extra, best=best))
    return shipped, fig


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", nargs="+", default=None,
                   help="run folders of agents.train to evaluate (without: rebuild the doc from --results)")
    p.add_argument("--results", default="docs/results/agents",
                   help="where the per-drop results are kept (SCENE.npz, report.json; in the repository)")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--seed", type=int, default=1000)
    p.add_argument("--scenes", default="rig,rig-randomized")
    p.add_argument("--oracle", default="oracle:warm=given", help="the oracle's spec, or none")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--resamples", type=int, default=10000)
    p.add_argument("--boot-seed", type=int, default=20251122)
    p.add_argument("--doc", default="docs/agents-results.md")
    p.add_argument("--readme", default=None,
                   help="the README whose agent table (between its agents_report:readme markers) is "
                        "rewritten too (default: README.md in the folder above --doc's; '' for none)")
    p.add_argument("--figure", default=None,
                   help="the figure file (default docs/figures/agents_results.FORMAT; its suffix picks the "
                        "format)")
    p.add_argument("--format", default=None, choices=FORMATS,
                   help=f"the figure's file format (default: --figure's suffix, else png; {DPI} dpi)")
    p.add_argument("--ship", default="agents/models/best", help="where the best run's agent goes")
    p.add_argument("--ship-sac", default="agents/models/sac",
                   help="where the best SAC run's agent goes (the best within the float32 check's bound)")
    p.add_argument("--no-ship", action="store_true")
    p.add_argument("--reuse", action="store_true",
                   help="with --runs: read the per-drop results already in --results for these runs (the "
                        "same labels) instead of evaluating again; the command recorded is the one "
                        "without it")
    p.add_argument("--join-laws", action="store_true",
                   help="without --runs: bring the kept oracle rows in --results to today's oracle, whose "
                        "final choice includes every classic law (the laws its comparison lacked run on the "
                        "same drops; no run folders needed), then rebuild")
    args = p.parse_args(argv)
    if args.join_laws and args.runs:
        p.error("--join-laws updates kept results; with --runs the oracle run already joins every law")
    try:  # checked before the evaluation, which takes minutes
        args.figure = output_figure(args.figure or DEFAULT_FIGURE.with_suffix(f".{args.format or 'png'}"),
                                    args.format if args.figure else None, "--figure")
    except ValueError as exc:
        p.error(str(exc))
    results = Path(args.results)
    if args.runs:
        infos = [run_info(Path(d)) for d in args.runs]
        results.mkdir(parents=True, exist_ok=True)
        for scene in args.scenes.split(","):
            if args.reuse and (results / f"{scene}.npz").is_file():
                d = load(results / f"{scene}.npz")
                if d["labels"][len(BASELINES):len(BASELINES) + len(infos)] != [i["label"] for i in infos]:
                    p.error(f"--reuse: {results / scene}.npz holds {d['labels']}, not these runs")
                print(f"== {scene}: reused {results / scene}.npz", flush=True)
                continue
            d = evaluate_scene(scene, infos, args)
            save(results / f"{scene}.npz", d)
            print(f"== {scene}: {d['wall_time_s']:.0f} s", flush=True)
        for info in infos:
            if not info.get("privileged"):
                info["c_float32"] = c_float32_check(info, args.scenes.split(","))
                c = info["c_float32"]
                what = ("not checked (no C compiler)" if c is None else
                        f"max |diff| {c['max_same']:.3g}, over the bound on {len(c['failed'])} of "
                        f"{c['drops']} drops")
                print(f"== {info['label']}: float32 C build {what}", flush=True)
        command = shlex.join(a for a in (sys.argv[1:] if argv is None else list(argv))
                             if a not in ("--no-ship", "--reuse"))  # quoted: --readme '' stays a word
        settings = {"results": str(results), "command": command, "episodes": args.episodes, "seed": args.seed,
                    "scenes": args.scenes.split(","), "oracle": args.oracle, "resamples": args.resamples,
                    "boot_seed": args.boot_seed}
        (results / "report.json").write_text(json.dumps({"settings": settings,
                                                         "runs": [_run_record(i) for i in infos]},
                                                        indent=1) + "\n")
        if not args.no_ship:
            ship(shipped_run(infos), Path(args.ship))
            sac = [i for i in infos if i["algo"] == "sac" and not i.get("privileged") and c_ok(i)]
            if sac and args.ship_sac:
                ship(max(sac, key=lambda i: i["val_best"]), Path(args.ship_sac), stem="sac")
    elif not (results / "report.json").is_file():
        p.error(f"no --runs and no {results / 'report.json'} to rebuild from")
    elif args.join_laws:
        rep = json.loads((results / "report.json").read_text())
        settings = rep["settings"]
        joined = {}
        try:  # every scene checked before any is written
            for scene in settings["scenes"]:
                d = load(results / f"{scene}.npz")
                if "oracle" not in d["labels"]:
                    p.error(f"--join-laws: {results / scene}.npz has no oracle row")
                ran = join_classic_laws(d, scene, settings["episodes"], settings["seed"], args.workers)
                joined[scene] = d
                print(f"== {scene}: the oracle row joined {', '.join(ran) or 'nothing new'}", flush=True)
        except ValueError as exc:
            # recorded, so that the docs say why these rows keep their older oracle
            settings["join_refused"] = str(exc)
            print(f"--join-laws: not joined: {exc}", flush=True)
        else:
            for scene, d in joined.items():
                save(results / f"{scene}.npz", d)
            settings["laws_joined_by"] = shlex.join(a for a in (sys.argv[1:] if argv is None else list(argv)))
            settings.pop("join_refused", None)
        (results / "report.json").write_text(json.dumps(rep, indent=1) + "\n")
    readme = Path(args.readme) if args.readme else None
    if args.readme is None:
        readme = Path(args.doc).resolve().parent.parent / "README.md"
    best, fig = build(results, Path(args.doc), Path(args.figure), readme=readme)
    print(f"shipped: {best}; wrote {args.doc} and {fig} from {results}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
