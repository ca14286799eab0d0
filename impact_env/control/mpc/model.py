"""The MPC's prediction model: the two bodies on the Hertz-Tsuji pad driven through the shaker,
one control period per step, with its Jacobians and the cost's derivatives.

State (:data:`NX` = 7, SI, thesis frame: x down-positive, penetration ``d = x1 - x2``)::

    s = [x1 m, v1 m/s, x2 m, v2 m/s, z0, z1, z2]

where ``z`` is the shaker's state (:mod:`impact_env.effects.shaker`'s discretised coil model,
rescaled so that each entry is of order one newton, :func:`shaker_realisation`).  Input: the
force demand u (N, upwards on body 2), held over the period.  One step of period h:

    f2  = Cz . z + Dz u                                   (the force the shaker applies this period)
    F   = c d^1.5 + b d^0.25 d'  for d > 0, clipped at 0   (Hertz-Tsuji, the plant's AUTO mode)
    v1' = v1 + h (g - F / m1)
    v2' = v2 + h (F - f2 - k2 x2 - c2 v2) / m2
    x1' = x1 + h v1',   x2' = x2 + h v2'                  (semi-implicit Euler)
    z'  = Az z + Bz u

Semi-implicit Euler at the control period (0.1 ms on ``rig``) resolves the contact's oscillation
(about 1000 rad/s at the deepest compression: omega h = 0.1) with a bounded energy error, which is
all a controller re-solved every tick needs; ``substeps`` > 1 divides the period.

Stage cost: body 1's catch energy (:mod:`impact_env.sim.metrics`, J)
``E1 = m1 v1^2/2 + m1 g (3/5 d_s - d) + (2/5) c d_+^2.5`` plus ``w2`` times body 2's energy
``m2 v2^2/2 + k2 x2^2/2``; the input pays ``r u^2``.  E1's Hessian is positive semi-definite
(``m1`` on v1, ``1.5 c d_+^0.5`` on d), so the Gauss-Newton value function stays PSD.

Every function here is written as scalar loops over the flat arrays, so that its C text
(:mod:`impact_env.control.mpc.c_text`) performs the same operations in the same order.
"""

from __future__ import annotations

from math import sqrt
from typing import NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env._packed import positions


class ModelState(NamedTuple):
    """The entries of the model's state vector (float64[NX]), read by name: ``s[STATE.x1]``."""

    x1: float  # m, body 1 (down positive)
    v1: float  # m/s
    x2: float  # m, body 2
    v2: float  # m/s
    z0: float  # the shaker's state (scaled to about 1 N each: shaker_realisation)
    z1: float
    z2: float


STATE = positions(ModelState)
NX = len(STATE)  # state size: x1, v1, x2, v2 and the shaker's three states
NZ = 3  # the shaker model's order (the coil model of effects.shaker: band-pass and coil pole)


class Constants(NamedTuple):
    """The solver's constants vector (float64, in this order; the MPC laws put it first in theirs)."""

    m1: float  # kg, body 1
    m2: float  # kg, body 2
    c: float  # N/m^1.5, Hertz stiffness
    b: float  # N s/m^1.25, Tsuji damping (0: elastic)
    g: float  # m/s^2
    k2: float  # N/m, suspension stiffness
    c2: float  # N s/m, suspension damping
    ds: float  # m, static penetration (m1 g / c)^(2/3)
    umax: float  # N, |u| limit (the smaller of the peak limit and the command scale)
    slew: float  # N per control period, the largest change of u between ticks (0: no slew limit)
    h: float  # s, the control period
    substeps: float  # model steps per control period (an integer >= 1)
    horizon: float  # prediction steps (an integer, 1 .. NMAX)
    iterations: float  # iLQR iterations per tick (an integer >= 1)
    line_search: float  # step halvings tried per iteration (an integer >= 1)
    r: float  # J/N^2, input weight
    w_terminal: float  # weight of the last predicted state's cost (in stage costs)
    w2: float  # weight of body 2's energy
    mu: float  # J/N^2, Levenberg-Marquardt regularisation of Quu
    dmin: float  # m, the smallest penetration at which the damping's derivative is evaluated
    a00: float  # the shaker's Az (row-major), Bz, Cz, Dz: see shaker_realisation
    a01: float
    a02: float
    a10: float
    a11: float
    a12: float
    a20: float
    a21: float
    a22: float
    b0: float
    b1: float
    b2: float
    c0: float
    c1: float
    cz2: float
    dz: float
    command_gain: float  # the amplifier's known gain: the law's demand is its planned force over it


K = positions(Constants)
N_CONSTANTS = len(K)


def shaker_realisation(A, B, C, D) -> dict[str, float]:
    """The shaker model (A, B, C, D of :func:`impact_env.effects.shaker.discrete_emf_model`, order
    <= :data:`NZ`, padded with zeros) rescaled by a diagonal similarity so that each state peaks
    near 1 N under a 1 N step (tf2ss's realisation spans 1e-14 .. 1e9), as constants."""
    A = np.asarray(A, float)
    n = A.shape[0]
    if n > NZ:
        raise ValueError(f"the MPC's model holds a shaker of order <= {NZ}, got {n}")
    Ap = np.zeros((NZ, NZ))
    Bp = np.zeros(NZ)
    Cp = np.zeros(NZ)
    Ap[:n, :n] = A
    Bp[:n] = np.asarray(B, float)
    Cp[:n] = np.asarray(C, float)
    z = np.zeros(NZ)
    peak = np.zeros(NZ)
    for _ in range(200):  # 20 ms at 10 kHz: past the coil's and the low-pass's settling
        z = Ap @ z + Bp
        peak = np.maximum(peak, np.abs(z))
    scale = np.where(peak > 0.0, 1.0 / np.where(peak > 0.0, peak, 1.0), 1.0)  # z_scaled = scale z
    As = (scale[:, None] * Ap) / scale[None, :]
    Bs = scale * Bp
    Cs = Cp / scale
    names = ("a00", "a01", "a02", "a10", "a11", "a12", "a20", "a21", "a22")
    out = {nm: float(v) for nm, v in zip(names, As.ravel(), strict=True)}
    out.update(b0=float(Bs[0]), b1=float(Bs[1]), b2=float(Bs[2]), c0=float(Cs[0]), c1=float(Cs[1]),
               cz2=float(Cs[2]), dz=float(D))
    return out


@jit
def contact(d, dd, k):
    """(F N, dF/dd N/m, dF/dd' N s/m) of the Hertz-Tsuji pad at penetration d (m) and rate dd (m/s);
    zero out of contact and where the damped force would pull (clipped, as the plant does)."""
    if d <= 0.0:
        return 0.0, 0.0, 0.0
    s = sqrt(d)
    q = sqrt(s)  # d^0.25
    f = k[K.c] * d * s + k[K.b] * q * dd
    if f <= 0.0:
        return 0.0, 0.0, 0.0
    de = d if d > k[K.dmin] else k[K.dmin]
    se = sqrt(de)
    return f, 1.5 * k[K.c] * s + 0.25 * k[K.b] * dd / (se * sqrt(se)), k[K.b] * q


@jit
def step(s, u, k, out):
    """One control period from the state ``s`` (float64[NX]) under the demand u (N) into ``out``."""
    x1 = s[STATE.x1]
    v1 = s[STATE.v1]
    x2 = s[STATE.x2]
    v2 = s[STATE.v2]
    f2 = k[K.c0] * s[STATE.z0] + k[K.c1] * s[STATE.z1] + k[K.cz2] * s[STATE.z2] + k[K.dz] * u
    n = int(k[K.substeps]) if k[K.substeps] >= 1.0 else 1
    h = k[K.h] / n
    for _ in range(n):
        f = contact(x1 - x2, v1 - v2, k)[0]
        v1 = v1 + h * (k[K.g] - f / k[K.m1])
        v2 = v2 + h * (f - f2 - k[K.k2] * x2 - k[K.c2] * v2) / k[K.m2]
        x1 = x1 + h * v1
        x2 = x2 + h * v2
    z0 = k[K.a00] * s[STATE.z0] + k[K.a01] * s[STATE.z1] + k[K.a02] * s[STATE.z2] + k[K.b0] * u
    z1 = k[K.a10] * s[STATE.z0] + k[K.a11] * s[STATE.z1] + k[K.a12] * s[STATE.z2] + k[K.b1] * u
    z2 = k[K.a20] * s[STATE.z0] + k[K.a21] * s[STATE.z1] + k[K.a22] * s[STATE.z2] + k[K.b2] * u
    out[STATE.x1] = x1
    out[STATE.v1] = v1
    out[STATE.x2] = x2
    out[STATE.v2] = v2
    out[STATE.z0] = z0
    out[STATE.z1] = z1
    out[STATE.z2] = z2


@jit
def jacobian(s, u, k, A, B):
    """The step's Jacobians at (s, u): A (float64[NX * NX], row-major) = d out / d s and
    B (float64[NX]) = d out / d u, through every substep (chain rule on the plant's 4 states)."""
    for i in range(NX * NX):
        A[i] = 0.0
    for i in range(4):
        A[i * NX + i] = 1.0  # the plant block starts as the identity; the shaker rows follow
        B[i] = 0.0
    x1 = s[STATE.x1]
    v1 = s[STATE.v1]
    x2 = s[STATE.x2]
    v2 = s[STATE.v2]
    f2 = k[K.c0] * s[STATE.z0] + k[K.c1] * s[STATE.z1] + k[K.cz2] * s[STATE.z2] + k[K.dz] * u
    n = int(k[K.substeps]) if k[K.substeps] >= 1.0 else 1
    h = k[K.h] / n
    m1 = k[K.m1]
    m2 = k[K.m2]
    for _ in range(n):
        f, fd, fdd = contact(x1 - x2, v1 - v2, k)
        # the substep's own Jacobian, columns x1 v1 x2 v2 (and f2 for body 2's speed):
        # v1+ = v1 + h a1, v2+ = v2 + h a2, x1+ = x1 + h v1+, x2+ = x2 + h v2+
        p10 = -h * fd / m1
        p11 = 1.0 - h * fdd / m1
        p12 = h * fd / m1
        p13 = h * fdd / m1
        p30 = h * fd / m2
        p31 = h * fdd / m2
        p32 = -h * (fd + k[K.k2]) / m2
        p33 = 1.0 - h * (fdd + k[K.c2]) / m2
        p3f = -h / m2
        # new rows = substep Jacobian times the accumulated rows (A's plant rows, B's plant
        # entries, and f2's dependence on z and u, which does not change within the period)
        for j in range(NX):
            r0 = A[STATE.x1 * NX + j]
            r1 = A[STATE.v1 * NX + j]
            r2 = A[STATE.x2 * NX + j]
            r3 = A[STATE.v2 * NX + j]
            fz = 0.0
            if j == STATE.z0:
                fz = k[K.c0]
            elif j == STATE.z1:
                fz = k[K.c1]
            elif j == STATE.z2:
                fz = k[K.cz2]
            n1 = p10 * r0 + p11 * r1 + p12 * r2 + p13 * r3
            n3 = p30 * r0 + p31 * r1 + p32 * r2 + p33 * r3 + p3f * fz
            A[STATE.v1 * NX + j] = n1
            A[STATE.v2 * NX + j] = n3
            A[STATE.x1 * NX + j] = r0 + h * n1
            A[STATE.x2 * NX + j] = r2 + h * n3
        r0 = B[STATE.x1]
        r1 = B[STATE.v1]
        r2 = B[STATE.x2]
        r3 = B[STATE.v2]
        n1 = p10 * r0 + p11 * r1 + p12 * r2 + p13 * r3
        n3 = p30 * r0 + p31 * r1 + p32 * r2 + p33 * r3 + p3f * k[K.dz]
        B[STATE.v1] = n1
        B[STATE.v2] = n3
        B[STATE.x1] = r0 + h * n1
        B[STATE.x2] = r2 + h * n3
        v1 = v1 + h * (k[K.g] - f / m1)
        v2 = v2 + h * (f - f2 - k[K.k2] * x2 - k[K.c2] * v2) / m2
        x1 = x1 + h * v1
        x2 = x2 + h * v2
    A[STATE.z0 * NX + STATE.z0] = k[K.a00]
    A[STATE.z0 * NX + STATE.z1] = k[K.a01]
    A[STATE.z0 * NX + STATE.z2] = k[K.a02]
    A[STATE.z1 * NX + STATE.z0] = k[K.a10]
    A[STATE.z1 * NX + STATE.z1] = k[K.a11]
    A[STATE.z1 * NX + STATE.z2] = k[K.a12]
    A[STATE.z2 * NX + STATE.z0] = k[K.a20]
    A[STATE.z2 * NX + STATE.z1] = k[K.a21]
    A[STATE.z2 * NX + STATE.z2] = k[K.a22]
    B[STATE.z0] = k[K.b0]
    B[STATE.z1] = k[K.b1]
    B[STATE.z2] = k[K.b2]


@jit
def state_cost(s, k):
    """Body 1's catch energy (J) plus w2 times body 2's energy at the state ``s``."""
    d = s[STATE.x1] - s[STATE.x2]
    e = 0.5 * k[K.m1] * s[STATE.v1] * s[STATE.v1] + k[K.m1] * k[K.g] * (0.6 * k[K.ds] - d)
    if d > 0.0:
        e += 0.4 * k[K.c] * d * d * sqrt(d)
    return e + k[K.w2] * (0.5 * k[K.m2] * s[STATE.v2] * s[STATE.v2]
                          + 0.5 * k[K.k2] * s[STATE.x2] * s[STATE.x2])


@jit
def add_state_cost_derivatives(s, k, w, gx, Hx):
    """Add w times :func:`state_cost`'s gradient to ``gx`` (float64[NX]) and its Hessian to ``Hx``
    (float64[NX * NX], row-major)."""
    d = s[STATE.x1] - s[STATE.x2]
    gd = -k[K.m1] * k[K.g]
    hdd = 0.0
    if d > 0.0:
        sd = sqrt(d)
        gd += k[K.c] * d * sd
        hdd = 1.5 * k[K.c] * sd
    gx[STATE.x1] += w * gd
    gx[STATE.x2] += w * (k[K.w2] * k[K.k2] * s[STATE.x2] - gd)
    gx[STATE.v1] += w * (k[K.m1] * s[STATE.v1])
    gx[STATE.v2] += w * (k[K.w2] * k[K.m2] * s[STATE.v2])
    Hx[STATE.x1 * NX + STATE.x1] += w * hdd
    Hx[STATE.x1 * NX + STATE.x2] -= w * hdd
    Hx[STATE.x2 * NX + STATE.x1] -= w * hdd
    Hx[STATE.x2 * NX + STATE.x2] += w * (hdd + k[K.w2] * k[K.k2])
    Hx[STATE.v1 * NX + STATE.v1] += w * k[K.m1]
    Hx[STATE.v2 * NX + STATE.v2] += w * (k[K.w2] * k[K.m2])
