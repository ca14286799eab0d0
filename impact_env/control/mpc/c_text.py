"""The solver in C99 (:func:`solver_c`): the same operations in the same order as the numba
kernels of :mod:`impact_env.control.mpc.model` and :mod:`impact_env.control.mpc.solver`, so that
a build with ``-ffp-contract=off`` in double precision gives bitwise their results (sqrt is
correctly rounded in both; no pow, no library call whose rounding could differ).  The text is
file-scope: static functions ``mpc_tick(x1, v1, x2, v2, k, mem)`` (as :func:`solver.mpc_tick`)
and its helpers, over ``impact_real`` (double, or float with ``IMPACT_FLOAT32``), with the
constants vector ``k`` (:class:`model.Constants` order) and the memory row ``mem``
(:data:`solver.MEMORY` values, zero at the episode start).
"""

from __future__ import annotations

from impact_env.control.mpc import model, solver


def _defines() -> str:
    k = [f"#define MPC_K_{name.upper()} {i}" for i, name in enumerate(model.Constants._fields)]
    m = [f"#define MPC_M_{name.upper()} {i}" for i, name in enumerate(solver.Memory._fields)]
    names = ("STATE", "PLAN", "XS", "GAINS", "FEED", "VX", "VXX", "JA", "JB", "VA", "QX", "QUX", "VB", "SCUR",
             "SNEXT", "VN", "TRIAL", "MEMORY", "NMAX")
    off = {name: getattr(solver, name) for name in names}
    o = [f"#define MPC_{name} {v}" for name, v in off.items()]
    return "\n".join([f"#define MPC_NX {model.NX}", *k, *m, *o])


def solver_c() -> str:
    """The solver's C text (file scope; needs <math.h> and ``impact_real``)."""
    return _defines() + r"""

static impact_real mpc_clip(impact_real u, impact_real lo, impact_real hi)
{
    if (u < lo) return lo;
    if (u > hi) return hi;
    return u;
}

/* (F, dF/dd, dF/dd') of the Hertz-Tsuji pad; zero out of contact and where it would pull */
static void mpc_contact(impact_real d, impact_real dd, const impact_real *k, impact_real *f, impact_real *fd,
                        impact_real *fdd)
{
    *f = 0.0; *fd = 0.0; *fdd = 0.0;
    if (d <= 0.0) return;
    impact_real s = sqrt(d);
    impact_real q = sqrt(s);
    impact_real ff = k[MPC_K_C] * d * s + k[MPC_K_B] * q * dd;
    if (ff <= 0.0) return;
    impact_real de = d > k[MPC_K_DMIN] ? d : k[MPC_K_DMIN];
    impact_real se = sqrt(de);
    *f = ff;
    *fd = 1.5 * k[MPC_K_C] * s + 0.25 * k[MPC_K_B] * dd / (se * sqrt(se));
    *fdd = k[MPC_K_B] * q;
}

static int mpc_substeps(const impact_real *k)
{
    return k[MPC_K_SUBSTEPS] >= 1.0 ? (int)k[MPC_K_SUBSTEPS] : 1;
}

static void mpc_step(const impact_real *s, impact_real u, const impact_real *k, impact_real *out)
{
    impact_real x1 = s[0], v1 = s[1], x2 = s[2], v2 = s[3];
    impact_real f2 = k[MPC_K_C0] * s[4] + k[MPC_K_C1] * s[5] + k[MPC_K_CZ2] * s[6] + k[MPC_K_DZ] * u;
    int n = mpc_substeps(k);
    impact_real h = k[MPC_K_H] / n;
    for (int i = 0; i < n; i++) {
        impact_real f, fd, fdd;
        mpc_contact(x1 - x2, v1 - v2, k, &f, &fd, &fdd);
        v1 = v1 + h * (k[MPC_K_G] - f / k[MPC_K_M1]);
        v2 = v2 + h * (f - f2 - k[MPC_K_K2] * x2 - k[MPC_K_C2] * v2) / k[MPC_K_M2];
        x1 = x1 + h * v1;
        x2 = x2 + h * v2;
    }
    impact_real z0 = k[MPC_K_A00] * s[4] + k[MPC_K_A01] * s[5] + k[MPC_K_A02] * s[6] + k[MPC_K_B0] * u;
    impact_real z1 = k[MPC_K_A10] * s[4] + k[MPC_K_A11] * s[5] + k[MPC_K_A12] * s[6] + k[MPC_K_B1] * u;
    impact_real z2 = k[MPC_K_A20] * s[4] + k[MPC_K_A21] * s[5] + k[MPC_K_A22] * s[6] + k[MPC_K_B2] * u;
    out[0] = x1; out[1] = v1; out[2] = x2; out[3] = v2; out[4] = z0; out[5] = z1; out[6] = z2;
}

static void mpc_jacobian(const impact_real *s, impact_real u, const impact_real *k, impact_real *A,
                         impact_real *B)
{
    for (int i = 0; i < MPC_NX * MPC_NX; i++) A[i] = 0.0;
    for (int i = 0; i < 4; i++) { A[i * MPC_NX + i] = 1.0; B[i] = 0.0; }
    impact_real x1 = s[0], v1 = s[1], x2 = s[2], v2 = s[3];
    impact_real f2 = k[MPC_K_C0] * s[4] + k[MPC_K_C1] * s[5] + k[MPC_K_CZ2] * s[6] + k[MPC_K_DZ] * u;
    int n = mpc_substeps(k);
    impact_real h = k[MPC_K_H] / n;
    impact_real m1 = k[MPC_K_M1], m2 = k[MPC_K_M2];
    for (int it = 0; it < n; it++) {
        impact_real f, fd, fdd;
        mpc_contact(x1 - x2, v1 - v2, k, &f, &fd, &fdd);
        impact_real p10 = -h * fd / m1;
        impact_real p11 = 1.0 - h * fdd / m1;
        impact_real p12 = h * fd / m1;
        impact_real p13 = h * fdd / m1;
        impact_real p30 = h * fd / m2;
        impact_real p31 = h * fdd / m2;
        impact_real p32 = -h * (fd + k[MPC_K_K2]) / m2;
        impact_real p33 = 1.0 - h * (fdd + k[MPC_K_C2]) / m2;
        impact_real p3f = -h / m2;
        for (int j = 0; j < MPC_NX; j++) {
            impact_real r0 = A[0 * MPC_NX + j], r1 = A[1 * MPC_NX + j], r2 = A[2 * MPC_NX + j],
                        r3 = A[3 * MPC_NX + j];
            impact_real fz = 0.0;
            if (j == 4) fz = k[MPC_K_C0];
            else if (j == 5) fz = k[MPC_K_C1];
            else if (j == 6) fz = k[MPC_K_CZ2];
            impact_real n1 = p10 * r0 + p11 * r1 + p12 * r2 + p13 * r3;
            impact_real n3 = p30 * r0 + p31 * r1 + p32 * r2 + p33 * r3 + p3f * fz;
            A[1 * MPC_NX + j] = n1;
            A[3 * MPC_NX + j] = n3;
            A[0 * MPC_NX + j] = r0 + h * n1;
            A[2 * MPC_NX + j] = r2 + h * n3;
        }
        {
            impact_real r0 = B[0], r1 = B[1], r2 = B[2], r3 = B[3];
            impact_real n1 = p10 * r0 + p11 * r1 + p12 * r2 + p13 * r3;
            impact_real n3 = p30 * r0 + p31 * r1 + p32 * r2 + p33 * r3 + p3f * k[MPC_K_DZ];
            B[1] = n1;
            B[3] = n3;
            B[0] = r0 + h * n1;
            B[2] = r2 + h * n3;
        }
        v1 = v1 + h * (k[MPC_K_G] - f / m1);
        v2 = v2 + h * (f - f2 - k[MPC_K_K2] * x2 - k[MPC_K_C2] * v2) / m2;
        x1 = x1 + h * v1;
        x2 = x2 + h * v2;
    }
    A[4 * MPC_NX + 4] = k[MPC_K_A00]; A[4 * MPC_NX + 5] = k[MPC_K_A01]; A[4 * MPC_NX + 6] = k[MPC_K_A02];
    A[5 * MPC_NX + 4] = k[MPC_K_A10]; A[5 * MPC_NX + 5] = k[MPC_K_A11]; A[5 * MPC_NX + 6] = k[MPC_K_A12];
    A[6 * MPC_NX + 4] = k[MPC_K_A20]; A[6 * MPC_NX + 5] = k[MPC_K_A21]; A[6 * MPC_NX + 6] = k[MPC_K_A22];
    B[4] = k[MPC_K_B0]; B[5] = k[MPC_K_B1]; B[6] = k[MPC_K_B2];
}

static impact_real mpc_state_cost(const impact_real *s, const impact_real *k)
{
    impact_real d = s[0] - s[2];
    impact_real e = 0.5 * k[MPC_K_M1] * s[1] * s[1] + k[MPC_K_M1] * k[MPC_K_G] * (0.6 * k[MPC_K_DS] - d);
    if (d > 0.0) e += 0.4 * k[MPC_K_C] * d * d * sqrt(d);
    return e + k[MPC_K_W2] * (0.5 * k[MPC_K_M2] * s[3] * s[3] + 0.5 * k[MPC_K_K2] * s[2] * s[2]);
}

static void mpc_add_cost_derivatives(const impact_real *s, const impact_real *k, impact_real w,
                                     impact_real *gx, impact_real *Hx)
{
    impact_real d = s[0] - s[2];
    impact_real gd = -k[MPC_K_M1] * k[MPC_K_G];
    impact_real hdd = 0.0;
    if (d > 0.0) {
        impact_real sd = sqrt(d);
        gd += k[MPC_K_C] * d * sd;
        hdd = 1.5 * k[MPC_K_C] * sd;
    }
    gx[0] += w * gd;
    gx[2] += w * (k[MPC_K_W2] * k[MPC_K_K2] * s[2] - gd);
    gx[1] += w * (k[MPC_K_M1] * s[1]);
    gx[3] += w * (k[MPC_K_W2] * k[MPC_K_M2] * s[3]);
    Hx[0 * MPC_NX + 0] += w * hdd;
    Hx[0 * MPC_NX + 2] -= w * hdd;
    Hx[2 * MPC_NX + 0] -= w * hdd;
    Hx[2 * MPC_NX + 2] += w * (hdd + k[MPC_K_W2] * k[MPC_K_K2]);
    Hx[1 * MPC_NX + 1] += w * k[MPC_K_M1];
    Hx[3 * MPC_NX + 3] += w * (k[MPC_K_W2] * k[MPC_K_M2]);
}

static void mpc_bounds(const impact_real *k, impact_real u_before, impact_real *lo, impact_real *hi)
{
    *lo = -k[MPC_K_UMAX];
    *hi = k[MPC_K_UMAX];
    impact_real sl = k[MPC_K_SLEW];
    if (sl > 0.0) {
        if (u_before - sl > *lo) *lo = u_before - sl;
        if (u_before + sl < *hi) *hi = u_before + sl;
    }
}

static impact_real mpc_forward(const impact_real *k, impact_real *mem, int n, impact_real alpha, int write)
{
    for (int i = 0; i < MPC_NX; i++) mem[MPC_SCUR + i] = mem[MPC_STATE + i];
    impact_real u_before = mem[MPC_M_U_PREV];
    impact_real r = k[MPC_K_R];
    impact_real cost = 0.0;
    for (int j = 0; j < n; j++) {
        impact_real u = mem[MPC_PLAN + j];
        if (alpha != 0.0) {
            u = u + alpha * mem[MPC_FEED + j];
            for (int i = 0; i < MPC_NX; i++)
                u = u + mem[MPC_GAINS + j * MPC_NX + i] * (mem[MPC_SCUR + i] - mem[MPC_XS + j * MPC_NX + i]);
        }
        impact_real lo, hi;
        mpc_bounds(k, u_before, &lo, &hi);
        u = mpc_clip(u, lo, hi);
        if (write) {
            for (int i = 0; i < MPC_NX; i++) mem[MPC_XS + j * MPC_NX + i] = mem[MPC_SCUR + i];
            mem[MPC_PLAN + j] = u;
        } else {
            mem[MPC_TRIAL + j] = u;
        }
        mpc_step(mem + MPC_SCUR, u, k, mem + MPC_SNEXT);
        for (int i = 0; i < MPC_NX; i++) mem[MPC_SCUR + i] = mem[MPC_SNEXT + i];
        impact_real w = j == n - 1 ? k[MPC_K_W_TERMINAL] : 1.0;
        cost += r * u * u + w * mpc_state_cost(mem + MPC_SCUR, k);
        u_before = u;
    }
    if (write)
        for (int i = 0; i < MPC_NX; i++) mem[MPC_XS + n * MPC_NX + i] = mem[MPC_SCUR + i];
    return cost;
}

static int mpc_backward(const impact_real *k, impact_real *mem, int n)
{
    for (int i = 0; i < MPC_NX; i++) mem[MPC_VX + i] = 0.0;
    for (int i = 0; i < MPC_NX * MPC_NX; i++) mem[MPC_VXX + i] = 0.0;
    mpc_add_cost_derivatives(mem + MPC_XS + n * MPC_NX, k, k[MPC_K_W_TERMINAL], mem + MPC_VX, mem + MPC_VXX);
    impact_real r = k[MPC_K_R];
    for (int j = n - 1; j >= 0; j--) {
        impact_real u = mem[MPC_PLAN + j];
        mpc_jacobian(mem + MPC_XS + j * MPC_NX, u, k, mem + MPC_JA, mem + MPC_JB);
        for (int a = 0; a < MPC_NX; a++) {
            for (int c = 0; c < MPC_NX; c++) {
                impact_real acc = 0.0;
                for (int m = 0; m < MPC_NX; m++)
                    acc += mem[MPC_VXX + a * MPC_NX + m] * mem[MPC_JA + m * MPC_NX + c];
                mem[MPC_VA + a * MPC_NX + c] = acc;
            }
            impact_real acc = 0.0;
            for (int m = 0; m < MPC_NX; m++) acc += mem[MPC_VXX + a * MPC_NX + m] * mem[MPC_JB + m];
            mem[MPC_VB + a] = acc;
        }
        impact_real qu = 2.0 * r * u;
        impact_real quu = 2.0 * r + k[MPC_K_MU];
        for (int m = 0; m < MPC_NX; m++) {
            qu += mem[MPC_JB + m] * mem[MPC_VX + m];
            quu += mem[MPC_JB + m] * mem[MPC_VB + m];
        }
        for (int c = 0; c < MPC_NX; c++) {
            impact_real acc = 0.0, acc2 = 0.0;
            for (int m = 0; m < MPC_NX; m++) {
                acc += mem[MPC_JA + m * MPC_NX + c] * mem[MPC_VX + m];
                acc2 += mem[MPC_JB + m] * mem[MPC_VA + m * MPC_NX + c];
            }
            mem[MPC_QX + c] = acc;
            mem[MPC_QUX + c] = acc2;
        }
        if (!(quu > 0.0 && isfinite(quu))) return 0;
        impact_real lo, hi;
        mpc_bounds(k, j > 0 ? mem[MPC_PLAN + j - 1] : mem[MPC_M_U_PREV], &lo, &hi);
        impact_real du = -qu / quu;
        int clamped = 1;
        if (u + du > hi) du = hi - u;
        else if (u + du < lo) du = lo - u;
        else clamped = 0;
        mem[MPC_FEED + j] = du;
        for (int c = 0; c < MPC_NX; c++)
            mem[MPC_GAINS + j * MPC_NX + c] = clamped ? 0.0 : -mem[MPC_QUX + c] / quu;
        for (int a = 0; a < MPC_NX; a++) {
            impact_real ka = mem[MPC_GAINS + j * MPC_NX + a];
            mem[MPC_VX + a] = mem[MPC_QX + a] + ka * (quu * du + qu) + mem[MPC_QUX + a] * du;
        }
        for (int a = 0; a < MPC_NX; a++) {
            impact_real ka = mem[MPC_GAINS + j * MPC_NX + a];
            for (int c = a; c < MPC_NX; c++) {
                impact_real kc = mem[MPC_GAINS + j * MPC_NX + c];
                impact_real acc = 0.0;
                for (int m = 0; m < MPC_NX; m++)
                    acc += mem[MPC_JA + m * MPC_NX + a] * mem[MPC_VA + m * MPC_NX + c];
                acc += quu * ka * kc + ka * mem[MPC_QUX + c] + mem[MPC_QUX + a] * kc;
                mem[MPC_VN + a * MPC_NX + c] = acc;
            }
        }
        for (int a = 0; a < MPC_NX; a++)
            for (int c = 0; c < MPC_NX; c++)
                mem[MPC_VXX + a * MPC_NX + c] = c >= a ? mem[MPC_VN + a * MPC_NX + c]
                                                       : mem[MPC_VN + c * MPC_NX + a];
        if (j > 0) mpc_add_cost_derivatives(mem + MPC_XS + j * MPC_NX, k, 1.0, mem + MPC_VX, mem + MPC_VXX);
    }
    return 1;
}

static int mpc_horizon(const impact_real *k)
{
    int n = k[MPC_K_HORIZON] >= 1.0 ? (int)k[MPC_K_HORIZON] : 1;
    return n <= MPC_NMAX ? n : MPC_NMAX;
}

static impact_real mpc_solve(const impact_real *k, impact_real *mem)
{
    int n = mpc_horizon(k);
    int iters = k[MPC_K_ITERATIONS] >= 0.0 ? (int)k[MPC_K_ITERATIONS] : 0;
    int halvings = k[MPC_K_LINE_SEARCH] >= 1.0 ? (int)k[MPC_K_LINE_SEARCH] : 1;
    impact_real cost = mpc_forward(k, mem, n, 0.0, 1);
    for (int it = 0; it < iters; it++) {
        if (!mpc_backward(k, mem, n)) { mem[MPC_M_NO_DESCENT] += 1.0; break; }
        impact_real alpha = 1.0, taken = 0.0, trial = 0.0;
        for (int t = 0; t < halvings; t++) {
            trial = mpc_forward(k, mem, n, alpha, 0);
            if (trial < cost) { taken = alpha; break; }
            alpha = 0.5 * alpha;
        }
        if (taken == 0.0) { mem[MPC_M_NO_DESCENT] += 1.0; break; }
        if (it < iters - 1) {
            cost = mpc_forward(k, mem, n, taken, 1);
        } else {
            for (int j = 0; j < n; j++) mem[MPC_PLAN + j] = mem[MPC_TRIAL + j];
            cost = trial;
        }
    }
    mem[MPC_M_COST] = cost;
    impact_real lo, hi;
    mpc_bounds(k, mem[MPC_M_U_PREV], &lo, &hi);
    return mpc_clip(mem[MPC_PLAN], lo, hi);
}

static impact_real mpc_tick(impact_real x1, impact_real v1, impact_real x2, impact_real v2,
                            const impact_real *k, impact_real *mem)
{
    int n = mpc_horizon(k);
    if (mem[MPC_M_STARTED] == 0.0) {
        for (int j = 0; j < MPC_NMAX; j++) mem[MPC_PLAN + j] = 0.0;
        for (int i = 0; i < MPC_NX; i++) mem[MPC_STATE + i] = 0.0;
        mem[MPC_M_U_PREV] = 0.0;
        mem[MPC_M_STARTED] = 1.0;
    }
    mem[MPC_STATE + 0] = x1; mem[MPC_STATE + 1] = v1; mem[MPC_STATE + 2] = x2; mem[MPC_STATE + 3] = v2;
    int ok = 1;
    for (int i = 0; i < MPC_NX; i++) if (!isfinite(mem[MPC_STATE + i])) ok = 0;
    impact_real u = 0.0;
    if (ok) {
        u = mpc_solve(k, mem);
        if (!isfinite(u)) ok = 0;
    }
    if (!ok) {
        mem[MPC_M_FALLBACKS] += 1.0;
        impact_real lo, hi;
        mpc_bounds(k, mem[MPC_M_U_PREV], &lo, &hi);
        u = mem[MPC_PLAN];
        u = isfinite(u) ? mpc_clip(u, lo, hi) : mpc_clip(0.0, lo, hi);
        for (int j = 0; j < MPC_NMAX; j++) mem[MPC_PLAN + j] = 0.0;
        for (int i = 4; i < MPC_NX; i++) mem[MPC_STATE + i] = 0.0;
    }
    impact_real s4 = mem[MPC_STATE + 4], s5 = mem[MPC_STATE + 5], s6 = mem[MPC_STATE + 6];
    mem[MPC_STATE + 4] = k[MPC_K_A00] * s4 + k[MPC_K_A01] * s5 + k[MPC_K_A02] * s6 + k[MPC_K_B0] * u;
    mem[MPC_STATE + 5] = k[MPC_K_A10] * s4 + k[MPC_K_A11] * s5 + k[MPC_K_A12] * s6 + k[MPC_K_B1] * u;
    mem[MPC_STATE + 6] = k[MPC_K_A20] * s4 + k[MPC_K_A21] * s5 + k[MPC_K_A22] * s6 + k[MPC_K_B2] * u;
    for (int j = 0; j < n - 1; j++) mem[MPC_PLAN + j] = mem[MPC_PLAN + j + 1];
    mem[MPC_M_U_PREV] = u;
    mem[MPC_M_TICKS] += 1.0;
    return u;
}
"""
