"""Calibrating the damped contact so that it delivers a requested coefficient of restitution.

The Tsuji et al. (1992) law ``F = c d^1.5 + b d^0.25 d'`` (force clipped at zero) has a
property that Hunt-Crossley lacks: in the scaled variables ``d = D s``, ``t = (D/v) tau`` with
``D = (m v^2 / c)^(2/5)`` (m the effective mass, v the impact speed), the collision reads

    s'' = -max(0, s^1.5 + zeta s^0.25 s'),    s(0) = 0, s'(0) = 1,    zeta = b / sqrt(m c)

so the restitution ``e = -s'(separation)`` is a function of zeta alone: one zeta gives the same
e for every m, c and v (exact for the free two-body collision; gravity, the suspension and the
shaker act on top of that during contact).  We solve that scaled problem with
``scipy.integrate.solve_ivp`` and invert it with ``brentq``; Hunt-Crossley's
``chi = 3(1 - e)/(2 v)`` is only right near e = 1 and needs the impact speed latched.
"""

from __future__ import annotations

from functools import lru_cache
from math import sqrt
from typing import NamedTuple

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

_S0 = 1e-12  # start just after the touch: s ~ tau there, so s0 = tau0 = 1e-12


class ScaledCollision(NamedTuple):
    """The scaled Tsuji collision for one zeta (``s = d / D``, ``tau = t v / D``,
    ``D = (m v^2 / c)^(2/5)``): restitution, deepest scaled penetration, scaled contact time."""

    restitution: float
    s_max: float
    tau_contact: float


@lru_cache(maxsize=256)
def scaled_collision(zeta: float) -> ScaledCollision:
    """Solve the scaled collision with damping zeta (``solve_ivp`` DOP853, rtol 1e-12): the
    restitution, the deepest penetration ``s_max`` (a penetration ``D s_max``, m) and the
    contact time ``tau_contact`` (``(D / v) tau_contact``, s) up to the separation (the damped
    force falling to zero, or the touch)."""
    if zeta < 0.0 or not np.isfinite(zeta):
        raise ValueError(f"zeta must be a finite number >= 0, got {zeta!r}")

    def rhs(_t, y):
        s = max(y[0], 0.0)
        return [y[1], -max(0.0, s**1.5 + zeta * s**0.25 * y[1])]

    def force_zero(_t, y):  # s^1.25 + zeta s' changes sign where the damped force vanishes
        s = max(y[0], 0.0)
        return s**1.25 + zeta * y[1]

    # solve_ivp reads an event's terminal/direction as attributes of the function (its documented API)
    force_zero.terminal = True  # type: ignore[attr-defined]
    force_zero.direction = -1  # type: ignore[attr-defined]

    def touch(_t, y):
        return y[0]

    touch.terminal = True  # type: ignore[attr-defined]
    touch.direction = -1  # type: ignore[attr-defined]

    def deepest(_t, y):
        return y[1]

    deepest.direction = -1  # type: ignore[attr-defined]
    events = (touch, deepest) if zeta == 0.0 else (force_zero, touch, deepest)
    sol = solve_ivp(rhs, (0.0, 50.0), [_S0, 1.0], method="DOP853", rtol=1e-12, atol=1e-15, events=events)
    if sol.status != 1:
        raise RuntimeError(f"scaled collision with zeta={zeta} did not end by tau=50")
    deep = sol.y_events[-1]
    s_max = float(deep[0][0]) if len(deep) else float(np.max(sol.y[0]))
    e = 1.0 if zeta == 0.0 else float(-sol.y[1, -1])
    return ScaledCollision(e, s_max, float(sol.t[-1]))


def restitution_of_zeta(zeta: float) -> float:
    """Coefficient of restitution delivered by the scaled Tsuji collision with damping zeta."""
    return scaled_collision(float(zeta)).restitution


@lru_cache(maxsize=256)
def zeta_for_restitution(e: float) -> float:
    """The scaled damping zeta whose collision delivers restitution ``e`` in (0, 1]."""
    if not (0.0 < e <= 1.0):
        raise ValueError(f"restitution must be in (0, 1], got {e!r}")
    if e == 1.0:
        return 0.0
    hi = 1.0
    while restitution_of_zeta(hi) > e:
        hi *= 4.0
        if hi > 1e8:
            raise ValueError(f"restitution {e} is too small to calibrate (needs zeta > 1e8)")
    return float(brentq(lambda z: restitution_of_zeta(z) - e, 0.0, hi, xtol=1e-14, rtol=1e-13))


def tsuji_damping(e: float, m1: float, m2: float, c: float) -> float:
    """Damping coefficient b (N s/m^1.25) that makes the pad deliver restitution ``e``."""
    m = m1 * m2 / (m1 + m2)
    return zeta_for_restitution(e) * sqrt(m * c)


class ZetaTable:
    """Fast ``zeta_for_restitution`` over a range of restitutions ``[e_lo, e_hi]``, for drawing a
    new restitution every episode (one brentq solve costs about 0.1 s; this, about 20 us).

    e(zeta) is interpolated by a Chebyshev polynomial of degree ``n - 1`` through ``n`` exact
    solves of the scaled collision on ``[zeta(e_hi), zeta(e_lo)]``, and inverted by Newton's
    method on the polynomial.  Agrees with :func:`zeta_for_restitution` to about 1e-10 relative
    (``tests/test_randomize.py``), which changes the delivered restitution by about 1e-12, the
    accuracy of the solves themselves.
    """

    def __init__(self, e_lo: float, e_hi: float, n: int = 24):
        if not (0.0 < e_lo <= e_hi <= 1.0):
            raise ValueError(f"restitution range [{e_lo!r}, {e_hi!r}] must satisfy 0 < lo <= hi <= 1")
        self.e_lo, self.e_hi = float(e_lo), float(e_hi)
        z_lo, z_hi = zeta_for_restitution(self.e_hi), zeta_for_restitution(self.e_lo)
        if z_hi - z_lo <= 1e-12 * max(z_hi, 1e-300):
            self._poly = None
            self._z = z_lo
            return
        self._poly = np.polynomial.Chebyshev.interpolate(
            np.vectorize(restitution_of_zeta), n - 1, domain=[z_lo, z_hi])
        self._dpoly = self._poly.deriv()
        self._z_lo, self._z_hi = z_lo, z_hi

    def __call__(self, e: float) -> float:
        if not (self.e_lo <= e <= self.e_hi):
            raise ValueError(f"restitution {e!r} is outside the table's range [{self.e_lo}, {self.e_hi}]")
        if e == 1.0:
            return 0.0
        if self._poly is None:
            return self._z
        lo, hi = self._z_lo, self._z_hi
        z = lo + (hi - lo) * (self.e_hi - e) / max(self.e_hi - self.e_lo, 1e-300)
        for _ in range(50):  # e(zeta) is decreasing: Newton, kept inside [lo, hi]
            r = float(self._poly(z)) - e
            if r > 0.0:
                lo = z
            else:
                hi = z
            step = r / float(self._dpoly(z))
            zn = z - step
            if not (lo <= zn <= hi):
                zn = 0.5 * (lo + hi)
            if abs(zn - z) <= 1e-15 * max(abs(z), 1e-300):
                return zn
            z = zn
        return z


@lru_cache(maxsize=16)
def zeta_table(e_lo: float, e_hi: float) -> ZetaTable:
    """The (cached) :class:`ZetaTable` for ``[e_lo, e_hi]``."""
    return ZetaTable(e_lo, e_hi)
