"""From a scene to the plant's arrays: parameters, initial state and contact mode, dopri5's error
scale, and the stability check of the fixed-step methods.  One module, used by the single drop
(:mod:`impact_env.sim.drop`) and by the batched Simulator (:mod:`impact_env.sim.simulator`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from impact_env.hardware.stability import check_step
from impact_env.plant.dynamics import event_value
from impact_env.plant.hertz import max_penetration
from impact_env.plant.layout import (
    AUTO,
    CONTACT,
    DOPRI5,
    EULER,
    FREE,
    N_PARAM,
    N_STATE,
    PARAM,
    RK4,
    SPLIT,
    STATE,
    SYMPLECTIC_EULER,
)
from impact_env.plant.restitution import tsuji_damping
from impact_env.scene import Scene

METHOD_CODES = {"euler": EULER, "symplectic-euler": SYMPLECTIC_EULER, "rk4": RK4, "dopri5": DOPRI5,
                "split": SPLIT}


def plant_params(scene: Scene, zeta_of: Callable[[float], float] | None = None) -> np.ndarray:
    """The plant's parameter array for a scene (see :mod:`impact_env.plant.layout`).

    ``zeta_of``: the scaled damping for a restitution (default: the exact solve,
    :func:`~impact_env.plant.restitution.zeta_for_restitution`; the Simulator passes a
    :class:`~impact_env.plant.restitution.ZetaTable` for drawn restitutions).
    """
    pl = scene.plant
    p = np.zeros(N_PARAM)
    p[PARAM.m1], p[PARAM.m2], p[PARAM.c], p[PARAM.g] = pl.m1, pl.m2, pl.c, pl.gravity
    if pl.restitution >= 1.0:
        p[PARAM.b] = 0.0
    elif zeta_of is None:
        p[PARAM.b] = tsuji_damping(pl.restitution, pl.m1, pl.m2, pl.c)
    else:
        p[PARAM.b] = zeta_of(pl.restitution) * math.sqrt(pl.effective_mass * pl.c)
    p[PARAM.k2], p[PARAM.c2] = pl.suspension_stiffness, pl.suspension_damping
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
    y = np.zeros(N_STATE)
    y[STATE.x1] = -(v * tau - 0.5 * g * tau * tau)
    y[STATE.v1] = v - g * tau
    return y, tau


def check_stability(scene: Scene) -> None:
    """Refuse (ConfigError naming ``integrator.dt``), before simulating, a fixed step that the
    drop's contact makes unstable or leaves unresolved: :func:`impact_env.hardware.stability.check_step`."""
    check_step(scene)


def initial_mode(scene: Scene, y0: np.ndarray, p: np.ndarray) -> int:
    """The contact mode to start in: FREE or CONTACT from the initial state when contact events
    are located, AUTO (the force switches inside the right-hand side) when they are not."""
    if not scene.integrator.event_location:
        return AUTO
    return CONTACT if event_value(y0[STATE.x1], y0[STATE.v1], y0[STATE.x2], y0[STATE.v2], p[PARAM.c],
                                  p[PARAM.b]) > 0 else FREE


def error_scale(scene: Scene, p: np.ndarray) -> np.ndarray:
    """Per-component scale for dopri5's absolute tolerance (rtol * scale)."""
    v = max(scene.impact_speed, 1e-3)
    m = scene.plant.effective_mass
    d = max(max_penetration(m, p[PARAM.c], v), scene.plant.static_penetration)
    e = 0.5 * scene.plant.m1 * v * v
    return np.array([d, v, d, v, e, e])

