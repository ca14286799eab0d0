"""``impact-env compare --rig udp://HOST:PORT``: the comparison measured on a rig behind a target.

Every policy runs the same episodes as in simulation (episode j seeded ``seed + j``):

* classic laws and compiled policy files run **onboard**: the policy is exported
  (:func:`impact_env.policy.export.export_policy`), uploaded at arm time and acts inside the
  target's tick; the host waits for the episode's end and fetches its log;
* saved stable-baselines3 models run in **host mode**: the host steps the model on the
  target's observations, one COMMAND per policy step, then fetches the log;
* with ``on_host`` (``compare --rig ... --on-host``) every policy, SB3 models included, is
  exported and runs in host mode **compiled on the host** (:meth:`RigClient.run_policy`): each
  OBSERVATION answered in the compiled call that read it, fast enough for hold 1 in real time.

The metrics come from each episode's log (:mod:`impact_env.rig.log_metrics`): exact from a
virtual rig's true columns, estimated from body 2's sensors on a physical rig (thesis eq 4.5).
With ``--scene`` too, the same policies run in simulation on the same seeds, classic laws as the
same compiled policies, so that on a lock-step virtual rig both tables agree (the sim-to-rig gap
is zero there; a physical rig's gap is the thing to look at).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from impact_env.config import ConfigError
from impact_env.eval.compare import ENERGY_CURVE_RATE, PolicyRun, summarize
from impact_env.plant.energy import catch_energy
from impact_env.policy.export import export_policy
from impact_env.policy.registry import is_model_spec, make_policy
from impact_env.rig.flight_energy import summarize as estimate
from impact_env.rig.host import RigClient
from impact_env.rig.log_metrics import exact_metrics, has_truth, skipped_fraction
from impact_env.rig.transport import RigTimeout
from impact_env.sim.metrics import EPISODE_METRICS

TRACE_MAP = {"x1": "true_x1_m", "v1": "true_v1_mps", "x2": "true_x2_m", "v2": "true_v2_mps",
             "force_demand": "hw_force_demand_N", "force_applied": "hw_force_applied_N",
             "contact_force": "hw_contact_force_N", "detected": "contact_detected",
             "saturated": "hw_saturated"}


def rig_compare(address: str, specs: list[str], episodes: int = 10, seed: int = 0,
                horizon: float | None = None, progress: bool = True,
                key=None, on_host: bool = False) -> tuple[Any, dict[str, PolicyRun]]:
    """(the target's scene, spec -> PolicyRun) measured on the rig at ``address`` (``key``: the
    session key file the target was started with, or None; ``on_host``: every policy compiled on
    this host, in host mode)."""

    try:
        client = RigClient(address, key=key)
    except (RigTimeout, ConnectionError) as exc:  # nothing listening yet: one line, not a traceback
        raise ConfigError(f"--rig {address}: no target answered ({type(exc).__name__}: {exc}); start it "
                          "first (impact-env rig serve --virtual|--driver ... --port PORT) or check the "
                          "address") from None
    scene = client.scene
    horizon = scene.episode.horizon if horizon is None else float(horizon)
    runs = {}
    try:
        prepared = {}
        for spec in specs:  # validate every policy before anything runs
            if on_host:
                prepared[spec] = ("on-host", export_policy(spec, scene))
            elif is_model_spec(spec):
                prepared[spec] = ("host", make_policy(spec, scene))
            else:
                prepared[spec] = ("onboard", export_policy(spec, scene))
        for spec in specs:
            mode, pol = prepared[spec]
            t0 = time.perf_counter()
            logs, failures = [], []
            for j in range(episodes):
                s = seed + j
                try:
                    logs.append(_episode(client, mode, pol, s, horizon, scene))
                except Exception as exc:  # a failed episode is reported, not fatal (as in compare)
                    logs.append(None)
                    failures.append({"policy": spec, "episode": j, "seed": s, "row": j, "t_s": 0.0,
                                     "error": f"{type(exc).__name__}: {exc}"})
                if progress:
                    print(f"\rcompare --rig: {spec}: {j + 1}/{episodes} episodes", end="", flush=True,
                          file=__import__("sys").stderr)
            if progress:
                print(file=__import__("sys").stderr)
            runs[spec], skipped = _run(spec, logs, failures, time.perf_counter() - t0)
            runs[spec].summary = summarize(runs[spec])
            runs[spec].summary["skipped_tick_fraction"] = skipped_tick_fraction(skipped)
    finally:
        client.close()
    return scene, runs


def skipped_tick_fraction(per_episode: np.ndarray) -> float:
    """The share of a policy's ticks that did not run (overruns): the mean of its episodes' shares
    (:func:`impact_env.rig.log_metrics.skipped_fraction`, NaN: no log); NaN without logs."""
    f = np.asarray(per_episode, dtype=np.float64)
    f = f[np.isfinite(f)]
    return float(f.mean()) if f.size else math.nan


def _episode(client, mode: str, pol, seed: int, horizon: float, scene):
    """One episode on the rig; returns its log."""
    if mode == "onboard":
        hold = pol.hold_ticks
        n_ticks = int(round(horizon / (scene.control_period * hold))) * hold
        client.arm("onboard", seed, n_ticks, pol.observation, pol.history, hold, pol)
        end = client.wait_end(timeout_s=30.0 + 20.0 * n_ticks / scene.control_rate)
        return client.fetch_log(end.episode, end.data_sha256)
    if mode == "on-host":
        run = client.run_policy(pol, seed, int(round(horizon / (scene.control_period * pol.hold_ticks))))
        return client.fetch_log(run.end.episode, run.end.data_sha256)
    hold = int(getattr(pol, "hold_ticks", 1))
    residual = None
    if getattr(pol, "residual", None):
        residual = export_policy(pol.residual, scene)
    n_steps = int(round(horizon / (scene.control_period * hold)))
    client.arm("host", seed, n_steps * hold, pol.observation, pol.history, hold, residual)
    obs = _observation(client, 0)
    state, start = None, np.ones(1, dtype=bool)
    for n in range(n_steps):
        action, state = pol.predict(np.asarray(obs.obs, dtype=np.float32)[None, :], state=state,
                                    episode_start=start, deterministic=True)
        start = np.zeros(1, dtype=bool)
        a = float(np.clip(np.asarray(action, dtype=np.float64).reshape(-1)[0], -1.0, 1.0))
        client.command(n, a)
        obs = _observation(client, n + 1, resend=(n, a))
    end = client.wait_end(timeout_s=10.0)
    return client.fetch_log(end.episode, end.data_sha256)


def _observation(client, step: int, resend=None):
    for _ in range(client.retries + 1):
        got = client.observation(step, client.timeout_s)
        if got is not None:
            return got
        if resend is not None:
            client.command(*resend)
    raise RigTimeout(f"OBSERVATION of step {step}", (client.retries + 1) * client.timeout_s, client.address)


# the ends of a whole episode, as the simulator's: any other (OVERRUN, SENSOR_FAULT, LINK_LOST,
# SAFETY, FAULT, FIRST_COMMAND_TIMEOUT, DISARMED) is an episode the rig cut short: failed, named
WHOLE_ENDS = ("HORIZON", "CAUGHT")


def _run(spec: str, logs: list, failures: list, wall: float) -> tuple[PolicyRun, np.ndarray]:
    """A PolicyRun (as compare makes it) from the episodes' logs, and each episode's share of
    skipped ticks (NaN: no log).  An episode whose log ends otherwise than at its horizon or a
    catch counts as failed (its metrics NaN) and is named in ``failures`` with its end reason."""
    n = len(logs)
    metrics = {k: np.full(n, np.nan) for k in EPISODE_METRICS}
    period = math.nan
    trace0, trace_t, t_touch0, e00 = None, None, math.nan, math.nan
    ratios = []
    energy_t: Any = None
    skipped = np.full(n, np.nan)
    for j, log in enumerate(logs):
        if log is None:
            continue
        period = 1.0 / log.meta.control_rate_hz
        skipped[j] = skipped_fraction(log)
        end = str(log.meta.end_reason)
        if end not in WHOLE_ENDS:
            failures.append({"policy": spec, "episode": j, "seed": int(log.meta.seed), "row": j,
                             "t_s": float(log["t_s"][-1]) if log.n_ticks else 0.0,
                             "error": f"the rig ended the episode {end} at tick {int(log['tick'][-1])}: cut "
                                      "short, not a whole episode"})
            continue
        if has_truth(log):
            m = exact_metrics(log)
        else:
            m = estimate(log)
        for k in EPISODE_METRICS:
            if k in m and m[k] is not None:
                metrics[k][j] = float(m[k])
        if has_truth(log):
            p = log.scene().plant
            e = catch_energy(log["true_x1_m"], log["true_v1_mps"], log["true_x2_m"], p.m1, p.c, p.gravity)
            e0 = float(log["impact_energy_J"][0])
            stride = max(1, int(round(1.0 / (ENERGY_CURVE_RATE * period))))
            t = log["t_s"] + period  # a row's truth is the state after its tick
            tick = np.asarray(log["tick"], dtype=np.int64)
            grid = np.arange(0, int(tick[-1]) + 1, stride)  # the true time axis, not the rows
            ratios.append(np.interp(grid, tick, e / e0))
            energy_t = (grid + 1) * period
            if trace0 is None:
                trace_t = t
                trace0 = {k: np.asarray(log[c], dtype=np.float64) for k, c in TRACE_MAP.items()}
                trace0["catch_energy"] = e
                t_touch0, e00 = float(log["t_touch_s"][0]), e0
    if ratios:
        size = min(len(r) for r in ratios)
        ratio = np.stack([r[:size] for r in ratios], axis=1)
        energy_t = energy_t[:size]
    else:
        ratio = None
    run = PolicyRun(spec=spec, episodes=np.arange(n), metrics=metrics, failures=failures, trace_t=trace_t,
                    trace0=trace0, t_touch0=t_touch0, impact_energy0=e00, energy_t=energy_t,
                    energy_ratio=ratio, control_period=period, wall_time_s=wall)
    return run, skipped
