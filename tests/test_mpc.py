"""The MPC solver (impact_env.control.mpc) and the ``mpc-state`` law: its model's derivatives,
agreement with scipy's box-constrained optimiser on a linear case, hard constraints, the counted
fallback, determinism.  Every check drives the solver's kernels directly (small compiles)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from impact_env.control.laws import mpc_state
from impact_env.control.mpc import model, solver
from impact_env.scene import load_scene

RIG = load_scene("rig")
NX = model.NX


def constants(scene=RIG, **gains) -> np.ndarray:
    P = {key: p.from_scene(scene) if p.default is None else p.default for key, p in mpc_state.PARAMS.items()}
    P.update(gains)
    c = mpc_state.solver_constants(scene, P)
    return np.array([c[f] for f in model.Constants._fields])


def test_jacobian_matches_central_differences():
    """A and B of one period (contact, damped pad, shaker states) against central differences:
    relative error of a central difference with step h is O(h^2 f''') + O(eps / h), about 1e-5
    at h = 1e-7 of each entry's scale (the Tsuji term's d^-0.75 curvature dominates)."""
    k = constants(substeps=2.0)
    s = np.array([5e-4, 0.8, 1e-4, -0.1, 3.0, -2.0, 5.0])
    u = 50.0
    A = np.zeros(NX * NX)
    B = np.zeros(NX)
    model.jacobian(s, u, k, A, B)
    num = np.zeros((NX, NX))
    for j in range(NX):
        e = np.zeros(NX)
        e[j] = 1e-7 * max(abs(s[j]), 1e-3)
        hi, lo = np.zeros(NX), np.zeros(NX)
        model.step(s + e, u, k, hi)
        model.step(s - e, u, k, lo)
        num[:, j] = (hi - lo) / (2 * e[j])
    hi, lo = np.zeros(NX), np.zeros(NX)
    model.step(s, u + 1e-3, k, hi)
    model.step(s, u - 1e-3, k, lo)
    np.testing.assert_allclose(A.reshape(NX, NX), num, rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(B, (hi - lo) / 2e-3, rtol=1e-6, atol=1e-15)


def plan_cost(k, mem, u):
    """The solver's predicted cost (J) of the plan u from the state in mem (the same forward pass)."""
    m = mem.copy()
    m[solver.PLAN:solver.PLAN + u.size] = u
    return solver.forward(k, m, u.size, 0.0, False)


def test_linear_case_agrees_with_scipy():
    """Body 1 far above the pad (no contact within the horizon): the model is linear and the cost
    (body 2's energy, weight w2, plus body 1's energy, linear in x2, plus r u^2) quadratic, so the
    condensed problem is a box-constrained QP, strictly convex (Hessian >= 2 r).  The reference
    solves it with L-BFGS-B (scipy) on the exact quadratic (gradient and Hessian from the
    solver's own cost function: second differences of a quadratic are exact to rounding).  With
    the limit at 3 N against the 10 N of the displaced suspension, the box binds.

    Tolerance: both plans are feasible and the QP is lambda-strongly convex, so
    J(u) - J* >= lambda/2 |u - u*|^2: a cost gap below 1e-9 J relative bounds the plan gap by
    sqrt(2 * gap / lambda)."""
    n = 20
    scene = RIG.with_overrides({"effects.saturation.peak_n": 3.0, "effects.saturation.continuous_n": 0.0})
    k = constants(scene, horizon=float(n), iterations=30.0, line_search=30.0, r=1e-6, w2=1.0,
                  w_terminal=1.0)
    mem = np.zeros(solver.MEMORY)
    mem[solver.STATE:solver.STATE + NX] = [-5e-3, 0.0, 1e-3, 0.05, 0.0, 0.0, 0.0]
    mem[solver.MEM.started] = 1.0
    work = mem.copy()
    solver.solve(k, work)
    u_mpc = work[solver.PLAN:solver.PLAN + n].copy()
    assert work[solver.MEM.no_descent] <= 30

    # the exact quadratic J(u) = c + g u + u' H u / 2, from the solver's cost of the plan
    J0 = plan_cost(k, mem, np.zeros(n))
    E = np.eye(n)
    Jp = np.array([plan_cost(k, mem, E[i]) for i in range(n)])
    Jm = np.array([plan_cost(k, mem, -E[i]) for i in range(n)])
    g = (Jp - Jm) / 2
    H = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            if i == j:
                H[i, j] = Jp[i] + Jm[i] - 2 * J0
            else:
                H[i, j] = plan_cost(k, mem, E[i] + E[j]) - Jp[i] - Jp[j] + J0
    H = (H + H.T) / 2
    lam = np.linalg.eigvalsh(H).min()
    assert lam >= 1.9e-6  # 2 r, the input weight's curvature

    def quad(u):
        return J0 + g @ u + 0.5 * u @ H @ u, g + H @ u

    ref = minimize(quad, np.zeros(n), jac=True, method="L-BFGS-B", bounds=[(-3.0, 3.0)] * n,
                   options={"ftol": 1e-15, "gtol": 1e-13, "maxiter": 10_000})
    assert ref.success
    j_mpc, j_ref = quad(u_mpc)[0], quad(ref.x)[0]
    assert np.isclose(j_mpc, plan_cost(k, mem, u_mpc), rtol=1e-9)  # the quadratic is the solver's cost
    gap = abs(j_mpc - j_ref)
    assert gap <= 1e-9 * abs(j_ref), (j_mpc, j_ref)
    assert np.max(np.abs(u_mpc)) == 3.0  # the limit binds ...
    assert np.max(np.abs(u_mpc - ref.x)) <= np.sqrt(2 * 1e-9 * abs(j_ref) / lam)  # ... and the plans agree


def closed_loop(k, ticks, x0, nan_at=-1):
    """Ticks of mpc_tick with the prediction model itself as the plant (forces, plans, memory)."""
    mem = np.zeros(solver.MEMORY)
    s = np.array(x0, dtype=float)
    nxt = np.zeros(NX)
    out, plans = [], []
    for t in range(ticks):
        x = s.copy()
        if t == nan_at:
            x[1] = np.nan
        u = solver.mpc_tick(x[0], x[1], x[2], x[3], k, mem)
        out.append(u)
        plans.append(mem[solver.PLAN:solver.PLAN + solver.horizon_of(k)].copy())
        model.step(s, u, k, nxt)
        s = nxt.copy()
    return np.array(out), np.array(plans), mem


DROP = [-2e-4, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]  # 0.2 ms before the touch at 1 m/s


@pytest.mark.parametrize("peak, slew", [(200.0, 0.0), (30.0, 0.0), (200.0, 2e5), (30.0, 3e4)])
def test_constraints_hold_on_every_tick_and_every_plan(peak, slew):
    """Force limit and slew are hard: the output and every input of every plan lie in the box
    (the slew measured from the output before; the box's ends are u_before +- slew, so rounding
    is the only excess: 1e-12 N)."""
    scene = RIG.with_overrides({"effects.saturation.peak_n": peak, "effects.saturation.continuous_n": 0.0,
                                "effects.saturation.slew_n_per_s": slew})
    k = constants(scene, iterations=2.0)
    u, plans, _ = closed_loop(k, 120, DROP)
    step = slew / scene.control_rate
    assert np.all(np.abs(u) <= peak) and np.all(np.abs(plans) <= peak)
    assert np.max(np.abs(u)) == peak  # the limit is reached: the test exercises saturation
    if slew > 0:
        du = np.diff(np.concatenate([[0.0], u]))
        assert np.all(np.abs(du) <= step + 1e-12), np.abs(du).max()
        assert np.max(np.abs(du)) >= step * (1 - 1e-12)  # ... and the slew limit
        inner = np.diff(plans, axis=1)  # (a plan is stored shifted: its first input follows u)
        assert np.all(np.abs(plans[:, 0] - u) <= step + 1e-12)
        assert np.all(np.abs(inner) <= step + 1e-12)


def test_fallback_is_counted_and_stays_in_the_box():
    """A non-finite state (tick 5) falls back to the previous plan's input, counted once; the
    next ticks solve again (no further fallback) and the output stays finite and in the box."""
    k = constants()
    u, _, mem = closed_loop(k, 40, DROP, nan_at=5)
    assert mem[solver.MEM.fallbacks] == 1.0 and mem[solver.MEM.ticks] == 40.0
    assert np.all(np.isfinite(u)) and np.all(np.abs(u) <= 200.0)
    ok = closed_loop(k, 40, DROP)[2]
    assert ok[solver.MEM.fallbacks] == 0.0


def test_results_are_deterministic():
    k = constants(iterations=2.0)
    a = closed_loop(k, 80, DROP)
    b = closed_loop(k, 80, DROP)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[2], b[2])
    assert np.max(np.abs(a[0])) > 10.0  # it acts


def test_the_law_runs_from_the_registry():
    """``mpc-state`` as a policy (the compiled law kernel behind compare and the rig's tick)
    gives the solver's force, clipped to the command scale, and counts in its memory row."""
    from baselines import make_policy

    pol = make_policy("mpc-state:horizon=30", RIG)
    assert pol.observation == "privileged" and pol.memory_size >= solver.MEMORY  # (the packed row of every law)
    k = constants(horizon=30.0)
    mem = np.zeros(solver.MEMORY)
    want = solver.mpc_tick(DROP[0], DROP[1], DROP[2], DROP[3], k, mem)
    state = np.zeros((1, pol.memory_size))
    got = pol.force(np.array([DROP[:4]]), state)
    assert got[0] == want and state[0, solver.MEM.ticks] == 1.0


def test_c_text_is_bitwise_the_kernel(tmp_path):
    """The solver's C text (impact_env.control.mpc.c_text), built in double with the export's
    flags (-ffp-contract=off), gives bitwise the numba kernel's forces and memory on the ticks of
    a closed loop (saturation, slew and a fallback included)."""
    import ctypes

    from impact_env.control.mpc import c_text
    from impact_env.deploy import parity

    src = tmp_path / "mpc.c"
    src.write_text("#include <math.h>\ntypedef double impact_real;\n" + c_text.solver_c() + r"""
void run(const double *k, double *mem, const double *states, int n, double *out)
{
    for (int t = 0; t < n; t++)
        out[t] = mpc_tick(states[4 * t], states[4 * t + 1], states[4 * t + 2], states[4 * t + 3], k, mem);
}
""")
    lib = tmp_path / "libmpc.so"
    import subprocess

    subprocess.run([parity.find_cc(), *parity.CFLAGS, "-fPIC", "-shared", "-o", str(lib), str(src), "-lm"],
                   check=True)
    run = ctypes.CDLL(str(lib)).run
    scene = RIG.with_overrides({"effects.saturation.peak_n": 120.0, "effects.saturation.continuous_n": 0.0,
                                "effects.saturation.slew_n_per_s": 4e5})
    k = constants(scene, iterations=2.0, substeps=2.0)
    ticks = 60
    mem = np.zeros(solver.MEMORY)
    s = np.array(DROP, dtype=float)
    nxt = np.zeros(NX)
    states, want = [], []
    for t in range(ticks):
        x = s[:4].copy()
        if t == 7:
            x[2] = np.inf
        states.append(x)
        want.append(solver.mpc_tick(x[0], x[1], x[2], x[3], k, mem))
        model.step(s, want[-1], k, nxt)
        s = nxt.copy()
    cmem = np.zeros(solver.MEMORY)
    got = np.zeros(ticks)
    st = np.ascontiguousarray(np.array(states))
    dbl = ctypes.POINTER(ctypes.c_double)
    run(k.ctypes.data_as(dbl), cmem.ctypes.data_as(dbl), st.ctypes.data_as(dbl), ctypes.c_int(ticks),
        got.ctypes.data_as(dbl))
    assert mem[solver.MEM.fallbacks] == 1.0 and np.max(np.abs(want)) == 120.0
    assert np.array_equal(got, np.array(want)) and np.array_equal(cmem, mem)
