"""Integrators over one span of constant shaker force, with optional contact-event location.

Methods (``layout``): explicit Euler (thesis eq 3.8), semi-implicit (symplectic) Euler, classic
RK4 (all fixed step ``dt``) and Dormand-Prince 5(4) with adaptive steps (``rtol``).

Event location: in ``FREE``/``CONTACT`` mode a step never integrates across a switch.  When a
step ends on the other side of the switching function (:func:`dynamics.event_value`), the
step length that lands exactly on the switch is found by the Illinois variant of regula falsi
on re-taken steps of the same method from the same start, the state on the far side of that
bracket (width <= ``EVENT_TOL`` times the step) is kept, the mode flips, and the rest of the
step is taken in the new mode.  Fixed-step methods therefore keep their grid (the control
sampling stays aligned) and the adaptive method keeps its error control.

All kernels take float64 arrays and floats, grouped in named tuples, and keep no global state:
a span's :class:`PlantConsts` (``consts``) and :class:`PlantCarry` (``carry``); the equations'
constants as one :class:`impact_env.plant.dynamics.Coefs` (``pc``), read from ``consts.p`` once
per span; a state held in scalars as one tuple ``(x1, v1, x2, v2, W_ext, W_diss)``.
"""

from __future__ import annotations

from math import sqrt
from typing import NamedTuple

import numpy as np

from impact_env._borrow import borrow
from impact_env._jit import jit
from impact_env.plant.dynamics import coefs, contact_force, deriv, event_sign, event_value
from impact_env.plant.free_flight import (
    body1_after,
    body2_after,
    body2_position_integral,
    free_cap,
    gap_after,
    gap_top,
    touch_and_end,
)
from impact_env.plant.layout import (
    AUTO,
    CONTACT,
    DIVERGED,
    DOPRI5,
    EULER,
    EVENT,
    EVENT_OVERFLOW,
    FREE,
    M1,
    OK,
    RK4,
    SPLIT,
    STEP_UNDERFLOW,
    SYMPLECTIC_EULER,
    V1,
    V2,
    W_DISS,
    W_EXT,
    X1,
    X2,
    C,
    G,
)


class PlantConsts(NamedTuple):
    """What the integrator keeps fixed over a span (one env)."""

    p: np.ndarray  # float64[N_PARAM]: the plant's parameters (impact_env.plant.layout)
    scale: np.ndarray  # float64[6]: dopri5's per-component scale (absolute tolerance rtol * scale)
    method: int  # EULER, SYMPLECTIC_EULER, RK4 or DOPRI5
    dt: float  # s: the fixed-step methods' step (a span is a whole number of them)
    rtol: float  # dopri5's relative tolerance


class PlantCarry(NamedTuple):
    """What the integrator updates in place (one env)."""

    y: np.ndarray  # float64[6]: x1, v1, x2, v2, W_ext, W_diss
    h: np.ndarray  # float64[1]: dopri5's step size, carried between calls (the fixed-step
    #                methods' time left in the graded zone after a touch)
    events: np.ndarray  # float64[E, N_EVENT_COLS]: the event log
    n_events: np.ndarray  # int64[1]: its fill count (events past its size are counted)
    peak: np.ndarray  # float64[1]: raised to the largest contact force at step ends and events;
    #                   or float64[2], whose peak[1] is raised to the largest penetration (m)
    # float64[1]: the time integral of body 1's catch energy over the span (J s) is added to
    # integral[0] (the metrics' energy integral, impact_env.sim.metrics).  The default, a shared
    # scratch cell, serves callers that do not read it (a drop, the benchmarks)
    integral: np.ndarray = np.zeros(1)


class Records(NamedTuple):
    """Where a recording run writes: the state, mode and peak contact force at ``n`` equally
    spaced times, into rows ``k0 .. k0 + n - 1`` (n = 0: no records)."""

    y: np.ndarray  # float64[rows, 6]
    mode: np.ndarray  # int64[rows]
    peak: np.ndarray  # float64[rows]
    k0: int
    n: int


EVENT_TOL = 1e-13  # event bracket width, relative to the step being split
MAX_EVENT_ITER = 200
DIVERGENCE_BOUND = 1e9  # |x1|+|x2|+|v1|+|v2| beyond this (or NaN) is reported as divergence
MAX_EVENTS_PER_STEP = 16
# graded zone after a touch on a damped pad (RK4): GRADE_STEPS steps taken in GRADE_PIECES pieces
# ending at Z (k/GRADE_PIECES)^GRADE_POWER; a power >= p / (1 + 0.25) = 3.2 (p = 4, the d^0.25
# singularity) is what a graded mesh needs to recover RK4's order (see _advance_fixed)
GRADE_STEPS = 2
GRADE_PIECES = 16
GRADE_POWER = 4.0


@jit(inline="always")
def _fixed_step(method, z, mode, f2, h, pc):
    """One step of a fixed-step method from the state ``z`` = (x1, v1, x2, v2, W_ext, W_diss);
    returns the new one."""
    x1, v1, x2, v2, we, wd = z
    k1 = deriv(x1, v1, x2, v2, mode, f2, pc)
    # W_ext' = -f2 v2 with f2 constant over the step, so every method's W_ext update is
    # exactly -f2 times its x2 update: computed that way, off the stages' dependency chain
    if method == EULER:
        nx2 = x2 + h * k1[X2]
        return (x1 + h * k1[X1], v1 + h * k1[V1], nx2, v2 + h * k1[V2],
                we - f2 * (nx2 - x2), wd + h * k1[W_DISS])
    if method == SYMPLECTIC_EULER:
        nv1 = v1 + h * k1[V1]
        nv2 = v2 + h * k1[V2]
        nx2 = x2 + h * nv2
        return x1 + h * nv1, nv1, nx2, nv2, we - f2 * (nx2 - x2), wd + h * k1[W_DISS]
    hh = 0.5 * h
    k2_ = deriv(x1 + hh * k1[X1], v1 + hh * k1[V1], x2 + hh * k1[X2], v2 + hh * k1[V2],
                mode, f2, pc)
    k3 = deriv(x1 + hh * k2_[X1], v1 + hh * k2_[V1], x2 + hh * k2_[X2], v2 + hh * k2_[V2],
               mode, f2, pc)
    k4 = deriv(x1 + h * k3[X1], v1 + h * k3[V1], x2 + h * k3[X2], v2 + h * k3[V2],
               mode, f2, pc)
    h6 = h / 6.0
    nx2 = x2 + h6 * (k1[X2] + 2.0 * (k2_[X2] + k3[X2]) + k4[X2])
    return (x1 + h6 * (k1[X1] + 2.0 * (k2_[X1] + k3[X1]) + k4[X1]),
            v1 + h6 * (k1[V1] + 2.0 * (k2_[V1] + k3[V1]) + k4[V1]),
            nx2,
            v2 + h6 * (k1[V2] + 2.0 * (k2_[V2] + k3[V2]) + k4[V2]),
            we - f2 * (nx2 - x2),
            wd + h6 * (k1[W_DISS] + 2.0 * (k2_[W_DISS] + k3[W_DISS]) + k4[W_DISS]))


# Dormand-Prince 5(4) tableau
A21 = 1.0 / 5.0
A31, A32 = 3.0 / 40.0, 9.0 / 40.0
A41, A42, A43 = 44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0
A51, A52, A53, A54 = 19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0
A61, A62, A63, A64, A65 = 9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0, 49.0 / 176.0, -5103.0 / 18656.0
B1, B3, B4, B5, B6 = 35.0 / 384.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0
E1, E3, E4, E5, E6, E7 = (71.0 / 57600.0, -71.0 / 16695.0, 71.0 / 1920.0, -17253.0 / 339200.0,
                          22.0 / 525.0, -1.0 / 40.0)
# its continuous extension (4th order, Dormand & Prince; the coefficients of scipy's RK45):
# y(t + theta h) = y + h sum_s k_s (P[s,0] theta + P[s,1] theta^2 + P[s,2] theta^3 + P[s,3] theta^4)
DENSE_P = np.array([
    [1.0, -8048581381.0 / 2820520608.0, 8663915743.0 / 2820520608.0, -12715105075.0 / 11282082432.0],
    [0.0, 0.0, 0.0, 0.0],
    [0.0, 131558114200.0 / 32700410799.0, -68118460800.0 / 10900136933.0, 87487479700.0 / 32700410799.0],
    [0.0, -1754552775.0 / 470086768.0, 14199869525.0 / 1410260304.0, -10690763975.0 / 1880347072.0],
    [0.0, 127303824393.0 / 49829197408.0, -318862633887.0 / 49829197408.0,
     701980252875.0 / 199316789632.0],
    [0.0, -282668133.0 / 205662961.0, 2019193451.0 / 616988883.0, -1453857185.0 / 822651844.0],
    [0.0, 40617522.0 / 29380423.0, -110615467.0 / 29380423.0, 69997945.0 / 29380423.0],
])


@jit(inline="always")
def _dense(y, k, h, theta, out):
    """Dormand-Prince's continuous extension: the state at ``theta`` (0..1) of the step of
    length h from y whose stages are k; into ``out``."""
    t2 = theta * theta
    t3 = t2 * theta
    t4 = t3 * theta
    for j in range(6):
        acc = 0.0
        for s in range(7):
            acc += k[s, j] * (DENSE_P[s, 0] * theta + DENSE_P[s, 1] * t2 + DENSE_P[s, 2] * t3
                              + DENSE_P[s, 3] * t4)
        out[j] = y[j] + h * acc


@jit(inline="always")
def _force_rate(y, dy, pc):
    """Time derivative of the contact force (N/s) at state y (in contact, d > 0) whose time
    derivative is dy (the stage)."""
    d = y[X1] - y[X2]
    dd = y[V1] - y[V2]
    ddd = dy[V1] - dy[V2]
    sd = sqrt(d)
    r = 1.5 * pc.c * sd * dd
    if pc.b != 0.0:
        q = sqrt(sd)
        r += pc.b * (0.25 * dd * dd / (sd * q) + q * ddd)
    return r


TOP_PENETRATION = 0  # _dense_top: the root of the penetration rate
TOP_FORCE = 1  # the root of the contact force's rate


@jit(inline="always")
def _rate(which, z, dz, pc):
    """The rate whose root :func:`_dense_top` finds, at state z with time derivative dz."""
    if which == TOP_FORCE:
        return _force_rate(z, dz, pc)
    return z[V1] - z[V2]


@jit
def _dense_top(which, y, k, h, tmp, mode, f2, pc):
    """The extremum inside a Dormand-Prince step (from y, stages k, length h) over which a rate
    changes sign: ``which`` = TOP_PENETRATION, the largest penetration (m; the rate turns from +
    to -); TOP_FORCE, the contact force's extremum (N; in contact).  The rate's root on the
    continuous extension (Illinois regula falsi), and the value there.  Returns ``(value,
    theta)``, theta the fraction of the step; ``tmp``: float64[6] scratch."""
    lo, hi = 0.0, 1.0
    flo = _rate(which, y, k[0], pc)
    _dense(y, k, h, 1.0, tmp)
    r = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # the state's derivative, which only the force's rate needs
    if which == TOP_FORCE:
        r = deriv(tmp[X1], tmp[V1], tmp[X2], tmp[V2], mode, f2, pc)
    fhi = _rate(which, tmp, r, pc)
    side = 0
    th = 1.0
    for _ in range(60):
        th = (lo * fhi - hi * flo) / (fhi - flo) if fhi != flo else 0.5 * (lo + hi)
        if not (lo < th < hi):
            th = 0.5 * (lo + hi)
        _dense(y, k, h, th, tmp)
        if which == TOP_FORCE:
            if not (tmp[X1] > tmp[X2]):
                break
            r = deriv(tmp[X1], tmp[V1], tmp[X2], tmp[V2], mode, f2, pc)
        fm = _rate(which, tmp, r, pc)
        if (fm > 0.0) == (flo > 0.0):
            lo, flo = th, fm
            if side == -1:
                fhi *= 0.5
            side = -1
        else:
            hi, fhi = th, fm
            if side == 1:
                flo *= 0.5
            side = 1
        if hi - lo <= 1e-12 or fm == 0.0:
            break
    _dense(y, k, h, th, tmp)
    if which == TOP_FORCE:
        f, _fe = contact_force(tmp[X1] - tmp[X2], tmp[V1] - tmp[V2], mode, pc.c, pc.b)
        return f, th
    return tmp[X1] - tmp[X2], th


@jit
def _dopri_step(y, out, err, k, mode, f2, h, pc):
    """One Dormand-Prince step from y; writes the 5th-order result to ``out``, the embedded
    error estimate to ``err`` (both length 6) and the seven stages (the last one at ``out``)
    to ``k[:7]`` (k: float64[8, 6], its last row scratch), which the dense output
    (:func:`_dense`) needs."""
    r = deriv(y[X1], y[V1], y[X2], y[V2], mode, f2, pc)
    for j in range(6):
        k[0, j] = r[j]
    t = k[7]
    for s in range(1, 7):
        for j in range(6):
            if s == 1:
                acc = A21 * k[0, j]
            elif s == 2:
                acc = A31 * k[0, j] + A32 * k[1, j]
            elif s == 3:
                acc = A41 * k[0, j] + A42 * k[1, j] + A43 * k[2, j]
            elif s == 4:
                acc = A51 * k[0, j] + A52 * k[1, j] + A53 * k[2, j] + A54 * k[3, j]
            elif s == 5:
                acc = A61 * k[0, j] + A62 * k[1, j] + A63 * k[2, j] + A64 * k[3, j] + A65 * k[4, j]
            else:
                acc = B1 * k[0, j] + B3 * k[2, j] + B4 * k[3, j] + B5 * k[4, j] + B6 * k[5, j]
            t[j] = y[j] + h * acc
        if s == 6:
            for j in range(6):
                out[j] = t[j]
        r = deriv(t[X1], t[V1], t[X2], t[V2], mode, f2, pc)
        for j in range(6):
            k[s, j] = r[j]
    for j in range(6):
        err[j] = h * (E1 * k[0, j] + E3 * k[2, j] + E4 * k[3, j] + E5 * k[4, j]
                      + E6 * k[5, j] + E7 * k[6, j])


@jit
def _trial(method, y, out, scratch, mode, f2, h, pc):
    """Take one step of length h from y into out (no error control)."""
    if method == DOPRI5:
        _dopri_step(y, out, scratch, np.empty((8, 6)), mode, f2, h, pc)
    else:
        r = _fixed_step(method, (y[X1], y[V1], y[X2], y[V2], y[W_EXT], y[W_DISS]), mode, f2, h, pc)
        for j in range(6):
            out[j] = r[j]


@jit(inline="always")
def _crossed(mode, gv):
    return (mode == CONTACT and gv < 0.0) or (mode == FREE and gv > 0.0)


@jit
def _locate(method, y, out, scratch, mode, f2, h, pc):
    """Find the step length in (0, h] that lands on the switch; writes the state at the far
    side of the final bracket into ``out`` and returns that step length."""
    lo = 0.0
    glo = event_value(y[X1], y[V1], y[X2], y[V2], pc.c, pc.b)
    hi = h
    _trial(method, y, out, scratch, mode, f2, hi, pc)
    ghi = event_value(out[X1], out[V1], out[X2], out[V2], pc.c, pc.b)
    trial = np.empty(6)
    side = 0
    tol = EVENT_TOL * h
    for _ in range(MAX_EVENT_ITER):
        if hi - lo <= tol:
            break
        if glo != ghi:
            hm = (lo * ghi - hi * glo) / (ghi - glo)
        else:
            hm = 0.5 * (lo + hi)
        # keep the trial strictly inside, and bisect when regula falsi stalls at an end
        w = hi - lo
        if not (lo + 0.01 * w < hm < hi - 0.01 * w):
            hm = min(max(hm, lo + 0.01 * w), hi - 0.01 * w)
        _trial(method, y, trial, scratch, mode, f2, hm, pc)
        gm = event_value(trial[X1], trial[V1], trial[X2], trial[V2], pc.c, pc.b)
        if _crossed(mode, gm) or gm == 0.0:
            hi = hm
            ghi = gm
            for j in range(6):
                out[j] = trial[j]
            if side == 1:
                glo *= 0.5
            side = 1
        else:
            lo = hm
            glo = gm
            if side == -1:
                ghi *= 0.5
            side = -1
    return hi


@jit
def _log_event(ev, evn, t, kind, y):
    n = evn[0]
    if n < ev.shape[0]:
        ev[n, EVENT.t] = t
        ev[n, EVENT.kind] = kind
        ev[n, EVENT.x1] = y[X1]
        ev[n, EVENT.v1] = y[V1]
        ev[n, EVENT.x2] = y[X2]
        ev[n, EVENT.v2] = y[V2]
    evn[0] = n + 1


@jit
def _diverged(y):
    s = abs(y[X1]) + abs(y[X2]) + abs(y[V1]) + abs(y[V2]) + abs(y[W_EXT]) + abs(y[W_DISS])
    return not (s < DIVERGENCE_BOUND)


@jit
def _force_now(y, mode, pc):
    f, _ = contact_force(y[X1] - y[X2], y[V1] - y[V2], mode, pc.c, pc.b)
    return f


@jit(inline="always")
def _graded_piece(tau, zone_len, rem):
    """Length of the next piece of the graded zone after a touch: from ``tau`` (s since the
    touch) to the next node ``zone_len (k / GRADE_PIECES)^GRADE_POWER`` above it, at most ``rem``."""
    k = int(GRADE_PIECES * (tau / zone_len) ** (1.0 / GRADE_POWER))
    node = zone_len
    while k <= GRADE_PIECES:
        node = zone_len * (k / GRADE_PIECES) ** GRADE_POWER
        if node - tau > 1e-9 * zone_len:  # (tau is a difference of times: skip a node it rounds onto)
            break
        k += 1
    piece = node - tau
    if not (piece > 0.0) or piece > rem:
        piece = rem
    return piece


@jit(inline="always")
def _penetration_peak(pkd, d0, s0, d1, s1, h):
    """The largest penetration so far, given a step of h seconds from (d0, d0' = s0) to
    (d1, s1): the step's end, and where the penetration rate turned from + to - within the step,
    the top of the parabola whose slope runs linearly from s0 to s1 (error O(h^3) against the
    O(h^2 / 8) of the samples alone; a short contact between two records is no longer missed,
    since this runs at every integrator step)."""
    if d1 > pkd:
        pkd = d1
    if s0 > 0.0 and s1 <= 0.0 and (d0 > 0.0 or d1 > 0.0):
        top = d0 + 0.5 * s0 * (s0 / (s0 - s1)) * h
        if top > pkd:
            pkd = top
    return pkd


@jit(inline="always")
def _catch_part(x1, v1, x2, pc):
    """Body 1's catch energy (:func:`impact_env.plant.energy.catch_energy_at`) less its constant
    ``(3/5) m1 g d_s`` (J), which :func:`advance` adds once per span: the integrand of the
    energy integral, without a power per evaluation."""
    d = x1 - x2
    e = 0.5 * pc.m1 * v1 * v1 - pc.m1 * pc.g * d
    if d > 0.0:
        e += 0.4 * pc.c * d * d * sqrt(d)
    return e


@jit(inline="always")
def _catch_rate(x1, v1, x2, v2, mode, pc):
    """``(e, de/dt)``: :func:`_catch_part` (J) and its time derivative (W) at a state under the
    contact force F of ``mode``: ``m1 g v2 - F v1 + c d_+^1.5 (v1 - v2)`` (body 1's power
    ``m1 v1 (g - F / m1)``, the gravity term's ``-m1 g d'`` and the pad energy's rate)."""
    d = x1 - x2
    dd = v1 - v2
    f, _fe = contact_force(d, dd, mode, pc.c, pc.b)
    e = 0.5 * pc.m1 * v1 * v1 - pc.m1 * pc.g * d
    r = pc.m1 * pc.g * v2 - f * v1
    if d > 0.0:
        sd = sqrt(d)
        e += 0.4 * pc.c * d * d * sd
        r += pc.c * d * sd * dd
    return e, r


@jit(inline="always")
def _hermite(h, ea, ra, eb, rb):
    """The integral over a step of h seconds of a function with values ``ea``, ``eb`` and
    derivatives ``ra``, ``rb`` at its ends: the corrected trapezoidal rule (the cubic Hermite
    interpolant's integral), error ``h^5 max|e(4)| / 720``."""
    return 0.5 * h * (ea + eb) + h * h * (ra - rb) / 12.0


@jit(inline="always")
def _advance_fixed(mode, f2, t0, span, consts, carry):
    """Fixed-step part of :func:`advance`: the state lives in scalars, arrays are touched only
    at a contact switch and in the graded zone after a touch.

    Graded zone (RK4 on a damped pad): the force's ``d^0.25`` factor is not smooth at the
    touch, which limits RK4 to order 1.25 in dt there, whatever the event location does.  The
    span of ``GRADE_STEPS`` steps after each located touch is therefore taken in pieces that
    end at the nodes ``Z (k / GRADE_PIECES)^GRADE_POWER`` (Z = GRADE_STEPS dt, time from the
    touch; a mesh graded towards the singular point), crossing grid points as needed: the grid
    itself is kept.  ``hstate[0]`` carries the time left in the zone from one call to the next.

    Energy integral (``carry.integral``): the trapezoidal rule on every step and piece, the
    method's own grid (so the integral does not depend on the control rate), error
    ``dt^2 max|e''| / 12`` per unit time: second order.
    """
    y, hstate, ev, evn, peak = carry.y, carry.h, carry.events, carry.n_events, carry.peak
    method, dt = consts.method, consts.dt
    pc = coefs(consts.p)
    grade = method == RK4 and pc.b != 0.0 and GRADE_STEPS > 0
    zone_len = GRADE_STEPS * dt
    zone = hstate[0] if grade and mode == CONTACT else 0.0  # time left in the graded zone, s
    x1, v1, x2, v2, we, wd = y[X1], y[V1], y[X2], y[V2], y[W_EXT], y[W_DISS]
    pk = peak[0]
    track = peak.shape[0] > 1  # peak[1]: the largest penetration, tracked when the caller asks
    pkd = peak[1] if track else 0.0
    e_prev = _catch_part(x1, v1, x2, pc)  # the integrand at the step's start
    q = 0.0  # the integral over the span, J s
    n = int(round(span / dt))
    for i in range(n):
        fnew = -1.0  # contact force at the new state, when it is computed for the crossing test
        side = 0.0
        pieces = False  # the step taken piece by piece
        d0 = x1 - x2  # penetration and its rate at the step's start (for the extremum between steps)
        s0 = v1 - v2
        if zone <= 0.0:
            r = _fixed_step(method, (x1, v1, x2, v2, we, wd), mode, f2, dt, pc)
            if mode != AUTO:
                # the crossing test needs only the sign of event_value: for d > 0 that is the
                # sign of the damped force f = c d^0.25 q, which the peak tracking needs anyway
                side = r[X1] - r[X2]
                if side > 0.0:
                    sd = sqrt(side)
                    fnew = pc.c * side * sd
                    if pc.b != 0.0:
                        fnew += pc.b * sqrt(sd) * (r[V1] - r[V2])
                    if fnew <= 0.0:
                        side = fnew
        else:
            r = (x1, v1, x2, v2, we, wd)
        if mode == AUTO:
            if (x1 - x2 > 0.0) != (r[X1] - r[X2] > 0.0):
                y[X1], y[V1], y[X2], y[V2], y[W_EXT], y[W_DISS] = r
                _log_event(ev, evn, t0 + (i + 1) * dt, 1.0 if r[X1] - r[X2] > 0.0 else -1.0, y)
            x1, v1, x2, v2, we, wd = r
        elif zone <= 0.0 and not _crossed(mode, side):
            x1, v1, x2, v2, we, wd = r
        else:
            # a switch within this step, or a step in the graded zone: piece by piece
            fnew = -1.0
            pieces = True
            y[X1], y[V1], y[X2], y[V2], y[W_EXT], y[W_DISS] = x1, v1, x2, v2, we, wd
            out = np.empty(6)  # allocated only here: a switch is rare, a step is not
            scratch = np.empty(6)
            rem = dt
            tt = t0 + i * dt
            have = zone <= 0.0  # the whole step is already taken (in r) and crosses
            if have:
                out[X1], out[V1], out[X2], out[V2], out[W_EXT], out[W_DISS] = r
            n_ev = 0
            for _piece in range((MAX_EVENTS_PER_STEP + 1) * (GRADE_PIECES + 2)):
                piece = rem
                if zone > 0.0:
                    piece = _graded_piece(zone_len - zone, zone_len, rem)
                if not have:
                    _trial(method, y, out, scratch, mode, f2, piece, pc)
                have = False
                if _crossed(mode, event_value(out[X1], out[V1], out[X2], out[V2], pc.c, pc.b)):
                    if n_ev == MAX_EVENTS_PER_STEP:
                        break
                    hs = _locate(method, y, out, scratch, mode, f2, piece, pc)
                    q += 0.5 * hs * (_catch_part(y[X1], y[V1], y[X2], pc)
                                     + _catch_part(out[X1], out[V1], out[X2], pc))
                    for j in range(6):
                        y[j] = out[j]
                    tt += hs
                    rem -= hs
                    mode = FREE if mode == CONTACT else CONTACT
                    _log_event(ev, evn, tt, 1.0 if mode == CONTACT else -1.0, y)
                    zone = zone_len if grade and mode == CONTACT else 0.0
                    n_ev += 1
                else:
                    q += 0.5 * piece * (_catch_part(y[X1], y[V1], y[X2], pc)
                                        + _catch_part(out[X1], out[V1], out[X2], pc))
                    for j in range(6):
                        y[j] = out[j]
                    rem -= piece
                    if zone > 0.0:
                        zone -= piece
                        if zone <= EVENT_TOL * dt:
                            zone = 0.0
                if rem <= EVENT_TOL * dt:
                    break
            if rem > EVENT_TOL * dt:
                hstate[0] = zone
                peak[0] = pk
                if track:
                    peak[1] = pkd
                carry.integral[0] += q
                return EVENT_OVERFLOW, mode
            x1, v1, x2, v2, we, wd = y[X1], y[V1], y[X2], y[V2], y[W_EXT], y[W_DISS]
            e_prev = _catch_part(x1, v1, x2, pc)  # (the pieces' integral is in q)
        if not pieces:
            e_new = _catch_part(x1, v1, x2, pc)
            q += 0.5 * dt * (e_prev + e_new)
            e_prev = e_new
        # a diverging state stays non-finite, so a check every 64 steps and at the end suffices
        if (i & 63) == 63 or i == n - 1:
            size = abs(x1) + abs(x2) + abs(v1) + abs(v2) + abs(we) + abs(wd)
        else:
            size = 0.0
        if not (size < DIVERGENCE_BOUND):
            y[X1], y[V1], y[X2], y[V2], y[W_EXT], y[W_DISS] = x1, v1, x2, v2, we, wd
            hstate[0] = zone
            peak[0] = pk
            if track:
                peak[1] = pkd
            carry.integral[0] += q
            return DIVERGED, mode
        if mode != FREE and x1 > x2:
            if fnew >= 0.0 and mode == CONTACT:
                f = fnew
            else:
                f, _fe = contact_force(x1 - x2, v1 - v2, mode, pc.c, pc.b)
            if f > pk:
                pk = f
        if track:
            pkd = _penetration_peak(pkd, d0, s0, x1 - x2, v1 - v2, dt)
    y[X1], y[V1], y[X2], y[V2], y[W_EXT], y[W_DISS] = x1, v1, x2, v2, we, wd
    hstate[0] = zone
    peak[0] = pk
    if track:
        peak[1] = pkd
    carry.integral[0] += q
    return OK, mode


@jit
def advance(mode, f2, t0, span, consts, carry):
    """Integrate ``carry.y`` (in place) over ``span`` seconds from time t0 under the constant
    shaker force f2 (N).

    mode: ``AUTO`` (no event location) or the current ``FREE``/``CONTACT`` mode.
    consts: :class:`PlantConsts` (parameters, method, step, tolerance); carry: :class:`PlantCarry`
    (the state, step size, event log and peaks, updated in place; ``carry.peak[1]``, if present, is
    raised to the largest penetration at every step, :func:`_penetration_peak`).
    Returns ``(status, mode)``.
    """
    # the catch energy's constant part, (3/5) m1 g d_s, integrated here once; the methods add
    # the rest (_catch_part)
    p = consts.p
    carry.integral[0] += 0.6 * p[M1] * p[G] * (p[M1] * p[G] / p[C]) ** (2.0 / 3.0) * span
    if consts.method == SPLIT:
        return _advance_split(mode, f2, t0, span, consts, carry)
    if consts.method != DOPRI5:
        return _advance_fixed(mode, f2, t0, span, consts, carry)
    status, mode, _n = dopri_run(mode, f2, t0, span, consts, carry,
                                 Records(np.empty((0, 6)), np.empty(0, dtype=np.int64), np.empty(0), 0, 0))
    return status, mode


@jit(inline="always")
def _pad_energy(d, c):
    """Elastic energy of the pad at penetration d (J), ``(2/5) c d^2.5`` for d > 0."""
    if d > 0.0:
        return 0.4 * c * d * d * sqrt(d)
    return 0.0


@jit(inline="always")
def _pad_rate(d, dd, c):
    """The time derivative of :func:`_pad_energy` (W) at penetration d (m) and rate dd (m/s)."""
    if d > 0.0:
        return c * d * sqrt(d) * dd
    return 0.0


PAD_PIECES = 8  # pieces of the corrected trapezoidal rule over a free pad's release (_free_pad_integral)


@jit
def _free_pad_integral(x1, v1, x2, v2, h, f2, pc):
    """The time integral (J s) of the pad's elastic energy ``(2/5) c d_+^2.5`` over a free
    sub-step of h seconds that starts with d > 0 (a damped pad let go while still pressed): on
    the exact free motion, over [0, t0], t0 the time d returns to 0 (bisection to ``1e-14 h``)
    or h, by the corrected trapezoidal rule on PAD_PIECES equal pieces.  The release lasts a few
    microseconds and the energy there is small; one rule over a whole sub-step (a control
    period) instead of [0, t0] would make the integral depend on the control rate."""
    t0 = h
    d_end, _s = gap_after(x1, v1, x2, v2, h, f2, pc)
    if not (d_end > 0.0):
        lo, hi = 0.0, h
        for _ in range(100):
            if hi - lo <= 1e-14 * h:
                break
            mid = 0.5 * (lo + hi)
            dm, _s = gap_after(x1, v1, x2, v2, mid, f2, pc)
            if dm > 0.0:
                lo = mid
            else:
                hi = mid
        t0 = hi
    piece = t0 / PAD_PIECES
    q = 0.0
    da, ra = x1 - x2, v1 - v2
    for k in range(1, PAD_PIECES + 1):
        db, rb = gap_after(x1, v1, x2, v2, k * piece, f2, pc)
        q += _hermite(piece, _pad_energy(da, pc.c), _pad_rate(da, ra, pc.c), _pad_energy(db, pc.c),
                      _pad_rate(db, rb, pc.c))
        da, ra = db, rb
    return q


@jit(inline="always")
def _contact_scale(y, pc, e_min):
    """The error scales of the contact in progress: ``(penetration m, speed m/s, energy J)``.

    From the energy of the relative motion, ``E_r = m u^2 / 2 + (2/5) c |d|^2.5`` (m the
    effective mass, u = v1 - v2, d = x1 - x2): at a touch it is the contact's own approach
    energy, ``m v_in^2 / 2``, and on an elastic pad without gravity it stays so through the
    contact.  The speed scale is ``sqrt(2 E_r / m)`` (the approach speed), the penetration scale
    the depth that energy reaches, ``(5 E_r / (2 c))^0.4`` (Hertz's d_max at that speed; never
    below |d|); body 1 resting on the pad gets its static penetration's scales.  So a slow
    impact, late in a drop, is integrated to the same relative accuracy as the first one,
    whatever the scene's first impact speed was.  ``e_min`` (J) keeps a touch at exactly zero
    speed from a zero scale."""
    ad = abs(y[X1] - y[X2])
    u = y[V1] - y[V2]
    e = max(0.5 * u * u / (pc.im1 + pc.im2) + 0.4 * pc.c * ad * ad * sqrt(ad), e_min)
    return (2.5 * e / pc.c) ** 0.4, sqrt(2.0 * e * (pc.im1 + pc.im2)), e


@jit(inline="always")
def _invariant(y, pc):
    """``E + W_diss - W_ext`` (J) in contact (elastic pad energy of the CONTACT mode's odd
    extension, ``(2/5) c |d|^2.5``): constant along the exact motion under a constant f2 (the
    shaker's work and the dampers' losses are in the ledger), so its change over a step is
    that step's energy error."""
    ad = abs(y[X1] - y[X2])
    return (0.5 * pc.m1 * y[V1] * y[V1] + 0.5 * pc.m2 * y[V2] * y[V2] - pc.m1 * pc.g * y[X1]
            + 0.5 * pc.k2 * y[X2] * y[X2] + 0.4 * pc.c * ad * ad * sqrt(ad) + y[W_DISS] - y[W_EXT])


# a projection larger than this many tolerances of the contact's speed scale is not an
# integration error being removed but an ill-conditioned one (both bodies nearly at rest): skipped
MAX_PROJECTION = 1e3


@jit(inline="always")
def _project_energy(y, target, pc, vs, rtol):
    """Move the velocities of an elastic contact's state y (in place) onto the energy
    invariant's level ``target`` (:func:`_invariant`): the standard projection (Hairer, Lubich
    & Wanner, *Geometric Numerical Integration*, IV.4) along the gradient ``(m1 v1, m2 v2)`` in
    the metric of the error scale, one Newton step (the residual is rtol-small, so the step's
    own error is of order rtol^2).  Positions are not moved: the located switch stays where it
    is.  Projection keeps the method's order and removes its energy drift, which otherwise
    adds up bounce after bounce (dopri5 is not symplectic)."""
    r = _invariant(y, pc) - target
    g1 = pc.m1 * y[V1]
    g2 = pc.m2 * y[V2]
    nn = g1 * g1 + g2 * g2
    if not (nn > 0.0):
        return
    lam = r / nn
    dv1 = lam * g1
    dv2 = lam * g2
    if abs(dv1) + abs(dv2) > MAX_PROJECTION * rtol * vs:
        return
    y[V1] -= dv1
    y[V2] -= dv2


DOPRI_WORK = 12  # rows of dopri5's scratch: 7 stages + 1, out, scratch, record, error

MAX_FREE_STEPS = 1 << 24  # sub-steps and phases of one split span before EVENT_OVERFLOW


@jit
def _advance_split(mode, f2, t0, span, consts, carry):
    """The ``split`` method of :func:`advance`: free flight exactly
    (:mod:`impact_env.plant.free_flight`: the touch located on the exact motion), contact by
    dopri5 at ``consts.rtol`` with its separation located (:func:`_dopri_span`), alternately
    until the span is done.  ``carry.h`` carries dopri5's step between contacts and calls."""
    y, ev, evn, peak = carry.y, carry.events, carry.n_events, carry.peak
    pc = coefs(consts.p)
    cap = free_cap(pc)
    track = peak.shape[0] > 1
    tol = 1e-12 * span
    t = 0.0
    for _ in range(MAX_FREE_STEPS):
        if span - t <= tol:
            return OK, mode
        if mode == CONTACT:
            work = np.empty((DOPRI_WORK, 6))  # (alive to the end of the call below)
            # no records: empty views of the right types, not three allocations a period, and
            # borrowed (impact_env._borrow): a view of an owned array costs two atomic instructions
            bw = borrow(work)
            status, mode, _r, t = _dopri_span(mode, f2, t0, t, span, consts, carry, Records(
                bw[:0], evn[:0], bw[0, :0], 0, 0), True, work)
            if status != OK:
                return status, mode
            continue
        x1, v1, x2, v2 = y[X1], y[V1], y[X2], y[V2]
        h = min(span - t, cap)
        tau, a1, b1, a2, b2 = touch_and_end(x1, v1, x2, v2, h, f2, pc)
        step = h
        if tau >= 0.0:
            step = tau
            a1, b1 = body1_after(x1, v1, step, pc.g)
            a2, b2 = body2_after(x2, v2, step, f2, pc)
        # the energy integral, exact: body 1's free fall keeps m1 v1^2 / 2 - m1 g x1, body 2's
        # position integrates term by term, and a pad let go while still pressed (FREE with
        # d > 0) adds its elastic energy while d > 0 (_free_pad_integral)
        q = (0.5 * pc.m1 * v1 * v1 - pc.m1 * pc.g * x1) * step + pc.m1 * pc.g * body2_position_integral(
            x2, v2, step, f2, pc)
        if x1 - x2 > 0.0:
            q += _free_pad_integral(x1, v1, x2, v2, step, f2, pc)
        carry.integral[0] += q
        # the shaker's work; the damper took it less body 2's stored energy, and a pad let go
        # while still pressed (FREE with d > 0) releases its elastic energy as dissipated (as deriv)
        w = -f2 * (a2 - x2)
        y[X1], y[V1], y[X2], y[V2] = a1, b1, a2, b2
        y[W_EXT] += w
        y[W_DISS] += (w - 0.5 * (pc.m2 * (b2 - v2) * (b2 + v2) + pc.k2 * (a2 - x2) * (a2 + x2))
                 - _pad_energy(a1 - a2, pc.c) + _pad_energy(x1 - x2, pc.c))
        t += step
        if _diverged(y):
            return DIVERGED, mode
        if track:
            # the largest penetration, or the closest approach, on the exact motion: the
            # sub-step's end, and where the rate turned from + to - inside, the exact top
            top = a1 - a2
            if v1 - v2 > 0.0 and b1 - b2 <= 0.0:
                top = max(top, gap_top(x1, v1, x2, v2, step, f2, pc))
            if top > peak[1]:
                peak[1] = top
        if tau >= 0.0:
            mode = CONTACT
            _log_event(ev, evn, t0 + t, 1.0, y)
    return EVENT_OVERFLOW, mode


@jit
def dopri_run(mode, f2, t0, span, consts, carry, rec):
    """Adaptive Dormand-Prince 5(4) over ``span`` seconds from t0 under the constant force f2,
    optionally recording (:class:`Records` ``rec``): with ``rec.n > 0`` the state at
    ``t0 + r span / rec.n`` (r = 1 .. rec.n) goes to ``rec.y[rec.k0 + r - 1]`` (with the mode and
    the peak contact force since the previous record), taken from the continuous extension of the
    step that contains it.  The steps are then those of an unrecorded run: the records do not cut
    them, so the recorded states do not depend on the record rate (only the span's end and the
    contact events end a step early).  ``rec.n = 0``: no records (:func:`advance`).

    Returns ``(status, mode, records written)``.
    """
    status, mode, r, _t = _dopri_span(mode, f2, t0, 0.0, span, consts, carry, rec, False,
                                      np.empty((DOPRI_WORK, 6)))
    return status, mode, r


@jit
def _dopri_span(mode, f2, t0, t, span, consts, carry, rec, stop_free, work):
    """:func:`dopri_run` from ``t`` (s after t0) to ``span``; with ``stop_free`` it returns at
    the first separation (the ``split`` integrator takes the free flight exactly).  Records
    (``rec.n > 0``) need ``t = 0``.  ``work``: float64[DOPRI_WORK, 6] scratch (one allocation
    per caller, not per step).  Returns ``(status, mode, records written, time reached)``."""
    y, hstate, ev, evn, peak = carry.y, carry.h, carry.events, carry.n_events, carry.peak
    integral = carry.integral
    have_start = False  # e_a, r_a hold the energy integrand and its rate at y (_catch_rate)
    e_a, r_a = 0.0, 0.0
    rtol, scale = consts.rtol, consts.scale
    pc = coefs(consts.p)
    # the caller owns work for the whole call: the views of it taken here (and inside the
    # calls below) need no reference counts (two atomic instructions each: impact_env._borrow)
    work = borrow(work)
    out_y, out_mode, out_peak, k0, n_rec = rec.y, rec.mode, rec.peak, rec.k0, rec.n
    status = OK
    kst = work[0:8]
    out = work[8]
    scratch = work[9]
    row = work[10]  # a record's state, or _dense_top's scratch
    err = work[11]
    rec_period = span / n_rec if n_rec > 0 else span
    # split's contact: error scales of this contact (_contact_scale), and on an elastic pad the
    # energy invariant at the start, onto which every step is projected (_project_energy)
    project = stop_free and pc.b == 0.0 and mode == CONTACT
    level = _invariant(y, pc) if project else 0.0
    # the floor of the contact's energy scale: 1e-12 of body 1's static pad energy under its
    # weight (2.4e-17 J for 0.1 kg on c = 2e6; a graze d deep under a relative deceleration a
    # has m a d, 1e-14 J for 1e-14 m at 10 m/s^2: only a touch at exactly zero speed needs it)
    dst = (pc.m1 * abs(pc.g) / pc.c) ** (2.0 / 3.0)
    e_min = max(1e-12 * 0.4 * pc.c * dst * dst * sqrt(dst), 1e-300)
    track = peak.shape[0] > 1
    r = 0  # records written
    pk = 0.0  # peak contact force since the last record
    h = hstate[0]
    if not (h > 0.0):
        h = min(span, 1e-5)
    hmin = 1e-15 * max(span, abs(t0) + span)
    while span - t > 1e-12 * span:
        h_free = h  # the controller's step, before the span's end cuts it
        if h > span - t:
            h = span - t
        _dopri_step(y, out, err, kst, mode, f2, h, pc)
        en = 0.0
        if stop_free:
            # the contact's own scales, not the scene's first impact's: each component relative
            # to them and to itself, and the relative motion (penetration, its rate) to them
            # alone, since the bodies' common motion (on the suspension, mm) may dwarf the
            # contact's (um) and would otherwise set the tolerance of the penetration
            ds, vs, es = _contact_scale(y, pc, e_min)
            for j in range(6):
                sj = ds if j < 4 and (j & 1) == 0 else (vs if j < 4 else es)
                sc = rtol * sj + rtol * max(abs(y[j]), abs(out[j]))
                en += (err[j] / sc) ** 2
            en += ((err[X1] - err[X2]) / (rtol * ds)) ** 2 + ((err[V1] - err[V2]) / (rtol * vs)) ** 2
            en *= 0.75  # the RMS over eight
        else:
            vs = 0.0
            for j in range(6):
                sc = rtol * scale[j] + rtol * max(abs(y[j]), abs(out[j]))
                en += (err[j] / sc) ** 2
        en = sqrt(en / 6.0)
        if not (en == en):
            en = 1e10
        if en <= 1.0:
            d0 = y[X1] - y[X2]
            s0 = y[V1] - y[V2]
            gv = event_sign(out[X1], out[V1], out[X2], out[V2], pc.c, pc.b)  # (only its sign is used here)
            step = h
            new_mode = mode
            if mode != AUTO and _crossed(mode, gv):
                step = _locate(DOPRI5, y, out, scratch, mode, f2, h, pc)
                new_mode = FREE if mode == CONTACT else CONTACT
                if n_rec > 0 or (track and s0 > 0.0 and out[V1] - out[V2] <= 0.0):
                    # the stages of the step that ends on the switch, for the records and for the
                    # top of a graze that separates within it (the same step: the same ``out``)
                    _dopri_step(y, out, err, kst, mode, f2, step, pc)
            elif mode == AUTO and ((y[X1] - y[X2] > 0.0) != (out[X1] - out[X2] > 0.0)):
                _log_event(ev, evn, t0 + t + h, 1.0 if out[X1] - out[X2] > 0.0 else -1.0, out)
            t_new = t + step
            top = -1e300
            if track and s0 > 0.0 and out[V1] - out[V2] <= 0.0:
                # the penetration turned inside this step (a graze's top too, when the step ends
                # on the separation): its top from the continuous extension
                top, _th = _dense_top(TOP_PENETRATION, y, kst, step, row, mode, f2, pc)
            if project:
                _project_energy(out, level, pc, vs, rtol)
            # the energy integral over the accepted step (corrected trapezoidal rule, the error
            # O(step^5) per step as dopri5's own); the step's start values come from the last
            # step's end when the mode did not change
            if not have_start:
                e_a, r_a = _catch_rate(y[X1], y[V1], y[X2], y[V2], mode, pc)
            e_b, r_b = _catch_rate(out[X1], out[V1], out[X2], out[V2], mode, pc)
            integral[0] += _hermite(step, e_a, r_a, e_b, r_b)
            e_a, r_a = e_b, r_b
            have_start = new_mode == mode
            ftop, fth = -1.0, 2.0
            if mode == CONTACT and new_mode == mode and y[X1] > y[X2] and out[X1] > out[X2]:
                if (_force_rate(y, kst[0], pc) > 0.0) != (_force_rate(out, kst[6], pc) > 0.0):
                    # the contact force peaked inside this step: its top from the continuous extension
                    ftop, fth = _dense_top(TOP_FORCE, y, kst, step, row, mode, f2, pc)
            # records inside this step, from its continuous extension (the last at its end)
            while r < n_rec:
                tr = (r + 1) * rec_period
                if tr > t_new + 1e-12 * span and not (r == n_rec - 1 and span - t_new <= 1e-12 * span):
                    break
                if tr >= t_new - 1e-12 * span:
                    for j in range(6):
                        row[j] = out[j]
                else:
                    _dense(y, kst, step, (tr - t) / step, row)
                fr, _fe = contact_force(row[X1] - row[X2], row[V1] - row[V2], mode, pc.c, pc.b)
                if ftop >= 0.0 and (tr - t) / step >= fth:  # the force's top falls in this record
                    pk = max(pk, ftop)
                    peak[0] = max(peak[0], ftop)
                    ftop = -1.0
                for j in range(6):
                    out_y[k0 + r, j] = row[j]
                out_mode[k0 + r] = mode
                out_peak[k0 + r] = max(pk, fr)
                pk = fr
                r += 1
            for j in range(6):
                y[j] = out[j]
            t = t_new
            if new_mode != mode:
                mode = new_mode
                _log_event(ev, evn, t0 + t, 1.0 if mode == CONTACT else -1.0, y)
            if _diverged(y):
                hstate[0] = h
                return DIVERGED, mode, _fail_record(y, mode, out_y, out_mode, out_peak, k0, r, n_rec), t
            if peak.shape[0] > 1:
                if top > -1e300:
                    peak[1] = max(peak[1], top, y[X1] - y[X2])
                else:
                    peak[1] = _penetration_peak(peak[1], d0, s0, y[X1] - y[X2], y[V1] - y[V2], step)
            f = _force_now(y, mode, pc)
            if ftop > f:
                f = ftop
            if f > peak[0]:
                peak[0] = f
            if f > pk:
                pk = f
            fac = 5.0 if en < 1e-4 else min(5.0, 0.9 * en ** -0.2)
            # a step cut short by the span's end says little about the next: start the next
            # span (a new control period) from the controller's own step, not the remnant
            h = max(h * fac, h_free) if step == h and h < h_free else h * fac
            if stop_free and mode == FREE:
                break
        else:
            h *= max(0.1, 0.9 * en ** -0.25)
            if h < hmin:
                hstate[0] = h
                return STEP_UNDERFLOW, mode, _fail_record(y, mode, out_y, out_mode, out_peak, k0, r, n_rec), t
    hstate[0] = h
    return status, mode, r, t


@jit
def _fail_record(y, mode, out_y, out_mode, out_peak, k0, r, n_rec):
    """On failure, the state reached goes into the next record; returns the records written."""
    if r < n_rec:
        for j in range(6):
            out_y[k0 + r, j] = y[j]
        out_mode[k0 + r] = mode
        out_peak[k0 + r] = 0.0
        return r + 1
    return r
