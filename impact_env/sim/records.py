"""Columns of the per-tick records a simulator step writes (float64[N, hold_ticks, N_REC]).

One row per control tick of the step, after the tick (SI units; booleans as 0/1):
``t`` (s since the episode start), the true state ``x1, v1, x2, v2`` (m, m/s; thesis frame,
x down), ``u`` (the drive command held over the tick, 1 = the scene's command scale),
``f_demand`` / ``f_applied`` (N: the demand and the force reaching body 2 after shaker and
saturation), ``saturated``, ``contact_force`` (N, true, at the end of the tick), ``detected``
(the front end's contact detector) and ``status`` (0 while the plant is finite and its kernel
reported no failure; once not, it stays so for the rest of the step, whose ticks are not run).
The task (reward, termination) and the episode metrics read them; they are what a tick log of
the rig holds, plus the true state.

What only the simulated plant knows, from inside its integrator, is kept apart, one
:class:`PlantRecord` per tick (float64[N, hold_ticks, N_PLANT_REC]), so that the records stay
what a rig's tick log and its telemetry carry: ``catch_integral`` (J s, the time integral of
body 1's catch energy over the tick, along the simulated motion) and the first contact
separation the plant located within the tick, ``t_separation`` (s since the episode start) and
body 1's velocity there, ``v1_separation`` (m/s; both NaN when the tick has none).  The episode
metrics read them when they are given (:mod:`impact_env.sim.metrics`).
"""


from typing import NamedTuple

from impact_env._packed import positions


class Record(NamedTuple):
    """A record's columns (float64[N_REC]), read by name: ``r[REC.x1]``."""

    t: float
    x1: float
    v1: float
    x2: float
    v2: float
    u: float
    f_demand: float
    f_applied: float
    saturated: float
    contact_force: float
    detected: float
    status: float


class PlantRecord(NamedTuple):
    """A plant record's columns (float64[N_PLANT_REC]): ``p[PREC.catch_integral]``."""

    catch_integral: float  # J s
    t_separation: float  # s, NaN: none in the tick
    v1_separation: float  # m/s


REC = positions(Record)
N_REC = len(REC)
PREC = positions(PlantRecord)
N_PLANT_REC = len(PREC)

