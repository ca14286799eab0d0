"""Slow, obvious references for the plant kernels (pure Python / numpy / scipy).

Nothing here is compiled or clever: the point is to be easy to check by eye against the
physics (thesis eq 2.7/2.8 with the Hertz-Tsuji pad) and so to catch the compiled kernels'
mistakes.  It imports nothing of impact_env, so it stays an independent oracle; it sits in the
package so that the tests and the benchmark scripts (``scripts/work_precision.py``,
``scripts/split_accuracy.py``, ``scripts/bench_plant.py``) share one copy.
Frame as in :mod:`impact_env.plant.layout`: x points down, penetration
``d = x1 - x2``, shaker force f2 on body 2 positive upwards.

State ``y = [x1, v1, x2, v2, W_ext, W_diss]`` (m, m/s, m, m/s, J, J); parameters are passed
by name.

* :func:`rhs` - the right-hand side with the force switched inside it (the kernels' ``AUTO``
  mode): ``F = c d^1.5 + b d^0.25 d'`` clipped at 0 for d > 0, zero otherwise.
* :func:`euler_step`, :func:`symplectic_euler_step`, :func:`rk4_step` and :func:`run_fixed` -
  plain fixed-step steppers (optionally with a zero-order-held shaker force).
* :func:`reference_drop` - ``scipy.integrate.solve_ivp`` (DOP853, rtol 1e-12) with a terminal
  contact event, restarted in the other mode at each event; returns the events and the states.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp


@dataclass(frozen=True)
class Params:
    """Plant parameters, SI (see :mod:`impact_env.plant.layout`)."""

    m1: float = 0.1
    m2: float = 1.0
    c: float = 2.0e6
    b: float = 0.0
    g: float = 9.81
    k2: float = 0.0
    c2: float = 0.0

    @classmethod
    def from_array(cls, p) -> Params:
        """From the plant's parameter array (``Trajectory.params``)."""
        from impact_env.plant.layout import PARAM

        return cls(m1=float(p[PARAM.m1]), m2=float(p[PARAM.m2]), c=float(p[PARAM.c]), b=float(p[PARAM.b]),
                   g=float(p[PARAM.g]), k2=float(p[PARAM.k2]), c2=float(p[PARAM.c2]))


# --------------------------------------------------------------------------------------------
# right-hand sides
# --------------------------------------------------------------------------------------------

def pad_force(d: float, dd: float, p: Params) -> tuple[float, float]:
    """(total, elastic) pad force (N) for penetration d (m) and rate dd (m/s); zero if d <= 0,
    and the total force never negative."""
    if d <= 0.0:
        return 0.0, 0.0
    fe = p.c * d**1.5
    f = fe + p.b * d**0.25 * dd
    return max(f, 0.0), fe


def rhs(y, p: Params, f2: float = 0.0) -> list[float]:
    """dy/dt for state y (6 entries) under the constant shaker force f2 (N, upwards on body 2)."""
    x1, v1, x2, v2 = y[0], y[1], y[2], y[3]
    d = x1 - x2
    dd = v1 - v2
    f, fe = pad_force(d, dd, p)
    a1 = p.g - f / p.m1  # the pad pushes body 1 up (negative x)
    a2 = (f - f2 - p.k2 * x2 - p.c2 * v2) / p.m2  # ... and body 2 down; the shaker pushes it up
    power_ext = -f2 * v2  # shaker's power into the system
    power_diss = (f - fe) * dd + p.c2 * v2 * v2  # pad damping (and clipping) + suspension damper
    return [v1, a1, v2, a2, power_ext, power_diss]


def rhs_mode(y, p: Params, f2: float, contact: bool) -> list[float]:
    """dy/dt with the contact mode fixed (for the event-restarted reference).

    In contact the force is ``c d^1.5 + b d^0.25 d'`` without clipping (the force-zero event
    ends the phase first) and, past d = 0, the smooth odd extension ``c d |d|^0.5`` so that the
    solver's trial stages never take a power of a negative number.  In free flight it is zero
    (the W_diss rate books ``-c d^1.5 d'`` while d > 0 after a damped separation, as in :func:`rhs`).
    """
    x1, v1, x2, v2 = y[0], y[1], y[2], y[3]
    d = x1 - x2
    dd = v1 - v2
    if contact and d > 0.0:
        fe = p.c * d**1.5
        f = fe + p.b * d**0.25 * dd
    elif contact:
        fe = p.c * d * math.sqrt(-d)
        f = fe
    else:  # free: no force, but a penetration left after the damped force fell to zero
        # still holds elastic energy, which the ledger books as dissipated when it is released
        f = 0.0
        fe = p.c * d**1.5 if d > 0.0 else 0.0
    a1 = p.g - f / p.m1
    a2 = (f - f2 - p.k2 * x2 - p.c2 * v2) / p.m2
    return [v1, a1, v2, a2, -f2 * v2, (f - fe) * dd + p.c2 * v2 * v2]


def switching_function(y, p: Params) -> float:
    """Positive in contact, negative in free flight: ``min(d, q)`` with
    ``q = sign * |d^1.25 + (b/c) d'|^0.8``; its zero is the touch (d = 0) or the point where the
    damped force falls to zero while d > 0 (the same function the kernels use)."""
    d = y[0] - y[2]
    if d <= 0.0 or p.b == 0.0:
        return d
    q = d**1.25 + (p.b / p.c) * (y[1] - y[3])
    r = math.copysign(abs(q) ** 0.8, q)
    return min(d, r)


# --------------------------------------------------------------------------------------------
# fixed-step steppers (force switched inside the rhs)
# --------------------------------------------------------------------------------------------

def euler_step(y, h, p: Params, f2: float = 0.0) -> list[float]:
    """Explicit Euler (thesis eq 3.8)."""
    k = rhs(y, p, f2)
    return [y[i] + h * k[i] for i in range(6)]


def symplectic_euler_step(y, h, p: Params, f2: float = 0.0) -> list[float]:
    """Semi-implicit Euler: velocities from the old state, positions from the new velocities."""
    k = rhs(y, p, f2)
    v1 = y[1] + h * k[1]
    v2 = y[3] + h * k[3]
    return [y[0] + h * v1, v1, y[2] + h * v2, v2, y[4] - f2 * h * v2, y[5] + h * k[5]]


def rk4_step(y, h, p: Params, f2: float = 0.0) -> list[float]:
    """Classic fourth-order Runge-Kutta."""
    k1 = rhs(y, p, f2)
    k2 = rhs([y[i] + 0.5 * h * k1[i] for i in range(6)], p, f2)
    k3 = rhs([y[i] + 0.5 * h * k2[i] for i in range(6)], p, f2)
    k4 = rhs([y[i] + h * k3[i] for i in range(6)], p, f2)
    return [y[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) for i in range(6)]


STEPPERS = {"euler": euler_step, "symplectic-euler": symplectic_euler_step, "rk4": rk4_step}


def run_fixed(y0, p: Params, dt: float, n_steps: int, method: str = "rk4", f2=0.0,
              control_every: int = 1) -> np.ndarray:
    """Take ``n_steps`` steps of ``method``; return the states, shape (n_steps + 1, 6).

    f2: a constant force (N) or a callable ``f2(t, y4)`` sampled every ``control_every`` steps
    and held in between (zero-order hold, as ``impact_env.simulate`` does).
    """
    step = STEPPERS[method]
    y = [float(v) for v in y0]
    if len(y) == 4:
        y += [0.0, 0.0]
    out = np.empty((n_steps + 1, 6))
    out[0] = y
    force = float(f2) if not callable(f2) else 0.0
    for i in range(n_steps):
        if callable(f2) and i % control_every == 0:
            force = float(f2(i * dt, np.array(y[:4])))
        y = step(y, dt, p, force)
        out[i + 1] = y
    return out


# --------------------------------------------------------------------------------------------
# solve_ivp reference with event restarts
# --------------------------------------------------------------------------------------------

@dataclass
class Reference:
    """Result of :func:`reference_drop`.

    events: rows (t, kind, x1, v1, x2, v2) like ``Trajectory.events`` (kind +1 onset, -1 separation).
    t, y: the states at the requested output times (y has shape (len(t), 6)).
    y_end: the state at t_end.  peak_force, max_penetration: the largest pad force (N) and
    penetration (m), from the dense output of each contact phase (0 if ``peak_samples=0``).
    """

    events: np.ndarray
    t: np.ndarray
    y: np.ndarray
    y_end: np.ndarray
    peak_force: float
    max_penetration: float
    n_rhs: int

    def restitution(self) -> float | None:
        on = self.events[self.events[:, 1] > 0]
        off = self.events[self.events[:, 1] < 0]
        if len(on) == 0:
            return None
        later = off[off[:, 0] > on[0, 0]]
        if len(later) == 0:
            return None
        return float(-(later[0, 3] - later[0, 5]) / (on[0, 3] - on[0, 5]))

    def first_contact_duration(self) -> float | None:
        on = self.events[self.events[:, 1] > 0]
        off = self.events[self.events[:, 1] < 0]
        if len(on) == 0:
            return None
        later = off[off[:, 0] > on[0, 0]]
        return float(later[0, 0] - on[0, 0]) if len(later) else None


def reference_drop(p: Params, y0, t_end: float, f2: float = 0.0, t_eval=None, rtol: float = 1e-12,
                   atol=None, t0: float = 0.0, max_events: int = 10_000,
                   peak_samples: int = 200) -> Reference:
    """Integrate the two-body impact with solve_ivp (DOP853), switching mode at each contact event.

    y0: [x1, v1, x2, v2] (or 6 entries with the energy ledgers).  f2: constant shaker force (N).
    In free flight the terminal event is the switching function crossing zero upwards (touch, or
    the damped force turning positive again), in contact it crossing downwards (d = 0, or the
    damped force falling to zero); the integration restarts from the located event state in the
    other mode.  atol: defaults to ``1e-2 * rtol`` times a natural scale per component (Hertz
    penetration at the current relative speed, that speed, the kinetic energy).
    peak_samples: samples of each contact phase's dense output searched for the peak force
    and penetration (0: skip, e.g. when timing the solver).
    """
    y = np.zeros(6)
    y[: len(y0)] = y0
    if atol is None:
        v = max(abs(y[1] - y[3]), abs(y[1]), abs(y[3]), 1e-3)
        m = p.m1 * p.m2 / (p.m1 + p.m2)
        dscale = (5.0 * m * v * v / (4.0 * p.c)) ** 0.4
        escale = 0.5 * p.m1 * v * v
        atol = 1e-2 * rtol * np.array([dscale, v, dscale, v, escale, escale])
    contact = switching_function(y, p) > 0.0
    t = t0
    events: list[list[float]] = []
    t_eval = None if t_eval is None else np.asarray(t_eval, dtype=float)
    ts: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    peak = 0.0
    dmax = max(y[0] - y[2], 0.0)
    n_rhs = 0
    while t < t_end:
        mode = contact

        def fun(_t, yy, mode=mode):
            return rhs_mode(yy, p, f2, mode)

        # the restart state sits on the switch; an offset of a few rounding errors of the
        # positions keeps the solver from finding the same switch again in rounding noise
        tiny = 16.0 * np.finfo(float).eps * max(abs(y[0]), abs(y[2]), 1e-300)
        offset = -tiny if mode else tiny

        def ev(_t, yy, offset=offset):
            return switching_function(yy, p) - offset

        # solve_ivp reads an event's settings from attributes of the function (its documented API)
        ev.terminal = True  # type: ignore[attr-defined]
        ev.direction = -1.0 if mode else 1.0  # type: ignore[attr-defined]
        seg_eval = None
        if t_eval is not None:
            seg_eval = t_eval[(t_eval >= t) & (t_eval <= t_end)]
        sol = solve_ivp(fun, (t, t_end), y, method="DOP853", rtol=rtol, atol=atol, events=ev,
                        dense_output=bool(peak_samples) or t_eval is not None)
        n_rhs += sol.nfev
        if sol.status < 0:
            raise RuntimeError(f"solve_ivp failed at t={t}: {sol.message}")
        t_stop = sol.t[-1]
        if seg_eval is not None and len(seg_eval):
            sel = seg_eval[seg_eval <= t_stop] if sol.status == 1 else seg_eval
            if len(sel):
                ts.append(sel)
                ys.append(sol.sol(sel).T)
                t_eval = t_eval[t_eval > sel[-1]]
        if mode and peak_samples:
            # peak force and penetration of this contact phase from the dense output
            tt = np.linspace(t, t_stop, peak_samples)
            yy = sol.sol(tt)
            d = yy[0] - yy[2]
            k = int(np.argmax(d))
            dmax = max(dmax, _refine_max(sol, tt, k, lambda z: z[0] - z[2]))
            fk = [pad_force(d[i], yy[1, i] - yy[3, i], p)[0] for i in range(len(tt))]
            j = int(np.argmax(fk))
            peak = max(peak, _refine_max(sol, tt, j,
                                         lambda z: pad_force(z[0] - z[2], z[1] - z[3], p)[0]))
        if sol.status == 1:
            te = float(sol.t_events[0][0])
            ye = np.array(sol.y_events[0][0], dtype=float)
            contact = not contact
            events.append([te, 1.0 if contact else -1.0, ye[0], ye[1], ye[2], ye[3]])
            if len(events) > max_events:
                raise RuntimeError("too many contact events")
            t, y = te, ye
        else:
            t, y = t_end, sol.y[:, -1].copy()
    tt = np.concatenate(ts) if ts else np.empty(0)
    yy = np.concatenate(ys) if ys else np.empty((0, 6))
    return Reference(events=np.array(events).reshape(-1, 6), t=tt, y=yy, y_end=np.array(y),
                     peak_force=peak, max_penetration=dmax, n_rhs=n_rhs)


def _refine_max(sol, tt, k, fn) -> float:
    """Maximum of fn(state) near sample k of the dense output (golden-section on the bracket)."""
    lo = tt[max(k - 1, 0)]
    hi = tt[min(k + 1, len(tt) - 1)]
    gr = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = lo, hi
    for _ in range(80):
        c1 = b - gr * (b - a)
        c2 = a + gr * (b - a)
        if fn(sol.sol(c1)) < fn(sol.sol(c2)):
            a = c1
        else:
            b = c2
    return max(fn(sol.sol(0.5 * (a + b))), fn(sol.sol(tt[k])))


def free_fall_start(v: float, g: float, tau: float) -> list[float]:
    """State [x1, v1, x2, v2] a time tau before body 1 touches body 2 (at rest at 0) at speed v."""
    return [-(v * tau - 0.5 * g * tau * tau), v - g * tau, 0.0, 0.0]


# --------------------------------------------------------------------------------------------
# scene overrides for the tests and scripts that compare against these references
# --------------------------------------------------------------------------------------------

def sim_overrides(method: str = "rk4", dt: float = 1e-6, rtol: float = 1e-9, events: bool = True,
                  control_rate: float | None = None, **kw) -> dict:
    """Dotted overrides for ``impact_env.simulate``: the integrator, a control rate that fits
    it (every step for fixed-step methods, ``control_rate`` or 1 MHz for dopri5), and plant /
    initial keys given as ``plant_m1=...`` or ``initial_impact_speed=...`` (first ``_`` -> ``.``)."""
    ov = {"integrator.method": method, "integrator.dt": dt, "integrator.rtol": rtol,
          "integrator.event_location": events}
    if control_rate is None:
        control_rate = 1.0 / dt if method != "dopri5" else 1e6
    ov["control.rate"] = control_rate
    for k, v in kw.items():
        head, _, rest = k.partition("_")
        ov[f"{head}.{rest}"] = v
    return ov
