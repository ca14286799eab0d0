"""The simulator's compiled step: for every active env, ``hold`` ticks of the hardware stage
under the held command, each followed by the front end's conditioning; then, unless the plant
failed, the observation.  One call per step for the whole batch, or, when the simulator has
threads, one call per block of envs, the blocks at once (:class:`impact_env._threads.BlockRunner`).

The order inside a tick is the rig's: the command for the tick is the policy's held action,
plus, with a residual law, that law's command from the readings of the tick before (its own
observation frame, rebuilt every tick), clipped to [-1, 1] (:mod:`impact_env.control.residual`);
the hardware (:func:`impact_env.hardware.stage.hardware_tick`) produces the raw readings; the
controller's front end (:func:`impact_env.control.front_end.condition`) filters them and runs the
detector.  At the end of the step the front end writes the policy's observation
(:func:`~impact_env.control.front_end.observe`).  Every tick leaves a record
(:mod:`impact_env.sim.records`).

Arguments: :class:`SimParams` and :class:`SimState`, each the named groups of the stages above.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from impact_env._borrow import borrow
from impact_env._jit import jit
from impact_env.control.front_end import (
    FrontEndParams,
    FrontEndState,
    ObsParams,
    ObsState,
    condition,
    observe,
)
from impact_env.control.residual import ResidualParams, ResidualState, add_residual, observe_residual
from impact_env.hardware.stage import (
    HW_INFO,
    HardwareParams,
    HardwareState,
    hardware_tick,
    state_ok,
)
from impact_env.plant.layout import EVENT, STATE
from impact_env.sim.records import PREC, REC


class SimParams(NamedTuple):
    hold: int  # control periods per policy step
    hw: HardwareParams
    fe: FrontEndParams
    obs: ObsParams  # the policy's observation layout
    law: ResidualParams


class SimState(NamedTuple):
    hw: HardwareState
    fe: FrontEndState
    obs: ObsState  # the policy's observation buffers
    law: ResidualState
    records: np.ndarray  # float64[N, hold, N_REC]: the last step's per-tick records
    plant_records: np.ndarray  # float64[N, hold, N_PLANT_REC]: their plant records (sim.records)


@jit(inline="always")
def _first_separation(pr, events, n0, n1, t_start):
    """The plant record's ``t_separation`` / ``v1_separation``: the first separation (kind -1)
    among the events ``n0 .. n1 - 1`` of the plant's log (those of this tick, whose times count
    from the tick's start ``t_start``), or NaN (none, or beyond the log's size)."""
    pr[PREC.t_separation] = np.nan
    pr[PREC.v1_separation] = np.nan
    for e in range(n0, min(n1, events.shape[0])):
        if events[e, EVENT.kind] < 0.0:
            pr[PREC.t_separation] = t_start + events[e, EVENT.t]
            pr[PREC.v1_separation] = events[e, EVENT.v1]
            return


@jit(inline="always")
def env_step(i, a, p, s):
    """Env i: ``p.hold`` ticks under the action ``a`` (and the residual law), then its
    observation.  Returns False if the plant failed (its observation is then left as it was)."""
    plant_states = s.hw.plant.y
    t = s.hw.plant.t
    n_events = s.hw.plant.n_events
    events = s.hw.plant.events
    period = p.hw.cfg.period
    info = s.hw.out.info
    detected = s.fe.detected
    law_on = p.law.on
    ok = True
    u = a
    for k in range(p.hold):
        n0 = n_events[i, 0]
        if ok:
            if law_on:
                u = add_residual(a, i, p.law, s.law)
            hardware_tick(i, u, p.hw, s.hw)
            condition(i, s.hw.out.raw, p.fe, s.fe)
            ok = state_ok(i, s.hw)
            if ok and law_on:
                observe_residual(i, plant_states[i], s.fe, p.law, s.law)
        r = s.records[i, k]
        r[REC.t] = t[i]
        r[REC.x1] = plant_states[i, STATE.x1]
        r[REC.v1] = plant_states[i, STATE.v1]
        r[REC.x2] = plant_states[i, STATE.x2]
        r[REC.v2] = plant_states[i, STATE.v2]
        r[REC.u] = u
        r[REC.f_demand] = info[i, HW_INFO.f_demand]
        r[REC.f_applied] = info[i, HW_INFO.f_applied]
        r[REC.saturated] = info[i, HW_INFO.saturated]
        r[REC.contact_force] = info[i, HW_INFO.contact_force]
        r[REC.detected] = detected[i]
        r[REC.status] = 0.0 if ok else 1.0
        plant_record = s.plant_records[i, k]
        plant_record[PREC.catch_integral] = info[i, HW_INFO.catch_integral]
        _first_separation(plant_record, events[i], n0, n_events[i, 0], t[i] - period)
    if ok:
        observe(i, True, a, plant_states[i], s.fe, p.obs, s.obs)
    return ok


@jit(nogil=True)
def sim_step(i0, i1, actions, active, p, s):
    """:func:`env_step` for every env i of ``i0 .. i1 - 1`` with ``active[i]`` under ``actions[i]``
    (the whole batch: 0, N).  Env i touches only its own rows, and the GIL is released, so blocks
    of envs may run in threads at once (:mod:`impact_env._threads`) with the same results.

    The one compiled copy of the env's step: the loops that step one env at a time (compare's
    compiled-policy loop, the oracle's replay) call it on envs ``i .. i + 1``, so numba types
    and compiles the inlined step once, not again inside each (about 55 s of a core on a first
    run); a step's plant status is its last tick's record (``REC.status``)."""
    actions, active, p, s = borrow(actions), borrow(active), borrow(p), borrow(s)  # (impact_env._borrow)
    for i in range(i0, i1):
        if active[i]:
            env_step(i, actions[i], p, s)
