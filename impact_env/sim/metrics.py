"""Catch metrics of episodes, accumulated tick by tick in compiled code: the one place where
each metric of ``impact-env compare`` is defined.

:class:`EpisodeMetrics` keeps, per env, an accumulator row that :func:`update` advances by one
control tick from that tick's record (:mod:`impact_env.sim.records`), whatever the policy rate,
at no Python cost per tick.  The same kernel runs in the Python rollout (one batched call per
step), in the compiled rollout of a compiled policy (inside the loop), and on a rig's tick log.

Energies (J; thesis frame, x down, penetration ``d = x1 - x2``, ``d_s = (m1 g / c)^(2/3)`` the
static penetration under body 1's weight, ``U(d) = m1 g (3/5 d_s - d) + (2/5) c d_+^2.5`` the
gravity-and-pad potential above resting on the pad, ``U(d_s) = 0``, ``U >= 0``):

* body 1's **catch energy** ``E1 = m1 v1^2 / 2 + U(d)`` (:func:`impact_env.plant.energy.catch_energy`;
  the thesis's E1, eq 4.5): body 1's *absolute* kinetic energy, so body 1 riding a vibrating
  body 2 keeps some;
* body 1's **relative catch energy** ``E1_rel = m1 (v1 - v2)^2 / 2 + U(d)``: its motion relative
  to body 2 plus the pad's energy above static rest, zero when body 1 rests on the pad whatever
  body 2 does;
* ``E0``, the **impact energy**: the catch energy at the first touch ``t_touch``
  (``m1 v0^2 / 2 + U(0)``, v0 the impact speed).

Definitions (tick k ends at ``t = k T``, T the control period, H the horizon):

* ``time_to_catch_s``: the **catch**, body 1 at rest on the pad: the time from the first touch
  after which ``E1_rel / E0`` stays below ``catch_fraction`` (default 1 %) at every tick *and*
  no bounce (a separation followed by a flight of at least ``min_flight_s``, below) starts, for
  at least ``catch_hold_s`` (default 10 ms, the env's ``catch_hold``) before the horizon ends;
  ``inf`` if there is no such time (censored: not caught within the horizon; among others a
  flight of at least ``min_flight_s`` still going at the end), 0 if never above.  A flight's
  ticks count as above (known when it lands).  The hold keeps a dip below the fraction in the
  last ticks, with body 1 about to leave the pad again, from counting as a catch "for good"
  (seen with the absolute energy: passive on rig, caught 0.3 ms before the horizon while
  separating).  ``compare``'s *caught* share
  is the fraction of episodes with a finite catch time.  *Changed*: it was judged on the
  absolute ``E1`` (the name stays); a law that stops body 1 on a body 2 that keeps vibrating on
  sensor noise counted as never catching, so doing nothing (passive) outranked the thesis law.
  The vibration is now its own column, ``residual_vibration_mps``, and the old figure is kept
  as ``time_to_catch_absolute_s``.  The relative energy is the
  rest test of the thesis's ch. 4.4, which separates the falling body's energy from the
  resonance of the body 2 / shaker setup.  (The env's ``caught`` and its termination keep the
  absolute ``E1``: :class:`impact_env.env.task.TaskConfig`.)
* ``time_to_catch_absolute_s``: the former ``time_to_catch_s``, unchanged: the time from the
  first touch after which the absolute ``E1 / E0`` stays below ``catch_fraction`` at every tick
  (no bounce rule, no hold); ``inf`` if above at the last tick, 0 if never above.  Kept for
  what still estimates that figure (a blind rig's flight-energy estimate,
  :mod:`impact_env.rig.flight_energy`) and for continuity; not a catch (see above).
* ``residual_vibration_mps``: body 2 still humming: the RMS of body 2's velocity v2 (m/s) over
  the last ``VIBRATION_WINDOW_S`` (50 ms) of the episode (the whole episode if shorter), sampled
  at every tick.  NaN when the horizon is not given (a rig's tick log).  *New*.
* ``residual_energy_{10,50,100}ms``: ``E1 / E0`` at the first tick at least 10, 50, 100 ms
  after the first touch (NaN past the horizon).  Unchanged.
* ``exit_speed_ratio``: body 1's speed |v1| at the first separation after the first touch over
  the impact speed (0 when contact is never lost within the horizon).  The separation is the
  one the plant locates (the contact force letting go: :mod:`impact_env.plant.integrators`),
  and v1 is read there.  ``exit_velocity_ratio`` is the same with a sign: positive when body 1
  leaves upwards (a bounce), negative when it is still falling and body 2 has moved away.
  *Changed*: it was read at the first tick with ``d <= 0``, which on a damped pad comes
  260-370 us after the force has let go (0.7-1.5 % low at 10 kHz).  On a rig's tick log, which
  has no located separation, it is still read there.
* ``bounces``: separations (ticks with ``d <= 0`` after ticks with ``d > 0``) after which body 1
  stays free for at least ``min_flight_s`` (default 1 ms, a flight about 1 um high; shorter ones
  are chatter, not visible bounces).  Unchanged.
* ``peak_force_N``, ``rms_force_N``: largest |force| and RMS force applied to body 2 over the
  episode's ticks (after shaker and saturation); ``peak_demand_N``: largest |demand|.
* ``energy_integral_ms``: ``int_0^H E1 dt / E0`` in ms, exact along the simulated trajectory:
  the plant integrates E1 inside its integrator over every span it takes (the plant record's
  ``catch_integral``, :mod:`impact_env.sim.records`): in free flight in closed form (body 1's
  ``m1 v1^2/2 - m1 g x1`` is constant, body 2's position integrates term by term in its
  exponential series), in contact by the corrected trapezoidal rule on each accepted dopri5
  step (error ``h^5 max|E1''''| / 720`` per step, below the step's own error), and with a
  fixed-step method by the trapezoidal rule on its own grid (``dt^2 max|E1''| / 12`` per unit
  time).  So it does not depend on the control rate: passive on ``rig``, seeds 95000-95007,
  reads 78.520344 ms at 2.5, 10 and 40 kHz (tested to 1e-4), and one drop agrees with a
  solve_ivp reference to 3e-10 (``tests/test_metric_definitions.py``).  *Changed*:
  it was the right-endpoint sum over ticks, kept as ``energy_integral_ticks_ms``; on a rig's
  tick log, which has no plant integral, ``energy_integral_ms`` is still that sum.
* ``energy_integral_ticks_ms``: ``T sum_k E1(t_k) / E0`` in ms, the right-endpoint sum over the
  ticks.  With the env's default reward weights it is minus the episode's return: the env's
  reward stays the per-tick sum (so that trained agents and their returns keep their meaning),
  and it approaches ``energy_integral_ms`` as T falls (0.03-0.7 % below it at 10 kHz on ``rig``).
* ``contact_fraction``: share of the ticks after the first touch with ``d > 0``.
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
from impact_env.sim.records import N_PLANT_REC, PREC, REC

RESIDUAL_MARKS_S = (0.010, 0.050, 0.100)
VIBRATION_WINDOW_S = 0.050  # s, the end of the episode over which residual_vibration_mps is taken
EPISODE_METRICS = ("impact_speed_mps", "time_to_catch_s", "time_to_catch_absolute_s",
                   "residual_vibration_mps", "residual_energy_10ms", "residual_energy_50ms",
                   "residual_energy_100ms", "exit_speed_ratio", "exit_velocity_ratio", "bounces",
                   "peak_force_N", "rms_force_N", "peak_demand_N", "energy_integral_ms",
                   "energy_integral_ticks_ms", "contact_fraction", "saturation_time_s")


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
    integral: float  # J s, the plant's integral of the catch energy (plant records' catch_integral)
    last_above: float  # s, the last tick not caught (relative ratio at or above the fraction, or flying)
    last_above_abs: float  # s, the last tick with the (absolute) catch-energy ratio at or above the fraction
    mark0: float  # the ratio at the first residual mark (NaN until reached); mark1, mark2 follow
    mark1: float
    mark2: float
    exit_velocity: float  # -v1 / v0 at the first separation (NaN until then)
    was_contact: float  # 1 if the previous tick was in contact
    t_separation: float  # s, the last separation (NaN while in contact)
    bounces: float  # separations followed by a flight of at least min_flight
    vib_sum: float  # (m/s)^2, the sum of v2^2 over the vibration window's ticks
    vib_ticks: float  # ticks in the vibration window
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
    plant_records: float  # 1: plant records (the plant's integral, located separations) are read
    vib_from: float  # the first tick (count, from 1) of the vibration window; inf: none
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
def update(acc, rec, prec, k_env, plant_row, settings):
    """Advance one env's accumulator ``acc`` by the tick record ``rec`` and its plant record
    ``prec`` (read only with ``settings``' plant_records; its constants ``k_env`` = t_touch s,
    impact speed m/s, impact energy J; its plant parameters ``plant_row``)."""
    acc[AC.ticks] += 1.0
    period = settings[ST.period]
    t = acc[AC.ticks] * period
    t_touch = k_env[EC.t_touch]
    plant = settings[ST.plant_records] > 0.5
    f = rec[REC.f_applied]
    af = abs(f)
    if af > acc[AC.peak]:
        acc[AC.peak] = af
    ad = abs(rec[REC.f_demand])
    if ad > acc[AC.peak_demand]:
        acc[AC.peak_demand] = ad
    acc[AC.sum_sq] += f * f
    if rec[REC.saturated] > 0.5 or abs(rec[REC.u]) >= 1.0:
        acc[AC.saturated] += 1.0
    after = t > t_touch
    x1 = rec[REC.x1]
    v1 = rec[REC.v1]
    x2 = rec[REC.x2]
    v2 = rec[REC.v2]
    contact = x1 - x2 > 0.0
    if after:
        acc[AC.after] += 1.0
        if contact:
            acc[AC.contact] += 1.0
    m1, c, g = plant_row[M1], plant_row[C], plant_row[G]
    e0 = k_env[EC.impact_energy]
    e = catch_energy_at(x1, v1, x2, m1, c, g)
    acc[AC.energy] = e
    ratio = e / e0
    acc[AC.ratio] = ratio
    acc[AC.ratio_sum] += ratio
    if ratio >= settings[ST.catch_fraction]:
        acc[AC.last_above_abs] = t
    if plant:
        acc[AC.integral] += prec[PREC.catch_integral]
    # the relative catch energy, m1 (v1 - v2)^2 / 2 + U(d), from the absolute one
    if e + 0.5 * m1 * v2 * (v2 - 2.0 * v1) >= settings[ST.catch_fraction] * e0:
        acc[AC.last_above] = t
    since = t - t_touch
    for m in range(len(RESIDUAL_MARKS_S)):
        if np.isnan(acc[AC.mark0 + m]) and since >= settings[ST.mark0 + m] - 1e-12:
            acc[AC.mark0 + m] = ratio
    if acc[AC.ticks] >= settings[ST.vib_from]:
        acc[AC.vib_sum] += v2 * v2
        acc[AC.vib_ticks] += 1.0
    if plant:
        if np.isnan(acc[AC.exit_velocity]) and prec[PREC.t_separation] > t_touch:
            acc[AC.exit_velocity] = -prec[PREC.v1_separation] / k_env[EC.impact_speed]
    was = acc[AC.was_contact] > 0.5
    if was and not contact and after:
        if np.isnan(acc[AC.exit_velocity]) and not plant:
            acc[AC.exit_velocity] = -v1 / k_env[EC.impact_speed]
        acc[AC.t_separation] = t
    if not was and contact and not np.isnan(acc[AC.t_separation]):
        if t - acc[AC.t_separation] >= settings[ST.min_flight]:
            acc[AC.bounces] += 1.0
            # the flight's ticks were not caught: its last one is the tick before this landing
            if t - period > acc[AC.last_above]:
                acc[AC.last_above] = t - period
        acc[AC.t_separation] = np.nan
    acc[AC.was_contact] = 1.0 if contact else 0.0


@jit
def update_batch(active, records, plant_records, consts, plant_params, settings, acc):
    """:func:`update` with every tick of the last step's records (and plant records), for every
    active env."""
    active, records, plant_records = borrow(active), borrow(records), borrow(plant_records)
    consts, plant_params = borrow(consts), borrow(plant_params)
    settings, acc = borrow(settings), borrow(acc)  # (_borrow)
    for i in range(records.shape[0]):
        if active[i]:
            for k in range(records.shape[1]):
                update(acc[i], records[i, k], plant_records[i, k], consts[i], plant_params[i], settings)


class MetricArrays(NamedTuple):
    """The accumulators' arrays, as the compiled loops take them."""

    acc: np.ndarray  # float64[N, N_ACC]
    consts: np.ndarray  # float64[N, N_CONST]: columns EnvConstants
    settings: np.ndarray  # float64[N_SETTINGS]: Settings


class EpisodeMetrics:
    """Accumulators of N episodes (see the module doc for the metrics).  ``start(t_touch, v0, e0,
    contact0)`` at the episode start, then :func:`update` per tick (or :meth:`step` per simulator
    step), then :meth:`finish`.

    ``horizon_s``: the episode's length (s), which places the vibration window (None: no
    ``residual_vibration_mps``, NaN).  ``catch_hold_s``: how long (s) a catch must have held
    before the episode's end to count.  ``plant_records``: every step comes with the simulator's
    plant records (the plant's energy integral and located separations,
    :mod:`impact_env.sim.records`); False for a rig's tick log, whose ``energy_integral_ms`` and
    exit speed are then taken at the ticks."""

    def __init__(self, n: int, period: float, catch_fraction: float = 0.01, min_flight_s: float = 1.0e-3,
                 horizon_s: float | None = None, plant_records: bool = False, catch_hold_s: float = 0.010):
        self.n = int(n)
        self.period = float(period)
        self.catch_hold = float(catch_hold_s)
        self.plant_records = bool(plant_records)
        vib_from = math.inf
        if horizon_s is not None:
            ticks = int(round(float(horizon_s) / self.period))
            vib_from = float(max(1, ticks - int(round(VIBRATION_WINDOW_S / self.period)) + 1))
        self.settings = np.array(Settings(period, catch_fraction, min_flight_s, float(self.plant_records),
                                          vib_from, *RESIDUAL_MARKS_S), dtype=np.float64)
        self.acc = np.zeros((self.n, N_ACC))
        self.consts = np.zeros((self.n, N_CONST))
        self._all = np.ones(self.n, dtype=bool)

    def start(self, t_touch, impact_speed, impact_energy, contact) -> None:
        self.acc[:] = 0.0
        self.acc[:, AC.last_above] = -np.inf
        self.acc[:, AC.last_above_abs] = -np.inf
        self.acc[:, AC.mark0:AC.mark2 + 1] = np.nan
        self.acc[:, AC.exit_velocity] = np.nan
        self.acc[:, AC.t_separation] = np.nan
        self.acc[:, AC.was_contact] = np.asarray(contact, dtype=np.float64)
        self.consts[:, EC.t_touch] = t_touch
        self.consts[:, EC.impact_speed] = impact_speed
        self.consts[:, EC.impact_energy] = impact_energy

    def step(self, records, P, active=None, plant_records=None) -> None:
        """:func:`update` with every tick of ``records`` (float64[N, ticks, N_REC]) and, with
        ``plant_records`` set at construction, ``plant_records`` (float64[N, ticks, N_PLANT_REC])."""
        active = self._all if active is None else active
        if plant_records is None:
            if self.plant_records:
                raise ValueError("EpisodeMetrics(plant_records=True) needs the plant records of every step")
            plant_records = np.zeros(records.shape[:2] + (N_PLANT_REC,))
        update_batch(active, records, plant_records, self.consts, P, self.settings, self.acc)

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
        e0 = self.consts[:, EC.impact_energy]
        t_sep = a[:, AC.t_separation]
        flying = ~np.isnan(t_sep) & (t_end - t_sep >= self.settings[ST.min_flight])  # a bounce not yet landed
        bounces = a[:, AC.bounces] + flying
        last = a[:, AC.last_above]
        ttc = np.where(last == -np.inf, 0.0, np.maximum(last + period, t_touch) - t_touch)
        held = t_end - (t_touch + ttc) >= self.catch_hold - 1e-12
        ttc = np.where(held & ~flying, ttc, np.inf)
        last_abs = a[:, AC.last_above_abs]
        ttc_abs = np.where(last_abs >= t_end - 1e-12, np.inf,
                           np.maximum(last_abs + period, t_touch) - t_touch)
        ttc_abs = np.where(last_abs == -np.inf, 0.0, ttc_abs)
        exit_vel = a[:, AC.exit_velocity]
        ticks_ms = a[:, AC.ratio_sum] * period * 1e3
        vib_ticks = a[:, AC.vib_ticks]
        vib = np.where(vib_ticks > 0, np.sqrt(a[:, AC.vib_sum] / np.maximum(vib_ticks, 1.0)), np.nan)
        m = {
            "impact_speed_mps": self.consts[:, EC.impact_speed].copy(),
            "time_to_catch_s": ttc,
            "time_to_catch_absolute_s": ttc_abs,
            "residual_vibration_mps": vib,
            "residual_energy_10ms": a[:, AC.mark0].copy(),
            "residual_energy_50ms": a[:, AC.mark1].copy(),
            "residual_energy_100ms": a[:, AC.mark2].copy(),
            "exit_speed_ratio": np.where(np.isnan(exit_vel), 0.0, np.abs(exit_vel)),
            "exit_velocity_ratio": np.where(np.isnan(exit_vel), 0.0, exit_vel),
            "bounces": bounces,
            "peak_force_N": a[:, AC.peak].copy(),
            "rms_force_N": np.sqrt(a[:, AC.sum_sq] / ticks),
            "peak_demand_N": a[:, AC.peak_demand].copy(),
            "energy_integral_ms": a[:, AC.integral] / e0 * 1e3 if self.plant_records else ticks_ms.copy(),
            "energy_integral_ticks_ms": ticks_ms,
            "contact_fraction": a[:, AC.contact] / np.maximum(a[:, AC.after], 1),
            "saturation_time_s": a[:, AC.saturated] * period,
        }
        bad = np.zeros(self.n, dtype=bool) if failed is None else np.asarray(failed, dtype=bool)
        return {k: np.where(bad, math.nan, v.astype(np.float64)) for k, v in m.items()}
