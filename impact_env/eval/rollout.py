"""Rollouts: one policy on a batch of seeded drops, stepped together, with metrics kept online.

A rollout runs the native vector env (:class:`~impact_env.env.vector.ImpactCatchVectorEnv`,
autoreset disabled, no termination on catch, so every episode lasts the whole horizon) with one
env per episode: the policy sees exactly the observations a trained agent sees, and the batch
is one kernel call per control step.  Env i is seeded with ``seeds[i]``; ``impact-env compare``
gives episode ``j`` of a run with seed ``s`` the seed ``s + j``, which is what
``ImpactCatchVectorEnv.reset(seed=s)`` gives its env ``j`` (and ``gymnasium.make("ImpactCatch-v0")``
reset with ``seed=s + j``), so every policy meets the same drops and the same sensor noise.

Metrics are exact at the control rate (accumulated at every control step, not from the
decimated traces):

* ``time_to_catch_s``: time from the first touch after which body 1's catch energy
  (:func:`impact_env.plant.energy.catch_energy`) stays below ``catch_fraction`` (default 1 %)
  of its value at the start; ``inf`` if it is above at the end of the horizon.
* ``residual_energy_{10,50,100}ms``: catch energy over its starting value, at the first control
  sample at least 10, 50, 100 ms after the first touch (NaN past the horizon).
* ``exit_speed_ratio``: body 1's speed |v1| at the first separation after the first touch over
  the impact speed (0 when contact is never lost within the horizon), read at the first control
  sample without contact (at most one period after the separation: an error below
  ``g T_s``, 1 mm/s at 10 kHz, in free flight).  ``exit_velocity_ratio`` is the
  same with a sign: positive when body 1 leaves upwards (a bounce), negative when it is still
  falling and body 2 has moved away from under it.
* ``bounces``: separations after which body 1 stays free for at least ``min_flight_s``
  (default 1 ms, a flight about 1 um high; shorter ones are chatter, not visible bounces).
* ``peak_force_N``, ``rms_force_N``: largest |force| and RMS force applied to body 2 over the
  episode (after shaker and saturation); ``peak_demand_N``: largest |demand| (action times
  ``command_scale``), what the law asked for.
* ``energy_integral_ms``: the time integral of the catch-energy ratio over the episode, in ms
  (an uncaught body keeping 40 % of its energy for 0.3 s scores 120); with the env's default
  reward weights it is minus the episode's return.
* ``contact_fraction``: share of the control samples after the first touch with true contact.
* ``saturation_time_s``: time at the force limit: the action at +-1 (the demand clipped to
  +-``command_scale``, by the policy or the env's action space) or the scene's ``saturation``
  effect changing the force.

A policy that raises, or returns a non-finite action, does not stop the rollout: the episodes
it failed are recorded in ``failures`` (episode, seed, time, message), get zero force from then
on and are left out of the metrics.

Open-loop policies (the hook :mod:`impact_env.eval.oracle` uses).  A policy with a method
``prepare(scene, seeds, horizon, warm_starts)`` has it called once before the first step with the
scene, the episodes' seeds (int64[N]), the horizon (s, a whole number of control periods) and
``warm_starts`` (name -> float64[n_steps, N]: other policies' commands on the same episodes, or
``{}``); whatever it leaves in ``policy.stats`` (a dict) is returned in ``extras["policy_stats"]``.
A policy whose ``open_loop`` attribute is then not None (float[n_steps, N], commands in [-1, 1])
is replayed from it: step k applies ``open_loop[k - 1]`` and ``predict`` is never called.
``record_commands=True`` keeps the commands the rollout applied (after clipping, 0 for failed
episodes) in ``extras["commands"]`` (float64[n_steps, N]); replaying them open loop on the same
seeds reproduces the bodies' motion bitwise (sensor noise does not move the bodies).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from gymnasium.vector import AutoresetMode

from impact_env.env.vector import ImpactCatchVectorEnv
from impact_env.scene import Scene

RESIDUAL_MARKS_S = (0.010, 0.050, 0.100)
TRACE_KEYS = ("x1", "v1", "x2", "v2", "force_demand", "force_applied", "contact_force", "catch_energy",
              "detected", "saturated")
EPISODE_METRICS = ("impact_speed_mps", "time_to_catch_s", "residual_energy_10ms", "residual_energy_50ms",
                   "residual_energy_100ms", "exit_speed_ratio", "exit_velocity_ratio", "bounces",
                   "peak_force_N", "rms_force_N", "peak_demand_N", "energy_integral_ms", "contact_fraction",
                   "saturation_time_s")


@dataclass
class RolloutResult:
    """What a rollout returns: per-episode metrics, failures and decimated traces.

    ``metrics[name]``: float64[N] (see the module doc; NaN for failed episodes).
    ``traces[key]``: float64[T, N] sampled every ``trace_period`` s, ``trace_t``: float64[T]
    (s since the episode start); ``t_touch``: float64[N] (s, first touch).
    """

    policy: str
    episodes: np.ndarray
    seeds: np.ndarray
    metrics: dict[str, np.ndarray]
    failures: list[dict]
    trace_t: np.ndarray
    traces: dict[str, np.ndarray]
    t_touch: np.ndarray
    impact_energy: np.ndarray
    control_period: float
    wall_time_s: float = 0.0
    extras: dict = field(default_factory=dict)


def rollout(scene: Scene, policy, seeds, horizon: float | None = None, episodes=None,
            trace_rate: float = 1.0e4, catch_fraction: float = 0.01, min_flight_s: float = 1.0e-3,
            name: str = "", progress: Callable[[int], None] | None = None,
            warm_starts: dict[str, np.ndarray] | None = None, record_commands: bool = False) -> RolloutResult:
    """Run ``policy`` (SB3 ``predict``; attributes ``observation`` and optionally ``history``) on
    one episode per entry of ``seeds`` (ints) for ``horizon`` s (default ``scene.episode.horizon``).
    ``episodes`` labels them in failure reports (default 0..N-1); traces are kept every
    ``1 / trace_rate`` s (rounded to whole control periods); ``progress(k)`` is called with the
    number of control steps done since its last call.  ``warm_starts``, ``record_commands``: see
    "Open-loop policies" in the module doc."""
    seeds = np.asarray(list(seeds), dtype=np.int64)
    n = len(seeds)
    if n < 1:
        raise ValueError("rollout needs at least one episode (seed)")
    episodes = np.arange(n) if episodes is None else np.asarray(list(episodes), dtype=np.int64)
    if len(episodes) != n:
        raise ValueError(f"episodes has {len(episodes)} labels for {n} seeds")
    horizon = scene.episode.horizon if horizon is None else float(horizon)
    if not (horizon > 0 and math.isfinite(horizon)):
        raise ValueError(f"horizon = {horizon!r} s must be a finite time > 0 s")
    period = scene.control_period
    n_steps = int(round(horizon / period))
    if n_steps < 1:
        raise ValueError(f"horizon = {horizon:g} s is shorter than one control period ({period:g} s)")
    # traces every 1/trace_rate s in whole control periods; trace_rate <= 0: only the start
    stride = max(1, int(round(1.0 / (trace_rate * period)))) if trace_rate > 0 else n_steps + 1
    observation = getattr(policy, "observation", None)
    if observation not in ("sensors", "privileged", "both"):
        raise ValueError(f"policy {name!r} must say which observation it needs (attribute 'observation' = "
                         f"'sensors', 'privileged' or 'both'), got {observation!r}")
    history = int(getattr(policy, "history", 1))

    t_wall = time.perf_counter()
    venv = ImpactCatchVectorEnv(n, scene, autoreset_mode=AutoresetMode.DISABLED, observation=observation,
                                history=history, horizon=n_steps * period, terminate_on_catch=False)
    obs, info = venv.reset(seed=[int(x) for x in seeds])
    t_touch = info["t_touch"].copy()
    v_imp = info["impact_speed"].copy()
    e0 = info["impact_energy"].copy()

    failed = np.zeros(n, dtype=bool)
    failures: list[dict] = []
    state = None
    starts = np.ones(n, dtype=bool)

    # online accumulators
    peak = np.zeros(n)
    peak_dem = np.zeros(n)
    sumsq = np.zeros(n)
    sat_steps = np.zeros(n)
    contact_steps = np.zeros(n)
    after_steps = np.zeros(n)
    ratio_sum = np.zeros(n)
    last_above = np.full(n, -np.inf)
    marks = np.full((len(RESIDUAL_MARKS_S), n), np.nan)
    exit_vel = np.full(n, np.nan)
    was_contact = info["contact"].copy()
    t_sep = np.full(n, np.nan)  # start of the current flight, s
    bounces = np.zeros(n)
    n_tr = n_steps // stride + 1
    traces = {k: np.zeros((n_tr, n)) for k in TRACE_KEYS}
    trace_t = np.zeros(n_tr)
    _trace(traces, trace_t, 0, info, 0.0)

    def fail(rows, t, message):
        for i in np.nonzero(rows & ~failed)[0]:
            failures.append({"policy": name, "episode": int(episodes[i]), "seed": int(seeds[i]),
                             "row": int(i), "t_s": float(t), "error": message})
        failed[rows] = True

    extras: dict = {}
    open_loop = _prepare(policy, scene, seeds, n_steps, period, warm_starts, extras,
                         lambda msg: fail(np.ones(n, dtype=bool), 0.0, msg))
    commands = np.zeros((n_steps, n)) if record_commands else None
    reported = 0
    for k in range(1, n_steps + 1):
        t_prev = (k - 1) * period
        try:
            if open_loop is not None:
                a = np.asarray(open_loop[k - 1], dtype=np.float64).reshape(n)
            else:
                action, state = policy.predict(obs, state=state, episode_start=starts, deterministic=True)
                a = np.asarray(action, dtype=np.float64).reshape(n)
        except Exception as exc:  # a broken policy is reported, not fatal (see module doc)
            fail(np.ones(n, dtype=bool), t_prev, f"{type(exc).__name__}: {exc}")
            a = np.zeros(n)
        starts = np.zeros(n, dtype=bool)
        bad = ~np.isfinite(a)
        if bad.any():
            fail(bad, t_prev, f"non-finite action {a[bad][0]!r}")
        a = np.clip(np.where(failed, 0.0, a), -1.0, 1.0)  # the env's action space
        if commands is not None:
            commands[k - 1] = a
        obs, _r, _term, _trunc, info = venv.step(a[:, None])
        t = k * period
        div = info["diverged"]
        if div.any():
            fail(div, t, "simulation diverged")
        f = info["force_applied"]
        np.maximum(peak, np.abs(f), out=peak)
        np.maximum(peak_dem, np.abs(info["force_demand"]), out=peak_dem)
        sumsq += f * f
        sat_steps += info["saturated"] | (np.abs(a) >= 1.0)
        after = t > t_touch
        contact = info["contact"]
        after_steps += after
        contact_steps += after & contact
        ratio = info["catch_energy_ratio"]
        ratio_sum += ratio
        last_above = np.where(ratio >= catch_fraction, t, last_above)
        since = t - t_touch
        for m, mark in enumerate(RESIDUAL_MARKS_S):
            hit = np.isnan(marks[m]) & (since >= mark - 1e-12)
            if hit.any():
                marks[m, hit] = ratio[hit]
        # separations and bounces, at the control samples
        left = was_contact & ~contact & after
        if left.any():
            first = left & np.isnan(exit_vel)
            exit_vel[first] = -info["state"][first, 1] / v_imp[first]  # upwards positive
            t_sep[left] = t
        landed = ~was_contact & contact & ~np.isnan(t_sep)
        if landed.any():
            bounces += landed & (t - t_sep >= min_flight_s)
            t_sep[landed] = np.nan
        was_contact = contact.copy()
        if k % stride == 0:
            _trace(traces, trace_t, k // stride, info, t)
        if progress is not None and (k - reported >= 200 or k == n_steps):
            progress(k - reported)
            reported = k
    t_end = n_steps * period
    bounces += ~np.isnan(t_sep) & (t_end - t_sep >= min_flight_s)  # still in a long flight at the end
    venv.close()

    ttc = np.where(last_above >= t_end - 1e-12, np.inf, np.maximum(last_above + period, t_touch) - t_touch)
    ttc = np.where(last_above == -np.inf, 0.0, ttc)
    metrics = {
        "impact_speed_mps": v_imp,
        "time_to_catch_s": ttc,
        "residual_energy_10ms": marks[0],
        "residual_energy_50ms": marks[1],
        "residual_energy_100ms": marks[2],
        "exit_speed_ratio": np.where(np.isnan(exit_vel), 0.0, np.abs(exit_vel)),
        "exit_velocity_ratio": np.where(np.isnan(exit_vel), 0.0, exit_vel),
        "bounces": bounces,
        "peak_force_N": peak,
        "rms_force_N": np.sqrt(sumsq / n_steps),
        "peak_demand_N": peak_dem,
        "energy_integral_ms": ratio_sum * period * 1e3,
        "contact_fraction": contact_steps / np.maximum(after_steps, 1),
        "saturation_time_s": sat_steps * period,
    }
    for key in metrics:
        metrics[key] = np.where(failed, np.nan, metrics[key].astype(np.float64))
    return RolloutResult(policy=name, episodes=episodes, seeds=seeds, metrics=metrics, failures=failures,
                         trace_t=trace_t, traces=traces, t_touch=t_touch, impact_energy=e0,
                         control_period=period, wall_time_s=time.perf_counter() - t_wall,
                         extras=extras if commands is None else {**extras, "commands": commands})


def _prepare(policy, scene, seeds, n_steps, period, warm_starts, extras, fail):
    """The open-loop hook (module doc): call ``policy.prepare`` if it has one and return its
    ``open_loop`` commands (float64[n_steps, N]) or None; a failing hook fails every episode."""
    prepare = getattr(policy, "prepare", None)
    if prepare is None:
        return None
    try:
        prepare(scene, seeds.copy(), n_steps * period, dict(warm_starts or {}))
        stats = getattr(policy, "stats", None)
        if stats is not None:
            extras["policy_stats"] = stats
        u = getattr(policy, "open_loop", None)
        if u is None:
            return None
        u = np.asarray(u, dtype=np.float64)
        if u.shape != (n_steps, len(seeds)):
            raise ValueError(f"open_loop has shape {u.shape}; expected ({n_steps}, {len(seeds)}) "
                             "(control steps, episodes)")
        return u
    except Exception as exc:  # reported like a failing predict (module doc)
        fail(f"prepare: {type(exc).__name__}: {exc}")
        return np.zeros((n_steps, len(seeds)))


def _trace(traces, trace_t, j, info, t):
    trace_t[j] = t
    y = info["state"]
    traces["x1"][j] = y[:, 0]
    traces["v1"][j] = y[:, 1]
    traces["x2"][j] = y[:, 2]
    traces["v2"][j] = y[:, 3]
    for key in ("force_demand", "force_applied", "contact_force", "catch_energy", "detected", "saturated"):
        traces[key][j] = info[key]


def _count_bounces(seps, onsets, t_end, min_flight):
    count = 0
    on = np.asarray(onsets)
    for ts in seps:
        later = on[on > ts]
        t_next = later[0] if later.size else t_end
        if t_next - ts >= min_flight:
            count += 1
    return count
