"""The MPC's solver: box-constrained iLQR (Gauss-Newton DDP) as a real-time iteration.

Each tick (:func:`mpc_tick`) starts from the previous tick's plan shifted by one period (the
warm start, in the memory row), rolls it out on the prediction model
(:mod:`impact_env.control.mpc.model`) from the current augmented state, and runs a FIXED number
of iterations, each a backward pass (the value function's quadratic model through the
linearised model; the scalar input's box-QP is solved exactly by clamping, and a clamped step
gets no feedback gain, as in Tassa et al. 2014's control-limited DDP) and a forward pass with a
FIXED number of step halvings (the first that lowers the predicted cost is taken).  The first
input of the plan is the force demand.  Constraints (hard, on every predicted step and on the
output): ``|u| <= umax`` and, when ``slew > 0``, ``|u_j - u_(j-1)| <= slew`` (N per period, from
the last output): the forward pass clips every input into that box, so every plan, and the
output, lies inside it.

Fallbacks, each counted in the memory row (:class:`Memory`): a non-finite state or result gives
the previous plan's input (0 if that is not finite either), and the plan and the shaker model
restart from zero (``fallbacks``); an iteration whose step halvings all fail to lower the cost
ends the tick's iterations with the plan as it stands (``no_descent``).  The work per tick is
fixed (iterations x (one backward pass + at most ``line_search`` + 1 forward passes)), so the
tick always returns within its budget, and the same inputs give bitwise the same output.

Memory row (float64[:data:`MEMORY`], zero at the episode start): :class:`Memory`'s header, the
augmented state, the plan U, and the scratch of one tick (predicted states, gains, the value
function), so that a tick allocates nothing.
"""

from __future__ import annotations

from math import isfinite
from typing import NamedTuple

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.control.mpc.model import NX, K, add_state_cost_derivatives, jacobian, state_cost, step

NMAX = 48  # the longest horizon the memory row holds (steps)


class Memory(NamedTuple):
    """The memory row's header (zero at the episode start)."""

    started: float  # 1 once the first tick has set the plan up
    fallbacks: float  # ticks that fell back (non-finite state or result)
    no_descent: float  # iterations whose step halvings all failed to lower the cost
    ticks: float  # ticks run
    u_prev: float  # N, the last output (the slew limit's reference)
    cost: float  # J, the predicted cost of the last plan
    m1_estimate: float  # kg, reserved (0: the constants' m1)
    spare: float  # reserved


MEM = positions(Memory)
HEAD = len(MEM)
STATE = HEAD  # the augmented state [x1, v1, x2, v2, z0, z1, z2] of this tick
PLAN = STATE + NX  # U[NMAX], N
XS = PLAN + NMAX  # predicted states X[(NMAX + 1) * NX]
GAINS = XS + (NMAX + 1) * NX  # feedback gains [NMAX * NX], N per state unit
FEED = GAINS + NMAX * NX  # feed-forward steps [NMAX], N
VX = FEED + NMAX  # value gradient [NX]
VXX = VX + NX  # value Hessian [NX * NX]
JA = VXX + NX * NX  # the step's Jacobian A [NX * NX]
JB = JA + NX * NX  # ... and B [NX]
VA = JB + NX  # V A [NX * NX]
QX = VA + NX * NX  # Qx [NX]
QUX = QX + NX  # Qux [NX]
VB = QUX + NX  # V B [NX]
SCUR = VB + NX  # the forward pass's state [NX]
SNEXT = SCUR + NX  # ... and the next [NX]
VN = SNEXT + NX  # the new value Hessian's upper triangle [NX * NX]
MEMORY = VN + NX * NX  # floats
# the last trial's plan [NMAX]: VA's space, which only the backward pass uses
TRIAL = VA
assert NMAX <= NX * NX


@jit
def bounds(k, u_before):
    """(lo, hi) of an input that follows ``u_before`` (N): the peak box, narrowed by the slew."""
    lo = -k[K.umax]
    hi = k[K.umax]
    sl = k[K.slew]
    if sl > 0.0:
        if u_before - sl > lo:
            lo = u_before - sl
        if u_before + sl < hi:
            hi = u_before + sl
    return lo, hi


@jit
def clip(u, lo, hi):
    if u < lo:
        return lo
    if u > hi:
        return hi
    return u


@jit
def forward(k, mem, n, alpha, write):
    """Roll the plan out with step ``alpha`` (0: the plan itself, projected) and the gains from
    the stored states; the predicted cost (J).  ``write``: the new plan and states replace them;
    otherwise (a trial) the new plan goes to TRIAL."""
    for i in range(NX):
        mem[SCUR + i] = mem[STATE + i]
    u_before = mem[MEM.u_prev]
    r = k[K.r]
    cost = 0.0
    for j in range(n):
        u = mem[PLAN + j]
        if alpha != 0.0:
            u = u + alpha * mem[FEED + j]
            for i in range(NX):
                u = u + mem[GAINS + j * NX + i] * (mem[SCUR + i] - mem[XS + j * NX + i])
        lo, hi = bounds(k, u_before)
        u = clip(u, lo, hi)
        if write:
            for i in range(NX):
                mem[XS + j * NX + i] = mem[SCUR + i]
            mem[PLAN + j] = u
        else:
            mem[TRIAL + j] = u
        step(mem[SCUR:SCUR + NX], u, k, mem[SNEXT:SNEXT + NX])
        for i in range(NX):
            mem[SCUR + i] = mem[SNEXT + i]
        w = k[K.w_terminal] if j == n - 1 else 1.0
        cost += r * u * u + w * state_cost(mem[SCUR:SCUR + NX], k)
        u_before = u
    if write:
        for i in range(NX):
            mem[XS + n * NX + i] = mem[SCUR + i]
    return cost


@jit
def backward(k, mem, n):
    """The backward pass over the stored plan and states: gains into GAINS and FEED; False if
    a curvature Quu is not positive and finite."""
    for i in range(NX):
        mem[VX + i] = 0.0
    for i in range(NX * NX):
        mem[VXX + i] = 0.0
    add_state_cost_derivatives(mem[XS + n * NX:XS + (n + 1) * NX], k, k[K.w_terminal],
                               mem[VX:VX + NX], mem[VXX:VXX + NX * NX])
    r = k[K.r]
    for j in range(n - 1, -1, -1):
        u = mem[PLAN + j]
        jacobian(mem[XS + j * NX:XS + (j + 1) * NX], u, k, mem[JA:JA + NX * NX], mem[JB:JB + NX])
        # V A, V B
        for a in range(NX):
            for c in range(NX):
                acc = 0.0
                for m in range(NX):
                    acc += mem[VXX + a * NX + m] * mem[JA + m * NX + c]
                mem[VA + a * NX + c] = acc
            acc = 0.0
            for m in range(NX):
                acc += mem[VXX + a * NX + m] * mem[JB + m]
            mem[VB + a] = acc
        # Qx = A' Vx, Qu = 2 r u + B' Vx, Quu = 2 r + B' V B + mu, Qux = B' V A
        qu = 2.0 * r * u
        quu = 2.0 * r + k[K.mu]
        for m in range(NX):
            qu += mem[JB + m] * mem[VX + m]
            quu += mem[JB + m] * mem[VB + m]
        for c in range(NX):
            acc = 0.0
            acc2 = 0.0
            for m in range(NX):
                acc += mem[JA + m * NX + c] * mem[VX + m]
                acc2 += mem[JB + m] * mem[VA + m * NX + c]
            mem[QX + c] = acc
            mem[QUX + c] = acc2
        if not (quu > 0.0 and isfinite(quu)):
            return False
        lo, hi = bounds(k, mem[PLAN + j - 1] if j > 0 else mem[MEM.u_prev])
        du = -qu / quu
        clamped = True
        if u + du > hi:
            du = hi - u
        elif u + du < lo:
            du = lo - u
        else:
            clamped = False
        mem[FEED + j] = du
        for c in range(NX):
            mem[GAINS + j * NX + c] = 0.0 if clamped else -mem[QUX + c] / quu
        # V = Qxx + Quu K K' + K Qux' + Qux K' (Qxx = A' V A), Vx = Qx + K (Quu du + Qu) + Qux du
        for a in range(NX):
            ka = mem[GAINS + j * NX + a]
            mem[VX + a] = mem[QX + a] + ka * (quu * du + qu) + mem[QUX + a] * du
        for a in range(NX):
            ka = mem[GAINS + j * NX + a]
            for c in range(a, NX):
                kc = mem[GAINS + j * NX + c]
                acc = 0.0
                for m in range(NX):
                    acc += mem[JA + m * NX + a] * mem[VA + m * NX + c]
                acc += quu * ka * kc + ka * mem[QUX + c] + mem[QUX + a] * kc
                mem[VN + a * NX + c] = acc
        for a in range(NX):
            for c in range(NX):
                mem[VXX + a * NX + c] = mem[VN + a * NX + c] if c >= a else mem[VN + c * NX + a]
        if j > 0:
            add_state_cost_derivatives(mem[XS + j * NX:XS + (j + 1) * NX], k, 1.0,
                                       mem[VX:VX + NX], mem[VXX:VXX + NX * NX])
    return True


@jit
def horizon_of(k):
    """The horizon (steps) the constants ask for, within 1 .. NMAX."""
    n = int(k[K.horizon]) if k[K.horizon] >= 1.0 else 1
    return n if n <= NMAX else NMAX


@jit
def solve(k, mem):
    """The force demand (N, upwards, inside the box) for the augmented state in
    ``mem[STATE:STATE + NX]``, improving the plan in ``mem`` in place (see the module doc)."""
    n = horizon_of(k)
    iters = int(k[K.iterations]) if k[K.iterations] >= 0.0 else 0
    halvings = int(k[K.line_search]) if k[K.line_search] >= 1.0 else 1
    cost = forward(k, mem, n, 0.0, True)
    for iteration in range(iters):
        if not backward(k, mem, n):
            mem[MEM.no_descent] += 1.0
            break
        alpha = 1.0
        taken = 0.0
        for _ in range(halvings):
            trial = forward(k, mem, n, alpha, False)
            if trial < cost:
                taken = alpha
                break
            alpha = 0.5 * alpha
        if taken == 0.0:
            mem[MEM.no_descent] += 1.0
            break
        if iteration < iters - 1:
            cost = forward(k, mem, n, taken, True)  # the next backward pass needs its states
        else:
            # the last iteration: the accepted trial is the plan (forward(k, mem, n, taken, True)
            # would repeat its operations; only its states, which nothing reads now, are not kept)
            for j in range(n):
                mem[PLAN + j] = mem[TRIAL + j]
            cost = trial
    mem[MEM.cost] = cost
    lo, hi = bounds(k, mem[MEM.u_prev])
    return clip(mem[PLAN], lo, hi)


@jit
def mpc_tick(x1, v1, x2, v2, k, mem):
    """One control tick on the state (x1 m, v1 m/s, x2 m, v2 m/s; x down-positive): the force
    demand (N, upwards, inside the box).  The shaker's state is the memory's model of it, driven
    by the demands this function returned; the plan shifts by one period for the next tick."""
    n = horizon_of(k)
    if mem[MEM.started] == 0.0:
        for j in range(NMAX):
            mem[PLAN + j] = 0.0
        for i in range(NX):
            mem[STATE + i] = 0.0
        mem[MEM.u_prev] = 0.0
        mem[MEM.started] = 1.0
    mem[STATE + 0] = x1
    mem[STATE + 1] = v1
    mem[STATE + 2] = x2
    mem[STATE + 3] = v2
    ok = True
    for i in range(NX):
        if not isfinite(mem[STATE + i]):
            ok = False
    u = 0.0
    if ok:
        u = solve(k, mem)
        if not isfinite(u):
            ok = False
    if not ok:
        mem[MEM.fallbacks] += 1.0
        lo, hi = bounds(k, mem[MEM.u_prev])
        u = mem[PLAN]  # the previous plan's input for this tick (already shifted)
        u = clip(u, lo, hi) if isfinite(u) else clip(0.0, lo, hi)
        for j in range(NMAX):
            mem[PLAN + j] = 0.0
        for i in range(4, NX):
            mem[STATE + i] = 0.0
    # the shaker's model takes this tick's demand; the plan moves on by one period
    z0 = k[K.a00] * mem[STATE + 4] + k[K.a01] * mem[STATE + 5] + k[K.a02] * mem[STATE + 6] + k[K.b0] * u
    z1 = k[K.a10] * mem[STATE + 4] + k[K.a11] * mem[STATE + 5] + k[K.a12] * mem[STATE + 6] + k[K.b1] * u
    z2 = k[K.a20] * mem[STATE + 4] + k[K.a21] * mem[STATE + 5] + k[K.a22] * mem[STATE + 6] + k[K.b2] * u
    mem[STATE + 4] = z0
    mem[STATE + 5] = z1
    mem[STATE + 6] = z2
    for j in range(n - 1):
        mem[PLAN + j] = mem[PLAN + j + 1]
    mem[MEM.u_prev] = u
    mem[MEM.ticks] += 1.0
    return u
