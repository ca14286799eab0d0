"""``mpc``: model-predictive control on an estimate built from the rig's sensors.

Each tick the extended Kalman filter of :mod:`impact_env.control.estimation` turns the frame's
filtered readings (accelerometer, force transducer, potentiometer) into an estimate of both
bodies' states and body 1's mass, and the solver of ``mpc-state``
(:mod:`impact_env.control.mpc.solver`: box-constrained iLQR over the Hertz-Tsuji pad and the
shaker's coil model, warm-started, a fixed number of iterations per tick, force and slew limits
as hard constraints) plans on that estimate.  The demand it returns is the input the filter
propagates with (through the policy's clip, the shaker and the amplifier limit), so the
estimate and the plan see the same force.

Before the touch the sensors say nothing about body 1: the estimate is the scene's prior (the
drop-height range), so the plan positions body 2 for the mean drop; the filter takes body 1 up
at the first contact force.  That is the information ``mpc-state`` has and this law lacks.

The estimator and the solver are part of the policy: both live in the law's memory row (the
solver's first, then the filter's), so the law runs wherever a law runs; the filter's
lost-track bit and count (:class:`impact_env.control.estimation.layout.EkfMemory`) and the
solver's fallback counters (``mem[solver.MEM.fallbacks]``) are there too.
"""

from __future__ import annotations

from collections import namedtuple

from impact_env._jit import jit
from impact_env.control.estimation.c_text import ekf_c
from impact_env.control.estimation.ekf import ekf_measure, ekf_tick
from impact_env.control.estimation.layout import MEMORY as EKF_MEMORY
from impact_env.control.estimation.layout import V1, V2, X1, X2, EkfConstants, EkfMemory
from impact_env.control.estimation.model import SETTINGS, ekf_constants
from impact_env.control.laws import mpc_state
from impact_env.control.laws.estimate import SensorReads
from impact_env.control.laws.law import Law, Param
from impact_env.control.mpc import model, solver
from impact_env.control.mpc.c_text import solver_c

#: the solver's constants first (prefixed ``solver_``: both name the masses), then the filter's
SOLVER_FIELDS = tuple(f"solver_{name}" for name in model.Constants._fields)
Constants = namedtuple("Constants", SOLVER_FIELDS + EkfConstants._fields)  # type: ignore[misc]
EKF_CONSTANTS_START = len(SOLVER_FIELDS)
#: the solver's memory first, then the filter's
EKF_MEMORY_START = solver.MEMORY

PARAMS = {key: value for key, value in mpc_state.PARAMS.items() if key != "m1"}
PARAMS.update({
    "q_a1": Param(SETTINGS["q_a1"], "m/s^2", "estimator: white acceleration on body 1", lo=0.0),
    "q_a2": Param(SETTINGS["q_a2"], "m/s^2", "estimator: white acceleration on body 2", lo=0.0),
})


def constants_of(scene, P: dict) -> dict:
    solver_gains = {key: P[key] for key in mpc_state.PARAMS if key != "m1"}
    solver_gains["m1"] = scene.plant.m1  # the scene's nominal mass (the filter estimates the drop's)
    out = {f"solver_{name}": value for name, value in mpc_state.solver_constants(scene, solver_gains).items()}
    out.update(ekf_constants(scene, {"q_a1": P["q_a1"], "q_a2": P["q_a2"]}))
    return out


@jit
def force(slots, k, v, mem):
    ekf_k = k[EKF_CONSTANTS_START:]
    ekf_mem = mem[EKF_MEMORY_START:]
    frame = ekf_mem[EkfMemory.innov:EkfMemory.innov + 3]
    frame[0] = v[slots[0]]
    frame[1] = v[slots[1]]
    frame[2] = v[slots[2]]
    ekf_measure(ekf_k, ekf_mem, frame)
    x = ekf_mem[EkfMemory.x:EkfMemory.x + 4]
    f = solver.mpc_tick(x[X1], x[V1], x[X2], x[V2], k[:EKF_CONSTANTS_START], mem[:EKF_MEMORY_START])
    ekf_tick(ekf_k, ekf_mem, frame, f)
    return f


def c_prelude() -> str:
    """The solver's and the filter's C text (file-scope static functions)."""
    return solver_c() + "\n" + ekf_c()


def c_body(P: str, sl: dict[str, int]) -> str:
    """:func:`force` in C: the filter's measurement half, the solver on its estimate, the
    filter's prediction with the demand."""
    return f"""
    /* the filter's frame (a2 m/s^2, T N, x2 m as filtered), kept in its memory as force() keeps it */
    const impact_real *ekf_k = {P}_CONSTANTS + {EKF_CONSTANTS_START};
    impact_real *ekf_mem = mem + {EKF_MEMORY_START};
    impact_real *frame = ekf_mem + EKF_M_INNOV;
    frame[0] = v[{sl["accelerometer"]}];
    frame[1] = v[{sl["force"]}];
    frame[2] = v[{sl["potentiometer"]}];
    ekf_measure(ekf_k, ekf_mem, frame);
    const impact_real *x = ekf_mem + EKF_M_X;
    f = mpc_tick(x[EKF_X1], x[EKF_V1], x[EKF_X2], x[EKF_V2], {P}_CONSTANTS, mem);
    ekf_tick(ekf_k, ekf_mem, frame, f);"""


LAW = Law("mpc", "sensors", "model-predictive control (the `mpc-state` solver) on an extended Kalman "
          "filter's estimate: the scene's model (both bodies, m1, the shaker, the limit, the filters "
          "inverted) fed by the accelerometer, transducer and potentiometer",
          SensorReads, Constants, constants_of, memory=solver.MEMORY + EKF_MEMORY, params=PARAMS,
          c_body=c_body, c_prelude=c_prelude,
          c_double_only="its command jumps by full scale within a tick where the plan switches "
          "(the force box's active set, the line search's accepted step), so the float32 front end's "
          "rounding moves a switch by a tick: no per-tick bound holds")
