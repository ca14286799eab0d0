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
from impact_env.effects.sensors import CHANNELS, N_CHANNELS

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
# the noise allowance of the jump check, in standard deviations of the difference of two readings:
# a Gaussian exceeds 8 sigma with probability 1.2e-15, once in 3e4 years of ticks at 10 kHz
NOISE_SIGMAS = 8.0



class ChannelCheck(NamedTuple):
    """A row of the per-channel parameters (float64[N_CHANNELS, N_P])."""

    on: float  # 1: the channel is checked (enabled)
    lo: float  # the lowest plausible reading
    hi: float  # the highest plausible reading
    max_jump: float  # the largest plausible change per tick (0: no jump check)
    tol: float  # the noise and quantisation allowance of the jump check


class Counters(NamedTuple):
    """The state's scalars, after its two per-channel blocks (the last plausible reading of
    each channel from S_GOOD, the tick of it from S_LAST)."""

    run: float  # faulty ticks in a row
    latch: float  # 1 once they outlasted the limit (SENSOR_TIMEOUT)
    primed: float  # 1 once a reading was seen this episode
    faulty: float  # the episode's faulty ticks


CC = positions(ChannelCheck)
N_P = len(CC)
S_GOOD = 0
S_LAST = N_CHANNELS
SC = positions(Counters, start=2 * N_CHANNELS)
N_STATE = 2 * N_CHANNELS + len(SC)


class PlausibilityParams(NamedTuple):
    """What :func:`check_readings` checks against (fixed for a scene)."""

    ch: np.ndarray  # float64[N_CHANNELS, N_P]: columns ChannelCheck
    limit_ticks: float  # faulty ticks in a row allowed; one more latches SENSOR_TIMEOUT


def _noise_scale_max(scene) -> float:
    r = getattr(scene.randomize, "noise_scale", ())
    return max(1.0, float(max(r))) if len(r) else 1.0


def plausibility_params(scene) -> PlausibilityParams:
    """The check's parameters from ``scene``'s sensors (``effects.sensors``) at its control rate.
    ConfigError when they cannot hold a real reading (a range the converter's own output leaves)."""
    sens = scene.effects.sensors
    noise = _noise_scale_max(scene)
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
        if c.enabled and c.max_step > 0.0 and not ch[i, CC.max_jump] + ch[i, CC.tol] > 0.0:
            raise ConfigError(f"effects.sensors.{CHANNELS[i]}.max_step = {c.max_step!r} allows no change "
                              "at all between two ticks; give a positive value (or 0: no jump check)")
    limit = math.ceil(sens.fault_limit_s * scene.control_rate - 1e-9)
    return PlausibilityParams(ch, float(max(limit, 1)))


def make_state() -> np.ndarray:
    return np.zeros(N_STATE)


def reset_state(state: np.ndarray) -> np.ndarray:
    """A new episode: no reading seen, no fault, the counter cleared (the rest readings, 0, held
    until the first plausible one)."""
    state[:] = 0.0
    return state


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
            out[c] = 0.0
            continue
        x = raw[c]
        ok = ch[c, CC.lo] <= x and x <= ch[c, CC.hi]
        if ok and primed and ch[c, CC.max_jump] > 0.0:
            allowed = ch[c, CC.max_jump] * (m - s[S_LAST + c]) + ch[c, CC.tol]
            ok = abs(x - s[S_GOOD + c]) <= allowed
        if ok:
            s[S_GOOD + c] = x
            s[S_LAST + c] = m
            out[c] = x
        else:
            bits |= 1 << (9 + c)
            out[c] = s[S_GOOD + c]
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


def describe_channels(bits: int) -> list[str]:
    """The channels whose bit is set in ``bits`` (config names)."""
    return [CHANNELS[c] for c, b in enumerate(CHANNEL_BITS) if int(bits) & b]
