"""Sensor plausibility: every channel's reading checked every tick before it reaches a filter,
a law or the safety layer (the rig target's tick, :mod:`impact_env.rig.controller`, and the
exported C tick, :mod:`impact_env.deploy.c_export`, run this same check).

A reading of an enabled channel is **plausible** when

1. it lies within the converter's output range: ``lo <= x <= hi``, the ADC's code range
   (``-2^(b-1) q`` to ``(2^(b-1) - 1) q``, q = 2 ``adc_range`` / 2^b, as
   :func:`impact_env.effects.sensors.sense` clips) or ``+-adc_range`` for an ideal converter
   (``adc_bits = 0``).  NaN, +-inf and 1e30 all fail here (NaN fails every comparison);
2. it moved by no more than the physics allows since the channel's last plausible reading, k
   ticks ago: ``|x - x_good| <= k max_step |gain| + tol`` (no jump check when ``max_step`` is 0,
   nor on the episode's first tick, which has no previous reading).  ``max_step`` is the largest
   change of the true value between two ticks (``effects.sensors.<channel>.max_step``, the
   channel's unit); ``tol`` covers the reading's own noise and rounding:
   ``NOISE_SIGMAS sqrt(2) noise_std s + 2 q``, s the largest noise scale the scene's
   randomisation draws (1 without), because two noisy readings differ by noise of std
   ``sqrt(2) noise_std``, and each is rounded by at most q / 2 (plus one code of clipping).

Derivation of the defaults (the ``rig`` scene: m2 = 1 kg, m2' = 0.1 kg, 200 N drive, drops of
30-70 mm onto a Hertz pad c = 2e6 N/m^1.5, 10 kHz):

* accelerometer, 500 m/s^2 per tick: body 2's acceleration is (drive + contact force +
  suspension) / m2.  The drive may reverse within a tick (-200 N to +200 N: the coil's pole
  R / (2 pi L) = 3.2 kHz lets 86 % of a step through in 0.1 ms), 400 N.  The contact force
  changes at ``dPhi/dt = 1.5 c^(2/3) Phi^(1/3) v`` (Hertz, Phi = c d^1.5) with Phi below 300 N
  (a 70 mm drop's peak is 120 N; a drive pushing body 2 up into body 1 adds at most its 200 N)
  and the approach speed v below 4.7 m/s (v0 < 1.2 m/s plus body 2's 3.5 m/s, below): 75 N per
  tick.  The suspension (10 kN/m, 20 N s/m) changes by far less than 1 N per tick.
  (400 + 75) N / 1 kg, rounded up.
* force transducer, 125 N per tick: T = Phi - m2' a2 (thesis eq 4.4), so |dT| <= |dPhi| +
  m2' |da2| = 75 N + 0.1 kg x 500 m/s^2.
* potentiometer, 0.35 mm per tick: body 2's speed is bounded by its energy: at most 2 m1 v0 /
  (m1 + m2) < 2 v0 from an impact (v0 < 1.2 m/s), plus the work of the drive over the stroke,
  2 x 200 N x 10 mm = 4 J; ``v2 <= sqrt((2 v0)^2 + 2 x 4 J / m2)`` = 3.5 m/s, x 0.1 ms.
* body-1 sensor, 0.35 mm per tick: body 1 is slower than that bound too (v0 plus a rebound
  below 2 v2).

Measured against them (``tests/test_plausibility.py::test_defaults_never_flag_a_real_episode``:
the largest change between two ticks of the virtual rig's readings over drops with every classic
law and the shipped agent, ``rig`` and ``rig-randomized``): accelerometer 186 m/s^2, force
transducer 19 N, potentiometer 0.12 mm, i.e. at most 40 % of the allowance with the noise term.

These are loose on purpose: a jump check must never flag a real reading (a false fault cuts
the drive in the middle of a catch); what it catches is what no physics gives, e.g. a 1e30
sample, a spike of a full converter span, a potentiometer jumping by millimetres.

Physics checks (docs/rig/faults.md derives every bound; :func:`physics_params` computes them):

3. **stuck**: a channel whose reading repeats exactly for ``repeat_limit`` ticks in a row (its
   noise vanished: two noisy readings fall in the same converter code with probability at most
   ``q / (sqrt(2 pi) noise_std s_min)``, s_min the smallest noise scale the scene draws; the limit
   is the smallest n with that probability to the n below 1.2e-15, the jump check's 8 sigma),
   counted only strictly inside the converter's range (``lo < x < hi``: at either limit the
   converter clips, so the repeats are real; docs/rig/faults.md says which checks catch a
   channel stuck there);
4. **the top part's Newton** (thesis eq 2.7b / 4.4: the contact force ``Phi = m2' a2 + T`` is
   never negative): ``m2' a2 + T >= -tol_sign``;
5. **the armature's Newton** (body 2 below the transducer, mass ``m2 - m2'``, driven by the
   shaker force f2 and its suspension): ``(m2 - m2') a2 - T + k2 x2 = -f2 - c2 v2``.  The contact
   force is not in it, so a touch leaves it still, and its change per tick is bounded by the
   change of the shaker's force (the largest change of the commanded force over the last
   ``DEMAND_TICKS`` ticks, through the shaker model's monotone low-pass part, times the
   largest command gain), the damper's (c2 a2 T) and the model's uncertainty; the check compares
   the residual with the one of the last plausible readings, ``k`` ticks ago:
   ``|R - R_good| <= k (drive_gain max|dd| + per_tick) + tail + tol_arm``.  A failed 4 or 5 is
   blamed on the one channel whose held reading would pass it, else on both the accelerometer
   and the force transducer.

The physics checks run only on readings that passed 1-3 (a tick with a failed channel is faulty
already); a spike, a dropout or a step on the accelerometer or the force transducer inside
their ranges shows in 5 on the tick it happens, while the shaker's force is steady (before the
touch: the drive is 0 N) down to ``(tol_arm + per_tick) / (m2 - m2')`` on a2 and
``tol_arm + per_tick`` on T; the controller records each tick's force demand with
:func:`note_demand` after the safety layer.

A **disabled** channel (``enabled = false``; the rig has no body-1 sensor, its driver reports
NaN) is not checked and its reading is replaced by 0.0, what the simulator's disabled channel
reads, so that a NaN never enters a filter.

An implausible reading: the tick's status gets ``SENSOR_FAULT`` and the channel's own bit
(``SENSOR_ACCELEROMETER``, ``SENSOR_FORCE``, ``SENSOR_POTENTIOMETER``, ``SENSOR_BODY1``); the
filters and the laws get the channel's last plausible reading instead (held, as a DAQ's
sample-and-hold would); the safety layer drives 0 N for the tick.  Faulty ticks in a row beyond
``effects.sensors.fault_limit_s`` (in ticks, rounded up) latch ``SENSOR_TIMEOUT``: 0 N for the rest
of the episode, which the target ends ``SENSOR_FAULT``.

The check is :func:`check_readings` (numba); its parameters are :class:`PlausibilityParams` from
:func:`plausibility_params`, its state a float64 array (:func:`make_state`, :func:`reset_state`).
Everything is compared in float64 (the C export does the same in both of its builds).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.config import ConfigError
from impact_env.effects.delay import delay_samples
from impact_env.effects.sensors import ACCEL, CHANNELS, FORCE, N_CHANNELS, POT

# status bits (the rig's u32 status word, impact_env.rig.safety: bits 0-15 the safety layer's)
SENSOR_FAULT = 1 << 8  # some reading of this tick was implausible: 0 N, held readings
SENSOR_ACCELEROMETER = 1 << 9
SENSOR_FORCE = 1 << 10
SENSOR_POTENTIOMETER = 1 << 11
SENSOR_BODY1 = 1 << 12
SENSOR_TIMEOUT = 1 << 13  # (latched) implausible readings outlasted fault_limit_s: 0 N, episode ends
CHANNEL_BITS = (SENSOR_ACCELEROMETER, SENSOR_FORCE, SENSOR_POTENTIOMETER, SENSOR_BODY1)
CHANNEL_BIT_NAMES = ("SENSOR_ACCELEROMETER", "SENSOR_FORCE", "SENSOR_POTENTIOMETER", "SENSOR_BODY1")
SENSOR_BITS = SENSOR_FAULT | SENSOR_TIMEOUT | SENSOR_ACCELEROMETER | SENSOR_FORCE | SENSOR_POTENTIOMETER \
    | SENSOR_BODY1
# the noise allowance of every check, in standard deviations of the statistic it compares: a
# Gaussian exceeds 8 sigma with probability 1.2e-15, once in 3e4 years of ticks at 10 kHz
NOISE_SIGMAS = 8.0
# the probability each check may flag a clean tick (the 8-sigma tail; the stuck check's limit
# is the number of repeats that is at most this likely)
FALSE_ALARM_P = math.erfc(NOISE_SIGMAS / math.sqrt(2.0))
# the force demands the armature check remembers (ticks): the scene's delays plus the shaker's
# settling (its slowest pole, 2 kHz in rig-randomized, leaves 1e-6 of a step after 12 ticks)
DEMAND_TICKS = 16


class ChannelCheck(NamedTuple):
    """A row of the per-channel parameters (float64[N_CHANNELS, N_P])."""

    on: float  # 1: the channel is checked (enabled)
    lo: float  # the lowest plausible reading
    hi: float  # the highest plausible reading
    max_jump: float  # the largest plausible change per tick (0: no jump check)
    tol: float  # the noise and quantisation allowance of the jump check
    repeat: float  # exact repeats in a row that flag the channel stuck (0: no stuck check)
    scale: float  # 1 / gain: the true value per unit of reading
    offset: float  # the declared offset of the reading (channel's unit)


class PhysicsCheck(NamedTuple):
    """The cross-channel checks' constants (float64[N_PH]; docs/rig/faults.md derives them)."""

    on: float  # 1: the accelerometer and the force transducer are both enabled
    top_mass: float  # m2', kg: the part of body 2 above the transducer
    lower_mass: float  # m2 - m2', kg: the armature
    k2: float  # N/m: the suspension's stiffness (0: no potentiometer)
    tol_sign: float  # N: noise, rounding and m2' uncertainty of m2' a2 + T
    tol_arm: float  # N: noise and rounding of the change of the armature's residual
    per_tick: float  # N per tick: the residual's change the shaker's command does not explain
    drive_gain: float  # N of shaker force change per N of demand change (the largest)
    tail: float  # N: demand changes older than the remembered ones, through the shaker
    force_gain: float  # the largest shaker force per N of the largest remembered demand
    peak: float  # N: the amplifier's peak limit (effects.saturation.peak_n; the largest double: none)
    rms2: float  # N^2: its RMS budget squared (< 0: none)
    alpha: float  # its mean-square tracker's factor per tick


class Counters(NamedTuple):
    """The state's scalars, after its per-channel blocks (the last plausible reading of each
    channel from S_GOOD, the tick of it from S_LAST, the previous raw reading from S_PREV, the
    exact repeats in a row from S_REPEAT) and the ring of force demands (S_DEMAND, N, slot
    tick % DEMAND_TICKS)."""

    mean_square: float  # N^2: an upper bound of the amplifier's mean-square tracker (its budget)

    run: float  # faulty ticks in a row
    latch: float  # 1 once they outlasted the limit (SENSOR_TIMEOUT)
    primed: float  # 1 once a reading was seen this episode
    faulty: float  # the episode's faulty ticks


CC = positions(ChannelCheck)
N_P = len(CC)
PH = positions(PhysicsCheck)
N_PH = len(PH)
S_GOOD = 0
S_LAST = N_CHANNELS
S_PREV = 2 * N_CHANNELS
S_REPEAT = 3 * N_CHANNELS
S_DEMAND = 4 * N_CHANNELS
SC = positions(Counters, start=S_DEMAND + DEMAND_TICKS)
N_STATE = S_DEMAND + DEMAND_TICKS + len(SC)


class PlausibilityParams(NamedTuple):
    """What :func:`check_readings` checks against (fixed for a scene)."""

    ch: np.ndarray  # float64[N_CHANNELS, N_P]: columns ChannelCheck
    limit_ticks: float  # faulty ticks in a row allowed; one more latches SENSOR_TIMEOUT
    phys: np.ndarray  # float64[N_PH]: columns PhysicsCheck


def _span(scene, name: str, nominal: float) -> tuple[float, float]:
    """The (lowest, highest) value a scene's episodes draw for ``randomize.name`` (the nominal
    value twice when it has no range)."""
    r = getattr(scene.randomize, name, ())
    return (float(min(r)), float(max(r))) if len(r) else (float(nominal), float(nominal))


def _noise_scale_max(scene) -> float:
    return max(1.0, _span(scene, "noise_scale", 1.0)[1])


def repeat_limit(quantum: float, noise_std: float) -> int:
    """Exact repeats in a row that a channel of converter step ``quantum`` and noise ``noise_std``
    (both in its unit) gives with probability at most :data:`FALSE_ALARM_P`: each reading falls
    in its predecessor's code with probability at most ``quantum / (sqrt(2 pi) noise_std)`` (the
    code's width times the noise's largest density).  0: no stuck check (no noise, or less noise
    than one code)."""
    if noise_std <= 0.0:
        return 0
    p_repeat = quantum / (math.sqrt(2.0 * math.pi) * noise_std)
    if p_repeat >= 1.0:
        return 0
    if p_repeat == 0.0:
        return 1
    return max(1, math.ceil(math.log(FALSE_ALARM_P) / math.log(p_repeat)))


def _delay_ticks_max(scene, effect: str, field: str, name: str) -> int:
    if effect not in scene.effects.active:
        return 0
    nominal = getattr(scene.effects.delay, field)
    return delay_samples(_span(scene, name, nominal)[1], scene.control_rate)


def _drive_response(scene, delays: int, demand_max: float) -> tuple[float, float, float]:
    """(drive_gain, tail N, highpass N per tick) of the shaker between the force demand and
    body 2 (docs/rig/faults.md): a change of the demand moves the force by at most drive_gain
    times it, spread over the following ticks; the changes older than the remembered ones
    move it by at most ``tail`` this tick."""
    fx = scene.effects
    gain = _span(scene, "command_gain", 1.0)[1]
    window = DEMAND_TICKS - 1 - delays  # ticks of the shaker's memory the ring holds
    if "shaker" not in fx.active:
        return gain, (0.0 if window >= 1 else 2.0 * gain * demand_max), 0.0
    sh = fx.shaker
    T = scene.control_period
    if sh.model == "measured":
        taps = np.abs(np.asarray(sh.fir_taps, dtype=np.float64))
        held = float(taps[:max(window, 0)].sum())
        return gain * held, 2.0 * gain * demand_max * float(taps[max(window, 0):].sum()), 0.0
    factor = 1.0
    if sh.inverse_filter:  # (s + a)/a * b/(s + b): impulse response b/a delta + b (a - b)/a e^(-bt)
        a = sh.coil_resistance / sh.coil_inductance
        b = 2.0 * math.pi * sh.inverse_rolloff_hz
        factor = b / a + abs(a - b) / a
    poles = [2.0 * math.pi * _span(scene, "shaker_lowpass_hz", sh.lowpass_hz)[0]]
    if sh.amplifier == "voltage":
        poles.append(sh.coil_resistance / _span(scene, "shaker_coil_inductance", sh.coil_inductance)[1])
    slow = min(poles)
    t = max(window, 0) * T
    left = (1.0 + slow * t) * math.exp(-slow * t)  # of a step, after t, through two real poles
    tail = 2.0 * gain * factor * demand_max * left
    # the band's high-pass edge: f = LP(d) - w_hp/(s + w_hp) LP(d), whose second part moves by at
    # most w_hp T (|its input| + |its output|) a tick
    hp = 2.0 * math.pi * sh.highpass_hz * T * 2.0 * gain * factor * demand_max
    return gain * factor, tail, hp


def physics_params(scene) -> np.ndarray:
    """float64[N_PH]: the cross-channel checks' constants for ``scene`` (docs/rig/faults.md)."""
    fx = scene.effects
    sens = fx.sensors
    acc, frc, pot = sens.accelerometer, sens.force, sens.potentiometer
    ph = np.zeros(N_PH)
    if not (acc.enabled and frc.enabled):
        return ph
    T = scene.control_period
    s_max = _noise_scale_max(scene)
    m2 = float(scene.plant.m2)
    top = float(frc.top_mass)
    top_lo, top_hi = _span(scene, "top_mass", top)
    m2_lo, m2_hi = _span(scene, "m2", m2)
    top_unc = max(top - top_lo, top_hi - top)
    lower_unc = max(abs((m2_lo - top_hi) - (m2 - top)), abs((m2_hi - top_lo) - (m2 - top)))
    k_nom = float(scene.plant.suspension_stiffness)
    k_lo, k_hi = _span(scene, "suspension_stiffness", k_nom)
    c_hi = _span(scene, "suspension_damping", scene.plant.suspension_damping)[1]

    def true_noise(c):  # (noise std, one rounding) of a channel, in its true unit
        return c.noise_std * s_max / abs(c.gain), 0.5 * c.quantum / abs(c.gain)

    a_max = max(abs(acc.adc_range / acc.gain), 1e-30)  # the largest a2 the converter holds
    a_step = acc.max_step if acc.max_step > 0.0 else 2.0 * a_max
    (na, ra), (nt, rt) = true_noise(acc), true_noise(frc)
    ph[PH.on] = 1.0
    ph[PH.top_mass] = top
    ph[PH.lower_mass] = m2 - top
    ph[PH.tol_sign] = NOISE_SIGMAS * math.hypot(top * na, nt) + top * ra + rt + top_unc * a_max
    if pot.enabled:
        nx, rx = true_noise(pot)
        k_term = max(k_hi - k_nom, k_nom - k_lo)
        ph[PH.k2] = k_nom
    else:
        nx, rx, k_term = 0.0, 0.0, k_hi
    x_step = pot.max_step if pot.max_step > 0.0 else 2.0 * pot.adc_range
    lower = m2 - top
    # two readings' difference: sqrt(2) times the noise, a rounding from each
    noise = math.sqrt((lower * na) ** 2 + nt ** 2 + (ph[PH.k2] * nx) ** 2)
    ph[PH.tol_arm] = NOISE_SIGMAS * math.sqrt(2.0) * noise + 2.0 * (lower * ra + rt + ph[PH.k2] * rx)
    demand_max = float(fx.command_scale)
    if "saturation" in fx.active:
        demand_max = min(demand_max, float(fx.saturation.peak_n))
    delays = _delay_ticks_max(scene, "sensor_delay", "sensor_s", "sensor_delay_s") \
        + _delay_ticks_max(scene, "actuator_delay", "actuator_s", "actuator_delay_s")
    drive_gain, tail, hp = _drive_response(scene, delays, demand_max)
    per_tick = k_term * x_step + c_hi * a_max * T + lower_unc * a_step + hp
    # the amplifier's RMS budget may cut the force within a tick once spent: the check keeps an
    # upper bound of its mean-square tracker (note_demand) and allows the cut it could make
    ph[PH.force_gain] = drive_gain
    ph[PH.peak] = np.finfo(np.float64).max  # (no amplifier limit: finite, for the C text)
    ph[PH.rms2] = -1.0
    if "saturation" in fx.active:
        sat = fx.saturation
        ph[PH.peak] = float(sat.peak_n)
        if sat.continuous_n > 0.0:
            ph[PH.rms2] = sat.rms_limit_n ** 2
            ph[PH.alpha] = -math.expm1(-1.0 / (scene.control_rate * sat.tau_s))
    if "shaker" in fx.active and fx.shaker.amplifier == "voltage" and fx.shaker.back_emf:
        per_tick += fx.shaker.force_factor ** 2 / fx.shaker.coil_resistance * a_max * T
    ph[PH.per_tick] = per_tick
    ph[PH.drive_gain] = drive_gain
    ph[PH.tail] = tail
    return ph


def plausibility_params(scene) -> PlausibilityParams:
    """The check's parameters from ``scene``'s sensors (``effects.sensors``) at its control rate.
    ConfigError when they cannot hold a real reading (a range the converter's own output leaves)."""
    sens = scene.effects.sensors
    noise = _noise_scale_max(scene)
    noise_min = _span(scene, "noise_scale", 1.0)[0]
    sensor_delay = _delay_ticks_max(scene, "sensor_delay", "sensor_s", "sensor_delay_s")
    ch = np.zeros((N_CHANNELS, N_P))
    for i, c in enumerate(sens.channels()):
        ch[i, CC.on] = 1.0 if c.enabled else 0.0
        if c.adc_bits:
            q = c.quantum
            half = 2.0 ** (c.adc_bits - 1)
            ch[i, CC.lo], ch[i, CC.hi] = -half * q, (half - 1.0) * q
        else:
            q = 0.0
            ch[i, CC.lo], ch[i, CC.hi] = -c.adc_range, c.adc_range
        ch[i, CC.max_jump] = c.max_step * abs(c.gain)
        ch[i, CC.tol] = NOISE_SIGMAS * math.sqrt(2.0) * c.noise_std * noise + 2.0 * q
        repeats = repeat_limit(q, c.noise_std * noise_min)
        # a sensor delay line starts full of the release's reading: that many repeats are real
        ch[i, CC.repeat] = repeats + sensor_delay if repeats else 0.0
        ch[i, CC.scale] = 1.0 / c.gain
        ch[i, CC.offset] = c.offset
        if c.enabled and c.max_step > 0.0 and not ch[i, CC.max_jump] + ch[i, CC.tol] > 0.0:
            raise ConfigError(f"effects.sensors.{CHANNELS[i]}.max_step = {c.max_step!r} allows no change "
                              "at all between two ticks; give a positive value (or 0: no jump check)")
    limit = math.ceil(sens.fault_limit_s * scene.control_rate - 1e-9)
    return PlausibilityParams(ch, float(max(limit, 1)), physics_params(scene))


def make_state() -> np.ndarray:
    return np.zeros(N_STATE)


def reset_state(state: np.ndarray) -> np.ndarray:
    """A new episode: no reading seen, no fault, the counter cleared (the rest readings, 0, held
    until the first plausible one; no force demanded before the release)."""
    state[:] = 0.0
    return state


@jit(inline="always")
def _true_value(ch, c, x):
    """A reading in the true value's unit (its declared offset and gain undone)."""
    return (x - ch[c, CC.offset]) * ch[c, CC.scale]


@jit(inline="always")
def _consistent(ph, a, t, x, ag, tg, xg, allowed):
    """Whether readings (a2, T, x2) pass checks 4 and 5 against the held ones (module doc)."""
    if ph[PH.top_mass] * a + t < -ph[PH.tol_sign]:
        return False
    r = ph[PH.lower_mass] * a - t + ph[PH.k2] * x
    r_good = ph[PH.lower_mass] * ag - tg + ph[PH.k2] * xg
    return abs(r - r_good) <= allowed


@jit(inline="always")
def _largest_force(ph, s):
    """An upper bound of the shaker's force now (N): the largest remembered demand through it,
    at most the amplifier's peak."""
    top = 0.0
    for j in range(DEMAND_TICKS):
        d = abs(s[S_DEMAND + j])
        if d > top:
            top = d
    top = ph[PH.force_gain] * top
    return top if top < ph[PH.peak] else ph[PH.peak]


@jit(inline="always")
def _budget_cut(ph, s):
    """The most the amplifier's RMS budget can cut the force this tick (N): from the largest
    force down to the lowest limit the budget can set (its tracker at most SC.mean_square)."""
    if ph[PH.rms2] < 0.0:
        return 0.0
    ms = s[SC.mean_square]
    room = ms + (ph[PH.rms2] - ms) / ph[PH.alpha]
    if room < 0.0:
        room = 0.0
    cut = _largest_force(ph, s) - np.sqrt(room)
    return cut if cut > 0.0 else 0.0


@jit
def check_physics(m, raw, p, s):
    """Checks 4 and 5 (module doc) of tick m's readings ``raw`` against the last plausible ones
    in ``s``; returns the channel bits of the readings they blame (0: consistent)."""
    ch, ph = p.ch, p.phys
    a = _true_value(ch, ACCEL, raw[ACCEL])
    t = _true_value(ch, FORCE, raw[FORCE])
    ag = _true_value(ch, ACCEL, s[S_GOOD + ACCEL])
    tg = _true_value(ch, FORCE, s[S_GOOD + FORCE])
    oldest = min(s[S_LAST + ACCEL], s[S_LAST + FORCE])
    if ch[POT, CC.on] != 0.0:
        x = _true_value(ch, POT, raw[POT])
        xg = _true_value(ch, POT, s[S_GOOD + POT])
        oldest = min(oldest, s[S_LAST + POT])
    else:
        x = 0.0
        xg = 0.0
    # the largest change of the force demand between two remembered ticks (the slot tick m
    # writes holds the oldest one, which has no predecessor in the ring)
    change = 0.0
    head = m % DEMAND_TICKS
    for j in range(DEMAND_TICKS):
        if j != head:
            jp = j - 1 if j > 0 else DEMAND_TICKS - 1
            d = abs(s[S_DEMAND + j] - s[S_DEMAND + jp])
            if d > change:
                change = d
    cut = _budget_cut(ph, s)
    ticks = m - oldest
    allowed = ticks * (ph[PH.drive_gain] * change + ph[PH.per_tick] + cut) + ph[PH.tail] + ph[PH.tol_arm]
    if _consistent(ph, a, t, x, ag, tg, xg, allowed):
        return 0
    # blame the one channel whose held reading makes the rest consistent
    held_a = _consistent(ph, ag, t, x, ag, tg, xg, allowed)
    held_t = _consistent(ph, a, tg, x, ag, tg, xg, allowed)
    held_x = ch[POT, CC.on] != 0.0 and _consistent(ph, a, t, xg, ag, tg, xg, allowed)
    if held_a and not held_t and not held_x:
        return SENSOR_ACCELEROMETER
    if held_t and not held_a and not held_x:
        return SENSOR_FORCE
    if held_x and not held_a and not held_t:
        return SENSOR_POTENTIOMETER
    return SENSOR_ACCELEROMETER | SENSOR_FORCE


@jit
def check_readings(m, raw, p, s, out):
    """Check tick m's readings ``raw`` (float64[4]) against ``p`` (PlausibilityParams), update
    ``s`` (float64[N_STATE]) and write what the front end may use into ``out`` (float64[4]: the
    reading where plausible, the channel's last plausible one where not, 0.0 for a disabled
    channel).  Returns the status bits (0: all plausible; module doc)."""
    ch = p.ch
    bits = 0
    primed = s[SC.primed] != 0.0
    for c in range(N_CHANNELS):
        if ch[c, CC.on] == 0.0:
            continue
        x = raw[c]
        ok = ch[c, CC.lo] <= x and x <= ch[c, CC.hi]
        if ok and primed and ch[c, CC.max_jump] > 0.0:
            allowed = ch[c, CC.max_jump] * (m - s[S_LAST + c]) + ch[c, CC.tol]
            ok = abs(x - s[S_GOOD + c]) <= allowed
        if primed and x == s[S_PREV + c]:
            s[S_REPEAT + c] += 1.0
        else:
            s[S_REPEAT + c] = 0.0
        s[S_PREV + c] = x
        # a reading at the converter's limit repeats because the converter clips, not because
        # the noise vanished: the stuck check counts only readings strictly inside the range
        if ok and ch[c, CC.repeat] > 0.0 and s[S_REPEAT + c] >= ch[c, CC.repeat] \
                and ch[c, CC.lo] < x and x < ch[c, CC.hi]:
            ok = False
        if not ok:
            bits |= 1 << (9 + c)
    if bits == 0 and primed and p.phys[PH.on] != 0.0:
        bits = check_physics(m, raw, p, s)
    for c in range(N_CHANNELS):
        if ch[c, CC.on] == 0.0:
            out[c] = 0.0
        elif bits & (1 << (9 + c)):
            out[c] = s[S_GOOD + c]
        else:
            s[S_GOOD + c] = raw[c]
            s[S_LAST + c] = m
            out[c] = raw[c]
    s[SC.primed] = 1.0
    if bits != 0:
        bits |= SENSOR_FAULT
        s[SC.run] += 1.0
        s[SC.faulty] += 1.0
        if s[SC.run] > p.limit_ticks:
            s[SC.latch] = 1.0
    else:
        s[SC.run] = 0.0
    if s[SC.latch] != 0.0:
        bits |= SENSOR_TIMEOUT
    return bits


@jit
def note_demand(m, force, p, s):
    """Remember tick m's force demand (N, the safety layer's output, what the shaker is sent)
    for the armature check of the ticks that follow, and update the bound of the amplifier's
    mean-square tracker with the largest force it may apply."""
    ph = p.phys
    s[S_DEMAND + m % DEMAND_TICKS] = force
    if ph[PH.rms2] >= 0.0:
        top = _largest_force(ph, s)
        s[SC.mean_square] += ph[PH.alpha] * (top * top - s[SC.mean_square])


def describe_channels(bits: int) -> list[str]:
    """The channels whose bit is set in ``bits`` (config names)."""
    return [CHANNELS[c] for c, b in enumerate(CHANNEL_BITS) if int(bits) & b]
