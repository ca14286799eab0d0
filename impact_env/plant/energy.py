"""Energies of the two-body system (vectorised over samples; the catch energy compiled).  All in J,
thesis frame."""

from __future__ import annotations

import numpy as np

from impact_env._jit import jit


@jit(inline="always")
def catch_energy_at(x1, v1, x2, m1, c, g):
    """:func:`catch_energy` of one state, compiled (J); the task's rewards and the episode
    metrics use it."""
    d = x1 - x2
    ds = (m1 * g / c) ** (2.0 / 3.0)
    dp = d if d > 0.0 else 0.0
    return 0.5 * m1 * v1 * v1 + m1 * g * (0.6 * ds - d) + 0.4 * c * dp * dp * np.sqrt(dp)


def elastic_energy(d, c):
    """Energy stored in the Hertz contact, ``(2/5) c d^2.5`` for d > 0 (J)."""
    dp = np.maximum(np.asarray(d, dtype=float), 0.0)
    return 0.4 * c * dp * dp * np.sqrt(dp)


def catch_energy(x1, v1, x2, m1, c, g):
    """Body 1's energy above resting on body 2 (J): ``m1 v1^2 / 2 + U(d)`` with

    ``U(d) = m1 g (3/5 d_s - d) + (2/5) c d_+^2.5``, ``d_s = (m1 g / c)^(2/3)``:

    gravitational energy relative to resting on body 2's surface plus the pad's elastic
    energy, shifted so that U(d_s) = 0 at rest; U >= 0 everywhere.
    The kinetic part is body 1's absolute kinetic energy, as in the thesis's E1 (eq 4.5).
    Arguments broadcast (numpy); each element is :func:`catch_energy_at`'s, bit for bit, so the
    records, the rewards and the metrics agree to the last bit.
    """
    args = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (x1, v1, x2, m1, c, g)))
    flat = [np.ascontiguousarray(a).ravel() for a in args]
    out = np.empty(flat[0].size)
    _catch_energy_many(*flat, out)
    return out.reshape(args[0].shape)


@jit
def _catch_energy_many(x1, v1, x2, m1, c, g, out):
    for i in range(out.shape[0]):
        out[i] = catch_energy_at(x1[i], v1[i], x2[i], m1[i], c[i], g[i])


def energies(x1, v1, x2, v2, m1, m2, c, g, k2):
    """Dict of the system's energies (J): kinetic1, kinetic2, gravity (of body 1, zero at
    x1 = 0), elastic (pad), suspension, total."""
    e = {
        "kinetic1": 0.5 * m1 * np.asarray(v1) ** 2,
        "kinetic2": 0.5 * m2 * np.asarray(v2) ** 2,
        "gravity": -m1 * g * np.asarray(x1),
        "elastic": elastic_energy(np.asarray(x1) - np.asarray(x2), c),
        "suspension": 0.5 * k2 * np.asarray(x2) ** 2,
    }
    e["total"] = e["kinetic1"] + e["kinetic2"] + e["gravity"] + e["elastic"] + e["suspension"]
    return e


def energy_above_rest(x1, v1, x2, v2, m1, m2, c, g, k2):
    """The system's energy above its state of rest (J), which no passive motion can increase.

    With a suspension (k2 > 0) rest is body 1 on the pad at ``d_s`` and body 2 at
    ``x_r = m1 g / k2``; the total energy above that state is

        ``E_rest = catch_energy + m2 v2^2 / 2 + k2 (x2 - x_r)^2 / 2``

    (body 1's catch energy plus body 2's kinetic energy and the suspension's energy about its
    loaded rest).  It is >= the catch energy and, without shaker force, non-increasing (its
    rate is minus the pad's and the suspension's dissipation), so once it is below a level,
    body 1's catch energy stays below that level for good.

    Without a suspension (k2 = 0) body 2 is not held and the pair has no rest in the lab frame;
    the energy of the relative motion above its rest is used instead,
    ``m dd^2 / 2 + (2/5) c d_+^2.5 - m g d + (3/5) m g d*`` with m the effective mass and
    ``d* = (m g / c)^(2/3)`` (non-increasing without shaker force as well; it does not bound
    body 1's absolute kinetic energy, which grows as the unheld pair falls).
    """
    x1, v1, x2, v2 = (np.asarray(a, dtype=float) for a in (x1, v1, x2, v2))
    if k2 > 0:
        xr = m1 * g / k2
        return catch_energy(x1, v1, x2, m1, c, g) + 0.5 * m2 * v2**2 + 0.5 * k2 * (x2 - xr) ** 2
    m = m1 * m2 / (m1 + m2)
    d = x1 - x2
    ds = (m * g / c) ** (2.0 / 3.0)
    return 0.5 * m * (v1 - v2) ** 2 + elastic_energy(d, c) - m * g * d + 0.6 * m * g * ds
