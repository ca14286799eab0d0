"""``simulate``: the headless entry point (scripts, baselines and tests use it).

It validates the scene, converts it to the plant's arrays, runs the compiled kernel period by
period (a control law is sampled once per control period and held, zero-order hold) and wraps
the result in a :class:`Trajectory`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from impact_env.config import whole_multiple
from impact_env.hardware.arrays import (
    METHOD_CODES,
    check_stability,
    error_scale,
    initial_mode,
    initial_state,
    plant_params,
)
from impact_env.plant.integrators import PlantCarry, PlantConsts, Records
from impact_env.plant.layout import DIVERGED, EVENT_OVERFLOW, N_EVENT_COLS, N_STATE, OK, STEP_UNDERFLOW
from impact_env.plant.run import run_periods
from impact_env.scene import Scene, load_scene
from impact_env.scene.scene import ADAPTIVE
from impact_env.sim.trajectory import Trajectory, build_trajectory

MAX_RECORDS = 20_000_000


class SimulationDiverged(RuntimeError):
    """The integration left the finite range; carries the time and the last finite state."""

    def __init__(self, message: str, t: float, state: np.ndarray):
        super().__init__(message)
        self.t = t
        self.state = state


Controller = Callable[[float, np.ndarray], float]


def simulate(scene: Scene | str, controller: Controller | None = None, t_end: float | None = None,
             record_rate: float | None = None, max_events: int = 100_000, overrides=None,
             rng: np.random.Generator | int | None = None, plant_only: bool = False) -> Trajectory:
    """Simulate one drop.

    scene: a Scene or preset name (``overrides``: dotted keys applied on top).
    rng: for a scene with ``[randomize]`` ranges, the numpy Generator (or an int seed) that draws
        this drop's values (:meth:`Scene.sample`, the seed policy of :mod:`impact_env.scene.randomize`);
        without it the scene's nominal values are used.  ``traj.scene`` is the drawn scene.
    controller: ``f(t, y) -> f2``, the shaker force (N, upwards) from the time (s) and the true
        state ``y = [x1, v1, x2, v2]``; sampled once per control period and held.  None: no force.
    t_end: simulated time (s); default ``scene.episode.horizon``.
    record_rate: samples per second in the Trajectory (default: the control rate); must divide it
        (or, without a controller, any rate whose period is a whole number of integration steps).
    plant_only: this function integrates the bare plant (the two bodies, the contact and the
        suspension, driven by ``controller``'s force); a scene whose ``effects.active`` is not
        empty is refused unless this is True, so that nobody mistakes the bare plant for the scene.
        Its effects (shaker, limit, sensors, filters, detector, delays) run in
        :class:`impact_env.sim.Simulator`: ``ImpactCatch-v0`` and ``impact_env.eval.rollout``
        (``impact-env compare``).
    """
    scene = load_scene(scene, overrides)
    if scene.effects.active and not plant_only:
        raise ValueError(
            f"scene {scene.name!r} has effects {list(scene.effects.active)}, which simulate() does "
            f"not run (it integrates the bare plant): run them with impact_env.sim.Simulator "
            f"(ImpactCatch-v0, impact_env.eval.rollout, impact-env compare), or pass "
            f"plant_only=True to integrate the plant alone")
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
        per = rec_period / integ.dt if integ.method not in ADAPTIVE else 1.0
        if integ.method not in ADAPTIVE and not whole_multiple(per):
            raise ValueError(f"record_rate = {record_rate:g} Hz: its period must be a whole number "
                             f"of integration steps (integrator.dt = {integ.dt:g} s)")
        sub = 1
    else:
        sub = whole_multiple(rec_period / ctrl_period)
        if not sub:
            raise ValueError(f"record_rate = {record_rate:g} Hz must divide control.rate = "
                             f"{scene.control_rate:g} Hz")
    n = int(round(t_end / rec_period))
    if n < 1:
        raise ValueError(f"t_end = {t_end:g} s is shorter than one record period ({rec_period:g} s)")
    if n > MAX_RECORDS:
        raise ValueError(f"{n} samples requested (t_end {t_end:g} s at {record_rate:g} Hz); "
                         f"lower record_rate to at most {MAX_RECORDS / t_end:g} Hz")

    p = plant_params(scene)
    y, t_touch = initial_state(scene)
    mode = initial_mode(scene, y, p)
    scale = error_scale(scene, p)
    hstate = np.zeros(1)
    ev = np.zeros((max_events, N_EVENT_COLS))
    evn = np.zeros(1, dtype=np.int64)
    out_y = np.empty((n + 1, N_STATE))
    out_mode = np.empty(n + 1, dtype=np.int64)
    out_peak = np.zeros(n + 1)
    # the period's peak force (scratch), and the largest penetration of the run (m; negative: the
    # closest approach, when the bodies never touch)
    peak = np.array([0.0, -np.inf])
    f2_rec = np.zeros(n + 1)
    out_y[0] = y
    out_mode[0] = mode
    consts = PlantConsts(p, scale, method, integ.dt, integ.rtol)
    carry = PlantCarry(y, hstate, ev, evn, peak)
    t0 = time.perf_counter()
    status = OK
    done = n
    if controller is None:
        status, mode, done = run_periods(mode, 0.0, 0.0, rec_period, consts, carry,
                                         Records(out_y, out_mode, out_peak, 1, n))
    else:
        scr_y = np.empty((1, N_STATE))
        scr_mode = np.empty(1, dtype=np.int64)
        scr_peak = np.zeros(1)
        scr = Records(scr_y, scr_mode, scr_peak, 0, 1)
        k_ctrl = 0
        for k in range(1, n + 1):
            peak_k = 0.0
            for _ in range(sub):
                t = k_ctrl * ctrl_period
                f2 = float(controller(t, y[:4].copy()))
                if not math.isfinite(f2):
                    raise ValueError(f"controller returned a non-finite force {f2!r} N at t = {t:g} s")
                status, mode, _done = run_periods(mode, f2, t, ctrl_period, consts, carry, scr)
                peak_k = max(peak_k, scr_peak[0])
                k_ctrl += 1
                if status != OK:
                    break
            out_y[k], out_mode[k], out_peak[k], f2_rec[k] = y, mode, peak_k, f2
            if status != OK:
                done = k
                break
    wall = time.perf_counter() - t0
    if status != OK:
        _raise_status(status, out_y, done, rec_period, scene)
    return build_trajectory(scene, p, out_y, out_mode, out_peak, f2_rec, ev, evn, t_touch, rec_period, wall,
                            float(peak[1]))


def _raise_status(status, out_y, done, rec_period, scene):
    last = out_y[max(done - 1, 0)]
    t = done * rec_period
    what = {DIVERGED: "the state left the finite range (|x|+|v| > 1e9 or NaN)",
            STEP_UNDERFLOW: "dopri5's step size fell below 1e-15 of the span",
            EVENT_OVERFLOW: "more than 16 contact switches within one step"}[status]
    raise SimulationDiverged(
        f"simulation of scene {scene.name!r} diverged near t = {t:.6g} s: {what}. Last finite "
        f"state x1, v1, x2, v2 = {last[:4].tolist()}. Try a smaller integrator.dt, "
        "integrator.method = dopri5, or smaller forces.", t, last.copy())


