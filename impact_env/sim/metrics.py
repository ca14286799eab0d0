"""Catch metrics of episodes, accumulated tick by tick in compiled code.

:class:`EpisodeMetrics` keeps, per env, an accumulator row that :func:`update` advances by one
control tick from that tick's record (:mod:`impact_env.sim.records`), so the metrics are exact
at the control rate, whatever the policy rate, and cost nothing in Python per tick.  The same
kernel runs in the Python rollout (one batched call per step), in the compiled rollout of a
compiled policy (inside the loop), and on a rig's tick log.

Definitions (time ``t = k T`` of tick k, T the control period; ``t_touch`` the first touch):

* ``time_to_catch_s``: time from the first touch after which body 1's catch energy
  (:func:`impact_env.plant.energy.catch_energy`) stays below ``catch_fraction`` (default 1 %) of
  its value at the start; ``inf`` if it is above at the end of the horizon, 0 if never above.
* ``residual_energy_{10,50,100}ms``: catch energy over its starting value at the first tick at
  least 10, 50, 100 ms after the first touch (NaN past the horizon).
* ``exit_speed_ratio``: body 1's speed |v1| at the first separation after the first touch over
  the impact speed (0 when contact is never lost within the horizon), read at the first tick
  without contact (at most one period after the separation: an error below ``g T``, 1 mm/s at
  10 kHz, in free flight).  ``exit_velocity_ratio`` is the same with a sign: positive when body 1
  leaves upwards (a bounce), negative when it is still falling and body 2 has moved away.
* ``bounces``: separations after which body 1 stays free for at least ``min_flight_s``
  (default 1 ms, a flight about 1 um high; shorter ones are chatter, not visible bounces).
* ``peak_force_N``, ``rms_force_N``: largest |force| and RMS force applied to body 2 over the
  episode (after shaker and saturation); ``peak_demand_N``: largest |demand|.
* ``energy_integral_ms``: the time integral of the catch-energy ratio over the episode, in ms;
  with the env's default reward weights it is minus the episode's return.
* ``contact_fraction``: share of the ticks after the first touch with true contact.
* ``saturation_time_s``: time at the force limit: the command at +-1 or the scene's
  ``saturation`` effect changing the force.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from impact_env._borrow import borrow
from impact_env._jit import jit
from impact_env.plant.energy import catch_energy_at
from impact_env.plant.layout import M1, C, G
from impact_env.sim import records as R

RESIDUAL_MARKS_S = (0.010, 0.050, 0.100)
EPISODE_METRICS = ("impact_speed_mps", "time_to_catch_s", "residual_energy_10ms", "residual_energy_50ms",
                   "residual_energy_100ms", "exit_speed_ratio", "exit_velocity_ratio", "bounces",
                   "peak_force_N", "rms_force_N", "peak_demand_N", "energy_integral_ms", "contact_fraction",
                   "saturation_time_s")
# accumulator columns
(A_TICKS, A_PEAK, A_PEAK_DEM, A_SUMSQ, A_SAT, A_CONTACT, A_AFTER, A_RATIO_SUM, A_LAST_ABOVE, A_MARK0, A_MARK1,
 A_MARK2, A_EXIT_VEL, A_WAS_CONTACT, A_T_SEP, A_BOUNCES, A_RATIO, A_ENERGY) = range(18)
N_ACC = 18
# per-env constants
K_T_TOUCH, K_V0, K_E0 = range(3)
# shared settings
S_PERIOD, S_FRACTION, S_MIN_FLIGHT, S_MARK0, S_MARK1, S_MARK2 = range(6)


@jit(inline="always")
def update(acc, rec, k_env, P_row, settings):
    """Advance one env's accumulator ``acc`` by the tick record ``rec`` (its constants
    ``k_env`` = t_touch s, impact speed m/s, impact energy J; its plant row ``P_row``)."""
    acc[A_TICKS] += 1.0
    t = acc[A_TICKS] * settings[S_PERIOD]
    t_touch = k_env[K_T_TOUCH]
    f = rec[R.REC_F_APPLIED]
    af = abs(f)
    if af > acc[A_PEAK]:
        acc[A_PEAK] = af
    ad = abs(rec[R.REC_F_DEMAND])
    if ad > acc[A_PEAK_DEM]:
        acc[A_PEAK_DEM] = ad
    acc[A_SUMSQ] += f * f
    if rec[R.REC_SATURATED] > 0.5 or abs(rec[R.REC_U]) >= 1.0:
        acc[A_SAT] += 1.0
    after = t > t_touch
    x1 = rec[R.REC_X1]
    x2 = rec[R.REC_X2]
    contact = x1 - x2 > 0.0
    if after:
        acc[A_AFTER] += 1.0
        if contact:
            acc[A_CONTACT] += 1.0
    e = catch_energy_at(x1, rec[R.REC_V1], x2, P_row[M1], P_row[C], P_row[G])
    acc[A_ENERGY] = e
    ratio = e / k_env[K_E0]
    acc[A_RATIO] = ratio
    acc[A_RATIO_SUM] += ratio
    if ratio >= settings[S_FRACTION]:
        acc[A_LAST_ABOVE] = t
    since = t - t_touch
    for m in range(3):
        if np.isnan(acc[A_MARK0 + m]) and since >= settings[S_MARK0 + m] - 1e-12:
            acc[A_MARK0 + m] = ratio
    was = acc[A_WAS_CONTACT] > 0.5
    if was and not contact and after:
        if np.isnan(acc[A_EXIT_VEL]):
            acc[A_EXIT_VEL] = -rec[R.REC_V1] / k_env[K_V0]
        acc[A_T_SEP] = t
    if not was and contact and not np.isnan(acc[A_T_SEP]):
        if t - acc[A_T_SEP] >= settings[S_MIN_FLIGHT]:
            acc[A_BOUNCES] += 1.0
        acc[A_T_SEP] = np.nan
    acc[A_WAS_CONTACT] = 1.0 if contact else 0.0


@jit
def update_batch(active, records, consts, P, settings, acc):
    """:func:`update` with every tick of the last step's records, for every active env."""
    active, records, consts, P, settings, acc = (borrow(active), borrow(records), borrow(consts), borrow(P),
                                                 borrow(settings), borrow(acc))  # (impact_env._borrow)
    for i in range(records.shape[0]):
        if active[i]:
            for k in range(records.shape[1]):
                update(acc[i], records[i, k], consts[i], P[i], settings)


class MetricArrays(NamedTuple):
    """The accumulators' arrays, as the compiled loops take them."""

    acc: np.ndarray  # float64[N, N_ACC]
    consts: np.ndarray  # float64[N, 3]: columns K_*
    settings: np.ndarray  # float64[6]: S_*


class EpisodeMetrics:
    """Accumulators of N episodes (see the module doc for the metrics).  ``start(t_touch, v0, e0,
    contact0)`` at the episode start, then :func:`update` per tick (or :meth:`step` per simulator
    step), then :meth:`finish`."""

    def __init__(self, n: int, period: float, catch_fraction: float = 0.01, min_flight_s: float = 1.0e-3):
        self.n = int(n)
        self.period = float(period)
        self.settings = np.array([period, catch_fraction, min_flight_s, *RESIDUAL_MARKS_S], dtype=np.float64)
        self.acc = np.zeros((self.n, N_ACC))
        self.consts = np.zeros((self.n, 3))
        self._all = np.ones(self.n, dtype=bool)

    def start(self, t_touch, impact_speed, impact_energy, contact) -> None:
        self.acc[:] = 0.0
        self.acc[:, A_LAST_ABOVE] = -np.inf
        self.acc[:, A_MARK0:A_MARK2 + 1] = np.nan
        self.acc[:, A_EXIT_VEL] = np.nan
        self.acc[:, A_T_SEP] = np.nan
        self.acc[:, A_WAS_CONTACT] = np.asarray(contact, dtype=np.float64)
        self.consts[:, K_T_TOUCH] = t_touch
        self.consts[:, K_V0] = impact_speed
        self.consts[:, K_E0] = impact_energy

    def step(self, records, P, active=None) -> None:
        active = self._all if active is None else active
        update_batch(active, records, self.consts, P, self.settings, self.acc)

    @property
    def arrays(self) -> MetricArrays:
        return MetricArrays(self.acc, self.consts, self.settings)

    @property
    def ratio(self) -> np.ndarray:
        """Each env's catch-energy ratio at its last tick."""
        return self.acc[:, A_RATIO]

    def finish(self, failed=None) -> dict[str, np.ndarray]:
        """The per-episode metrics (float64[N] each; NaN where ``failed``)."""
        a = self.acc
        period = self.period
        ticks = np.maximum(a[:, A_TICKS], 1.0)
        t_end = a[:, A_TICKS] * period
        t_touch = self.consts[:, K_T_TOUCH]
        t_sep = a[:, A_T_SEP]
        bounces = a[:, A_BOUNCES] + (~np.isnan(t_sep) & (t_end - t_sep >= self.settings[S_MIN_FLIGHT]))
        last = a[:, A_LAST_ABOVE]
        ttc = np.where(last >= t_end - 1e-12, np.inf, np.maximum(last + period, t_touch) - t_touch)
        ttc = np.where(last == -np.inf, 0.0, ttc)
        exit_vel = a[:, A_EXIT_VEL]
        m = {
            "impact_speed_mps": self.consts[:, K_V0].copy(),
            "time_to_catch_s": ttc,
            "residual_energy_10ms": a[:, A_MARK0].copy(),
            "residual_energy_50ms": a[:, A_MARK1].copy(),
            "residual_energy_100ms": a[:, A_MARK2].copy(),
            "exit_speed_ratio": np.where(np.isnan(exit_vel), 0.0, np.abs(exit_vel)),
            "exit_velocity_ratio": np.where(np.isnan(exit_vel), 0.0, exit_vel),
            "bounces": bounces,
            "peak_force_N": a[:, A_PEAK].copy(),
            "rms_force_N": np.sqrt(a[:, A_SUMSQ] / ticks),
            "peak_demand_N": a[:, A_PEAK_DEM].copy(),
            "energy_integral_ms": a[:, A_RATIO_SUM] * period * 1e3,
            "contact_fraction": a[:, A_CONTACT] / np.maximum(a[:, A_AFTER], 1),
            "saturation_time_s": a[:, A_SAT] * period,
        }
        bad = np.zeros(self.n, dtype=bool) if failed is None else np.asarray(failed, dtype=bool)
        return {k: np.where(bad, math.nan, v.astype(np.float64)) for k, v in m.items()}
