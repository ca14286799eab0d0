"""The classic laws, compiled: each law exists once, here; the Python baselines (``baselines/``)
call these kernels (:func:`law_forces`), the real-time target and the simulator's compiled loops
run them (:func:`law_force`), with no Python per call.

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
PASSIVE, THESIS_IDEAL, THESIS_RIG, PD_PENETRATION = range(len(LAWS))  # kind codes; the MLP is len(LAWS)
KIND = {name: k for k, name in enumerate(LAWS)}
# each law's constants vector: the names in order, and next to them the positions its kernel reads
IDEAL = ("m1", "m2", "c", "g", "h01", "h11", "h02", "h12", "dref", "sign")
I_M1, I_M2, I_C, I_G, I_H01, I_H11, I_H02, I_H12, I_DREF, I_SIGN = range(len(IDEAL))
RIG = ("m1", "m2", "c", "g", "h01", "h11", "h02", "h12", "dref", "top_mass", "rate", "threshold")
R_M1, R_M2, R_C, R_G, R_H01, R_H11, R_H02, R_H12, R_DREF, R_TOP, R_RATE, R_THRESHOLD = range(len(RIG))
PD = ("m2", "c", "kp", "kd", "dref", "top_mass", "rate", "threshold")
P_M2, P_C, P_KP, P_KD, P_DREF, P_TOP, P_RATE, P_THRESHOLD = range(len(PD))
CONSTANTS = {"passive": (), "thesis-ideal": IDEAL, "thesis-rig": RIG, "pd-penetration": PD}
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


def law_slots(name: str, names: tuple[str, ...]) -> np.ndarray:
    """int64 slots (:data:`SLOTS`) of law ``name`` in an observation frame whose entries are
    ``names``; ConfigError naming what is missing."""
    if name not in KIND:
        raise ConfigError(f"compiled law {name!r} is not one of {', '.join(LAWS)}")
    missing = [r for r in READS[name] if r not in names]
    if missing:
        raise ConfigError(f"law {name!r} reads {', '.join(missing)}, which the observation "
                          f"({', '.join(names)}) does not hold")
    return np.array([names.index(s) if s in names else -1 for s in SLOTS], dtype=np.int64)


def constants_rows(name: str, constants: dict, n: int) -> np.ndarray:
    """float64[n, k]: law ``name``'s constants vector for each of n envs (a constant may be a
    number or an array over the envs, as the baselines' gains are)."""
    keys = CONSTANTS[name]
    out = np.empty((n, len(keys)))
    for j, key in enumerate(keys):
        if key not in constants:
            raise ConfigError(f"law {name!r} needs the constant {key!r}")
        v = constants[key]
        if isinstance(v, (float, int)):  # the usual case: predict() is called per step
            out[:, j] = v
        else:
            out[:, j] = np.broadcast_to(np.asarray(v, dtype=np.float64), (n,))
    return out


def pack_law(name: str, constants: dict[str, float],
             names: tuple[str, ...]) -> tuple[int, np.ndarray, np.ndarray]:
    """(kind code, int64 slots, float64 constants) of law ``name`` for an observation frame whose
    entries are ``names``; ConfigError naming what is missing or not finite."""
    slots = law_slots(name, names)
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
    if kind == THESIS_IDEAL:
        m1, m2, c, g = k[I_M1], k[I_M2], k[I_C], k[I_G]
        h01, h11, h02, h12, dref, sign = k[I_H01], k[I_H11], k[I_H02], k[I_H12], k[I_DREF], k[I_SIGN]
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
    if kind == THESIS_RIG:
        m1, m2, c, g = k[R_M1], k[R_M2], k[R_C], k[R_G]
        h01, h11, h02, h12, dref = k[R_H01], k[R_H11], k[R_H02], k[R_H12], k[R_DREF]
        phi, d, d_rate, x2, v2, detected = _estimate(v, slots, k[R_TOP], c, k[R_RATE], k[R_THRESHOLD], mem)
        if not detected:
            return 0.0
        return m2 * (phi * (m1 + m2) / (m1 * m2) - g - h11 * d_rate - h01 * (d - dref)) - h12 * v2 - h02 * x2
    if kind == PD_PENETRATION:
        m2, c, kp, kd, dref = k[P_M2], k[P_C], k[P_KP], k[P_KD], k[P_DREF]
        phi, d, d_rate, x2, v2, detected = _estimate(v, slots, k[P_TOP], c, k[P_RATE], k[P_THRESHOLD], mem)
        if not detected:
            return 0.0
        return -m2 * (kp * (d - dref) + kd * d_rate)
    return 0.0  # passive


@jit
def law_forces(kind, slots, K, V, mem, out):
    """:func:`law_force` for every row i (constants ``K[i]``, frame values ``V[i]`` in SI units,
    memory ``mem[i]`` of at least :data:`MEMORY` floats) into ``out[i]``: the baselines'
    (``baselines/``) Python face of the same kernel."""
    for i in range(V.shape[0]):
        out[i] = law_force(kind, slots, K[i], V[i], mem[i])
    return out
