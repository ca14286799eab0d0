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
from impact_env._packed import positions
from impact_env.plant.energy import catch_energy_at
from impact_env.plant.layout import M1, C, G
from impact_env.sim import records as R

RESIDUAL_MARKS_S = (0.010, 0.050, 0.100)
EPISODE_METRICS = ("impact_speed_mps", "time_to_catch_s", "residual_energy_10ms", "residual_energy_50ms",
                   "residual_energy_100ms", "exit_speed_ratio", "exit_velocity_ratio", "bounces",
                   "peak_force_N", "rms_force_N", "peak_demand_N", "energy_integral_ms", "contact_fraction",
                   "saturation_time_s")


class Accumulators(NamedTuple):
    """An env's accumulator row (float64[N_ACC]), advanced by :func:`update`."""

    ticks: float  # ticks taken
    peak: float  # N, the largest |applied force|
    peak_demand: float  # N, the largest |demand|
    sum_sq: float  # N^2, the sum of the squared applied forces
    saturated: float  # ticks at the force limit
    contact: float  # ticks in contact after the first touch
    after: float  # ticks after the first touch
    ratio_sum: float  # the sum of the catch-energy ratios
    last_above: float  # s, the last tick with the ratio at or above the catch fraction
    mark0: float  # the ratio at the first residual mark (NaN until reached); mark1, mark2 follow
    mark1: float
    mark2: float
    exit_velocity: float  # -v1 / v0 at the first separation (NaN until then)
    was_contact: float  # 1 if the previous tick was in contact
    t_separation: float  # s, the last separation (NaN while in contact)
    bounces: float  # separations followed by a flight of at least min_flight
    ratio: float  # the catch-energy ratio at the last tick
    energy: float  # J, the catch energy at the last tick


class EnvConstants(NamedTuple):
    """An env's constants row (float64[N_CONST]), set at its episode start."""

    t_touch: float  # s, the first touch
    impact_speed: float  # m/s
    impact_energy: float  # J


class Settings(NamedTuple):
    """The settings shared by every env (float64[N_SETTINGS])."""

    period: float  # s, the control period
    catch_fraction: float  # of the impact energy
    min_flight: float  # s, the shortest flight that is a bounce
    mark0: float  # s after the first touch, the residual marks (RESIDUAL_MARKS_S); mark1, mark2 follow
    mark1: float
    mark2: float


AC = positions(Accumulators)
EC = positions(EnvConstants)
ST = positions(Settings)
N_ACC = len(AC)
N_CONST = len(EC)
N_SETTINGS = len(ST)


@jit(inline="always")
def update(acc, rec, k_env, P_row, settings):
    """Advance one env's accumulator ``acc`` by the tick record ``rec`` (its constants
    ``k_env`` = t_touch s, impact speed m/s, impact energy J; its plant row ``P_row``)."""
    acc[AC.ticks] += 1.0
    t = acc[AC.ticks] * settings[ST.period]
    t_touch = k_env[EC.t_touch]
    f = rec[R.REC.f_applied]
    af = abs(f)
    if af > acc[AC.peak]:
        acc[AC.peak] = af
    ad = abs(rec[R.REC.f_demand])
    if ad > acc[AC.peak_demand]:
        acc[AC.peak_demand] = ad
    acc[AC.sum_sq] += f * f
    if rec[R.REC.saturated] > 0.5 or abs(rec[R.REC.u]) >= 1.0:
        acc[AC.saturated] += 1.0
    after = t > t_touch
    x1 = rec[R.REC.x1]
    x2 = rec[R.REC.x2]
    contact = x1 - x2 > 0.0
    if after:
        acc[AC.after] += 1.0
        if contact:
            acc[AC.contact] += 1.0
    e = catch_energy_at(x1, rec[R.REC.v1], x2, P_row[M1], P_row[C], P_row[G])
    acc[AC.energy] = e
    ratio = e / k_env[EC.impact_energy]
    acc[AC.ratio] = ratio
    acc[AC.ratio_sum] += ratio
    if ratio >= settings[ST.catch_fraction]:
        acc[AC.last_above] = t
    since = t - t_touch
    for m in range(len(RESIDUAL_MARKS_S)):
        if np.isnan(acc[AC.mark0 + m]) and since >= settings[ST.mark0 + m] - 1e-12:
            acc[AC.mark0 + m] = ratio
    was = acc[AC.was_contact] > 0.5
    if was and not contact and after:
        if np.isnan(acc[AC.exit_velocity]):
            acc[AC.exit_velocity] = -rec[R.REC.v1] / k_env[EC.impact_speed]
        acc[AC.t_separation] = t
    if not was and contact and not np.isnan(acc[AC.t_separation]):
        if t - acc[AC.t_separation] >= settings[ST.min_flight]:
            acc[AC.bounces] += 1.0
        acc[AC.t_separation] = np.nan
    acc[AC.was_contact] = 1.0 if contact else 0.0


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
    consts: np.ndarray  # float64[N, N_CONST]: columns EnvConstants
    settings: np.ndarray  # float64[N_SETTINGS]: Settings


class EpisodeMetrics:
    """Accumulators of N episodes (see the module doc for the metrics).  ``start(t_touch, v0, e0,
    contact0)`` at the episode start, then :func:`update` per tick (or :meth:`step` per simulator
    step), then :meth:`finish`."""

    def __init__(self, n: int, period: float, catch_fraction: float = 0.01, min_flight_s: float = 1.0e-3):
        self.n = int(n)
        self.period = float(period)
        self.settings = np.array(Settings(period, catch_fraction, min_flight_s, *RESIDUAL_MARKS_S),
                                 dtype=np.float64)
        self.acc = np.zeros((self.n, N_ACC))
        self.consts = np.zeros((self.n, N_CONST))
        self._all = np.ones(self.n, dtype=bool)

    def start(self, t_touch, impact_speed, impact_energy, contact) -> None:
        self.acc[:] = 0.0
        self.acc[:, AC.last_above] = -np.inf
        self.acc[:, AC.mark0:AC.mark2 + 1] = np.nan
        self.acc[:, AC.exit_velocity] = np.nan
        self.acc[:, AC.t_separation] = np.nan
        self.acc[:, AC.was_contact] = np.asarray(contact, dtype=np.float64)
        self.consts[:, EC.t_touch] = t_touch
        self.consts[:, EC.impact_speed] = impact_speed
        self.consts[:, EC.impact_energy] = impact_energy

    def step(self, records, P, active=None) -> None:
        active = self._all if active is None else active
        update_batch(active, records, self.consts, P, self.settings, self.acc)

    @property
    def arrays(self) -> MetricArrays:
        return MetricArrays(self.acc, self.consts, self.settings)

    @property
    def ratio(self) -> np.ndarray:
        """Each env's catch-energy ratio at its last tick."""
        return self.acc[:, AC.ratio]

    def finish(self, failed=None) -> dict[str, np.ndarray]:
        """The per-episode metrics (float64[N] each; NaN where ``failed``)."""
        a = self.acc
        period = self.period
        ticks = np.maximum(a[:, AC.ticks], 1.0)
        t_end = a[:, AC.ticks] * period
        t_touch = self.consts[:, EC.t_touch]
        t_sep = a[:, AC.t_separation]
        bounces = a[:, AC.bounces] + (~np.isnan(t_sep) & (t_end - t_sep >= self.settings[ST.min_flight]))
        last = a[:, AC.last_above]
        ttc = np.where(last >= t_end - 1e-12, np.inf, np.maximum(last + period, t_touch) - t_touch)
        ttc = np.where(last == -np.inf, 0.0, ttc)
        exit_vel = a[:, AC.exit_velocity]
        m = {
            "impact_speed_mps": self.consts[:, EC.impact_speed].copy(),
            "time_to_catch_s": ttc,
            "residual_energy_10ms": a[:, AC.mark0].copy(),
            "residual_energy_50ms": a[:, AC.mark1].copy(),
            "residual_energy_100ms": a[:, AC.mark2].copy(),
            "exit_speed_ratio": np.where(np.isnan(exit_vel), 0.0, np.abs(exit_vel)),
            "exit_velocity_ratio": np.where(np.isnan(exit_vel), 0.0, exit_vel),
            "bounces": bounces,
            "peak_force_N": a[:, AC.peak].copy(),
            "rms_force_N": np.sqrt(a[:, AC.sum_sq] / ticks),
            "peak_demand_N": a[:, AC.peak_demand].copy(),
            "energy_integral_ms": a[:, AC.ratio_sum] * period * 1e3,
            "contact_fraction": a[:, AC.contact] / np.maximum(a[:, AC.after], 1),
            "saturation_time_s": a[:, AC.saturated] * period,
        }
        bad = np.zeros(self.n, dtype=bool) if failed is None else np.asarray(failed, dtype=bool)
        return {k: np.where(bad, math.nan, v.astype(np.float64)) for k, v in m.items()}
