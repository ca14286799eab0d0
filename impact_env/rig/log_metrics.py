"""compare's metrics of a logged rig episode: exact from a virtual rig's true columns (the same
:class:`~impact_env.sim.metrics.EpisodeMetrics` kernel as ``impact-env compare``, so a lock-step
virtual rig gives the simulator's numbers), estimated from body 2's sensors otherwise
(:func:`impact_env.rig.flight_energy.summarize`, thesis eq 4.5)."""

from __future__ import annotations

import numpy as np

from impact_env.rig.log import EpisodeLog
from impact_env.sim import records as R
from impact_env.sim.metrics import EpisodeMetrics


def has_truth(log: EpisodeLog) -> bool:
    return "true_x1_m" in log.columns


def log_records(log: EpisodeLog) -> np.ndarray:
    """The tick records (float64[n, N_REC], :mod:`impact_env.sim.records`) of the ticks that
    applied a command, from a virtual rig's log.  A tick's detector bit is the one of the next
    row: the front end conditions tick k's readings at tick k + 1."""
    act = ~np.isnan(log["action"])
    n = int(np.flatnonzero(act)[-1]) + 1 if act.any() else 0
    rec = np.zeros((n, R.N_REC))
    rec[:, R.REC_T] = (np.arange(n) + 1) / log.meta.control_rate_hz
    for j, name in enumerate(("true_x1_m", "true_v1_mps", "true_x2_m", "true_v2_mps")):
        rec[:, R.REC_X1 + j] = log[name][:n]
    rec[:, R.REC_U] = log["command"][:n]
    rec[:, R.REC_F_DEMAND] = log["hw_force_demand_N"][:n]
    rec[:, R.REC_F_APPLIED] = log["hw_force_applied_N"][:n]
    rec[:, R.REC_SATURATED] = log["hw_saturated"][:n]
    rec[:, R.REC_CONTACT_FORCE] = log["hw_contact_force_N"][:n]
    det = log["contact_detected"].astype(np.float64)
    rec[:, R.REC_DETECTED] = det[1:n + 1] if det.size > n else np.append(det[1:n + 1], det[-1])
    rec[:, R.REC_STATUS] = log["hw_status"][:n]
    return rec


def exact_metrics(log: EpisodeLog, catch_fraction: float = 0.01,
                  min_flight_s: float = 1e-3) -> dict[str, float]:
    """The episode's metrics from a virtual rig's true columns (NaN where the plant failed).  The
    drop's constants (plant row, start state, impact energy and speed, first touch) are those the
    virtual rig drew from the log's seed, rebuilt the same way (from its physics, when it differs
    from the scene it was described by)."""
    from gymnasium.utils import seeding

    from impact_env.hardware.batch import Hardware

    rec = log_records(log)
    hw = Hardware(log.physics(), 1)  # (a virtual rig's own hardware, when it differs from its description)
    hw.reset([seeding.np_random(int(log.meta.seed))[0]])
    m = EpisodeMetrics(1, 1.0 / log.meta.control_rate_hz, catch_fraction, min_flight_s)
    m.start(hw.t_touch, hw.impact_speed, hw.impact_energy, hw.Y[:, 0] - hw.Y[:, 2] > 0.0)
    m.step(rec[None, :, :], hw.P)
    failed = np.array([bool(np.any(rec[:, R.REC_STATUS] != 0.0)) or len(rec) == 0])
    return {k: float(v[0]) for k, v in m.finish(failed).items()}
