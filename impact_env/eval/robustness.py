"""``impact-env robustness``: where each policy breaks as the rig departs from its model.

Each grid point moves one or two hardware parameters off their nominal values and runs every
policy on the same seeded drops (``compare``'s episodes ``seed + j``).  A parameter is moved the
way a rig departs from its description: through a one-point range of the scene's ``[randomize]``
section (``c = [v, v]``), not listed in ``control.known_hardware``, so the hardware runs with
``v`` while the controller side (the observation's reference scales, a law's constants and
model, the detector) keeps the scene's fixed values, as a deployed policy and the target serving
the scene do.  The parameters are the
``[randomize]`` fields (:data:`FIELDS`: the pad's c and restitution, the coil inductance, the
sensor delay, the command gain, m1, the noise level, ...); a delay's effect is switched on (at
its nominal 0 s) when the scene has it off.

Output: ``robustness.csv``/``.json`` (one row per grid point and policy: compare's summary) and a
figure of the energy integral, the catch time, the time at the force limit and the bounces
against the parameter, the nominal value marked, and, given an identification
(``identification.json`` of ``impact-env identify``), the identified value with its 95 % band.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from impact_env.config import ConfigError, get_dotted
from impact_env.eval.compare import (
    RolloutJob,
    check_cluster_specs,
    check_specs,
    merge_runs,
    run_job,
    split_episodes,
    summarize,
    warm_up,
)
from impact_env.eval.labels import metric_label, policy_colors
from impact_env.eval.parallel import prepare, run_tasks, session
from impact_env.eval.sweep import parse_grid
from impact_env.figstyle import save_figure
from impact_env.scene import load_scene
from impact_env.scene.randomize import LOG, RandomizeConfig

FIELDS = tuple(f for f in RandomizeConfig.__dataclass_fields__)
NEEDS = {"sensor_delay_s": "sensor_delay", "actuator_delay_s": "actuator_delay"}
LABELS = {"c": "pad stiffness c, N/m^1.5", "restitution": "pad restitution", "m1": "body 1's mass m1, kg",
          "m2": "body 2's mass m2, kg", "drop_height": "drop height, m", "impact_speed": "impact speed, m/s",
          "suspension_stiffness": "suspension stiffness, N/m",
          "suspension_damping": "suspension damping, N s/m", "noise_scale": "sensor noise / nominal",
          "command_gain": "command gain (force per command / nominal)",
          "shaker_lowpass_hz": "shaker band edge, Hz", "shaker_coil_inductance": "coil inductance, H",
          "sensor_delay_s": "sensor delay, s", "actuator_delay_s": "actuator delay, s",
          "top_mass": "transducer's top mass m2', kg"}
# identification.json's field -> (randomize field, as a factor of the base value?)
FROM_IDENTIFIED = {"plant.c": ("c", False), "plant.restitution": ("restitution", False),
                   "plant.m2": ("m2", False), "plant.m1": ("m1", False),
                   "plant.suspension_stiffness": ("suspension_stiffness", False),
                   "plant.suspension_damping": ("suspension_damping", False),
                   "effects.command_scale": ("command_gain", True),
                   "effects.shaker.lowpass_hz": ("shaker_lowpass_hz", False),
                   "effects.shaker.coil_inductance": ("shaker_coil_inductance", False),
                   "effects.sensors.force.top_mass": ("top_mass", False)}
SHORT = {"energy_integral_ms": "energy integral (catch energy / impact), ms",
         "time_to_catch_median_s": "catch time (median), s", "peak_force_N": "peak force on body 2 (mean), N",
         "saturation_time_s": "time at the force limit (mean), s", "bounces": "bounces (mean)"}
METRICS = ("energy_integral_ms", "time_to_catch_median_s", "peak_force_N", "saturation_time_s", "bounces",
           "caught_fraction")


def parse_vary(text: str, rate: float) -> tuple[str, np.ndarray]:
    """``FIELD=LO:HI[:N]`` (N default 7; geometric for the log-uniform fields, whole control
    periods for the delays) -> (field, values)."""

    name, sep, grid = str(text).partition("=")
    name = name.strip()
    if not sep or name not in FIELDS:
        raise ConfigError(f"--vary {text!r}: expected FIELD=LO:HI[:N] with FIELD one of {', '.join(FIELDS)}")
    parts = grid.split(":")
    if len(parts) == 2:
        grid += ":7"
    log = RandomizeConfig.dist(name) == LOG
    values = parse_grid(f"--vary {name}", grid, log)
    if name in NEEDS:
        ticks = np.unique(np.round(values * rate).astype(int))
        values = ticks / rate
    return name, values


def nominal(scene, name: str) -> float:
    """The scene's own value of a [randomize] field (1 for the factors)."""
    if name in ("noise_scale", "command_gain"):
        return 1.0
    value = get_dotted(scene, RandomizeConfig.__dataclass_fields__[name].metadata["target"])
    return float(value) if value is not None else float("nan")


def point_scene(scene, point: dict[str, float]):
    """``scene`` with each field of ``point`` as a one-point range (module doc)."""
    ov: dict = {f"randomize.{k}": [float(v), float(v)] for k, v in point.items()}
    active = list(scene.effects.active)
    for k in point:
        if k in NEEDS and NEEDS[k] not in active:
            active.append(NEEDS[k])
    if active != list(scene.effects.active):
        ov["effects.active"] = active
    if "impact_speed" in point:
        ov["initial.impact_speed"] = float(point["impact_speed"])
    return scene.with_overrides(ov)


@dataclass
class Robustness:
    scene_name: str
    axes: list[tuple[str, np.ndarray]]
    specs: list[str]
    points: list[dict[str, float]]
    summaries: list[dict[str, dict]]  # per point: spec -> compare's summary
    nominal: dict[str, float]
    episodes: int
    seed: int
    horizon: float
    wall_s: float = 0.0
    identified: dict[str, tuple[float, float]] = field(default_factory=dict)  # field -> (value, rel sigma)


def robustness(scene, specs: list[str], axes: list[tuple[str, np.ndarray]], episodes: int = 50, seed: int = 0,
               workers: int | None = None, progress: bool = True, cluster=None) -> Robustness:
    """Every policy of ``specs`` at every grid point of ``axes`` (one or two), on the same drops.

    ``cluster``: a Dask scheduler's ``tcp://HOST:PORT`` (or a connected
    :class:`~impact_env.eval.parallel.Cluster`): the tasks (points x policies x chunks of drops)
    run on its workers, with the same results; ``workers`` then defaults to its worker threads."""
    import itertools

    scene = load_scene(scene)
    if not 1 <= len(axes) <= 2:
        raise ConfigError("give one or two --vary FIELD=LO:HI[:N]")
    if len(axes) == 2 and axes[0][0] == axes[1][0]:
        raise ConfigError(f"--vary {axes[0][0]} given twice")
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ConfigError(f"--episodes {episodes!r} must be an integer >= 1")
    if any(s.strip().startswith("oracle") for s in specs):
        raise ConfigError("the oracle is not a policy to map (it re-optimises every drop): leave it out")
    points = [dict(zip([a[0] for a in axes], vals, strict=True))
              for vals in itertools.product(*[a[1] for a in axes])]
    scenes = [point_scene(scene, p) for p in points]  # every point checked before anything runs
    check_specs(specs, scene)
    for s in scenes:
        check_specs(specs, s)
    if cluster is not None:
        check_cluster_specs(specs)
    with session(cluster, workers) as (cl, workers):
        return _robustness(scene, scenes, points, specs, axes, episodes, seed, workers, progress, cl)


def _robustness(scene, scenes, points, specs, axes, episodes, seed, workers, progress, cl) -> Robustness:
    import time

    horizon = scene.episode.horizon
    chunks = split_episodes(episodes, max(1, math.ceil(workers / max(len(points) * len(specs), 1))))
    tasks = [(i, RolloutJob(spec, s, chunk, seed, horizon, 0.0))
             for i, s in enumerate(scenes) for spec in specs
             for chunk in chunks]
    prepare(warm_up, scene, horizon, workers=workers, cluster=cl)
    n_steps = int(round(horizon / scene.control_period))
    t0 = time.perf_counter()
    outs = run_tasks(run_job, [t for _i, t in tasks], workers, total=n_steps * len(tasks),
                     desc=f"robustness ({len(points)} points x {len(specs)} policies x {episodes} drops)",
                     progress=progress, cluster=cl)
    summaries = []
    for i, s in enumerate(scenes):
        row = {}
        for spec in specs:
            parts = [o for (j, t), o in zip(tasks, outs, strict=True) if j == i and t.spec == spec]
            row[spec] = summarize(merge_runs(spec, parts, s))
        summaries.append(row)
    return Robustness(scene.name, axes, list(specs), points, summaries,
                      {a[0]: nominal(scene, a[0]) for a in axes}, episodes, seed, horizon,
                      time.perf_counter() - t0)


def identified_bands(path, scene) -> dict[str, tuple[float, float]]:
    """field -> (identified value, relative standard uncertainty) from an ``identification.json``."""
    d = json.loads(Path(path).read_text())
    if d.get("format") != "impact-env-identification":
        raise ConfigError(f"--identified {str(path)!r} is not an identification.json of impact-env identify")
    out = {}
    for row in d["fields"]:
        m = FROM_IDENTIFIED.get(row["field"])
        if m is None or row["status"] != "identified":
            continue
        name, factor = m
        out[name] = (row["value"] / row["base"] if factor else row["value"], row["rel_sigma"])
    delays = d.get("delays_ticks", {})
    rate = scene.control_rate
    if "sensor" in delays:
        out["sensor_delay_s"] = (delays["sensor"] / rate, 0.0)
    if "actuator" in delays:
        out["actuator_delay_s"] = (delays["actuator"] / rate, 0.0)
    return out


def _value(summary: dict, key: str, horizon: float) -> float:
    v = summary.get(key)
    if v is None:
        return float("nan")
    v = float(v)
    if key == "time_to_catch_median_s" and math.isinf(v):
        return horizon * 1.05  # not caught within the horizon: drawn just above it
    return v


def write_outputs(res: Robustness, out_dir, fmt: str = "png") -> list[Path]:
    """robustness.csv, robustness.json and the figure (module doc)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = [a[0] for a in res.axes]
    with open(out / "robustness.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow([*names, "policy", *METRICS])
        for p, row in zip(res.points, res.summaries, strict=True):
            for spec in res.specs:
                s = row[spec]
                w.writerow([*(p[n] for n in names), spec,
                            *("" if s.get(k) is None or not math.isfinite(float(s[k])) else s[k]
                              for k in METRICS)])
    js = {"scene": res.scene_name, "axes": {n: v.tolist() for n, v in res.axes}, "nominal": res.nominal,
          "episodes": res.episodes, "seed": res.seed, "horizon_s": res.horizon, "wall_s": res.wall_s,
          "identified": res.identified,
          "rows": [{"point": p, "policy": spec,
                    **{k: (None if row[spec].get(k) is None or not math.isfinite(float(row[spec][k]))
                           else float(row[spec][k])) for k in METRICS}}
                   for p, row in zip(res.points, res.summaries, strict=True) for spec in res.specs]}
    (out / "robustness.json").write_text(json.dumps(js, indent=1) + "\n")
    fig = plot(res, out / f"robustness_{'_'.join(names)}.{fmt}")
    return [out / "robustness.csv", out / "robustness.json", fig]


def plot(res: Robustness, path, labels: dict[str, str] | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = policy_colors(res.specs)
    if len(res.axes) == 1:
        name, xs = res.axes[0]
        # (the peak force is the 200 N limit for every policy that catches: bounces say more)
        keys = ("energy_integral_ms", "time_to_catch_median_s", "saturation_time_s", "bounces")
        fig, axes = plt.subplots(2, 2, figsize=(10, 7))
        for ax, key in zip(axes.ravel(), keys, strict=True):
            for spec in res.specs:
                ys = [_value(row[spec], key, res.horizon) for row in res.summaries]
                ax.plot(xs, ys, "o-", color=colors[spec], label=(labels or {}).get(spec, spec), ms=4)
            if key == "time_to_catch_median_s":
                ax.axhline(res.horizon, color="0.6", lw=0.8, ls=":")
                ax.text(xs[0], res.horizon * 1.05, " not caught (median > horizon)", va="center", fontsize=7,
                        color="0.4")
            ax.axvline(res.nominal[name], color="k", ls="--", lw=0.9, label="nominal")
            if name in res.identified:
                v, s = res.identified[name]
                ax.axvline(v, color="C3", lw=0.9, label="identified")
                if s > 0:
                    ax.axvspan(v * math.exp(-2 * s), v * math.exp(2 * s), color="C3", alpha=0.15,
                               label="identified, 95 %")
            if RandomizeConfig.dist(name) == LOG:
                ax.set_xscale("log")
            ax.set_xlabel(LABELS.get(name, name))
            ax.set_ylabel(SHORT[key])
            ax.grid(alpha=0.3)
        axes[0, 0].legend(fontsize=7, loc="best")
        fig.suptitle(f"{res.scene_name}: each policy on the same {res.episodes} drops, the hardware's "
                     f"{LABELS.get(name, name).split(',')[0]} moved", fontsize=10)
        fig.tight_layout()
    else:
        (n1, x1), (n2, x2) = res.axes
        fig, axes = plt.subplots(1, len(res.specs), figsize=(4.2 * len(res.specs), 3.8), squeeze=False)
        grid = {spec: np.array([_value(row[spec], "energy_integral_ms", res.horizon)
                                for row in res.summaries]).reshape(len(x1), len(x2)) for spec in res.specs}
        vmax = np.nanmax([g for g in grid.values()])
        for ax, spec in zip(axes[0], res.specs, strict=True):
            im = ax.pcolormesh(x2, x1, grid[spec], shading="nearest", vmin=0, vmax=vmax, cmap="viridis")
            ax.plot(res.nominal[n2], res.nominal[n1], "w+", ms=10, mew=2)
            ax.set_title((labels or {}).get(spec, spec), fontsize=9)
            ax.set_xlabel(LABELS.get(n2, n2))
            ax.set_ylabel(LABELS.get(n1, n1))
            for n, setter in ((n1, ax.set_yscale), (n2, ax.set_xscale)):
                if RandomizeConfig.dist(n) == LOG:
                    setter("log")
        fig.colorbar(im, ax=axes[0].tolist(), label=metric_label("energy_integral_ms"))
        fig.suptitle(f"{res.scene_name}: energy integral on the same {res.episodes} drops (+: nominal)")
    return save_figure(fig, path)


def format_table(res: Robustness) -> str:
    names = [a[0] for a in res.axes]
    head = [*names, "policy", "int E ms", "catch s", "caught", "peak N", "sat ms", "bounces"]
    lines = ["  ".join(f"{h:>14s}" for h in head)]
    for p, row in zip(res.points, res.summaries, strict=True):
        for spec in res.specs:
            s = row[spec]
            t = s.get("time_to_catch_median_s")
            catch = ">H" if t is None or not math.isfinite(float(t)) else f"{float(t):.3f}"
            cells = [*(f"{p[n]:.4g}" for n in names), spec[-14:], f"{_value(s, 'energy_integral_ms', 0):.2f}",
                     catch, f"{100 * _value(s, 'caught_fraction', 0):.0f}%",
                     f"{_value(s, 'peak_force_N', 0):.1f}",
                     f"{1e3 * _value(s, 'saturation_time_s', 0):.2f}", f"{_value(s, 'bounces', 0):.1f}"]
            lines.append("  ".join(f"{c:>14s}" for c in cells))
    return "\n".join(lines)
