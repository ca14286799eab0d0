"""``simulate``: the headless entry point (scripts, baselines and tests use it).

It validates the scene, converts it to the plant's arrays, runs the compiled kernel period by
period (a control law is sampled once per control period and held, zero-order hold) and wraps
the result in a :class:`Trajectory`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from impact_env.plant import layout as L
from impact_env.plant.energy import catch_energy, energies
from impact_env.plant.hertz import max_contact_frequency, max_penetration
from impact_env.plant.restitution import tsuji_damping
from impact_env.plant.run import run_periods
from impact_env.scene import Scene, load_scene

METHOD_CODES = {"euler": L.EULER, "symplectic-euler": L.SYMPLECTIC_EULER, "rk4": L.RK4, "dopri5": L.DOPRI5}
# largest stable omega*dt of each fixed-step method on an undamped oscillator
# (RK4: 2*sqrt(2) on the imaginary axis; symplectic Euler: 2); explicit Euler grows for any
# step, we refuse steps past omega*dt = 1 where it gains over 40 % amplitude per step.
STABILITY_LIMIT = {"euler": 1.0, "symplectic-euler": 2.0, "rk4": 2.0 * math.sqrt(2.0)}
MAX_RECORDS = 20_000_000


class SimulationDiverged(RuntimeError):
    """The integration left the finite range; carries the time and the last finite state."""

    def __init__(self, message: str, t: float, state: np.ndarray):
        super().__init__(message)
        self.t = t
        self.state = state


def plant_params(scene: Scene, zeta_of: Callable[[float], float] | None = None) -> np.ndarray:
    """The plant's parameter array for a scene (see :mod:`impact_env.plant.layout`).

    ``zeta_of``: the scaled damping for a restitution (default: the exact solve,
    :func:`~impact_env.plant.restitution.zeta_for_restitution`; the Simulator passes a
    :class:`~impact_env.plant.restitution.ZetaTable` for drawn restitutions).
    """
    pl = scene.plant
    p = np.zeros(L.N_PARAM)
    p[L.M1], p[L.M2], p[L.C], p[L.G] = pl.m1, pl.m2, pl.c, pl.gravity
    if pl.restitution >= 1.0:
        p[L.B] = 0.0
    elif zeta_of is None:
        p[L.B] = tsuji_damping(pl.restitution, pl.m1, pl.m2, pl.c)
    else:
        p[L.B] = zeta_of(pl.restitution) * math.sqrt(pl.effective_mass * pl.c)
    p[L.K2], p[L.C2] = pl.suspension_stiffness, pl.suspension_damping
    return p


def initial_state(scene: Scene) -> tuple[np.ndarray, float]:
    """State at the start and the time of the first touch after it (s).

    Free fall is solved in closed form; the run starts ``pre_contact_time`` before the touch,
    or at the release if the fall is shorter.
    """
    return free_fall_state(scene.impact_speed, scene.plant.gravity, scene.initial.pre_contact_time)


def free_fall_state(v: float, g: float, tau: float) -> tuple[np.ndarray, float]:
    """:func:`initial_state` from the impact speed v (m/s), gravity g and pre-contact time tau."""
    if g > 0:  # a body released from rest has fallen for v/g only
        tau = min(tau, v / g)
    y = np.zeros(L.N_STATE)
    y[L.X1] = -(v * tau - 0.5 * g * tau * tau)
    y[L.V1] = v - g * tau
    return y, tau


def check_stability(scene: Scene) -> None:
    """Refuse, before simulating, a fixed step beyond the method's stability limit for the
    stiffest contact oscillation the scene's drop will excite."""
    method = scene.integrator.method
    if method == "dopri5":
        return
    pl = scene.plant
    m = pl.effective_mass
    v = scene.impact_speed
    d = max(max_penetration(m, pl.c, v) if v > 0 else 0.0, pl.static_penetration)
    if d <= 0:
        return
    omega = max_contact_frequency(m, pl.c, d)
    limit = STABILITY_LIMIT[method] / omega
    if scene.integrator.dt > limit:
        tc = 2.9432751843247047 * d / v if v > 0 else 2 * math.pi / omega
        raise ValueError(
            f"integrator.dt = {scene.integrator.dt:g} s is beyond the stability limit of {method} "
            f"for this contact: it needs dt < {limit:.3g} s (omega*dt < {STABILITY_LIMIT[method]:.3g}, "
            f"contact time about {tc:.3g} s, penetration up to {d:.3g} m). "
            "Reduce integrator.dt or use integrator.method = dopri5.")


@dataclass
class Trajectory:
    """A simulated run, sampled at the record rate (state at each sample time).

    Frame: x down, body 2's rest surface at 0; ``d = x1 - x2`` is the penetration.
    ``events`` has one row per contact onset (+1) or separation (-1): t (s), kind, x1, v1, x2, v2.
    """

    t: np.ndarray  # s
    x1: np.ndarray  # m
    v1: np.ndarray  # m/s
    x2: np.ndarray  # m
    v2: np.ndarray  # m/s
    contact: np.ndarray  # bool, in contact at the sample
    contact_force: np.ndarray  # N, at the sample
    peak_force: np.ndarray  # N, largest contact force seen within the interval ending at the sample
    shaker_force: np.ndarray  # N (upwards), held over the interval ending at the sample
    work_shaker: np.ndarray  # J, work done by the shaker since t = 0
    dissipated: np.ndarray  # J, energy dissipated since t = 0
    events: np.ndarray
    t_first_contact: float  # s, the time of the first touch (from the initial condition)
    scene: Scene
    params: np.ndarray
    wall_time_s: float = 0.0
    n_events_dropped: int = 0
    extras: dict = field(default_factory=dict)

    @property
    def penetration(self) -> np.ndarray:
        return self.x1 - self.x2

    def energies(self) -> dict[str, np.ndarray]:
        p = self.params
        return energies(self.x1, self.v1, self.x2, self.v2, p[L.M1], p[L.M2], p[L.C], p[L.G], p[L.K2])

    def catch_energy(self) -> np.ndarray:
        """Body 1's energy above resting on body 2 (J); see :func:`plant.energy.catch_energy`."""
        p = self.params
        return catch_energy(self.x1, self.v1, self.x2, p[L.M1], p[L.C], p[L.G])

    def energy_balance_error(self) -> float:
        """max |E(t) + dissipated(t) - work_shaker(t) - E(0)| / E_scale over the run, E_scale the
        larger of the initial total and the initial catch energy."""
        e = self.energies()["total"]
        resid = e + self.dissipated - self.work_shaker - e[0]
        scale = max(abs(e[0]), float(self.catch_energy()[0]), 1e-300)
        return float(np.max(np.abs(resid)) / scale)

    def onsets(self) -> np.ndarray:
        return self.events[self.events[:, 1] > 0]

    def separations(self) -> np.ndarray:
        return self.events[self.events[:, 1] < 0]

    def restitution(self) -> float | None:
        """Relative separation speed over relative impact speed at the first separation."""
        on, off = self.onsets(), self.separations()
        if len(on) == 0 or len(off) == 0:
            return None
        vin = on[0, 3] - on[0, 5]
        first_off = off[off[:, 0] > on[0, 0]]
        if len(first_off) == 0 or vin == 0:
            return None
        return float(-(first_off[0, 3] - first_off[0, 5]) / vin)

    def first_contact_duration(self) -> float | None:
        on, off = self.onsets(), self.separations()
        if len(on) == 0:
            return None
        later = off[off[:, 0] > on[0, 0]]
        return float(later[0, 0] - on[0, 0]) if len(later) else None

    def max_penetration(self) -> float:
        """Largest penetration (m), refined by a parabola through the three samples at the peak."""
        d = self.penetration
        k = int(np.argmax(d))
        if 0 < k < len(d) - 1:
            a, b, c = d[k - 1], d[k], d[k + 1]
            den = a - 2 * b + c
            if den < 0:
                return float(b - 0.125 * (c - a) ** 2 / den)
        return float(d[k])

    def time_to_fraction(self, fraction: float = 0.01) -> float | None:
        """Time from the first touch after which body 1's catch energy stays below ``fraction``
        of its initial value; None if it is above at the end of the run."""
        e = self.catch_energy()
        above = np.nonzero(e >= fraction * e[0])[0]
        if len(above) == 0:
            return 0.0
        last = above[-1]
        if last == len(e) - 1:
            return None
        return float(max(self.t[last + 1] - self.t_first_contact, 0.0))

    def metrics(self) -> dict:
        """The summary of a drop (the fields ``impact-env drop --json`` prints)."""
        return {
            "max_penetration_m": self.max_penetration(),
            "first_contact_duration_s": self.first_contact_duration(),
            "peak_contact_force_N": float(max(self.peak_force.max(), self.contact_force.max())),
            "restitution": self.restitution(),
            "energy_balance_error": self.energy_balance_error(),
            "time_to_1pct_energy_s": self.time_to_fraction(0.01),
            "n_contacts": int(len(self.onsets())),
            "wall_time_s": self.wall_time_s,
        }


Controller = Callable[[float, np.ndarray], float]


def simulate(scene: Scene | str, controller: Controller | None = None, t_end: float | None = None,
             record_rate: float | None = None, max_events: int = 100_000, overrides=None,
             rng: np.random.Generator | int | None = None) -> Trajectory:
    """Simulate one drop.

    scene: a Scene or preset name (``overrides``: dotted keys applied on top).
    rng: for a scene with ``[randomize]`` ranges, the numpy Generator (or an int seed) that draws
        this drop's values (:meth:`Scene.sample`, the seed policy of :mod:`impact_env.randomize`);
        without it the scene's nominal values are used.  ``traj.scene`` is the drawn scene.
    controller: ``f(t, y) -> f2``, the shaker force (N, upwards) from the time (s) and the true
        state ``y = [x1, v1, x2, v2]``; sampled once per control period and held.  None: no force.
    t_end: simulated time (s); default ``scene.episode.horizon``.
    record_rate: samples per second in the Trajectory (default: the control rate); must divide it
        (or, without a controller, any rate whose period is a whole number of integration steps).
    """
    scene = load_scene(scene, overrides)
    if rng is not None and scene.randomized:
        scene = scene.sample(rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng))
    t_end = scene.episode.horizon if t_end is None else float(t_end)
    if not (t_end > 0 and math.isfinite(t_end)):
        raise ValueError(f"t_end = {t_end!r} s must be a finite time > 0 s")
    check_stability(scene)
    integ = scene.integrator
    method = METHOD_CODES[integ.method]
    ctrl_period = scene.control_period
    record_rate = scene.control_rate if record_rate is None else float(record_rate)
    if not (record_rate > 0 and math.isfinite(record_rate)):
        raise ValueError(f"record_rate = {record_rate!r} Hz must be > 0 Hz")
    rec_period = 1.0 / record_rate
    if controller is None:
        per = rec_period / integ.dt if integ.method != "dopri5" else 1.0
        if integ.method != "dopri5" and (per < 1 - 1e-9 or abs(per - round(per)) > 1e-6 * per):
            raise ValueError(f"record_rate = {record_rate:g} Hz: its period must be a whole number "
                             f"of integration steps (integrator.dt = {integ.dt:g} s)")
        sub = 1
    else:
        ratio = rec_period / ctrl_period
        if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6 * ratio:
            raise ValueError(f"record_rate = {record_rate:g} Hz must divide control.rate = "
                             f"{scene.control_rate:g} Hz")
        sub = int(round(ratio))
    n = int(round(t_end / rec_period))
    if n < 1:
        raise ValueError(f"t_end = {t_end:g} s is shorter than one record period ({rec_period:g} s)")
    if n > MAX_RECORDS:
        raise ValueError(f"{n} samples requested (t_end {t_end:g} s at {record_rate:g} Hz); "
                         f"lower record_rate to at most {MAX_RECORDS / t_end:g} Hz")

    p = plant_params(scene)
    y, t_touch = initial_state(scene)
    mode = L.AUTO
    if integ.event_location or integ.method == "dopri5":
        from impact_env.plant.dynamics import event_value

        mode = L.CONTACT if event_value(y[0], y[1], y[2], y[3], p[L.C], p[L.B]) > 0 else L.FREE
        if not integ.event_location:
            mode = L.AUTO
    scale = _error_scale(scene, p)
    hstate = np.zeros(1)
    ev = np.zeros((max_events, L.N_EVENT_COLS))
    evn = np.zeros(1, dtype=np.int64)
    out_y = np.empty((n + 1, L.N_STATE))
    out_mode = np.empty(n + 1, dtype=np.int64)
    out_peak = np.zeros(n + 1)
    f2_rec = np.zeros(n + 1)
    out_y[0] = y
    out_mode[0] = mode
    t0 = time.perf_counter()
    status = L.OK
    done = n
    if controller is None:
        status, mode, done = run_periods(y, mode, 0.0, 0.0, rec_period, n, p, method, integ.dt,
                                         integ.rtol, scale, hstate, ev, evn, out_y, out_mode, out_peak, 1)
    else:
        scr_y = np.empty((1, L.N_STATE))
        scr_mode = np.empty(1, dtype=np.int64)
        scr_peak = np.zeros(1)
        k_ctrl = 0
        for k in range(1, n + 1):
            peak = 0.0
            for _ in range(sub):
                t = k_ctrl * ctrl_period
                f2 = float(controller(t, y[:4].copy()))
                if not math.isfinite(f2):
                    raise ValueError(f"controller returned a non-finite force {f2!r} N at t = {t:g} s")
                status, mode, _done = run_periods(y, mode, f2, t, ctrl_period, 1, p, method, integ.dt,
                                                  integ.rtol, scale, hstate, ev, evn, scr_y, scr_mode,
                                                  scr_peak, 0)
                peak = max(peak, scr_peak[0])
                k_ctrl += 1
                if status != L.OK:
                    break
            out_y[k], out_mode[k], out_peak[k], f2_rec[k] = y, mode, peak, f2
            if status != L.OK:
                done = k
                break
    wall = time.perf_counter() - t0
    if status != L.OK:
        _raise_status(status, out_y, done, rec_period, scene)
    return _trajectory(scene, p, out_y, out_mode, out_peak, f2_rec, ev, evn, t_touch, rec_period, wall)


def _error_scale(scene: Scene, p: np.ndarray) -> np.ndarray:
    """Per-component scale for dopri5's absolute tolerance (rtol * scale)."""
    v = max(scene.impact_speed, 1e-3)
    m = scene.plant.effective_mass
    d = max(max_penetration(m, p[L.C], v), scene.plant.static_penetration)
    e = 0.5 * scene.plant.m1 * v * v
    return np.array([d, v, d, v, e, e])


def _raise_status(status, out_y, done, rec_period, scene):
    last = out_y[max(done - 1, 0)]
    t = done * rec_period
    what = {L.DIVERGED: "the state left the finite range (|x|+|v| > 1e9 or NaN)",
            L.STEP_UNDERFLOW: "dopri5's step size fell below 1e-15 of the span",
            L.EVENT_OVERFLOW: "more than 16 contact switches within one step"}[status]
    raise SimulationDiverged(
        f"simulation of scene {scene.name!r} diverged near t = {t:.6g} s: {what}. Last finite "
        f"state x1, v1, x2, v2 = {last[:4].tolist()}. Try a smaller integrator.dt, "
        "integrator.method = dopri5, or smaller forces.", t, last.copy())


def _trajectory(scene, p, out_y, out_mode, out_peak, f2_rec, ev, evn, t_touch, rec_period, wall):
    from impact_env.plant.dynamics import contact_force

    n = out_y.shape[0]
    t = np.arange(n) * rec_period
    x1, v1, x2, v2 = (out_y[:, j].copy() for j in range(4))
    d = x1 - x2
    mode = out_mode
    fc = np.array([contact_force(d[i], v1[i] - v2[i], L.AUTO if mode[i] == L.AUTO else int(mode[i]),
                                 p[L.C], p[L.B])[0] for i in range(n)]) if n < 50_000 else \
        _contact_force_vec(d, v1 - v2, mode, p)
    contact = (mode == L.CONTACT) if mode[0] != L.AUTO else (fc > 0)
    k = int(min(evn[0], ev.shape[0]))
    return Trajectory(t=t, x1=x1, v1=v1, x2=x2, v2=v2, contact=contact, contact_force=fc,
                      peak_force=out_peak.copy(), shaker_force=f2_rec, work_shaker=out_y[:, L.W_EXT].copy(),
                      dissipated=out_y[:, L.W_DISS].copy(), events=ev[:k].copy(), t_first_contact=t_touch,
                      scene=scene, params=p, wall_time_s=wall, n_events_dropped=int(evn[0]) - k)


def _contact_force_vec(d, dd, mode, p):
    c, b = p[L.C], p[L.B]
    dp = np.maximum(d, 0.0)
    f = c * dp * np.sqrt(dp) + b * np.sqrt(np.sqrt(dp)) * dd
    f = np.where((d > 0) & (mode != L.FREE), f, 0.0)
    return np.maximum(f, 0.0)
