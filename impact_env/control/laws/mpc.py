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

A plan is only as good as the model under it.  Where the scene leaves hardware untold
(``rig-randomized``'s drawn delays, pad, shaker gain and noise: ``untold_hardware``), a filter
that takes the nominal model as exact sees innovations tens of thousands of times their predicted
variance from the first ticks, and a plan on its estimate drives the shaker into body 1 at full
scale.  So there the filter allows for the model's error (:data:`MODEL_ERROR`, times
``untold_error``: :func:`filter_constants`) and leans on each reading only as far as the model
explains it.  And the law checks its model every tick and hands over to a law that needs none:
once the filter reports lost track (its windowed test) or one tick's normalised innovation squared
exceeds ``nis_gate``, it drives ``pd-penetration`` on the same sensors for the rest of the episode
(latched: a plan switched back in mid-contact would start from an estimate it has just shown to
be wrong).  The hand-over is counted in the memory row (``FALLBACK_ON``, ``FALLBACK_TICKS``).
``nis_gate``'s default, 1e3, is three times the largest one-tick NIS met on ``rig``'s held-out
drops (301, at a contact's onset, where the linearisation about a near-zero penetration is
poorest), while a consistent filter's 3-channel NIS, chi-square with 3 degrees of freedom,
exceeds 44 once in 1e9 ticks (docs/mpc.md).

The estimator, the solver and the fallback are part of the policy: all live in the law's memory
row (the solver's first, then the filter's, then the fallback's), so the law runs wherever a law
runs; the filter's lost-track bit and count
(:class:`impact_env.control.estimation.layout.EkfMemory`) and the solver's fallback counters
(``mem[solver.MEM.fallbacks]``) are there too.
"""

from __future__ import annotations

import math
from collections import namedtuple

from impact_env._jit import jit
from impact_env.control.estimation.c_text import ekf_ahead_c, ekf_c
from impact_env.control.estimation.ekf import AHEAD_SCRATCH, ekf_ahead, ekf_measure, ekf_tick
from impact_env.control.estimation.layout import (
    CHANNEL_NAMES,
    REPLICAS_END,
    V1,
    V2,
    X1,
    X2,
    EkfConstants,
    EkfMemory,
)
from impact_env.control.estimation.layout import MEMORY as EKF_MEMORY
from impact_env.control.estimation.model import SETTINGS, ekf_constants
from impact_env.control.laws import mpc_state, pd_penetration
from impact_env.control.laws.estimate import MEMORY as ESTIMATE_MEMORY
from impact_env.control.laws.estimate import SensorReads, top_mass_of
from impact_env.control.laws.law import Law, Param
from impact_env.control.mpc import model, solver
from impact_env.control.mpc.c_text import solver_c

#: the solver's constants first (prefixed ``solver_``: both name the masses), then the filter's,
#: then the fallback law's (prefixed ``fallback_``), then the gate
SOLVER_FIELDS = tuple(f"solver_{name}" for name in model.Constants._fields)
FALLBACK_FIELDS = tuple(f"fallback_{name}" for name in pd_penetration.Constants._fields)
Constants = namedtuple("Constants", SOLVER_FIELDS + EkfConstants._fields + FALLBACK_FIELDS  # type: ignore[misc]
                       + ("nis_gate", "lag"))
EKF_CONSTANTS_START = len(SOLVER_FIELDS)
FALLBACK_CONSTANTS_START = EKF_CONSTANTS_START + len(EkfConstants._fields)
NIS_GATE = FALLBACK_CONSTANTS_START + len(FALLBACK_FIELDS)
LAG = NIS_GATE + 1  # the known sensor and actuator delays, in control periods together
#: the solver's memory first, then the filter's, then the fallback law's, then the hand-over's
#: flag (1 once the fallback drives) and its count of ticks
EKF_MEMORY_START = solver.MEMORY
FALLBACK_MEMORY_START = EKF_MEMORY_START + EKF_MEMORY
FALLBACK_ON = FALLBACK_MEMORY_START + ESTIMATE_MEMORY
FALLBACK_TICKS = FALLBACK_ON + 1
#: ... then the demands of the last ``lag`` ticks (N, oldest first) and the look-ahead's scratch
MAX_LAG = 8
DEMANDS = FALLBACK_TICKS + 1
AHEAD = DEMANDS + MAX_LAG
AHEAD_STATE = AHEAD + REPLICAS_END  # where ekf_ahead leaves the state
MEMORY = AHEAD + AHEAD_SCRATCH

#: The model error the filter allows for where the scene leaves hardware untold
#: (:func:`impact_env.scene.randomize.untold_hardware`), at ``untold_error = 1``: a standard deviation
#: added to each reading's noise (m/s^2, N, m) and a white acceleration on body 2 (m/s^2) added to
#: ``q_a2`` in quadrature.  Their sizes are those of ``rig-randomized``'s own spread: an untold sensor
#: delay of 1-2 periods shifts a push that changes body 2's acceleration by 200 m/s^2 within a
#: period (full scale on m2 = 1 kg), so the accelerometer's model error is of order 100 m/s^2; c
#: known to 25 % moves a contact force of about 100 N by 20 N; two periods of body 2 moving at 0.5
#: m/s are 1e-4 m on the potentiometer; and a 10 % amplifier gain at full scale is 20 m/s^2 on
#: body 2, the order of ``q_a2``'s 30.  Chosen among 2-3 values each on validation drops of
#: ``rig-randomized`` (seeds 900000 on; docs/mpc.md gives the search and the figures).
MODEL_ERROR = {"acc": 100.0, "force": 20.0, "pot": 1e-4, "q_a2": 30.0}

PARAMS = {key: value for key, value in mpc_state.PARAMS.items() if key != "m1"}
PARAMS.update({
    "q_a1": Param(SETTINGS["q_a1"], "m/s^2", "estimator: white acceleration on body 1", lo=0.0),
    "q_a2": Param(SETTINGS["q_a2"], "m/s^2", "estimator: white acceleration on body 2", lo=0.0),
    "untold_error": Param(1.0, "", "scale of the model error (MODEL_ERROR) the estimator allows for where "
                          "the scene leaves hardware untold; 0: none", lo=0.0),
    "nis_gate": Param(1e3, "", "one tick's normalised innovation squared (3 channels) above which the "
                      "model is taken as wrong: pd-penetration drives for the rest of the episode", lo=0.0),
    "fallback_kp": Param(pd_penetration.PARAMS["kp"].default, "1/s^2", "the fallback pd-penetration's kp",
                         lo=0.0),
    "fallback_kd": Param(pd_penetration.PARAMS["kd"].default, "1/s", "the fallback pd-penetration's kd",
                         lo=0.0),
})


def constants_of(scene, P: dict) -> dict:
    solver_gains = {key: P[key] for key in mpc_state.PARAMS if key != "m1"}
    solver_gains["m1"] = scene.plant.m1  # the scene's nominal mass (the filter estimates the drop's)
    out = {f"solver_{name}": value for name, value in mpc_state.solver_constants(scene, solver_gains).items()}
    out.update(filter_constants(scene, P))
    gains = {"kp": P["fallback_kp"], "kd": P["fallback_kd"], "dref": 0.0, "top_mass": top_mass_of(scene)}
    fallback = pd_penetration.constants_of(scene, gains)
    out.update({f"fallback_{name}": value for name, value in fallback.items()})
    out["nis_gate"] = P["nis_gate"]
    out["lag"] = float(known_lag(scene))
    return out


def filter_constants(scene, P: dict) -> dict:
    """The filter's constants: the scene's model, with :data:`MODEL_ERROR` (times ``untold_error``)
    added where the scene leaves hardware untold.  A filter that takes the nominal rig's model as
    exact, on a rig it has not been told, sees innovations thousands of times their predicted
    variance and hands over to ``pd-penetration`` (or, with the hand-over off, plans on an estimate
    that chases each reading); one that allows for the model's error as noise keeps planning."""
    from impact_env.scene.randomize import untold_hardware

    scale = P["untold_error"] if untold_hardware(scene) else 0.0
    k = ekf_constants(scene, {"q_a1": P["q_a1"], "q_a2": math.hypot(P["q_a2"], scale * MODEL_ERROR["q_a2"])})
    for channel in CHANNEL_NAMES:
        k[f"{channel}_r"] += (scale * MODEL_ERROR[channel]) ** 2
    return k


def known_lag(scene) -> int:
    """The sensor and actuator delays the scene knows (its hardware's, where fixed:
    :func:`impact_env.scene.randomize.known_hardware`), in control periods together.  The
    filter's estimate is of the plant that many periods before the tick's demand takes effect."""
    from impact_env.config import ConfigError
    from impact_env.scene.randomize import known_hardware

    hw = known_hardware(scene)
    sensor, actuator = hw.effects.delay.samples(hw.control_rate)
    lag = ((sensor if hw.effects.on("sensor_delay") else 0)
           + (actuator if hw.effects.on("actuator_delay") else 0))
    if lag > MAX_LAG:
        raise ConfigError(f"mpc models at most {MAX_LAG} control periods of sensor and actuator delay "
                          f"together; effects.delay gives {lag} ({lag / hw.control_rate:g} s)")
    return lag


@jit
def force(slots, k, v, mem):
    ekf_k = k[EKF_CONSTANTS_START:]
    ekf_mem = mem[EKF_MEMORY_START:]
    frame = ekf_mem[EkfMemory.innov:EkfMemory.innov + 3]
    frame[0] = v[slots[0]]
    frame[1] = v[slots[1]]
    frame[2] = v[slots[2]]
    ekf_measure(ekf_k, ekf_mem, frame)
    # the fallback's estimate runs every tick, so that it takes over with its differences warm
    fallback_k = k[FALLBACK_CONSTANTS_START:NIS_GATE]
    f_fallback = pd_penetration.force(slots, fallback_k, v, mem[FALLBACK_MEMORY_START:])
    if ekf_mem[EkfMemory.lost_count] > 0.0 or ekf_mem[EkfMemory.nis_last] > k[NIS_GATE]:
        mem[FALLBACK_ON] = 1.0
    lag = int(k[LAG])
    if mem[FALLBACK_ON] > 0.0:
        mem[FALLBACK_TICKS] += 1.0
        f = f_fallback
    else:
        x = ekf_mem[EkfMemory.x:EkfMemory.x + 4]
        if lag > 0:  # the estimate is of the plant lag periods before this demand acts: move it on
            ekf_ahead(ekf_k, ekf_mem, mem[DEMANDS:DEMANDS + lag], lag, mem[AHEAD:MEMORY])
            x = mem[AHEAD_STATE:AHEAD_STATE + 4]
        f = solver.mpc_tick(x[X1], x[V1], x[X2], x[V2], k[:EKF_CONSTANTS_START], mem[:EKF_MEMORY_START])
        f = f / k[model.K.command_gain]  # the demand that gives the planned force
    told = f
    if lag > 0:  # the filter's period is lag periods back: the demand that acts over it
        told = mem[DEMANDS]
        for j in range(lag - 1):
            mem[DEMANDS + j] = mem[DEMANDS + j + 1]
        mem[DEMANDS + lag - 1] = f
    ekf_tick(ekf_k, ekf_mem, frame, told)
    return f


def c_prelude() -> str:
    """The solver's and the filter's C text (file-scope static functions)."""
    return solver_c() + "\n" + ekf_c() + ekf_ahead_c()


def c_body(P: str, sl: dict[str, int]) -> str:
    """:func:`force` in C: the filter's measurement half, the fallback law, the solver on the
    estimate unless the gate has handed over, the filter's prediction with the demand.  The
    fallback's body sees its own memory as ``mem`` (a pointer shadowing the law's, in a block)."""
    return f"""
    /* the filter's frame (a2 m/s^2, T N, x2 m as filtered), kept in its memory as force() keeps it */
    const impact_real *ekf_k = {P}_CONSTANTS + {EKF_CONSTANTS_START};
    impact_real *ekf_mem = mem + {EKF_MEMORY_START};
    impact_real *frame = ekf_mem + EKF_M_INNOV;
    frame[0] = v[{sl["accelerometer"]}];
    frame[1] = v[{sl["force"]}];
    frame[2] = v[{sl["potentiometer"]}];
    ekf_measure(ekf_k, ekf_mem, frame);
    /* the fallback's estimate runs every tick, so that it takes over with its differences warm */
    impact_real f_fallback;
    {{
        impact_real *fallback_mem = mem + {FALLBACK_MEMORY_START};
        {{
            impact_real *mem = fallback_mem;
            impact_real f;{_indent(pd_penetration.c_body(f"{P}_FALLBACK", sl))}
            f_fallback = f;
        }}
    }}
    if (ekf_mem[EKF_M_LOST_COUNT] > 0.0 || ekf_mem[EKF_M_NIS_LAST] > {P}_NIS_GATE) mem[{FALLBACK_ON}] = 1.0;
    int lag = (int){P}_CONSTANTS[{LAG}];
    if (mem[{FALLBACK_ON}] > 0.0) {{
        mem[{FALLBACK_TICKS}] += 1.0;
        f = f_fallback;
    }} else {{
        const impact_real *x = ekf_mem + EKF_M_X;
        if (lag > 0) {{  /* the estimate is of the plant lag periods before this demand acts */
            ekf_ahead(ekf_k, ekf_mem, mem + {DEMANDS}, lag, mem + {AHEAD});
            x = mem + {AHEAD_STATE};
        }}
        f = mpc_tick(x[EKF_X1], x[EKF_V1], x[EKF_X2], x[EKF_V2], {P}_CONSTANTS, mem);
        f = f / {P}_CONSTANTS[MPC_K_COMMAND_GAIN];
    }}
    impact_real told = f;
    if (lag > 0) {{  /* the filter's period is lag periods back: the demand that acts over it */
        told = mem[{DEMANDS}];
        for (int j = 0; j < lag - 1; j++) mem[{DEMANDS} + j] = mem[{DEMANDS} + j + 1];
        mem[{DEMANDS} + lag - 1] = f;
    }}
    ekf_tick(ekf_k, ekf_mem, frame, told);"""


def _indent(text: str) -> str:
    """A law body's C text, indented two levels deeper (it sits in nested blocks)."""
    return text.replace("\n    ", "\n            ")


LAW = Law("mpc", "sensors", "model-predictive control (the `mpc-state` solver) on an extended Kalman "
          "filter's estimate: the scene's model (both bodies, m1, the shaker, the limit, the filters "
          "inverted) fed by the accelerometer, transducer and potentiometer, allowing for the model's "
          "error where the scene leaves hardware untold; pd-penetration once the filter's innovations "
          "show the model wrong",
          SensorReads, Constants, constants_of, memory=MEMORY, params=PARAMS,
          c_body=c_body, c_prelude=c_prelude,
          c_double_only="its command jumps by full scale within a tick where the plan switches "
          "(the force box's active set, the line search's accepted step), so the float32 front end's "
          "rounding moves a switch by a tick: no per-tick bound holds")
