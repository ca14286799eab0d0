"""compare's metrics of a logged rig episode: exact from a virtual rig's true columns (the same
:class:`~impact_env.sim.metrics.EpisodeMetrics` kernel as ``impact-env compare``, so a lock-step
virtual rig gives the simulator's numbers), estimated from body 2's sensors otherwise
(:func:`impact_env.rig.flight_energy.summarize`, thesis eq 4.5)."""

from __future__ import annotations

import numpy as np

from impact_env.hardware.batch import Hardware
from impact_env.rig.log import EpisodeLog
from impact_env.sim import records
from impact_env.sim.metrics import EpisodeMetrics


def has_truth(log: EpisodeLog) -> bool:
    return "true_x1_m" in log.columns


def log_records(log: EpisodeLog) -> np.ndarray:
    """The tick records (float64[n, N_REC], :mod:`impact_env.sim.records`) of ticks 0 .. n - 1, n
    the tick after the last that applied a command, from a virtual rig's log, on the true time
    axis: row k is tick k (``tick / rate``), whatever rows the log lacks.  A tick skipped by an
    overrun has no row: its command is the one held (the DAC held it: exact), its true state is
    interpolated linearly between the rows around it (an approximation, for those ticks only; a
    log without skipped ticks is used as it is).  A tick's detector bit is the one of the next
    row: the front end conditions tick k's readings at tick k + 1."""
    act = ~np.isnan(log["action"])
    n_rows = int(np.flatnonzero(act)[-1]) + 1 if act.any() else 0
    tick = np.asarray(log["tick"][:n_rows], dtype=np.int64)
    n = int(tick[-1]) + 1 if n_rows else 0
    k = np.arange(n)
    prev = np.searchsorted(tick, k, side="right") - 1  # the row at or before each tick (held values)

    def smooth(name):
        v = np.asarray(log[name][:n_rows], dtype=np.float64)
        return v if n == n_rows else np.interp(k, tick, v)  # (no gap: the rows as they are)

    def held(values):
        return np.asarray(values, dtype=np.float64)[:n_rows][prev] if n else np.zeros(0)

    rec = np.zeros((n, records.N_REC))
    rec[:, records.REC.t] = (k + 1) / log.meta.control_rate_hz
    for j, name in enumerate(("true_x1_m", "true_v1_mps", "true_x2_m", "true_v2_mps")):
        rec[:, records.REC.x1 + j] = smooth(name)
    rec[:, records.REC.u] = held(log["command"])
    rec[:, records.REC.f_demand] = held(log["hw_force_demand_N"])
    rec[:, records.REC.f_applied] = smooth("hw_force_applied_N")
    rec[:, records.REC.saturated] = held(log["hw_saturated"])
    rec[:, records.REC.contact_force] = smooth("hw_contact_force_N")
    det = np.asarray(log["contact_detected"], dtype=np.float64)
    nxt = np.append(det[1:n_rows + 1], det[-1]) if det.size <= n_rows else det[1:n_rows + 1]
    rec[:, records.REC.detected] = nxt[prev] if n else 0.0
    rec[:, records.REC.status] = held(log["hw_status"])
    return rec


def skipped_fraction(log: EpisodeLog) -> float:
    """The share of the episode's ticks that did not run (overruns), from its rows' tick numbers."""
    tick = np.asarray(log["tick"], dtype=np.int64)
    if tick.size == 0:
        return 0.0
    return float(int(tick[-1]) + 1 - tick.size) / float(int(tick[-1]) + 1)


def exact_metrics(log: EpisodeLog, catch_fraction: float = 0.01,
                  min_flight_s: float = 1e-3) -> dict[str, float]:
    """The episode's metrics from a virtual rig's true columns (NaN where the plant failed).  The
    drop's constants (plant row, start state, impact energy and speed, first touch) are those the
    virtual rig drew from the log's seed, rebuilt the same way (from its physics, when it differs
    from the scene it was described by)."""
    from gymnasium.utils import seeding

    rec = log_records(log)
    hw = Hardware(log.physics(), 1)  # (a virtual rig's own hardware, when it differs from its description)
    hw.reset([seeding.np_random(int(log.meta.seed))[0]])
    m = EpisodeMetrics(1, 1.0 / log.meta.control_rate_hz, catch_fraction, min_flight_s)
    m.start(hw.t_touch, hw.impact_speed, hw.impact_energy, hw.Y[:, 0] - hw.Y[:, 2] > 0.0)
    m.step(rec[None, :, :], hw.P)
    failed = np.array([bool(np.any(rec[:, records.REC.status] != 0.0)) or len(rec) == 0])
    return {k: float(v[0]) for k, v in m.finish(failed).items()}
