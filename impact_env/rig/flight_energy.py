"""Body 1's energy without a body-1 sensor (thesis eq 4.5), and a log summary with compare's metrics.

The rig measures body 2 only.  The thesis estimated body 1's energy from the time T between
successive contacts: a body that leaves the pad with speed u and lands on it again at the same
height flies ``T = 2u/g``, so

    E1 = m1 u^2 / 2 = g^2 T^2 m1 / 8                                       (eq 4.5)

and during a contact E1 is interpolated linearly between the flights before and after it.

:func:`estimate_energy` estimates the simulator's *catch energy*
(:func:`impact_env.plant.energy.catch_energy`) that way, and (given the potentiometer) one step
further.  Between a separation and the next touch body 1 is ballistic while body 2 moves by
``dx2`` (its potentiometer), so body 1's velocity at the separation is (down positive)

    v1_sep = dx2 / T - g T / 2                     (eq 4.5 is the case dx2 = 0)

(``method="ballistic"``, the default of :func:`summarize`; ``"thesis"`` assumes dx2 = 0).  In a
flight the estimate is ``m1 v1_sep^2 / 2 + U0 + m1 g (x2(t) - x2_sep)`` (the catch energy counts
the gap to body 2; constant with ``"thesis"``), ``U0 = 0.6 m1 g d_s`` (body 1 at the pad's
surface relative to resting on it: 3.6e-5 J on the rig, 0.07 % of a 50 mm drop); before the
first touch the scene's impact energy ``E0 = m1 v0^2 / 2 + U0``; during a contact the linear
interpolation between the energy at the landing and at the next separation.  The last contact
(no flight after it: body 1 was caught, or rests) falls linearly to 0 over one elastic Hertz
contact time at its landing speed, ``t_c = 2.9432 d_max / v``, ``d_max = (5 m v^2 / 4c)^(2/5)``
(Johnson, *Contact Mechanics*; 3.7 ms at 1 m/s on the rig): a body still on the pad after that
long did not rebound (an ASSUMPTION of this estimate; the thesis drew no curve there).  After a
flight that has not landed when the log ends the energy is unknown (NaN).

Contacts (:func:`contact_from_log`): ``source="force"`` thresholds the contact force rebuilt from
body 2's sensors, ``Phi = m2' a2 + T`` (thesis eq 4.4; m2' the detector's ``top_mass``), at
``threshold_n`` (default: the scene detector's 2 N, ten times the force channel's noise), each
edge interpolated linearly between the two samples around the crossing.  A level detector
reads a resting body 1 (Phi = m1 g, about 1 N) as no contact, like the rig (thesis sec 4.2),
so a stretch below the threshold whose mean force exceeds ``m1 g / 2`` is light contact, not
flight (over a stretch the mean contact force is ``m1 g - m1 dv1/dt``: 0 in flight, m1 g at
rest), and a log that ends in one ends at rest.  ``source="detector"`` takes the front end's
contact bit (each edge at the middle of its sample interval) and cannot tell rest from flight.
Flights shorter than ``min_flight_s`` (1 ms) are merged into the contacts around them (chatter,
as for ``bounces`` in :mod:`impact_env.eval.rollout`).

Errors (derived bounds, checked flight by flight against the simulator's exact contact
events in ``tests/test_rig_energy.py``):

* **The pad's lag.**  A damped pad releases body 1 at the penetration ``d_sep`` > 0 where the
  contact force vanishes (0.2 mm at the first rig bounce), so exactly
  ``v1_sep = (dx2 - d_sep) / T - g T / 2``; the ballistic estimate misses ``d_sep / T``.  Eq 4.5
  also misses ``dx2 / T``: 0.7 % of the energy on the first passive rig bounce (0.13 s), tens of
  percent on late millimetre hops, and a factor of 10 on a controlled drop where the shaker
  pulls body 2 away (the thesis: "the control force is fooling the eyes").  Both are exact for
  an immobile body 2 and an elastic pad.
* **Edge timing.**  A force threshold F sees a touch late, once the penetration reaches
  ``d_th = (F/c)^(2/3)`` (0.1 mm at 2 N): by at most ``d_th / v`` (v the landing speed), and a
  separation early, where the damped force falls through F at ``d_a > d_sep``: by
  ``(d_a - d_sep) / u`` (:func:`crossing_delays`).  The measured flight is longer by up to the
  sum, plus at most a sample per edge (interpolation; a detector bit: half a sample, plus its
  own delay, which cancels in T when the same at both edges): 60 us on the first rig bounce,
  about a millisecond on a 20 ms hop.  The potentiometer is read at the measured edges.  A flight
  whose apex ``g T^2 / 8`` is below ``4 d_th`` is flagged unresolved; a contact whose force
  stays below the threshold (a soft landing under control) is not seen at all.
* **Within a contact** the estimate is an interpolation, not a measurement.

:func:`summarize` computes, from an :class:`~impact_env.rig.log.EpisodeLog`, the metrics of
``impact-env compare`` that the rig allows (its docstring says which are estimates).  Against
the simulator's truth (``pytest -s tests/test_rig_energy.py -k summary`` prints it): the
passive ``rig`` drop, catch time 0.331 s (0.330 s), 9 bounces (9), residual energy at
10/50/100 ms 0.420/0.377/0.393 (0.417/0.374/0.390); the thesis law clipped to 200 N, catch
time 0.1736 s (0.1736 s), residual 0.095/0.291/0.433 (0.112/0.289/0.432), 4 bounces (5: one
soft landing below the threshold).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from impact_env._packed import positions
from impact_env.plant import hertz
from impact_env.rig.safety import CLAMP_PEAK, CLAMP_RMS


def flight_energy(T, m1: float, g: float):
    """Thesis eq 4.5: ``g^2 T^2 m1 / 8`` (J) for flight times T (s)."""
    T = np.asarray(T, dtype=float)
    return g * g * T * T * m1 / 8.0


def hertz_contact_time(v: float, m_eff: float, c: float) -> float:
    """Duration (s) of an elastic Hertz impact at relative speed ``v`` (m/s), effective mass
    ``m_eff`` (kg), stiffness ``c`` (N/m^1.5)."""
    if not v > 0:
        return 0.0
    return hertz.contact_time(m_eff, c, v)


@dataclass(frozen=True)
class Plant:
    """What the estimate needs to know about the rig (SI): masses, stiffness, gravity, and the
    impact speed of the drop."""

    m1: float
    m2: float
    c: float
    g: float
    impact_speed: float

    @classmethod
    def of(cls, scene) -> Plant:
        p = scene.plant
        return cls(p.m1, p.m2, p.c, p.gravity, scene.impact_speed)

    @property
    def rest_energy(self) -> float:
        """U0 = 0.6 m1 g d_s: body 1 at the pad's surface relative to resting on it, J."""
        ds = (self.m1 * self.g / self.c) ** (2.0 / 3.0)
        return 0.6 * self.m1 * self.g * ds

    @property
    def impact_energy(self) -> float:
        """E0 = m1 v0^2 / 2 + U0, the catch energy at the start, J."""
        return 0.5 * self.m1 * self.impact_speed**2 + self.rest_energy

    @property
    def effective_mass(self) -> float:
        return self.m1 * self.m2 / (self.m1 + self.m2)


@dataclass
class Contacts:
    """Contact intervals: ``onsets`` and ``separations`` (s), alternating from the first onset;
    ``separations`` may be one shorter (a contact running to the end).  ``open_flight``: the
    last separation has no onset after it and is not rest (its energy is unknown)."""

    onsets: np.ndarray
    separations: np.ndarray
    t_end: float
    open_flight: bool = False
    threshold_n: float = 0.0  # the force threshold the edges are crossings of (0: a detector bit)


@dataclass
class EnergyEstimate:
    """Body 1's estimated catch energy ``energy_J`` (NaN where unknown) at the times ``t`` (s).

    ``flights``: one row per flight, columns ``FLIGHT_COLUMNS``: separation and touch times (s),
    flight time T (s), body 1's velocity at the separation (m/s, down positive), the catch
    energy at the separation and at the landing (J), resolved (1 if the apex ``g T^2 / 8`` is at
    least ``4 d_th``, module doc);
    ``e0_J``: the impact energy; ``t_touch``: the first onset (NaN if none); ``contact``: bool per
    sample (between an onset and its separation, rest included)."""

    t: np.ndarray
    energy_J: np.ndarray
    e0_J: float
    t_touch: float
    flights: np.ndarray
    contact: np.ndarray


def _edges_bool(t, on):
    """Onset/separation times of a bool signal: each edge at the middle of its sample interval."""
    on = np.asarray(on, dtype=bool)
    d = np.diff(on.astype(np.int8))
    rise = np.flatnonzero(d == 1) + 1
    fall = np.flatnonzero(d == -1) + 1
    ton = 0.5 * (t[rise - 1] + t[rise])
    toff = 0.5 * (t[fall - 1] + t[fall])
    if on.size and on[0]:
        ton = np.concatenate([[t[0]], ton])
    return ton, toff


def _edges_level(t, s, thr):
    """Onset/separation times where ``s`` crosses ``thr`` (linear interpolation between samples)."""
    on = s > thr
    d = np.diff(on.astype(np.int8))
    idx = np.flatnonzero(d != 0)
    a, b = s[idx], s[idx + 1]
    frac = np.where(b != a, (thr - a) / np.where(b != a, b - a, 1.0), 0.5)
    tc = t[idx] + np.clip(frac, 0.0, 1.0) * (t[idx + 1] - t[idx])
    ton, toff = tc[d[idx] == 1], tc[d[idx] == -1]
    if on.size and on[0]:
        ton = np.concatenate([[t[0]], ton])
    return ton, toff


def _merge_flights(ton, toff, is_contact):
    """Drop the flights (separation k, onset k+1) for which ``is_contact(k)``: the contact goes on."""
    keep_on = [ton[0]] if ton.size else []
    keep_off = []
    for k in range(len(toff)):
        if k + 1 < len(ton) and is_contact(k):
            continue
        keep_off.append(toff[k])
        if k + 1 < len(ton):
            keep_on.append(ton[k + 1])
    return np.asarray(keep_on, dtype=float), np.asarray(keep_off, dtype=float)


def contact_intervals(t, contact=None, signal=None, threshold_n: float = 0.0, min_flight_s: float = 1e-3,
                      rest_level_n: float | None = None) -> Contacts:
    """Contact intervals from a bool ``contact`` per sample, or from the contact force ``signal``
    (N) crossing ``threshold_n``.  With ``rest_level_n`` (and a signal), an unfinished last flight
    whose signal stays above it (median of its second half) is rest: the last contact runs on to
    the end."""
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size < 2 or not np.all(np.diff(t) > 0):
        raise ValueError("t must be a 1-d array of at least 2 increasing times (s)")
    if (contact is None) == (signal is None):
        raise ValueError("give exactly one of contact (bool per sample) or signal (N)")
    if signal is not None:
        s = np.asarray(signal, dtype=float)
        if s.shape != t.shape:
            raise ValueError(f"signal has shape {s.shape}, t has {t.shape}")
        if not np.all(np.isfinite(s)):
            raise ValueError("signal has non-finite samples")
        ton, toff = _edges_level(t, s, threshold_n)
    else:
        c = np.asarray(contact)
        if c.shape != t.shape:
            raise ValueError(f"contact has shape {c.shape}, t has {t.shape}")
        ton, toff = _edges_bool(t, c)
    if ton.size and toff.size and toff[0] < ton[0]:
        toff = toff[1:]  # a "separation" before any onset: the log starts in flight
    light = rest_level_n is not None and signal is not None

    def mean_between(t_a, t_b):
        seg = s[(t > t_a) & (t < t_b)]
        return float(np.mean(seg)) if seg.size else -math.inf

    # chatter (too short to be a flight), and with the force: light contact, where the force
    # stays below the threshold but its mean is about body 1's weight (over a stretch, the mean
    # contact force is m1 g minus m1 dv1/dt: 0 in flight, m1 g at rest)
    ton, toff = _merge_flights(ton, toff, lambda k: ton[k + 1] - toff[k] < min_flight_s or (
        light and mean_between(toff[k], ton[k + 1]) > rest_level_n))
    open_flight = bool(ton.size and len(toff) == len(ton))
    if open_flight and light and mean_between(toff[-1], t[-1] + 1.0) > rest_level_n:
        toff, open_flight = toff[:-1], False
    return Contacts(ton, toff, float(t[-1]), open_flight, float(threshold_n) if signal is not None else 0.0)


def crossing_delays(threshold_n: float, c: float, v_land: float, u_sep: float, d_sep: float = 0.0):
    """First-order edge delays (s) of a threshold ``threshold_n`` (N) on the contact force:
    ``(late_on, early_off)``, how late the touch and how early the separation are seen.

    At the touch the force (Hertz, plus a positive damping term while compressing) exceeds the
    threshold by the penetration ``d_th = (F/c)^(2/3)``: ``late_on <= d_th / v_land``.  At the
    separation the Tsuji force at the relative speed u, ``c d^1.5 - b d^0.25 u`` with
    ``b u = c d_sep^1.25`` (it vanishes at ``d_sep``), equals the threshold at ``d_a``:
    ``early_off = (d_a - d_sep) / u_sep``.  Both treat the relative speed as constant over the
    traverse (sub-millimetre), valid while ``a_rel d / v^2`` is small.
    """
    from scipy.optimize import brentq

    d_th = (threshold_n / c) ** (2.0 / 3.0)
    late_on = d_th / v_land
    if d_sep <= 0.0:
        return late_on, d_th / u_sep
    k = d_sep**1.25
    d_a = brentq(lambda d: c * d**0.25 * (d**1.25 - k) - threshold_n, d_sep, d_sep + d_th, xtol=1e-15)
    return late_on, (d_a - d_sep) / u_sep


class Flight(NamedTuple):
    """A row of the flights table (``EnergyEstimate.flights``), read by name: ``fl[k, FL.T]``."""

    t_sep: int  # s: the separation
    t_on: int  # s: the next touch
    T: int  # s: the flight's length
    v1: int  # m/s: body 1 at the separation (down positive)
    e_sep: int  # J: body 1's energy at the separation
    e_land: int  # J: and at the landing
    resolved: int  # 1: both ends seen


FL = positions(Flight)
FLIGHT_COLUMNS = ("t_sep_s", "t_on_s", "T_s", "v1_sep_mps", "E_sep_J", "E_land_J", "resolved")
assert len(FLIGHT_COLUMNS) == len(FL)


def estimate_energy(t, contacts: Contacts, plant: Plant, x2=None) -> EnergyEstimate:
    """Body 1's catch energy at the times ``t`` (s) from the contact intervals (module doc).

    ``x2``: body 2's travel at the times ``t`` (m, the potentiometer), or None.  With it each
    flight uses the ballistic relation ``v1_sep = dx2 / T - g T / 2`` (down positive) and the
    energy in flight follows body 2 (``E_sep + m1 g (x2(t) - x2_sep)``, the catch energy's
    dependence on the gap); without it, eq 4.5 as the thesis (dx2 = 0, constant in flight).
    """
    t = np.asarray(t, dtype=float)
    g, m1 = plant.g, plant.m1
    e0, u0 = plant.impact_energy, plant.rest_energy
    d_th = (contacts.threshold_n / plant.c) ** (2.0 / 3.0) if contacts.threshold_n > 0 else 0.0
    ton, toff = contacts.onsets, contacts.separations
    E = np.full(t.shape, np.nan)
    contact = np.zeros(t.shape, dtype=bool)
    if ton.size == 0:
        E[:] = e0
        return EnergyEstimate(t, E, e0, math.nan, np.zeros((0, len(FLIGHT_COLUMNS))), contact)
    if x2 is not None:
        x2 = np.asarray(x2, dtype=float)
        if x2.shape != t.shape or not np.all(np.isfinite(x2)):
            raise ValueError(f"x2 must be finite and shaped like t {t.shape}, got {x2.shape}")

    def pot(tt):
        return np.interp(tt, t, x2) if x2 is not None else np.zeros_like(np.asarray(tt, dtype=float))

    n_closed = min(len(toff), len(ton) - 1)  # flights with a landing
    t_sep, t_on = toff[:n_closed], ton[1:n_closed + 1]
    T = t_on - t_sep
    dx2 = pot(t_on) - pot(t_sep)
    v1 = dx2 / np.where(T > 0, T, np.inf) - g * T / 2.0  # at the separation, down positive
    e_sep = 0.5 * m1 * v1 * v1 + u0
    fl = np.column_stack([t_sep, t_on, T, v1, e_sep, e_sep + m1 * g * dx2,
                          (g * T * T / 8.0 >= 4.0 * d_th).astype(float)])
    E[t < ton[0]] = e0
    for k in range(len(ton)):
        start = ton[k]
        before = e0 if k == 0 else fl[k - 1, FL.e_land]
        stop = toff[k] if k < len(toff) else t[-1]
        contact |= (t >= start) & (t <= stop)
        if k < n_closed:  # between two flights (or the drop and a flight): interpolate
            seg = (t >= start) & (t <= stop)
            E[seg] = before + (fl[k, FL.e_sep] - before) * (t[seg] - start) / max(stop - start, 1e-300)
            fly = (t > stop) & (t < ton[k + 1])
            E[fly] = fl[k, FL.e_sep] + m1 * g * (pot(t[fly]) - pot(stop))
        elif k < len(toff):  # followed by a flight that does not end within the log: unknown
            E[t >= start] = np.nan
        else:  # the last contact, to the end: caught or at rest, down to 0 over a contact time
            v_land = abs(fl[k - 1, FL.v1] + g * fl[k - 1, FL.T]) if k > 0 else plant.impact_speed
            settle = hertz_contact_time(v_land, plant.effective_mass, plant.c)
            seg = (t >= start) & (t <= start + settle)
            E[seg] = before * (1.0 - (t[seg] - start) / settle) if settle > 0 else 0.0
            E[t > start + settle] = 0.0
    return EnergyEstimate(t, E, e0, float(ton[0]), fl, contact)


def contact_from_log(log, source: str = "force", threshold_n: float | None = None,
                     min_flight_s: float = 1e-3) -> Contacts:
    """Contact intervals of an :class:`~impact_env.rig.log.EpisodeLog` (module doc)."""
    scene = log.scene()
    t = log["t_s"]
    if source == "force":
        top = scene.effects.detector.top_mass
        phi = top * log["accelerometer_mps2"] + log["force_N"]
        thr = scene.effects.detector.threshold_n if threshold_n is None else float(threshold_n)
        if not thr > 0:
            raise ValueError(f"threshold_n = {thr!r} N must be > 0 N")
        rest = 0.5 * scene.plant.m1 * scene.plant.gravity
        return contact_intervals(t, signal=phi, threshold_n=thr, min_flight_s=min_flight_s, rest_level_n=rest)
    if source == "detector":
        return contact_intervals(t, contact=log["contact_detected"] != 0, min_flight_s=min_flight_s)
    raise ValueError(f"source = {source!r} must be 'force' or 'detector'")


RESIDUAL_MARKS_S = (0.010, 0.050, 0.100)


def summarize(log, source: str = "force", threshold_n: float | None = None, min_flight_s: float = 1e-3,
              catch_fraction: float = 0.01, method: str = "ballistic") -> dict:
    """The metrics of ``impact-env compare`` for one logged episode, where the rig allows them.

    Measured (from body 2's sensors, the applied force and the status bits):
    ``peak_force_N``, ``rms_force_N`` (force_applied_N, over the ticks), ``peak_demand_N``
    (force_demand_N), ``saturation_time_s`` (ticks with |action| >= 1 or a safety clamp bit,
    times the period), ``bounces`` (flights of at least ``min_flight_s`` after the first touch,
    an unfinished one included), ``contact_fraction`` (ticks after the first touch inside a
    contact, rest included).

    Estimated from the flight times (``method="ballistic"``: eq 4.5 with body 2's travel from the
    potentiometer, ``v1_sep = dx2 / T - g T / 2``; ``"thesis"``: eq 4.5 as printed; module doc for
    the errors): ``time_to_catch_s`` (from the first touch, after which the estimated catch
    energy stays below ``catch_fraction`` of E0; inf if not within the log; NaN if unknown at the
    end), ``caught``, ``residual_energy_{10,50,100}ms`` (estimate / E0 at the first sample at
    least that long after the first touch), ``energy_integral_ms`` (sum of estimate / E0 times
    the period, in ms), ``exit_speed_ratio`` and ``exit_velocity_ratio`` (body 1's velocity at
    the first separation over the impact speed, upwards positive; 0 without a flight; the
    velocity ratio is NaN with ``method="thesis"``, which assumes it upwards).

    From the scene: ``impact_speed_mps`` (nominal; the rig has no speed sensor on body 1), and
    E0 with it.  Also returned: ``t_touch_s``, ``flights``, ``unresolved_flights``,
    ``energy_source``, ``energy_method``.
    """
    scene = log.scene()
    plant = Plant.of(scene)
    contacts = contact_from_log(log, source, threshold_n, min_flight_s)
    t = log["t_s"]
    if method not in ("ballistic", "thesis"):
        raise ValueError(f"method = {method!r} must be 'ballistic' (eq 4.5 with the potentiometer) "
                         "or 'thesis'")
    est = estimate_energy(t, contacts, plant, log["potentiometer_m"] if method == "ballistic" else None)
    period = 1.0 / log.meta.control_rate_hz
    ratio = est.energy_J / est.e0_J
    t_touch = est.t_touch
    out = {"impact_speed_mps": plant.impact_speed, "energy_source": source, "t_touch_s": t_touch}
    if math.isnan(t_touch):
        above = np.ones(t.size, dtype=bool)
    else:
        above = ~(ratio < catch_fraction)  # NaN counts as above (unknown)
    if not above.any():
        ttc = 0.0
    elif above[-1]:
        ttc = math.inf
        if np.isnan(ratio[-1]):  # an unfinished last flight: caught only if even its lower bound is not
            t_open = float(t[-1] - contacts.separations[-1])
            low = float(flight_energy(t_open, plant.m1, plant.g)) + plant.rest_energy
            ttc = math.inf if low >= catch_fraction * est.e0_J else math.nan
    else:
        last = int(np.flatnonzero(above)[-1])
        ttc = max(float(t[last + 1]) - t_touch, 0.0)
    out["time_to_catch_s"] = ttc
    out["caught"] = bool(math.isfinite(ttc))
    for mark in RESIDUAL_MARKS_S:
        key = f"residual_energy_{int(round(mark * 1e3))}ms"
        idx = np.flatnonzero(t - t_touch >= mark - 1e-12) if not math.isnan(t_touch) else np.zeros(0, int)
        out[key] = float(ratio[idx[0]]) if len(idx) else math.nan
    out["energy_integral_ms"] = float(np.sum(ratio) * period * 1e3)
    fl = est.flights
    first = fl[fl[:, 0] >= t_touch] if fl.size else fl
    v_exit = -float(first[0, FL.v1]) / plant.impact_speed if len(first) else 0.0  # upwards positive
    out["exit_speed_ratio"] = abs(v_exit)
    out["exit_velocity_ratio"] = v_exit if method == "ballistic" else math.nan
    out["bounces"] = int(np.sum(fl[:, FL.T] >= min_flight_s)) + int(contacts.open_flight)
    f = log["force_applied_N"]
    out["peak_force_N"] = float(np.max(np.abs(f))) if f.size else 0.0
    out["rms_force_N"] = float(np.sqrt(np.mean(f * f))) if f.size else 0.0
    out["peak_demand_N"] = float(np.nanmax(np.abs(log["force_demand_N"]))) if f.size else 0.0
    after = t > t_touch if not math.isnan(t_touch) else np.zeros(t.size, dtype=bool)
    out["contact_fraction"] = float(np.sum(est.contact & after) / max(int(np.sum(after)), 1))
    sat = (np.abs(np.nan_to_num(log["action"])) >= 1.0) | ((log["status"] & (CLAMP_PEAK | CLAMP_RMS)) != 0)
    out["saturation_time_s"] = float(np.sum(sat) * period)
    out["flights"] = int(len(fl))
    out["unresolved_flights"] = int(np.sum(fl[:, FL.resolved] == 0)) if fl.size else 0
    out["energy_method"] = method
    return out
