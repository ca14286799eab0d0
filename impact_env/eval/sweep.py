"""``impact-env sweep``: a policy's two gains over a grid (the thesis's fig 4.4).

The thesis ran the rig law (eq 4.3) for many (h01, h11) pairs in simulation and plotted, per
pair, the peak control force against body 1's speed when the bodies first separate (sec 4.3,
fig 4.4): many pairs stop body 1 completely but ask for more force than the shaker has; with
about 200 N the exit speed can be brought to about 30 % of the impact speed.

Here every pair is one env of one batch (the law takes per-env gain arrays), all on the same
seeded drop, so a 20 x 20 grid is a single rollout of 400 envs, split over the cores.

Force limit.  By default (``limit="none"``) the scene's ``saturation`` effect is switched off and
``effects.command_scale`` raised to ``UNLIMITED_SCALE`` so that the law gets the force it asks for,
as in the thesis's figure; the pairs whose peak force stays within the scene's limit
(``effects.saturation.peak_n`` if the scene saturates, else its ``command_scale``) are marked,
and the best pair is the one among them with the smallest ``objective`` (default: the exit
speed ratio; ties go to the smaller peak force).  With ``limit="scene"`` the scene runs as it
is (forces clipped), and every pair is within the limit by construction.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from impact_env.eval.compare import check_cluster_specs, warm_up
from impact_env.eval.labels import metric_label
from impact_env.eval.parallel import prepare, report, run_tasks, session
from impact_env.eval.rollout import EPISODE_METRICS, rollout
from impact_env.figstyle import save_figure
from impact_env.policy.registry import policy_class
from impact_env.scene import load_scene

UNLIMITED_SCALE = 1.0e5  # N: command_scale when the force is not limited
DEFAULT_AXES = {"thesis-rig": (("h01", "1e5:5e6:20"), ("h11", "1:1000:20"))}


def parse_grid(name: str, text: str, log: bool) -> np.ndarray:
    """``"lo:hi:n"`` -> n values from lo to hi, linear or (``log``) geometric."""
    parts = str(text).split(":")
    try:
        if len(parts) == 1:
            lo = hi = float(parts[0])
            n = 1
        elif len(parts) == 3:
            lo, hi, n = float(parts[0]), float(parts[1]), int(parts[2])
        else:
            raise ValueError
    except ValueError:
        raise ValueError(f"grid for {name} = {text!r}: expected LO:HI:N (e.g. 1e5:5e6:20) "
                         "or one value") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo or n < 1 or (n > 1 and hi == lo):
        raise ValueError(f"grid for {name} = {text!r} is out of range: need finite LO < HI and N >= 1 points")
    if n > 1000:
        raise ValueError(f"grid for {name} = {text!r}: N = {n} is out of range, at most 1000 points per axis")
    if log:
        if lo <= 0:
            raise ValueError(f"grid for {name} = {text!r}: a log grid needs LO > 0")
        return np.geomspace(lo, hi, n)
    return np.linspace(lo, hi, n)


@dataclass
class SweepResult:
    policy: str
    x_name: str
    y_name: str
    x: np.ndarray
    y: np.ndarray
    metrics: dict  # name -> float64[nx, ny]
    within_limit: np.ndarray  # bool[nx, ny]
    force_limit_N: float
    objective: str
    best: dict | None
    failures: list
    limit: str
    t_end: float
    seed: int
    fixed: dict = field(default_factory=dict)
    wall_time_s: float = 0.0

    def to_json(self) -> dict:
        def clean(v):
            return None if isinstance(v, float) and not math.isfinite(v) else v

        return {"policy": self.policy, "x": self.x_name, "y": self.y_name,
                "pairs": int(self.within_limit.size),
                "within_limit": int(self.within_limit.sum()), "force_limit_N": self.force_limit_N,
                "limit": self.limit, "objective": self.objective, "t_end_s": self.t_end, "seed": self.seed,
                "fixed": self.fixed,
                "best": None if self.best is None else {k: clean(v) for k, v in self.best.items()},
                "failed_pairs": len(self.failures), "wall_time_s": self.wall_time_s}


@dataclass
class _Chunk:
    policy: str
    scene: Any
    x_name: str
    y_name: str
    xs: np.ndarray
    ys: np.ndarray
    fixed: dict
    seed: int
    t_end: float


def _run_chunk(c: _Chunk):
    policy = policy_class(c.policy)(c.scene, **c.fixed, **{c.x_name: c.xs, c.y_name: c.ys})
    r = rollout(c.scene, policy, [c.seed] * len(c.xs), horizon=c.t_end, trace_rate=0.0, name=c.policy,
                progress=report)
    return r.metrics, r.failures


def sweep_scene(scene, limit: str):
    """The scene the sweep runs and the force limit (N) that marks the pairs."""
    fx = scene.effects
    force_limit = fx.saturation.peak_n if fx.on("saturation") else fx.command_scale
    if limit == "none":
        active = [e for e in fx.active if e != "saturation"]
        scene = scene.with_overrides({"effects.active": active, "effects.command_scale": UNLIMITED_SCALE})
    elif limit != "scene":
        raise ValueError(f"limit = {limit!r} is not one of none, scene")
    return scene, float(force_limit)


def sweep(scene, policy: str = "thesis-rig", axes=None, fixed: dict | None = None, seed: int = 0,
          t_end: float = 0.02, limit: str = "none", objective: str = "exit_speed_ratio",
          workers: int | None = None, progress: bool = True, cluster=None) -> SweepResult:
    """Run ``policy`` for every pair of ``axes = ((name_x, values), (name_y, values))``.

    ``cluster``: a Dask scheduler's ``tcp://HOST:PORT`` (or a connected
    :class:`~impact_env.eval.parallel.Cluster`): the chunks run on its workers, with the same
    results; ``workers`` (the number of chunks) then defaults to the cluster's worker threads."""

    scene = load_scene(scene)
    cls = policy_class(policy)
    if objective not in EPISODE_METRICS:
        raise ValueError(f"objective {objective!r} is not a metric (valid: {', '.join(EPISODE_METRICS)})")
    if not (t_end > 0 and math.isfinite(t_end)):
        raise ValueError(f"t_end = {t_end!r} s must be a finite time > 0 s")
    (xn, xv), (yn, yv) = axes
    if xn == yn:
        raise ValueError(f"the two grid axes must be different parameters, got {xn!r} twice")
    fixed = dict(fixed or {})
    run_scene, force_limit = sweep_scene(scene, limit)
    # validate names and values once, before anything runs
    cls(run_scene, **fixed, **{xn: np.asarray(xv, float), yn: np.asarray(yv, float)})
    if cluster is not None:
        check_cluster_specs([policy])
    with session(cluster, workers) as (cl, workers):
        return _sweep(run_scene, policy, xn, xv, yn, yv, fixed, seed, t_end, limit, objective, force_limit,
                      workers, progress, cl)


def _sweep(run_scene, policy, xn, xv, yn, yv, fixed, seed, t_end, limit, objective, force_limit, workers,
           progress, cl) -> SweepResult:

    X, Y = np.meshgrid(np.asarray(xv, float), np.asarray(yv, float), indexing="ij")
    xs, ys = X.ravel(), Y.ravel()
    k = min(workers, len(xs))
    bounds = np.linspace(0, len(xs), k + 1).round().astype(int)
    chunks = [_Chunk(policy, run_scene, xn, yn, xs[a:b], ys[a:b], fixed, seed, t_end)
              for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    prepare(warm_up, run_scene, t_end, workers=workers, cluster=cl)
    n_steps = int(round(t_end / run_scene.control_period))
    t0 = time.perf_counter()
    outs = run_tasks(_run_chunk, chunks, workers, total=n_steps * len(chunks),
                     desc=f"sweep ({len(xs)} gain pairs)", progress=progress, cluster=cl)
    wall = time.perf_counter() - t0
    metrics = {key: np.concatenate([o[0][key] for o in outs]).reshape(X.shape) for key in EPISODE_METRICS}
    failures = []
    for a, o in zip(bounds[:-1], outs, strict=True):
        for f in o[1]:
            i = a + f["row"]
            failures.append({**f, xn: float(xs[i]), yn: float(ys[i])})
    ok = ~np.isnan(metrics[objective])
    within = ok & (metrics["peak_force_N"] <= force_limit + 1e-9)
    best = None
    if within.any():
        obj = np.where(within, metrics[objective], np.inf)
        cand = np.flatnonzero(obj.ravel() == obj.min())
        i = cand[np.argmin(metrics["peak_force_N"].ravel()[cand])]
        bi, bj = np.unravel_index(i, X.shape)
        best = {xn: float(X[bi, bj]), yn: float(Y[bi, bj]),
                **{key: float(metrics[key][bi, bj]) for key in EPISODE_METRICS}}
    return SweepResult(policy, xn, yn, np.asarray(xv, float), np.asarray(yv, float), metrics, within,
                       force_limit, objective, best, failures, limit, t_end, seed, fixed, wall)


def write_csv(res: SweepResult, path: Path) -> Path:
    import csv

    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow([res.x_name, res.y_name, *EPISODE_METRICS, "within_limit"])
        for i, xv in enumerate(res.x):
            for j, yv in enumerate(res.y):
                w.writerow([xv, yv, *(float(res.metrics[k][i, j]) for k in EPISODE_METRICS),
                            int(res.within_limit[i, j])])
    return path


def plot(res: SweepResult, path: Path, log: bool, title: str = "") -> Path:
    """Left: peak force against exit speed per pair (the thesis's fig 4.4 seen from its side);
    right: the objective over the grid; pairs within the force limit marked, the best starred."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = res.metrics
    units = _param_units(res.policy)
    xlab, ylab = (f"{n}, {units[n]}" if units.get(n) else n for n in (res.x_name, res.y_name))
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.3))
    inside = res.within_limit
    ax[0].scatter(m["exit_speed_ratio"][~inside], m["peak_force_N"][~inside], s=8, c="0.6",
                  label="above the force limit")
    ax[0].scatter(m["exit_speed_ratio"][inside], m["peak_force_N"][inside], s=10, c="tab:blue",
                  label=f"within {res.force_limit_N:g} N")
    ax[0].axhline(res.force_limit_N, color="k", lw=0.7, ls=":")
    ax[0].set_yscale("log")
    ax[0].set_xlabel(metric_label("exit_speed_ratio"))
    ax[0].set_ylabel("peak force on body 2, N")
    ax[0].set_title("each gain pair (cf. thesis fig 4.4)", fontsize=9)
    Z = m[res.objective]
    mesh = ax[1].pcolormesh(res.x, res.y, Z.T, shading="nearest", cmap="viridis")
    fig.colorbar(mesh, ax=ax[1], label=metric_label(res.objective))
    if res.within_limit.any() and not res.within_limit.all():
        ax[1].contour(res.x, res.y, res.within_limit.T.astype(float), levels=[0.5], colors="w", linewidths=1)
    Xg, Yg = np.meshgrid(res.x, res.y, indexing="ij")
    ax[1].scatter(Xg[inside], Yg[inside], s=4, c="w", label=f"peak <= {res.force_limit_N:g} N")
    if log:
        ax[1].set_xscale("log")
        ax[1].set_yscale("log")
    ax[1].set_xlabel(xlab)
    ax[1].set_ylabel(ylab)
    ax[1].set_title("over the gain grid (colour: see the bar)", fontsize=9)
    if res.best is not None:
        b = res.best
        ax[0].scatter([b["exit_speed_ratio"]], [b["peak_force_N"]], marker="*", s=160, c="tab:red",
                      label=f"best: {res.x_name}={b[res.x_name]:.3g}, {res.y_name}={b[res.y_name]:.3g}")
        ax[1].scatter([b[res.x_name]], [b[res.y_name]], marker="*", s=160, c="tab:red")
    ax[0].legend(fontsize=7)
    ax[1].legend(fontsize=7, loc="upper right")
    limits = "no force limit" if res.limit == "none" else "scene limits"
    fig.suptitle(title or f"{res.policy}: gain sweep ({limits})", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def _param_units(policy: str) -> dict[str, str]:
    """Units of the swept policy's parameters (empty if it cannot be looked up)."""
    try:
        return {k: p.unit for k, p in policy_class(policy).PARAMS.items()}
    except Exception:  # noqa: BLE001  (labels only: a plot without units beats no plot)
        return {}
