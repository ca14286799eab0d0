"""Exact free flight of the two bodies over a span of constant shaker force, and the contact
onset located on that exact motion (the ``split`` integrator's free phase).

Out of contact the plant is linear with a constant input: body 1 falls on a parabola
(``x1'' = g``) and body 2 is a mass on its suspension (``m2 x2'' = -f2 - k2 x2 - c2 x2'``).
Both are propagated exactly: body 1 in closed form, body 2 by the exponential series of its
2x2 system, ``z(h) = z + sum_n h^n / n! A^(n-1) (A z + u)``, summed until a term no longer
changes the sum.  A sub-step is capped at ``SERIES_REACH / max(omega_2, c2/m2)`` so that the
terms fall at least as fast as ``SERIES_REACH^n / n!``: a few terms for the rig's 16 Hz
suspension over a 100 us period, round-off accuracy always (checked against
``scipy.linalg.expm`` in ``tests/test_split.py``).

Energy ledger: ``W_ext`` grows by ``-f2 (x2(h) - x2)`` (f2 is constant), and since body 2's
stored energy ``m2 v2^2 / 2 + k2 x2^2 / 2`` changes by the shaker's work minus the damper's
``c2 int v2^2 dt``, the damper's share is that difference, exactly (Van Loan's integral of the
same quadratic form, in three products).

Onset: the switching function of :func:`impact_env.plant.dynamics.event_value` is evaluated on
the exact motion, so the touch is found to round-off (no integration error in the located
time).  A touch between two sub-step ends (penetration rate turning from + to - inside) is
found from the interior maximum of the penetration.

The kernels take the plant's constants as one :class:`impact_env.plant.dynamics.Coefs` (``pc``).
"""

from __future__ import annotations

from math import sqrt

from impact_env._jit import jit
from impact_env.plant.dynamics import event_value

SERIES_REACH = 0.5  # largest |A| h of one sub-step (dimensionless): terms fall as 0.5^n / n!
MAX_TERMS = 40  # reached only with a zero sum; 0.5^40 / 40! is far below round-off
MAX_ROOT_ITER = 100
ROOT_TOL = 1e-14  # bracket width of a located touch, relative to the sub-step


@jit(inline="always")
def free_cap(pc):
    """The longest sub-step (s) over which :func:`body2_after` converges fast, ``inf`` for a
    free body 2 with no suspension."""
    rate = max(sqrt(pc.k2 * pc.im2), pc.c2 * pc.im2)
    if rate > 0.0:
        return SERIES_REACH / rate
    return 1e300


@jit(inline="always")
def body2_after(x2, v2, h, f2, pc):
    """Body 2's position (m) and velocity (m/s) after h seconds (0 <= h <= :func:`free_cap`) on
    its suspension under the constant force f2 (N, upwards)."""
    sx = x2
    sv = v2
    tx = v2 * h
    tv = (-f2 - pc.k2 * x2 - pc.c2 * v2) * pc.im2 * h
    for n in range(2, MAX_TERMS + 2):
        nx = sx + tx
        nv = sv + tv
        if nx == sx and nv == sv:
            break
        sx = nx
        sv = nv
        r = h / n
        tx, tv = tv * r, -(pc.k2 * tx + pc.c2 * tv) * pc.im2 * r
    return sx, sv


@jit(inline="always")
def body1_after(x1, v1, h, g):
    """Body 1's position (m) and velocity (m/s) after h seconds of free fall."""
    return x1 + h * (v1 + 0.5 * g * h), v1 + g * h


@jit(inline="always")
def gap_after(x1, v1, x2, v2, h, f2, pc):
    """Penetration (m) and its rate (m/s) after h seconds of free flight."""
    a1, b1 = body1_after(x1, v1, h, pc.g)
    a2, b2 = body2_after(x2, v2, h, f2, pc)
    return a1 - a2, b1 - b2


@jit(inline="always")
def _switch_after(x1, v1, x2, v2, h, f2, pc):
    a1, b1 = body1_after(x1, v1, h, pc.g)
    a2, b2 = body2_after(x2, v2, h, f2, pc)
    return event_value(a1, b1, a2, b2, pc.c, pc.b)


@jit(inline="always")
def touch_time(x1, v1, x2, v2, h, f2, pc):
    """The time (s, in (0, h]) at which the switching function turns positive on the exact
    free motion, or -1 if it does not within h (:func:`touch_and_end`'s first value)."""
    return touch_and_end(x1, v1, x2, v2, h, f2, pc)[0]


@jit(inline="always")
def touch_and_end(x1, v1, x2, v2, h, f2, pc):
    """``(tau, x1(h), v1(h), x2(h), v2(h))``: the time (s, in (0, h]) at which the switching function turns
    positive on the exact free motion, or -1 if it does not within h; and the state at h, which
    the search evaluates anyway (the caller's next state when there is no touch: the series of
    :func:`body2_after` summed once, not twice).  The returned time is the contact side of a
    bracket ``ROOT_TOL h`` wide (the state there is in contact, or exactly on the switch).

    The usual touch (penetration from <= 0 to > 0) is found by Newton's method on the
    penetration with its exact rate, kept inside the bracket (bisection where a step leaves
    it); a touch from a positive penetration (after a damped pad let go while still pressed)
    by the Illinois variant of regula falsi on the switching function itself.
    """
    d0 = x1 - x2
    hi = h
    a1, b1 = body1_after(x1, v1, h, pc.g)  # the sub-step's end, once: its switch and its rate
    a2, b2 = body2_after(x2, v2, h, f2, pc)
    ghi = event_value(a1, b1, a2, b2, pc.c, pc.b)
    if not (ghi > 0.0):
        # an excursion into the pad between the sub-step's ends: the penetration's interior top
        s0 = v1 - v2
        s1 = b1 - b2
        if not (s0 > 0.0 and s1 < 0.0):
            return -1.0, a1, b1, a2, b2
        lo, up = 0.0, h
        for _ in range(MAX_ROOT_ITER):  # the rate's root, by bisection (a rate is monotone here)
            if up - lo <= ROOT_TOL * h:
                break
            mid = 0.5 * (lo + up)
            _d, sm = gap_after(x1, v1, x2, v2, mid, f2, pc)
            if sm > 0.0:
                lo = mid
            else:
                up = mid
        ghi = _switch_after(x1, v1, x2, v2, up, f2, pc)
        if not (ghi > 0.0):
            return -1.0, a1, b1, a2, b2
        hi = up
    tol = ROOT_TOL * h
    lo = 0.0
    if d0 <= 0.0:
        # Newton on the penetration, bracketed: d(lo) <= 0 < d(hi)
        t = hi
        dt_, st = gap_after(x1, v1, x2, v2, t, f2, pc)
        for _ in range(MAX_ROOT_ITER):
            if dt_ > 0.0:
                hi = t
            else:
                lo = t
            if hi - lo <= tol or dt_ == 0.0:
                break
            tn = t - dt_ / st if st != 0.0 else -1.0
            if not (lo < tn < hi):
                tn = 0.5 * (lo + hi)
            t = tn
            dt_, st = gap_after(x1, v1, x2, v2, t, f2, pc)
        if dt_ == 0.0:
            return t, a1, b1, a2, b2
        return hi, a1, b1, a2, b2
    glo = _switch_after(x1, v1, x2, v2, 0.0, f2, pc)
    side = 0
    for _ in range(MAX_ROOT_ITER):
        if hi - lo <= tol:
            break
        tm = (lo * ghi - hi * glo) / (ghi - glo) if ghi != glo else 0.5 * (lo + hi)
        w = hi - lo
        if not (lo + 0.01 * w < tm < hi - 0.01 * w):
            tm = min(max(tm, lo + 0.01 * w), hi - 0.01 * w)
        gm = _switch_after(x1, v1, x2, v2, tm, f2, pc)
        if gm >= 0.0:
            hi, ghi = tm, gm
            if side == 1:
                glo *= 0.5
            side = 1
        else:
            lo, glo = tm, gm
            if side == -1:
                ghi *= 0.5
            side = -1
    return hi, a1, b1, a2, b2


@jit(inline="always")
def gap_top(x1, v1, x2, v2, h, f2, pc):
    """The largest penetration (m; negative: the closest approach) on the exact free motion
    within a sub-step of h seconds over which the penetration rate turns from + (at 0) to <= 0
    (at h): Newton's method on the rate with its exact derivative ``g - x2''``, kept inside the
    bracket (bisection where a step leaves it), to ``ROOT_TOL h``; the penetration there.  Near
    the top the penetration is flat, so a time error dt costs only ``|g - x2''| dt^2 / 2``:
    the top is exact to rounding, however shallow (no floor)."""
    lo, hi = 0.0, h
    t = h
    a1, b1 = body1_after(x1, v1, t, pc.g)
    a2, b2 = body2_after(x2, v2, t, f2, pc)
    s = b1 - b2
    for _ in range(MAX_ROOT_ITER):
        if s > 0.0:
            lo = t
        else:
            hi = t
        if hi - lo <= ROOT_TOL * h or s == 0.0:
            break
        ds = pc.g - (-f2 - pc.k2 * a2 - pc.c2 * b2) * pc.im2
        tn = t - s / ds if ds != 0.0 else -1.0
        if not (lo < tn < hi):
            tn = 0.5 * (lo + hi)
        t = tn
        a1, b1 = body1_after(x1, v1, t, pc.g)
        a2, b2 = body2_after(x2, v2, t, f2, pc)
        s = b1 - b2
    return a1 - a2


@jit(inline="always")
def body2_position_integral(x2, v2, h, f2, pc):
    """The time integral of body 2's position over h seconds (m s; 0 <= h <= :func:`free_cap`)
    of the motion :func:`body2_after` propagates: the same series integrated term by term,
    ``int z = z h + sum_n h^(n+1) / (n+1)! A^(n-1) (A z + u)``, summed until neither the sum nor
    the next term's seed changes it (round-off accuracy, as the motion itself)."""
    s = x2 * h
    tx = v2 * h  # the terms of body2_after's series for x2 and v2
    tv = (-f2 - pc.k2 * x2 - pc.c2 * v2) * pc.im2 * h
    for n in range(1, MAX_TERMS + 1):
        ns = s + tx * h / (n + 1)
        if ns == s and s + tv * h * h / ((n + 1) * (n + 2)) == s:
            break
        s = ns
        r = h / (n + 1)
        tx, tv = tv * r, -(pc.k2 * tx + pc.c2 * tv) * pc.im2 * r
    return s
