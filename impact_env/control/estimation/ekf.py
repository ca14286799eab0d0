"""The extended Kalman filter of the sensor-fed ``mpc`` law: one control tick per call, on the
scene's own model, with its state and covariance in the law's memory row.

Model (SI, x down-positive, as the plant; :mod:`impact_env.plant.dynamics`)::

    x1' = v1        v1' = g - F im1
    x2' = v2        v2' = (F - f2 - k2 x2 - c2 v2) / m2          im1' = 0
    F = max(0, c d^1.5 + b d^0.25 d')  for d = x1 - x2 > 0,  else 0     (Hertz-Tsuji, the plant's pad)
    b = zeta sqrt(c m),  m = m1 m2 / (m1 + m2),  m1 = 1 / im1    (the pad's damping, its restitution's)

with f2 the force the shaker applied over the period (a replica of the scene's shaker and limit
driven by the law's own demand: :func:`applied_force`), held over the period and integrated by
one RK4 step; the covariance moves with ``Phi = I + J dt + (J dt)^2 / 2`` (J the Jacobian at the
updated estimate).  Raw readings, as the sensors stage makes them (the force f2 of the period
that has just ended, :mod:`impact_env.effects.sensors`)::

    accelerometer a2 = (F - f2 - k2 x2 - c2 v2) / m2,   transducer T = F - m2' a2,   potentiometer x2

each ``gain * true + offset + noise``, noise variance ``noise_std^2 + q^2 / 12`` (q the ADC's step).
The policy sees them after each channel's filter, a known linear recursion from a known
start (zero state, first frame unfiltered): ``y = C z + D r``, ``z+ = A z + B r``.  With
``D != 0`` (a bilinear Butterworth section's b0) the raw reading is recovered exactly, tick by
tick, as ``r = (y - C z) / D``, and ``z`` advanced with it: the inverse filter.  This is what
augmenting the state with the filter states reduces to: since the raw noise drives z+ and y
alike, eliminating it with this tick's reading (``D v = y - C z - D h``; Simon, *Optimal State
Estimation*, sec 7.1) leaves ``z+ = (A - G C) z + G y`` (G = B / D) with no input from the
plant and no noise, so z is known and the augmented filter is this one, with 5 states instead of
15.  The band-pass removes the static load from y, not from the recovered r: the inverse
restores it from the filter's start.  Its zeros (z = 1 and z = -1 for a band-pass) are the
inverse's poles, on the unit circle: the observation's float32 rounding (relative 6e-8) is
summed, not damped, which ``tests/test_ekf.py`` bounds on whole episodes.

Lost track: every ``nis_window`` ticks the summed normalised innovations squared (chi-square with
3 x window degrees of freedom when the model holds) is tested against ``nis_bound``; above it the
status bit is set, the count rises, and the plant states' covariance is re-inflated (the mean
kept).  A non-finite estimate or a covariance with a non-positive variance is lost track too,
and restarts the estimate.  The constants come from
:func:`impact_env.control.estimation.model.ekf_constants`; the memory's layout is
:class:`impact_env.control.estimation.layout.EkfMemory`.
"""

from __future__ import annotations

from math import isfinite, sqrt

from impact_env._jit import jit
from impact_env.control.estimation.layout import (
    BIAS,
    BIAS_ALT,
    CH_BASE,
    CO_A,
    CO_B,
    CO_C,
    CO_D,
    CO_GAIN,
    CO_NZ,
    CO_OFFSET,
    CO_R,
    EK,
    IM1,
    MAX_Z,
    N_MEAS,
    N_PLANT,
    N_STATE,
    REPLICAS_END,
    SHAKER_BLOCK,
    V1,
    V2,
    X1,
    X2,
    EkfMemory,
)
from impact_env.effects.saturation import saturate
from impact_env.effects.shaker import shaker_packed

M = EkfMemory
N = N_STATE
ACC, FORCE, POT = 0, 1, 2


@jit
def contact(d, dd, c, b, d_floor):
    """(F N, dF/dd N/m, dF/dd' N s/m): the pad's force, clipped at 0, and its slopes (the damping
    term's d^-0.75 slope taken at ``max(d, d_floor)``, finite at the touch)."""
    if d <= 0.0:
        return 0.0, 0.0, 0.0
    s = sqrt(d)
    q = sqrt(s)
    f = c * d * s + b * q * dd
    if f <= 0.0:
        return 0.0, 0.0, 0.0
    de = d if d > d_floor else d_floor
    return f, 1.5 * c * s + 0.25 * b * dd * sqrt(sqrt(de)) / de, b * q


@jit
def damping(k, im1):
    """The pad's Tsuji damping b (N s/m^1.25) for body 1's inverse mass im1 (1/kg)."""
    m2 = k[EK.m2]
    return k[EK.zeta] * sqrt(k[EK.c] * m2 / (1.0 + m2 * im1))


@jit
def _accels(k, x1, v1, x2, v2, im1, f2, b):
    f, _fd, _fdd = contact(x1 - x2, v1 - v2, k[EK.c], b, k[EK.d_floor])
    return k[EK.g] - f * im1, (f - f2 - k[EK.k2] * x2 - k[EK.c2] * v2) / k[EK.m2]


@jit
def plant_step(k, x, f2):
    """One RK4 step of the plant states ``x[:4]`` over the period under the held force f2 (N, up)."""
    dt = k[EK.dt]
    im1 = x[IM1]
    b = damping(k, im1)
    x1, v1, x2, v2 = x[X1], x[V1], x[X2], x[V2]
    h = 0.5 * dt
    a1, a2 = _accels(k, x1, v1, x2, v2, im1, f2, b)
    u1, u2 = v1 + h * a1, v2 + h * a2
    b1, b2 = _accels(k, x1 + h * v1, u1, x2 + h * v2, u2, im1, f2, b)
    w1, w2 = v1 + h * b1, v2 + h * b2
    c1, c2 = _accels(k, x1 + h * u1, w1, x2 + h * u2, w2, im1, f2, b)
    s1, s2 = v1 + dt * c1, v2 + dt * c2
    e1, e2 = _accels(k, x1 + dt * w1, s1, x2 + dt * w2, s2, im1, f2, b)
    w = dt / 6.0
    x[X1] = x1 + w * (v1 + 2.0 * u1 + 2.0 * w1 + s1)
    x[V1] = v1 + w * (a1 + 2.0 * b1 + 2.0 * c1 + e1)
    x[X2] = x2 + w * (v2 + 2.0 * u2 + 2.0 * w2 + s2)
    x[V2] = v2 + w * (a2 + 2.0 * b2 + 2.0 * c2 + e2)


@jit
def readings(k, x, f2, hy, hx):
    """The raw readings' true values (before gain and offset) at the state ``x`` after a period
    under f2 (N): a2, T, x2 into ``hy`` (float64[3]), their gradients in the state into ``hx``
    (float64[3 * N_STATE], row-major; the damping's dependence on im1 left out)."""
    m2, top = k[EK.m2], k[EK.top_mass]
    b = damping(k, x[IM1])
    f, fd, fdd = contact(x[X1] - x[X2], x[V1] - x[V2], k[EK.c], b, k[EK.d_floor])
    a2 = (f - f2 - k[EK.k2] * x[X2] - k[EK.c2] * x[V2]) / m2
    hy[ACC] = a2
    hy[FORCE] = f - top * a2
    hy[POT] = x[X2]
    ga0, ga1, ga2, ga3 = fd / m2, fdd / m2, (-fd - k[EK.k2]) / m2, (-fdd - k[EK.c2]) / m2
    hx[ACC * N + X1] = ga0
    hx[ACC * N + V1] = ga1
    hx[ACC * N + X2] = ga2
    hx[ACC * N + V2] = ga3
    hx[ACC * N + IM1] = 0.0
    hx[FORCE * N + X1] = fd - top * ga0
    hx[FORCE * N + V1] = fdd - top * ga1
    hx[FORCE * N + X2] = -fd - top * ga2
    hx[FORCE * N + V2] = -fdd - top * ga3
    hx[FORCE * N + IM1] = 0.0
    for j in range(N):
        hx[POT * N + j] = 0.0
    hx[POT * N + X2] = 1.0
    for c in range(N_MEAS):  # (each drift adds to its own reading, after the gain: 1 / gain here)
        for j in range(N_MEAS):
            hx[c * N + BIAS + j] = 0.0
            hx[c * N + BIAS_ALT + j] = 0.0
        hx[c * N + BIAS + c] = 1.0 / k[CH_BASE[c] + CO_GAIN]
        hx[c * N + BIAS_ALT + c] = 1.0 / k[CH_BASE[c] + CO_GAIN]


@jit
def applied_force(k, mem, f_law, v2):
    """The force (N, up) the scene's hardware applies over this period for the law's demand
    ``f_law`` (N): the policy's clip to +-command_scale, the amplifier's gain on it
    (``command_gain``: 1 unless the scene knows its hardware's), the shaker (back-EMF from the
    estimate's v2, m/s) and the amplifier's limit, by the hardware stage's own kernels on a replica
    of their state in ``mem``."""
    cs = k[EK.command_scale]
    u = f_law / cs
    if u < -1.0:
        u = -1.0
    elif u > 1.0:
        u = 1.0
    f = u * cs * k[EK.command_gain]
    if k[EK.sh_on] > 0.0:
        n = int(k[EK.sh_n])
        f = shaker_packed(k[EK.sh_0:EK.sh_0 + SHAKER_BLOCK], mem[M.shaker:M.shaker + 2 * n], f, v2,
                          k[EK.back_emf] > 0.0)
    if k[EK.sat_on] > 0.0:
        f, _sat = saturate(f, mem[M.sat:M.sat + 2], k[EK.sat_peak:EK.sat_peak + 4])
    return f


@jit
def unfilter(k, mem, y):
    """Each channel's raw reading from its filtered one ``y[c]`` (the inverse filter, on its
    state in ``mem``) into ``mem[raw]``."""
    for c in range(N_MEAS):
        base = CH_BASE[c]
        nz = int(k[base + CO_NZ])
        z = mem[M.filt + c * MAX_Z:M.filt + (c + 1) * MAX_Z]
        acc = y[c]
        for a in range(nz):
            acc -= k[base + CO_C + a] * z[a]
        r = acc / k[base + CO_D]
        s = mem[M.scratch:M.scratch + MAX_Z]
        for a in range(nz):
            t = k[base + CO_B + a] * r
            for bb in range(nz):
                t += k[base + CO_A + a * MAX_Z + bb] * z[bb]
            s[a] = t
        for a in range(nz):
            z[a] = s[a]
        mem[M.raw + c] = r


@jit
def _prior(k, mem):
    """The estimate at the episode start (body 1 not yet seen: the scene's drop ranges)."""
    x = mem[M.x:M.x + N]
    p = mem[M.p:M.p + N * N]
    for i in range(N):
        x[i] = 0.0
    for i in range(N * N):
        p[i] = 0.0
    x[X1] = k[EK.x1_0]
    x[V1] = k[EK.v1_0]
    x[IM1] = k[EK.im1_0]
    p[X1 * N + X1] = k[EK.p_x1]
    p[X1 * N + V1] = k[EK.p_x1v1]
    p[V1 * N + X1] = k[EK.p_x1v1]
    p[V1 * N + V1] = k[EK.p_v1]
    p[X2 * N + X2] = k[EK.p_x2]
    p[V2 * N + V2] = k[EK.p_v2]
    p[IM1 * N + IM1] = k[EK.p_im1]
    _bias_prior(k, p)


@jit
def _bias_prior(k, p):
    for b0 in (BIAS, BIAS_ALT):
        p[(b0 + ACC) * N + b0 + ACC] = k[EK.p_b_acc]
        p[(b0 + FORCE) * N + b0 + FORCE] = k[EK.p_b_force]
        p[(b0 + POT) * N + b0 + POT] = k[EK.p_b_pot]


@jit
def _reinflate(k, mem, restart):
    """After lost track: the covariance back to the reset's (diagonal); with ``restart`` (a
    non-finite estimate) also the mean: both bodies at the potentiometer's x2, at rest."""
    x = mem[M.x:M.x + N]
    p = mem[M.p:M.p + N * N]
    if restart:
        x2 = mem[M.raw + POT]
        if not isfinite(x2):
            x2 = 0.0
        x[X1] = x2
        x[X2] = x2
        x[V1] = 0.0
        x[V2] = 0.0
        x[IM1] = k[EK.im1_0]
    for i in range(N * N):
        p[i] = 0.0
    rx, rv = k[EK.reset_x], k[EK.reset_v]
    p[X1 * N + X1] = rx * rx
    p[X2 * N + X2] = rx * rx
    p[V1 * N + V1] = rv * rv
    p[V2 * N + V2] = rv * rv
    p[IM1 * N + IM1] = k[EK.p_im1]
    _bias_prior(k, p)


@jit
def _healthy(x, p):
    for i in range(N):
        if not isfinite(x[i]) or not (p[i * N + i] > 0.0) or not isfinite(p[i * N + i]):
            return False
    return True


@jit
def ekf_update(k, mem):
    """The measurement update with this tick's raw readings (``mem[raw]``: a2 m/s^2, T N,
    x2 m), channel by channel (the channels' noises are independent, so the sequential scalar
    updates with one linearisation equal the joint one); then the lost-track test.  Returns
    this tick's normalised innovation squared."""
    x = mem[M.x:M.x + N]
    p = mem[M.p:M.p + N * N]
    hy = mem[M.hy:M.hy + N_MEAS]
    hx = mem[M.hx:M.hx + N_MEAS * N]
    ph = mem[M.ph:M.ph + N]
    x0 = mem[M.x_prior:M.x_prior + N]
    readings(k, x, mem[M.f_applied], hy, hx)
    for i in range(N):
        x0[i] = x[i]
    nis = 0.0
    for c in range(N_MEAS):
        base = CH_BASE[c]
        gain = k[base + CO_GAIN]
        # the innovation against the estimate as updated so far (linear in the correction)
        e = mem[M.raw + c] - (gain * hy[c] + k[base + CO_OFFSET] + x0[BIAS + c] + x0[BIAS_ALT + c])
        for j in range(N):
            e -= gain * hx[c * N + j] * (x[j] - x0[j])
        for i in range(N):
            acc = 0.0
            for j in range(N):
                acc += p[i * N + j] * hx[c * N + j]
            ph[i] = gain * acc
        s = k[base + CO_R]
        for j in range(N):
            s += gain * hx[c * N + j] * ph[j]
        if not (s > 0.0):
            continue  # (an indefinite covariance: the health check below catches it)
        nis += e * e / s
        g = e / s
        for i in range(N):
            x[i] += ph[i] * g
        for i in range(N):
            pi = ph[i] / s
            for j in range(N):
                p[i * N + j] -= pi * ph[j]
    _lost_track_test(k, mem, nis)
    return nis


@jit
def _lost_track_test(k, mem, nis):
    mem[M.nis_last] = nis
    if not _healthy(mem[M.x:M.x + N], mem[M.p:M.p + N * N]) or not isfinite(nis):
        mem[M.lost] = 1.0
        mem[M.lost_count] += 1.0
        mem[M.resets] += 1.0
        mem[M.nis_sum] = 0.0
        mem[M.nis_ticks] = 0.0
        _reinflate(k, mem, True)
        return
    mem[M.nis_sum] += nis
    mem[M.nis_ticks] += 1.0
    if mem[M.nis_ticks] >= k[EK.nis_window]:
        if mem[M.nis_sum] > k[EK.nis_bound]:
            mem[M.lost] = 1.0
            mem[M.lost_count] += 1.0
            _reinflate(k, mem, False)
        else:
            mem[M.lost] = 0.0
        mem[M.nis_sum] = 0.0
        mem[M.nis_ticks] = 0.0


@jit
def _white_acceleration(p, ix, iv, q, dt):
    """Q of a white acceleration of std q (m/s^2) held over a period dt on (position, speed)."""
    q2 = q * q
    d2 = dt * dt
    p[ix * N + ix] += q2 * d2 * d2 / 4.0
    p[ix * N + iv] += q2 * d2 * dt / 2.0
    p[iv * N + ix] += q2 * d2 * dt / 2.0
    p[iv * N + iv] += q2 * d2


@jit
def _finite(a, n):
    for i in range(n):
        if not isfinite(a[i]):
            return False
    return True


@jit
def _block(i, blocks):
    """The columns [lo, hi) of Phi's row i that may be non-zero (all of them unless ``blocks``)."""
    if not blocks:
        return 0, N
    if i < N_PLANT:
        return 0, N_PLANT
    return i, i + 1


@jit
def ekf_predict(k, mem, f2):
    """The estimate at the next tick: the plant under the applied force f2 (N, up) held over
    the period (mean by RK4, covariance by ``Phi = I + J dt + (J dt)^2 / 2`` at the updated
    estimate, plus Q)."""
    dt = k[EK.dt]
    x = mem[M.x:M.x + N]
    p = mem[M.p:M.p + N * N]
    phi = mem[M.phi:M.phi + N * N]
    mm = mem[M.scratch:M.scratch + N * N]
    im1 = x[IM1]
    b = damping(k, im1)
    f, fd, fdd = contact(x[X1] - x[X2], x[V1] - x[V2], k[EK.c], b, k[EK.d_floor])
    m2 = k[EK.m2]
    for i in range(N * N):
        phi[i] = 0.0
    phi[X1 * N + V1] = 1.0
    phi[V1 * N + X1] = -im1 * fd
    phi[V1 * N + V1] = -im1 * fdd
    phi[V1 * N + X2] = im1 * fd
    phi[V1 * N + V2] = im1 * fdd
    phi[V1 * N + IM1] = -f
    phi[X2 * N + V2] = 1.0
    phi[V2 * N + X1] = fd / m2
    phi[V2 * N + V1] = fdd / m2
    phi[V2 * N + X2] = (-fd - k[EK.k2]) / m2
    phi[V2 * N + V2] = (-fdd - k[EK.c2]) / m2
    # Phi is block-diagonal (the plant's N_PLANT states, then the drifts' diagonal), so the
    # products below skip the terms whose Phi factor is an exact zero; with finite factors a
    # skipped term is +-0, which leaves a sum started at +0 unchanged: the same numbers as the
    # full sums, which non-finite factors still take (0 * inf is NaN)
    blocks = _finite(phi, N * N) and _finite(p, N * N)
    for i in range(N):  # J^2 into the scratch (J lies in the plant block)
        for j in range(N):
            hi = N
            if blocks:
                hi = N_PLANT if i < N_PLANT and j < N_PLANT else 0
            acc = 0.0
            for m in range(hi):
                acc += phi[i * N + m] * phi[m * N + j]
            mm[i * N + j] = acc
    h2 = 0.5 * dt * dt
    for i in range(N):
        for j in range(N):
            phi[i * N + j] = (1.0 if i == j else 0.0) + dt * phi[i * N + j] + h2 * mm[i * N + j]
    for c in range(N_MEAS):  # the alternating drifts flip their sign every tick
        phi[(BIAS_ALT + c) * N + BIAS_ALT + c] = -1.0
        x[BIAS_ALT + c] = -x[BIAS_ALT + c]
    plant_step(k, x, f2)
    mem[M.f_applied] = f2
    for i in range(N):  # Phi P
        lo, hi = _block(i, blocks)
        for j in range(N):
            acc = 0.0
            for m in range(lo, hi):
                acc += phi[i * N + m] * p[m * N + j]
            mm[i * N + j] = acc
    blocks = blocks and _finite(mm, N * N)
    for i in range(N):  # (Phi P) Phi', symmetric: the upper triangle, mirrored
        for j in range(i, N):
            lo, hi = _block(j, blocks)
            acc = 0.0
            for m in range(lo, hi):
                acc += mm[i * N + m] * phi[j * N + m]
            p[i * N + j] = acc
            p[j * N + i] = acc
    _white_acceleration(p, X1, V1, k[EK.q_a1], dt)
    _white_acceleration(p, X2, V2, k[EK.q_a2], dt)
    p[IM1 * N + IM1] += k[EK.q_im1] * k[EK.q_im1]
    for b0 in (BIAS, BIAS_ALT):
        p[(b0 + ACC) * N + b0 + ACC] += k[EK.q_b_acc] * k[EK.q_b_acc]
        p[(b0 + FORCE) * N + b0 + FORCE] += k[EK.q_b_force] * k[EK.q_b_force]
        p[(b0 + POT) * N + b0 + POT] += k[EK.q_b_pot] * k[EK.q_b_pot]


@jit
def ekf_measure(k, mem, y):
    """This tick's half before the controller: the raw readings recovered from the frame's
    filtered ones ``y`` (a2, T, x2); on the episode's first tick the prior (the first frame is
    the reset's, which the filters have not seen: no update), afterwards the measurement update."""
    if mem[M.started] == 0.0:
        _prior(k, mem)
        mem[M.started] = 1.0
        for c in range(N_MEAS):
            mem[M.raw + c] = y[c]
        return
    unfilter(k, mem, y)
    ekf_update(k, mem)


@jit
def ekf_tick(k, mem, y, f_law):
    """The tick's second half, once the controller has chosen its demand ``f_law`` (N): the
    force the hardware applies for it (:func:`applied_force`) and the prediction."""
    f2 = applied_force(k, mem, f_law, mem[M.x + V2])
    ekf_predict(k, mem, f2)
    return f2


#: the scratch :func:`ekf_ahead` needs (floats): the memory row's replicas' region, then a state
AHEAD_SCRATCH = REPLICAS_END + N


@jit
def ekf_ahead(k, mem, demands, lag, scratch):
    """The plant ``lag`` periods after the filter's estimate, for a controller whose readings
    arrive late and whose demands act late: the estimate moved by the filter's own model under the
    demands ``demands[:lag]`` (N, oldest first, the first the one this tick's prediction applies),
    each through copies of the hardware replicas (:func:`applied_force`) and the mean's RK4 step.
    The state ends in ``scratch[REPLICAS_END:]`` (N_STATE floats); ``mem`` is not changed."""
    for i in range(M.shaker, REPLICAS_END):
        scratch[i] = mem[i]
    x = scratch[REPLICAS_END:REPLICAS_END + N]
    for i in range(N):
        x[i] = mem[M.x + i]
    for j in range(lag):
        f2 = applied_force(k, scratch, demands[j], x[V2])
        plant_step(k, x, f2)


@jit
def ekf_run(k, mem, frames, forces, out_x, out_status):
    """Offline use (tests, figures): the filter over a recorded episode with the law's demands
    given: frame t's readings ``frames[t]`` (float64[T, 3]: a2, T, x2 as the policy saw them)
    and the demand ``forces[t]`` (N) chosen at tick t.  Fills the estimate after tick t's update
    ``out_x[t]`` (float64[T, N_STATE]) and ``out_status[t]`` = (lost bit, lost count, NIS, P's
    diagonal (N_STATE), recovered raw readings (3)), float64[T, 6 + N_STATE]."""
    for t in range(frames.shape[0]):
        ekf_measure(k, mem, frames[t])
        for i in range(N):
            out_x[t, i] = mem[M.x + i]
            out_status[t, 3 + i] = mem[M.p + i * N + i]
        out_status[t, 0] = mem[M.lost]
        out_status[t, 1] = mem[M.lost_count]
        out_status[t, 2] = mem[M.nis_last]
        for c in range(N_MEAS):
            out_status[t, 3 + N + c] = mem[M.raw + c]
        ekf_tick(k, mem, frames[t], forces[t])
