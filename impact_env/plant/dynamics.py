"""Right-hand side of the two-body impact (thesis eq 2.7/2.8) with a Hertz-Tsuji contact.

Contact force on body 1 (N, positive when it pushes the bodies apart), penetration d = x1 - x2:

    F = c d^1.5 + b d^0.25 d'      for d > 0            (Tsuji et al. 1992; b = 0 is pure Hertz, eq 2.2)

With ``b = zeta * sqrt(m c)`` (m the effective mass) the coefficient of restitution depends on
zeta alone, for every m, c and impact speed: see :mod:`impact_env.plant.restitution`.
The force is never negative in the physical model.  How the switch between contact and free
flight is handled depends on the mode:

* ``AUTO``: the force is clipped at 0 and switched off for d <= 0 inside the right-hand side
  (the thesis's way, eq 3.2/3.3).  Simple, but a fixed step straddles each switch.
* ``CONTACT`` / ``FREE``: the mode is fixed for a whole step and the event locator
  (:mod:`impact_env.plant.integrators`) finds the switch.  In ``CONTACT`` the force is the
  smooth odd extension ``c d |d|^0.5`` for d <= 0 (reached only by trial steps that overshoot
  the switch), so no power of a negative number is ever taken.
"""

from __future__ import annotations

from math import sqrt
from typing import NamedTuple

from impact_env._jit import jit
from impact_env.plant.layout import AUTO, CONTACT, FREE, PARAM


class Coefs(NamedTuple):
    """The plant's parameters as its equations use them, for one env: read from its parameter
    row once (:func:`coefs`) and passed whole to every kernel that evaluates the equations."""

    m1: float  # body 1's mass, kg
    m2: float  # body 2's mass, kg
    im1: float  # 1 / m1 (1/kg): a multiplication keeps the RK stages' dependency chain free of divisions
    im2: float  # 1 / m2 (1/kg)
    c: float  # Hertz stiffness, N/m^1.5
    b: float  # Tsuji damping coefficient, N s/m^1.25 (0: elastic Hertz)
    g: float  # gravity on body 1, m/s^2
    k2: float  # body 2's suspension stiffness, N/m
    c2: float  # body 2's suspension damping, N s/m


@jit(inline="always")
def coefs(p):
    """:class:`Coefs` of the parameter row ``p`` (float64[N_PARAM], :mod:`impact_env.plant.layout`)."""
    return Coefs(p[PARAM.m1], p[PARAM.m2], 1.0 / p[PARAM.m1], 1.0 / p[PARAM.m2], p[PARAM.c], p[PARAM.b],
                 p[PARAM.g], p[PARAM.k2], p[PARAM.c2])


@jit(inline="always")
def contact_force(d, dd, mode, c, b):
    """Return ``(F, Fe)``: the contact force and its elastic part (both N) for penetration d (m),
    penetration rate dd (m/s) and contact mode."""
    if d > 0.0:
        s = sqrt(d)
        fe = c * d * s
        if mode == FREE:
            return 0.0, fe
        if b == 0.0:
            return fe, fe
        f = fe + b * sqrt(s) * dd
        if mode == AUTO and f < 0.0:
            f = 0.0
        return f, fe
    if mode == CONTACT:
        f = c * d * sqrt(-d)
        return f, f
    return 0.0, 0.0


@jit
def contact_forces(d, dd, mode, c, b, out):
    """:func:`contact_force` (its total force, N) of each sample: penetrations ``d`` (m), rates
    ``dd`` (m/s) and modes ``mode`` (int64) into ``out``."""
    for i in range(d.shape[0]):
        out[i] = contact_force(d[i], dd[i], mode[i], c, b)[0]


@jit(inline="always")
def event_value(x1, v1, x2, v2, c, b):
    """Switching function: positive in contact, negative in free flight, continuous.

    ``min(d, (d^1.25 + (b/c) d')^0.8)`` with signed powers: its first factor switches at the
    touch (d = 0), its second where the damped force falls to zero while still d > 0.  Both
    are lengths (m), which keeps the root finder well scaled.
    """
    d = x1 - x2
    if d <= 0.0 or b == 0.0:
        return d
    q = d * sqrt(sqrt(d)) + (b / c) * (v1 - v2)
    if q >= 0.0:
        r = q**0.8
    else:
        r = -((-q) ** 0.8)
    return d if d < r else r


@jit(inline="always")
def event_sign(x1, v1, x2, v2, c, b):
    """A value with the sign of :func:`event_value` (and zero where it is zero), without its
    power 0.8: for the crossing test of every accepted step, where only the sign counts."""
    d = x1 - x2
    if d <= 0.0 or b == 0.0:
        return d
    q = d * sqrt(sqrt(d)) + (b / c) * (v1 - v2)
    return q if q <= 0.0 else d


@jit(inline="always")
def deriv(x1, v1, x2, v2, mode, f2, pc):
    """Time derivative of (x1, v1, x2, v2, W_ext, W_diss) under a shaker force f2 (N, upwards).

    W_ext' is the shaker's power into the system, W_diss' the power lost in the pad's damping
    (including elastic energy released while the damped force is clipped) and the suspension
    damper; with them the energy balance ``E + W_diss - W_ext = const`` holds exactly.
    ``pc``: the plant's :class:`Coefs`.
    """
    d = x1 - x2
    dd = v1 - v2
    f, fe = contact_force(d, dd, mode, pc.c, pc.b)
    a1 = pc.g - f * pc.im1
    a2 = (f - f2 - pc.k2 * x2 - pc.c2 * v2) * pc.im2
    pext = -f2 * v2
    pdiss = (f - fe) * dd + pc.c2 * v2 * v2
    return v1, a1, v2, a2, pext, pdiss
