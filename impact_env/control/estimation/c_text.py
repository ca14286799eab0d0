"""The extended Kalman filter in C99 (:func:`ekf_c`): the same operations in the same order as
the numba kernels of :mod:`impact_env.control.estimation.ekf` (and the replicas of the shaker
and the amplifier's limit it drives, :func:`impact_env.effects.shaker.shaker_packed` and
:func:`impact_env.effects.saturation.saturate`), so that a build with ``-ffp-contract=off`` in
double precision gives bitwise their results (only sqrt, correctly rounded in both; no pow).

The text is file-scope: static functions ``ekf_measure(k, mem, y)`` and ``ekf_tick(k, mem, y,
f_law)`` (as the kernels of the same names) and their helpers, over ``impact_real`` (double, or
float with ``IMPACT_FLOAT32``), with the constants vector ``k``
(:class:`~impact_env.control.estimation.layout.EkfConstants` order) and the memory row ``mem``
(:data:`~impact_env.control.estimation.layout.MEMORY` values, zero at the episode start), both
laid out by :mod:`impact_env.control.estimation.layout`, whose positions are printed here as
``#define``s.
"""

from __future__ import annotations

import re

from impact_env.control.estimation import layout
from impact_env.control.estimation.layout import EkfConstants, EkfMemory
from impact_env.effects.saturation import SP, ST
from impact_env.effects.shaker import P_D


def _defines() -> str:
    # the named constants (an array's numbered ones are reached from its first, a channel's
    # block from EKF_CH_BASE)
    channel = re.compile(rf"({'|'.join(layout.CHANNEL_NAMES)})_")
    names: tuple[str, ...] = EkfConstants._fields
    ks = [f"#define EKF_K_{name.upper()} {i}" for i, name in enumerate(names)
          if not (re.fullmatch(r"sh_\d+", name) or channel.match(name)) or name == "sh_0"]
    memory: dict[str, int] = EkfMemory._asdict()  # type: ignore[attr-defined]  # (a namedtuple instance)
    ms = [f"#define EKF_M_{name.upper()} {pos}" for name, pos in memory.items()]
    plain = {"N": layout.N_STATE, "N_MEAS": layout.N_MEAS, "MAX_Z": layout.MAX_Z, "X1": layout.X1,
             "V1": layout.V1, "X2": layout.X2, "V2": layout.V2, "IM1": layout.IM1, "BIAS": layout.BIAS,
             "BIAS_ALT": layout.BIAS_ALT, "CO_GAIN": layout.CO_GAIN, "CO_OFFSET": layout.CO_OFFSET,
             "CO_R": layout.CO_R, "CO_D": layout.CO_D, "CO_NZ": layout.CO_NZ, "CO_A": layout.CO_A,
             "CO_B": layout.CO_B, "CO_C": layout.CO_C, "CH_BASE": layout.CH_BASE[0],
             "CH_STRIDE": layout.CH_STRIDE, "ACC": 0, "FORCE": 1, "POT": 2,
             "SAT_PEAK": SP.peak, "SAT_RMS2": SP.rms2, "SAT_ALPHA": SP.alpha, "SAT_SLEW": SP.slew_step,
             "SAT_MS": ST.mean_square, "SAT_PREV": ST.prev, "SH_D": P_D,
             "REPLICAS_END": layout.REPLICAS_END}
    assert all(b == layout.CH_BASE[0] + c * layout.CH_STRIDE for c, b in enumerate(layout.CH_BASE))
    return "\n".join([*(f"#define EKF_{name} {v}" for name, v in plain.items()), *ks, *ms])


def ekf_ahead_c() -> str:
    """:func:`impact_env.control.estimation.ekf.ekf_ahead` in C (after :func:`ekf_c`)."""
    return """
/* the plant lag periods after the estimate, under the demands given since (oldest first), by the
 * filter's model on copies of its replicas; the state ends in scratch + EKF_REPLICAS_END */
static void ekf_ahead(const impact_real *k, const impact_real *mem, const impact_real *demands, int lag,
                      impact_real *scratch)
{
    for (int i = EKF_M_SHAKER; i < EKF_REPLICAS_END; i++) scratch[i] = mem[i];
    impact_real *x = scratch + EKF_REPLICAS_END;
    for (int i = 0; i < EKF_N; i++) x[i] = mem[EKF_M_X + i];
    for (int j = 0; j < lag; j++) {
        impact_real f2 = ekf_applied_force(k, scratch, demands[j], x[EKF_V2]);
        ekf_plant_step(k, x, f2);
    }
}
"""


def ekf_c() -> str:
    """The filter's C text (file scope; needs <math.h> and ``impact_real``)."""
    return _defines() + r"""

/* (F N, dF/dd N/m, dF/dd' N s/m) of the pad, clipped at 0 (ekf.contact) */
static void ekf_contact(impact_real d, impact_real dd, impact_real c, impact_real b, impact_real d_floor,
                        impact_real *f, impact_real *fd, impact_real *fdd)
{
    *f = 0.0; *fd = 0.0; *fdd = 0.0;
    if (d <= 0.0) return;
    impact_real s = sqrt(d);
    impact_real q = sqrt(s);
    impact_real ff = c * d * s + b * q * dd;
    if (ff <= 0.0) return;
    impact_real de = d > d_floor ? d : d_floor;
    *f = ff;
    *fd = 1.5 * c * s + 0.25 * b * dd * sqrt(sqrt(de)) / de;
    *fdd = b * q;
}

/* the pad's Tsuji damping b (N s/m^1.25) for body 1's inverse mass im1 (1/kg) */
static impact_real ekf_damping(const impact_real *k, impact_real im1)
{
    impact_real m2 = k[EKF_K_M2];
    return k[EKF_K_ZETA] * sqrt(k[EKF_K_C] * m2 / (1.0 + m2 * im1));
}

static void ekf_accels(const impact_real *k, impact_real x1, impact_real v1, impact_real x2, impact_real v2,
                       impact_real im1, impact_real f2, impact_real b, impact_real *a1, impact_real *a2)
{
    impact_real f, fd, fdd;
    ekf_contact(x1 - x2, v1 - v2, k[EKF_K_C], b, k[EKF_K_D_FLOOR], &f, &fd, &fdd);
    *a1 = k[EKF_K_G] - f * im1;
    *a2 = (f - f2 - k[EKF_K_K2] * x2 - k[EKF_K_C2] * v2) / k[EKF_K_M2];
}

/* one RK4 step of the plant states x[0..3] over the period under the held force f2 (N, up) */
static void ekf_plant_step(const impact_real *k, impact_real *x, impact_real f2)
{
    impact_real dt = k[EKF_K_DT];
    impact_real im1 = x[EKF_IM1];
    impact_real b = ekf_damping(k, im1);
    impact_real x1 = x[EKF_X1], v1 = x[EKF_V1], x2 = x[EKF_X2], v2 = x[EKF_V2];
    impact_real h = 0.5 * dt;
    impact_real a1, a2, b1, b2, c1, c2, e1, e2;
    ekf_accels(k, x1, v1, x2, v2, im1, f2, b, &a1, &a2);
    impact_real u1 = v1 + h * a1, u2 = v2 + h * a2;
    ekf_accels(k, x1 + h * v1, u1, x2 + h * v2, u2, im1, f2, b, &b1, &b2);
    impact_real w1 = v1 + h * b1, w2 = v2 + h * b2;
    ekf_accels(k, x1 + h * u1, w1, x2 + h * u2, w2, im1, f2, b, &c1, &c2);
    impact_real s1 = v1 + dt * c1, s2 = v2 + dt * c2;
    ekf_accels(k, x1 + dt * w1, s1, x2 + dt * w2, s2, im1, f2, b, &e1, &e2);
    impact_real w = dt / 6.0;
    x[EKF_X1] = x1 + w * (v1 + 2.0 * u1 + 2.0 * w1 + s1);
    x[EKF_V1] = v1 + w * (a1 + 2.0 * b1 + 2.0 * c1 + e1);
    x[EKF_X2] = x2 + w * (v2 + 2.0 * u2 + 2.0 * w2 + s2);
    x[EKF_V2] = v2 + w * (a2 + 2.0 * b2 + 2.0 * c2 + e2);
}

/* the raw readings' true values (a2, T, x2) at x after a period under f2 into hy, their
 * gradients in the state into hx (row-major, EKF_N_MEAS x EKF_N) */
static void ekf_readings(const impact_real *k, const impact_real *x, impact_real f2, impact_real *hy,
                         impact_real *hx)
{
    impact_real m2 = k[EKF_K_M2], top = k[EKF_K_TOP_MASS];
    impact_real b = ekf_damping(k, x[EKF_IM1]);
    impact_real f, fd, fdd;
    ekf_contact(x[EKF_X1] - x[EKF_X2], x[EKF_V1] - x[EKF_V2], k[EKF_K_C], b, k[EKF_K_D_FLOOR], &f, &fd, &fdd);
    impact_real a2 = (f - f2 - k[EKF_K_K2] * x[EKF_X2] - k[EKF_K_C2] * x[EKF_V2]) / m2;
    hy[EKF_ACC] = a2;
    hy[EKF_FORCE] = f - top * a2;
    hy[EKF_POT] = x[EKF_X2];
    impact_real ga0 = fd / m2, ga1 = fdd / m2;
    impact_real ga2 = (-fd - k[EKF_K_K2]) / m2, ga3 = (-fdd - k[EKF_K_C2]) / m2;
    hx[EKF_ACC * EKF_N + EKF_X1] = ga0;
    hx[EKF_ACC * EKF_N + EKF_V1] = ga1;
    hx[EKF_ACC * EKF_N + EKF_X2] = ga2;
    hx[EKF_ACC * EKF_N + EKF_V2] = ga3;
    hx[EKF_ACC * EKF_N + EKF_IM1] = 0.0;
    hx[EKF_FORCE * EKF_N + EKF_X1] = fd - top * ga0;
    hx[EKF_FORCE * EKF_N + EKF_V1] = fdd - top * ga1;
    hx[EKF_FORCE * EKF_N + EKF_X2] = -fd - top * ga2;
    hx[EKF_FORCE * EKF_N + EKF_V2] = -fdd - top * ga3;
    hx[EKF_FORCE * EKF_N + EKF_IM1] = 0.0;
    for (int j = 0; j < EKF_N; j++) hx[EKF_POT * EKF_N + j] = 0.0;
    hx[EKF_POT * EKF_N + EKF_X2] = 1.0;
    for (int c = 0; c < EKF_N_MEAS; c++) {
        for (int j = 0; j < EKF_N_MEAS; j++) {
            hx[c * EKF_N + EKF_BIAS + j] = 0.0;
            hx[c * EKF_N + EKF_BIAS_ALT + j] = 0.0;
        }
        hx[c * EKF_N + EKF_BIAS + c] = 1.0 / k[EKF_CH_BASE + c * EKF_CH_STRIDE + EKF_CO_GAIN];
        hx[c * EKF_N + EKF_BIAS_ALT + c] = 1.0 / k[EKF_CH_BASE + c * EKF_CH_STRIDE + EKF_CO_GAIN];
    }
}

/* the shaker replica's step on its packed block p (shaker.shaker_packed): the force held over
 * the period for the demand u (N); st: its n states, then n of scratch */
static impact_real ekf_shaker(const impact_real *p, impact_real *st, int n, impact_real u, impact_real v2,
                              int back_emf)
{
    impact_real *x = st, *scratch = st + n;
    int o = EKF_SH_D + 1 + n * n;
    impact_real y = p[EKF_SH_D] * u;
    for (int i = 0; i < n; i++) y += p[o + n + i] * x[i];
    for (int i = 0; i < n; i++) {
        impact_real acc = p[o + i] * u;
        for (int j = 0; j < n; j++) acc += p[EKF_SH_D + 1 + i * n + j] * x[j];
        scratch[i] = acc;
    }
    for (int i = 0; i < n; i++) x[i] = scratch[i];
    if (back_emf)
        for (int j = 0; j < n; j++) x[j] += p[o + 2 * n + j] * v2;
    return y;
}

/* the amplifier's limits on the replica's state (saturation.saturate): the applied force */
static impact_real ekf_saturate(impact_real f_cmd, impact_real *state, const impact_real *params)
{
    impact_real f = f_cmd;
    if (!isfinite(f)) f = 0.0;
    impact_real prev = state[EKF_SAT_PREV];
    impact_real step = params[EKF_SAT_SLEW];
    if (f > prev + step) f = prev + step;
    else if (f < prev - step) f = prev - step;
    impact_real lim = params[EKF_SAT_PEAK];
    impact_real rms2 = params[EKF_SAT_RMS2];
    if (rms2 >= 0.0) {
        impact_real ms = state[EKF_SAT_MS];
        impact_real room = ms + (rms2 - ms) / params[EKF_SAT_ALPHA];
        if (room < 0.0) room = 0.0;
        impact_real r = sqrt(room);
        if (r < lim) lim = r;
    }
    if (f > lim) f = lim;
    else if (f < -lim) f = -lim;
    state[EKF_SAT_MS] += params[EKF_SAT_ALPHA] * (f * f - state[EKF_SAT_MS]);
    state[EKF_SAT_PREV] = f;
    return f;
}

/* the force (N, up) the scene's hardware applies over this period for the law's demand f_law (N) */
static impact_real ekf_applied_force(const impact_real *k, impact_real *mem, impact_real f_law,
                                     impact_real v2)
{
    impact_real cs = k[EKF_K_COMMAND_SCALE];
    impact_real u = f_law / cs;
    if (u < -1.0) u = -1.0;
    else if (u > 1.0) u = 1.0;
    impact_real f = u * cs * k[EKF_K_COMMAND_GAIN];
    if (k[EKF_K_SH_ON] > 0.0)
        f = ekf_shaker(k + EKF_K_SH_0, mem + EKF_M_SHAKER, (int)k[EKF_K_SH_N], f, v2,
                       k[EKF_K_BACK_EMF] > 0.0);
    if (k[EKF_K_SAT_ON] > 0.0) f = ekf_saturate(f, mem + EKF_M_SAT, k + EKF_K_SAT_PEAK);
    return f;
}

/* each channel's raw reading from its filtered one y[c] (the inverse filter) into mem[raw] */
static void ekf_unfilter(const impact_real *k, impact_real *mem, const impact_real *y)
{
    for (int c = 0; c < EKF_N_MEAS; c++) {
        int base = EKF_CH_BASE + c * EKF_CH_STRIDE;
        int nz = (int)k[base + EKF_CO_NZ];
        impact_real *z = mem + EKF_M_FILT + c * EKF_MAX_Z;
        impact_real acc = y[c];
        for (int a = 0; a < nz; a++) acc -= k[base + EKF_CO_C + a] * z[a];
        impact_real r = acc / k[base + EKF_CO_D];
        impact_real *s = mem + EKF_M_SCRATCH;
        for (int a = 0; a < nz; a++) {
            impact_real t = k[base + EKF_CO_B + a] * r;
            for (int bb = 0; bb < nz; bb++) t += k[base + EKF_CO_A + a * EKF_MAX_Z + bb] * z[bb];
            s[a] = t;
        }
        for (int a = 0; a < nz; a++) z[a] = s[a];
        mem[EKF_M_RAW + c] = r;
    }
}

static void ekf_bias_prior(const impact_real *k, impact_real *p)
{
    for (int t = 0; t < 2; t++) {
        int b0 = t == 0 ? EKF_BIAS : EKF_BIAS_ALT;
        p[(b0 + EKF_ACC) * EKF_N + b0 + EKF_ACC] = k[EKF_K_P_B_ACC];
        p[(b0 + EKF_FORCE) * EKF_N + b0 + EKF_FORCE] = k[EKF_K_P_B_FORCE];
        p[(b0 + EKF_POT) * EKF_N + b0 + EKF_POT] = k[EKF_K_P_B_POT];
    }
}

/* the estimate at the episode start (body 1 not yet seen: the scene's drop ranges) */
static void ekf_prior(const impact_real *k, impact_real *mem)
{
    impact_real *x = mem + EKF_M_X, *p = mem + EKF_M_P;
    for (int i = 0; i < EKF_N; i++) x[i] = 0.0;
    for (int i = 0; i < EKF_N * EKF_N; i++) p[i] = 0.0;
    x[EKF_X1] = k[EKF_K_X1_0];
    x[EKF_V1] = k[EKF_K_V1_0];
    x[EKF_IM1] = k[EKF_K_IM1_0];
    p[EKF_X1 * EKF_N + EKF_X1] = k[EKF_K_P_X1];
    p[EKF_X1 * EKF_N + EKF_V1] = k[EKF_K_P_X1V1];
    p[EKF_V1 * EKF_N + EKF_X1] = k[EKF_K_P_X1V1];
    p[EKF_V1 * EKF_N + EKF_V1] = k[EKF_K_P_V1];
    p[EKF_X2 * EKF_N + EKF_X2] = k[EKF_K_P_X2];
    p[EKF_V2 * EKF_N + EKF_V2] = k[EKF_K_P_V2];
    p[EKF_IM1 * EKF_N + EKF_IM1] = k[EKF_K_P_IM1];
    ekf_bias_prior(k, p);
}

/* after lost track: the covariance back to the reset's; with restart also the mean */
static void ekf_reinflate(const impact_real *k, impact_real *mem, int restart)
{
    impact_real *x = mem + EKF_M_X, *p = mem + EKF_M_P;
    if (restart) {
        impact_real x2 = mem[EKF_M_RAW + EKF_POT];
        if (!isfinite(x2)) x2 = 0.0;
        x[EKF_X1] = x2;
        x[EKF_X2] = x2;
        x[EKF_V1] = 0.0;
        x[EKF_V2] = 0.0;
        x[EKF_IM1] = k[EKF_K_IM1_0];
    }
    for (int i = 0; i < EKF_N * EKF_N; i++) p[i] = 0.0;
    impact_real rx = k[EKF_K_RESET_X], rv = k[EKF_K_RESET_V];
    p[EKF_X1 * EKF_N + EKF_X1] = rx * rx;
    p[EKF_X2 * EKF_N + EKF_X2] = rx * rx;
    p[EKF_V1 * EKF_N + EKF_V1] = rv * rv;
    p[EKF_V2 * EKF_N + EKF_V2] = rv * rv;
    p[EKF_IM1 * EKF_N + EKF_IM1] = k[EKF_K_P_IM1];
    ekf_bias_prior(k, p);
}

static int ekf_healthy(const impact_real *x, const impact_real *p)
{
    for (int i = 0; i < EKF_N; i++)
        if (!isfinite(x[i]) || !(p[i * EKF_N + i] > 0.0) || !isfinite(p[i * EKF_N + i])) return 0;
    return 1;
}

static void ekf_lost_track_test(const impact_real *k, impact_real *mem, impact_real nis)
{
    mem[EKF_M_NIS_LAST] = nis;
    if (!ekf_healthy(mem + EKF_M_X, mem + EKF_M_P) || !isfinite(nis)) {
        mem[EKF_M_LOST] = 1.0;
        mem[EKF_M_LOST_COUNT] += 1.0;
        mem[EKF_M_RESETS] += 1.0;
        mem[EKF_M_NIS_SUM] = 0.0;
        mem[EKF_M_NIS_TICKS] = 0.0;
        ekf_reinflate(k, mem, 1);
        return;
    }
    mem[EKF_M_NIS_SUM] += nis;
    mem[EKF_M_NIS_TICKS] += 1.0;
    if (mem[EKF_M_NIS_TICKS] >= k[EKF_K_NIS_WINDOW]) {
        if (mem[EKF_M_NIS_SUM] > k[EKF_K_NIS_BOUND]) {
            mem[EKF_M_LOST] = 1.0;
            mem[EKF_M_LOST_COUNT] += 1.0;
            ekf_reinflate(k, mem, 0);
        } else {
            mem[EKF_M_LOST] = 0.0;
        }
        mem[EKF_M_NIS_SUM] = 0.0;
        mem[EKF_M_NIS_TICKS] = 0.0;
    }
}

/* the measurement update with this tick's raw readings, channel by channel; then the
 * lost-track test */
static void ekf_update(const impact_real *k, impact_real *mem)
{
    impact_real *x = mem + EKF_M_X, *p = mem + EKF_M_P, *hy = mem + EKF_M_HY, *hx = mem + EKF_M_HX;
    impact_real *ph = mem + EKF_M_PH, *x0 = mem + EKF_M_X_PRIOR;
    ekf_readings(k, x, mem[EKF_M_F_APPLIED], hy, hx);
    for (int i = 0; i < EKF_N; i++) x0[i] = x[i];
    impact_real nis = 0.0;
    for (int c = 0; c < EKF_N_MEAS; c++) {
        int base = EKF_CH_BASE + c * EKF_CH_STRIDE;
        impact_real gain = k[base + EKF_CO_GAIN];
        impact_real e = mem[EKF_M_RAW + c]
                        - (gain * hy[c] + k[base + EKF_CO_OFFSET] + x0[EKF_BIAS + c] + x0[EKF_BIAS_ALT + c]);
        for (int j = 0; j < EKF_N; j++) e -= gain * hx[c * EKF_N + j] * (x[j] - x0[j]);
        for (int i = 0; i < EKF_N; i++) {
            impact_real acc = 0.0;
            for (int j = 0; j < EKF_N; j++) acc += p[i * EKF_N + j] * hx[c * EKF_N + j];
            ph[i] = gain * acc;
        }
        impact_real s = k[base + EKF_CO_R];
        for (int j = 0; j < EKF_N; j++) s += gain * hx[c * EKF_N + j] * ph[j];
        if (!(s > 0.0)) continue;
        nis += e * e / s;
        impact_real g = e / s;
        for (int i = 0; i < EKF_N; i++) x[i] += ph[i] * g;
        for (int i = 0; i < EKF_N; i++) {
            impact_real pi = ph[i] / s;
            for (int j = 0; j < EKF_N; j++) p[i * EKF_N + j] -= pi * ph[j];
        }
    }
    ekf_lost_track_test(k, mem, nis);
}

static void ekf_white_acceleration(impact_real *p, int ix, int iv, impact_real q, impact_real dt)
{
    impact_real q2 = q * q;
    impact_real d2 = dt * dt;
    p[ix * EKF_N + ix] += q2 * d2 * d2 / 4.0;
    p[ix * EKF_N + iv] += q2 * d2 * dt / 2.0;
    p[iv * EKF_N + ix] += q2 * d2 * dt / 2.0;
    p[iv * EKF_N + iv] += q2 * d2;
}

/* the estimate at the next tick under the applied force f2 (N, up) */
static void ekf_predict(const impact_real *k, impact_real *mem, impact_real f2)
{
    impact_real dt = k[EKF_K_DT];
    impact_real *x = mem + EKF_M_X, *p = mem + EKF_M_P, *phi = mem + EKF_M_PHI, *mm = mem + EKF_M_SCRATCH;
    impact_real im1 = x[EKF_IM1];
    impact_real b = ekf_damping(k, im1);
    impact_real f, fd, fdd;
    ekf_contact(x[EKF_X1] - x[EKF_X2], x[EKF_V1] - x[EKF_V2], k[EKF_K_C], b, k[EKF_K_D_FLOOR], &f, &fd, &fdd);
    impact_real m2 = k[EKF_K_M2];
    for (int i = 0; i < EKF_N * EKF_N; i++) phi[i] = 0.0;
    phi[EKF_X1 * EKF_N + EKF_V1] = 1.0;
    phi[EKF_V1 * EKF_N + EKF_X1] = -im1 * fd;
    phi[EKF_V1 * EKF_N + EKF_V1] = -im1 * fdd;
    phi[EKF_V1 * EKF_N + EKF_X2] = im1 * fd;
    phi[EKF_V1 * EKF_N + EKF_V2] = im1 * fdd;
    phi[EKF_V1 * EKF_N + EKF_IM1] = -f;
    phi[EKF_X2 * EKF_N + EKF_V2] = 1.0;
    phi[EKF_V2 * EKF_N + EKF_X1] = fd / m2;
    phi[EKF_V2 * EKF_N + EKF_V1] = fdd / m2;
    phi[EKF_V2 * EKF_N + EKF_X2] = (-fd - k[EKF_K_K2]) / m2;
    phi[EKF_V2 * EKF_N + EKF_V2] = (-fdd - k[EKF_K_C2]) / m2;
    for (int i = 0; i < EKF_N; i++)  /* J^2 into the scratch */
        for (int j = 0; j < EKF_N; j++) {
            impact_real acc = 0.0;
            for (int m = 0; m < EKF_N; m++) acc += phi[i * EKF_N + m] * phi[m * EKF_N + j];
            mm[i * EKF_N + j] = acc;
        }
    impact_real h2 = 0.5 * dt * dt;
    for (int i = 0; i < EKF_N; i++)
        for (int j = 0; j < EKF_N; j++)
            phi[i * EKF_N + j] = (i == j ? 1.0 : 0.0) + dt * phi[i * EKF_N + j] + h2 * mm[i * EKF_N + j];
    for (int c = 0; c < EKF_N_MEAS; c++) {  /* the alternating drifts flip their sign every tick */
        phi[(EKF_BIAS_ALT + c) * EKF_N + EKF_BIAS_ALT + c] = -1.0;
        x[EKF_BIAS_ALT + c] = -x[EKF_BIAS_ALT + c];
    }
    ekf_plant_step(k, x, f2);
    mem[EKF_M_F_APPLIED] = f2;
    for (int i = 0; i < EKF_N; i++)  /* Phi P */
        for (int j = 0; j < EKF_N; j++) {
            impact_real acc = 0.0;
            for (int m = 0; m < EKF_N; m++) acc += phi[i * EKF_N + m] * p[m * EKF_N + j];
            mm[i * EKF_N + j] = acc;
        }
    for (int i = 0; i < EKF_N; i++)  /* (Phi P) Phi', symmetric: the upper triangle, mirrored */
        for (int j = i; j < EKF_N; j++) {
            impact_real acc = 0.0;
            for (int m = 0; m < EKF_N; m++) acc += mm[i * EKF_N + m] * phi[j * EKF_N + m];
            p[i * EKF_N + j] = acc;
            p[j * EKF_N + i] = acc;
        }
    ekf_white_acceleration(p, EKF_X1, EKF_V1, k[EKF_K_Q_A1], dt);
    ekf_white_acceleration(p, EKF_X2, EKF_V2, k[EKF_K_Q_A2], dt);
    p[EKF_IM1 * EKF_N + EKF_IM1] += k[EKF_K_Q_IM1] * k[EKF_K_Q_IM1];
    for (int t = 0; t < 2; t++) {
        int b0 = t == 0 ? EKF_BIAS : EKF_BIAS_ALT;
        p[(b0 + EKF_ACC) * EKF_N + b0 + EKF_ACC] += k[EKF_K_Q_B_ACC] * k[EKF_K_Q_B_ACC];
        p[(b0 + EKF_FORCE) * EKF_N + b0 + EKF_FORCE] += k[EKF_K_Q_B_FORCE] * k[EKF_K_Q_B_FORCE];
        p[(b0 + EKF_POT) * EKF_N + b0 + EKF_POT] += k[EKF_K_Q_B_POT] * k[EKF_K_Q_B_POT];
    }
}

/* the tick's half before the controller: the raw readings from the frame's filtered ones y
 * (a2, T, x2); the prior on the episode's first tick, the measurement update afterwards */
static void ekf_measure(const impact_real *k, impact_real *mem, const impact_real *y)
{
    if (mem[EKF_M_STARTED] == 0.0) {
        ekf_prior(k, mem);
        mem[EKF_M_STARTED] = 1.0;
        for (int c = 0; c < EKF_N_MEAS; c++) mem[EKF_M_RAW + c] = y[c];
        return;
    }
    ekf_unfilter(k, mem, y);
    ekf_update(k, mem);
}

/* the tick's second half, once the controller has chosen its demand f_law (N): the applied
 * force and the prediction */
static impact_real ekf_tick(const impact_real *k, impact_real *mem, const impact_real *y, impact_real f_law)
{
    (void)y;
    impact_real f2 = ekf_applied_force(k, mem, f_law, mem[EKF_M_X + EKF_V2]);
    ekf_predict(k, mem, f2);
    return f2;
}
"""
