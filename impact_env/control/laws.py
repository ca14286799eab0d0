"""The classic laws, compiled: the same arithmetic as the Python baselines (``baselines/``), for
one env, with no Python per call, so that the real-time target and the simulator's compiled
loops can run them.

A law is given by its name, its gains and the scene's constants it needs (masses, pad
stiffness, the force transducer's top mass m2', the control rate, the detector's threshold);
:func:`pack_law` turns them into the ``constants`` vector its kernel reads, and lists the
observation entries it reads (by name, so that any layout that has them works).  Every law
computes a force demand f (N, upwards) and the policy's command is ``clip(f / command_scale,
-1, 1)`` (:mod:`impact_env.control.policy`).

Laws and their constants (SI units):

* ``passive``: f = 0.
* ``thesis-ideal`` (privileged x1, v1, x2, v2): eq 2.17 in contact, the corrected eq 2.18 out of
  contact; constants m1, m2 (kg), c (N/m^1.5), g (m/s^2), h01 (1/s^2), h11 (1/s), h02 (N/m),
  h12 (N s/m), dref (m), sign (+1 corrected, -1 the printed, unstable sign).
* ``thesis-rig`` (sensors): eq 4.3 with its derivative term corrected, gated by the detector;
  constants m1, m2, c, g, h01, h11, h02, h12, dref, top_mass (kg), rate (Hz), threshold (N).
* ``pd-penetration`` (sensors): ``f = -m2 (kp (d - dref) + kd d')`` on the same estimate and
  gate; constants m2, c, kp (1/s^2), kd (1/s), dref, top_mass, rate, threshold.

The sensor-fed laws estimate the contact force ``Phi = max(m2' a2 + T, 0)``, the penetration
``d = (Phi / c)^(2/3)`` and its rate from successive samples, body 2's speed from the
potentiometer (:mod:`baselines.estimate` says why), keeping the previous d and x2 in a memory
row of :data:`MEMORY` floats that starts at 0.
"""

from __future__ import annotations

import math

import numpy as np

from impact_env._jit import jit
from impact_env.config import ConfigError

LAWS = ("passive", "thesis-ideal", "thesis-rig", "pd-penetration")
KIND = {name: k for k, name in enumerate(LAWS)}  # kind codes; the MLP is len(LAWS)
CONSTANTS = {
    "passive": (),
    "thesis-ideal": ("m1", "m2", "c", "g", "h01", "h11", "h02", "h12", "dref", "sign"),
    "thesis-rig": ("m1", "m2", "c", "g", "h01", "h11", "h02", "h12", "dref", "top_mass", "rate", "threshold"),
    "pd-penetration": ("m2", "c", "kp", "kd", "dref", "top_mass", "rate", "threshold"),
}
# observation entries a law reads (an absent "contact_detected" means: apply eq 4.4 here)
READS = {
    "passive": (),
    "thesis-ideal": ("x1", "v1", "x2", "v2"),
    "thesis-rig": ("accelerometer", "force", "potentiometer"),
    "pd-penetration": ("accelerometer", "force", "potentiometer"),
}
MEMORY = 2  # previous penetration estimate (m), previous x2 (m)
PREV_D, PREV_X2 = 0, 1
# the index slots of a law (into the observation's first frame): -1 where absent
SLOTS = ("accelerometer", "force", "potentiometer", "contact_detected", "x1", "v1", "x2", "v2")
S_ACC, S_FORCE, S_POT, S_DET, S_X1, S_V1, S_X2, S_V2 = range(len(SLOTS))


def pack_law(name: str, constants: dict[str, float],
             names: tuple[str, ...]) -> tuple[int, np.ndarray, np.ndarray]:
    """(kind code, int64 slots, float64 constants) of law ``name`` for an observation frame whose
    entries are ``names``; ConfigError naming what is missing or not finite."""
    if name not in KIND:
        raise ConfigError(f"compiled law {name!r} is not one of {', '.join(LAWS)}")
    missing = [r for r in READS[name] if r not in names]
    if missing:
        raise ConfigError(f"law {name!r} reads {', '.join(missing)}, which the observation "
                          f"({', '.join(names)}) does not hold")
    slots = np.array([names.index(s) if s in names else -1 for s in SLOTS], dtype=np.int64)
    vals = []
    for key in CONSTANTS[name]:
        if key not in constants:
            raise ConfigError(f"law {name!r} needs the constant {key!r}")
        v = float(constants[key])
        if not math.isfinite(v):
            raise ConfigError(f"law {name!r}: constant {key} = {v!r} must be finite")
        vals.append(v)
    return KIND[name], slots, np.array(vals, dtype=np.float64)


@jit(inline="always")
def _estimate(v, slots, top, c, rate, threshold, mem):
    """(phi N, d m, d' m/s, x2 m, v2 m/s, detected) from the frame values ``v`` (SI); updates mem."""
    a2 = v[slots[S_ACC]]
    t = v[slots[S_FORCE]]
    x2 = v[slots[S_POT]]
    s = top * a2 + t
    phi = s if s > 0.0 else 0.0
    d = (phi / c) ** (2.0 / 3.0)
    d_rate = (d - mem[PREV_D]) * rate
    v2 = (x2 - mem[PREV_X2]) * rate
    if slots[S_DET] >= 0:
        detected = v[slots[S_DET]] > 0.5
    else:
        detected = top * a2 + t > threshold
    mem[PREV_D] = d
    mem[PREV_X2] = x2
    return phi, d, d_rate, x2, v2, detected


@jit(inline="always")
def law_force(kind, slots, k, v, mem):
    """The force demand (N, upwards) of law ``kind`` with constants ``k`` on the frame values
    ``v`` (float64, SI units); ``mem`` is its memory row."""
    if kind == 1:  # thesis-ideal
        m1, m2, c, g = k[0], k[1], k[2], k[3]
        h01, h11, h02, h12, dref, sign = k[4], k[5], k[6], k[7], k[8], k[9]
        x1 = v[slots[S_X1]]
        v1 = v[slots[S_V1]]
        x2 = v[slots[S_X2]]
        v2 = v[slots[S_V2]]
        y1 = x1 - x2
        e = y1 - dref
        de = v1 - v2
        if y1 > 0.0:
            phi = c * y1 * np.sqrt(y1)
            f = m2 * (phi * (m1 + m2) / (m1 * m2) - g - h11 * de - h01 * e)
        else:
            f = m2 * (-g - sign * (h11 * de + h01 * e))
        return f - h12 * v2 - h02 * x2
    if kind == 2:  # thesis-rig
        m1, m2, c, g = k[0], k[1], k[2], k[3]
        h01, h11, h02, h12, dref = k[4], k[5], k[6], k[7], k[8]
        phi, d, d_rate, x2, v2, detected = _estimate(v, slots, k[9], c, k[10], k[11], mem)
        if not detected:
            return 0.0
        return m2 * (phi * (m1 + m2) / (m1 * m2) - g - h11 * d_rate - h01 * (d - dref)) - h12 * v2 - h02 * x2
    if kind == 3:  # pd-penetration
        m2, c, kp, kd, dref = k[0], k[1], k[2], k[3], k[4]
        phi, d, d_rate, x2, v2, detected = _estimate(v, slots, k[5], c, k[6], k[7], mem)
        if not detected:
            return 0.0
        return -m2 * (kp * (d - dref) + kd * d_rate)
    return 0.0  # passive
