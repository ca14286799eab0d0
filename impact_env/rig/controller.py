"""The target's controller: the compiled code of one tick between ``driver.read()`` and
``driver.apply()``, the same kernels the simulator runs (:mod:`impact_env.control`).

Tick m of an episode (T the control period, H = hold_ticks, step n = m // H):

1. :func:`observe_tick`: the raw readings of tick m (what the rig did in tick m - 1) go through
   the front end's filters and detector (:func:`impact_env.control.front_end.condition`; at
   m = 0 the readings at the release start the front end unfiltered, as in the simulator's
   reset), a residual law's frame is rebuilt, and at a step boundary (m % H == 0) the policy's
   observation of step n is written.
2. :func:`act_tick`: onboard, at a step boundary the action of step n is taken (the policy's
   :func:`~impact_env.control.policy.act` on that observation); in host mode every tick takes
   the command the episode chose for it (the newest accepted one for step n, from the first
   tick at or after its arrival);
   the tick's command is the action (plus the residual law, clipped to [-1, 1]); the safety
   layer (:func:`impact_env.rig.safety.safety_step`) may zero or clamp it; the tick's log row is
   written.  The driver then applies the returned command for the tick.

So the observation of step n is that of tick n H, made from the readings after tick n H - 1,
and the action of step n acts over ticks n H .. n H + H - 1: exactly the simulator's order
(:mod:`impact_env.sim.step`), which is why a lock-step virtual rig reproduces ``ImpactCatch-v0``
bitwise.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from impact_env._borrow import borrow
from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.control.front_end import (
    FrontEnd,
    FrontEndParams,
    FrontEndState,
    ObsParams,
    ObsState,
    condition,
    observe,
)
from impact_env.control.observation import ObservationLayout
from impact_env.control.plausibility import (  # issue 25: the sensor plausibility check
    PlausibilityParams,
    check_readings,
    make_state,
    note_demand,
    plausibility_params,
    reset_state,
)
from impact_env.control.policy import CompiledPolicy, PolicyArrays, act
from impact_env.control.residual import (
    ResidualParams,
    ResidualState,
    add_residual,
    observe_residual,
    residual_arrays,
    start_residual,
)
from impact_env.effects.sensors import ACCEL, FORCE, POT
from impact_env.hardware.stage import INFO_CONTACT_FORCE, INFO_F_APPLIED, INFO_F_DEMAND, INFO_SATURATED
from impact_env.plant.layout import STATE
from impact_env.rig import log as tick_log
from impact_env.rig import safety as rig_safety
from impact_env.rig.safety import SafetyConfig, safety_step
from impact_env.sim import records


class OwnState(NamedTuple):
    """The controller's own state (float64[N_STATE]), read by name: ``st[OWN.cmd_first]``."""

    action: int  # the last tick's action
    command: int  # the last tick's command sent
    cmd_id: int  # the id of the host command in use
    cmd_first: int  # the tick it first acted at
    sensor: int  # the plausibility check's status bits for this tick


OWN = positions(OwnState)
N_STATE = len(OWN)
# the safety bits after which the command sent is the safety layer's force, not the demand
MODIFIED = rig_safety.FORCE_ZEROED | rig_safety.CLAMP_PEAK | rig_safety.CLAMP_RMS | rig_safety.LATCHING
NAN4 = np.full(4, np.nan)


class ControllerParams(NamedTuple):
    """What a controller keeps fixed for an episode."""

    onboard: bool  # the policy acts here (else the host's commands)
    hold: int  # ticks per policy step
    scale: float  # N per unit command (the scene's command scale)
    rate: float  # Hz, the control rate
    fe: FrontEndParams
    obs: ObsParams  # the policy's observation layout
    law: ResidualParams
    policy: PolicyArrays  # the onboard policy (a placeholder in host mode)
    safety: np.ndarray  # float64[N_PARAMS]: the safety layer's parameters (rig_safety.PARAM)
    plaus: PlausibilityParams  # the sensor plausibility check's (impact_env.control.plausibility)


class ControllerState(NamedTuple):
    """What a controller changes every tick."""

    fe: FrontEndState
    obs: ObsState
    law: ResidualState
    memory: np.ndarray  # float64[1, m]: the onboard policy's memory
    safety: np.ndarray  # the safety layer's state (impact_env.rig.safety)
    own: np.ndarray  # float64[N_STATE]: columns ST_*
    log: tick_log.LogBuffers
    plaus: np.ndarray  # the plausibility check's state
    readings: np.ndarray  # float64[4]: this tick's readings as the check passed them (bad ones held)


class HostCommand(NamedTuple):
    """The host's command in use at a tick (host mode)."""

    action: float  # the command in [-1, 1]
    step: int  # the policy step it is for (-1: none yet)
    id: int  # its serial number


@jit
def observe_tick(m, raw, truth, p, s):
    """Step 1 of tick m (module doc); ``truth``: x1, v1, x2, v2 for privileged entries (NaN on
    a physical rig).  Returns True at a step boundary."""
    raw, truth, p, s = borrow(raw), borrow(truth), borrow(p), borrow(s)  # (impact_env._borrow)
    hold = p.hold
    if m > 0:
        # issue 25: no reading reaches the filters unchecked (a bad one: the last good one, 0 N)
        s.own[OWN.sensor] = check_readings(m, raw, p.plaus, s.plaus, s.readings)
        r = s.readings.reshape((1, s.readings.shape[0]))
        condition(0, r, p.fe, s.fe)
        if p.law.on:
            observe_residual(0, truth, s.fe, p.law, s.law)
        if m % hold == 0:
            observe(0, True, s.own[OWN.action], truth, s.fe, p.obs, s.obs)
    return m % hold == 0


@jit
def act_tick(m, ticks_armed, cmd, p, s, raw):
    """Step 2 of tick m: returns (command for the driver, force demanded after safety N, status
    bits, log row index or -1 when the log is full).

    Host mode: ``cmd`` (HostCommand) is the command the target chose for this tick (the newest
    accepted one for the current step, :class:`impact_env.rig.episode.Episode`), for policy step
    ``cmd.step`` (-1: none yet: 0 N, NO_COMMAND), ``cmd.id`` its serial number (the tick it
    first acts at is kept in ``own[OWN.cmd_first]``, the id in ``own[OWN.cmd_id]``: so the caller
    sees whether it acted).  It acts from this tick on, whatever tick of its step that is; the
    watchdog's age counts from its step's first tick to ``ticks_armed`` (``ticks_armed - cmd.step
    H``), so a command is held for the rest of its step, repeated through the next one (REPEATED)
    and zeroed after.  ``ticks_armed`` is the time since tick 0 in periods of the clock (the
    real-time loop passes the tick the clock is in, which a late tick is behind of; lock-step: m),
    so the watchdog and the first-command allowance count seconds, not ticks run."""
    cmd, p, s, raw = borrow(cmd), borrow(p), borrow(s), borrow(raw)  # (impact_env._borrow)
    st = s.own
    hold = p.hold
    if p.onboard:
        if m % hold == 0:
            st[OWN.action] = act(p.policy.ints, p.policy.floats, s.obs.obs[0], s.memory[0])
        age = 0
        log_age = 0
        log_step = m // hold
    elif cmd.step < 0:
        st[OWN.action] = 0.0
        age = -1
        log_age = -1
        log_step = -1
    else:
        if st[OWN.cmd_id] != cmd.id:
            st[OWN.cmd_id] = cmd.id
            st[OWN.cmd_first] = m
        st[OWN.action] = cmd.action
        age = ticks_armed - cmd.step * hold  # the clock's time since its step began (see below)
        log_age = m - int(st[OWN.cmd_first])
        log_step = cmd.step
    u = st[OWN.action]
    if p.law.on:
        u = add_residual(u, 0, p.law, s.law)
    f, status = safety_step(u, age, ticks_armed, s.readings[POT], int(st[OWN.sensor]), p.safety, s.safety)
    note_demand(m, f, p.plaus, s.plaus)  # the armature check's drive (impact_env.control.plausibility)
    out = f / p.scale if status & MODIFIED else u
    st[OWN.command] = out
    rows = s.log.rows
    i = tick_log.claim_row(rows, s.log.filled)
    if i >= 0:
        row = rows[i]
        row[tick_log.COL.tick] = m
        row[tick_log.COL.t_s] = m / p.rate
        row[tick_log.COL.accelerometer_mps2] = raw[ACCEL]
        row[tick_log.COL.force_N] = raw[FORCE]
        row[tick_log.COL.potentiometer_m] = raw[POT]
        row[tick_log.COL.action] = u
        row[tick_log.COL.force_demand_N] = f
        row[tick_log.COL.command_age_ticks] = log_age
        row[tick_log.COL.status] = status
        row[tick_log.COL.step] = m // hold
        row[tick_log.COL.contact_detected] = s.fe.detected[0]
        row[tick_log.COL.command_step] = log_step
        row[tick_log.COL.skipped_ticks] = 0
        obs = s.obs.obs[0]
        for j in range(obs.shape[0]):
            s.log.obs[i, j] = obs[j]
    return out, f, status, i


@jit
def skip_allowed(m, late_ticks, hold, m1, onboard):
    """How many of the ticks from m (before m1) a loop ``late_ticks`` whole periods behind lets
    pass unrun.  Onboard: all of them.  Host mode: never a policy step's first tick (every step
    has its observation sent, its command's chance to act, and the host its step's records), so
    at most up to the next step boundary, and none at a boundary: that tick runs late instead,
    and the loop catches up over the step's other ticks."""
    if late_ticks <= 0:
        return 0
    if onboard:
        return max(0, min(late_ticks, m1 - m))
    r = m % hold
    if r == 0:
        return 0
    k = min(late_ticks, hold - r)
    return max(0, min(k, m1 - m))


class Controller:
    """One target's controller for one episode at a time: the front end of ``layout`` on the
    driver's scene, an onboard ``policy`` (or the host's commands), an optional ``residual`` law,
    the safety layer and the tick log.  :meth:`start` at the release, then per tick
    :meth:`observe` and :meth:`act`.  :attr:`params` and :attr:`state` are the compiled tick's
    arguments."""

    def __init__(self, scene, layout: ObservationLayout, hold_ticks: int, horizon_ticks: int, mode: str,
                 policy: CompiledPolicy | None = None, residual: CompiledPolicy | None = None,
                 safety: SafetyConfig | None = None, extra_columns: tuple[str, ...] = (),
                 observation: str = "sensors"):
        if layout.privileged:
            raise ValueError("a rig measures no body-1 state: privileged observations (x1, v1, x2, v2) "
                             "are not available on the target; use observation='sensors'")
        self.scene = scene
        self.layout = layout
        self.observation = observation
        self.hold = int(hold_ticks)
        self.mode = mode
        self.scale = float(scene.effects.command_scale)
        self.rate = float(scene.control_rate)
        self.fe = FrontEnd(scene, layout, 1)
        self.policy = policy
        if mode == "onboard":
            if policy is None:
                raise ValueError("onboard mode needs a policy")
            pi, pf, m = policy.arrays()
            pol, memory = PolicyArrays(pi, pf), np.zeros((1, m))
        else:
            pol, memory = PolicyArrays(np.zeros(1, np.int64), np.zeros(1)), np.zeros((1, 1))
        self.residual = residual
        law_p, law_s = residual_arrays(residual, layout, 1)
        self.safety_cfg = safety or SafetyConfig()
        #: the safety layer, whose arrays the compiled tick updates (params, state)
        self.safety = rig_safety.SafetyLayer(self.safety_cfg, self.scale, self.rate, self.hold, mode)
        sp = self.safety.params
        self.log = tick_log.TickLog(int(horizon_ticks) + 1, layout.size, extra=extra_columns)
        self.params = ControllerParams(mode == "onboard", self.hold, self.scale, self.rate, self.fe.params,
                                       self.fe.obs_params, law_p, pol, sp, plausibility_params(scene))
        self.state = ControllerState(self.fe.state, self.fe.obs_state, law_s, memory, self.safety.state,
                                     np.zeros(N_STATE), self.log.buffers, make_state(), np.zeros(4))

    @property
    def st(self) -> np.ndarray:
        """The controller's own state (columns ST_*)."""
        return self.state.own

    def start(self, raw: np.ndarray, truth: np.ndarray | None) -> None:
        """The release: the front end (and a residual law's frame) start from these readings,
        the onboard policy's memory and the log are cleared; the safety layer's latches too
        (its RMS window, the coil's heat, is kept)."""
        t = NAN4 if truth is None else np.asarray(truth, dtype=np.float64).reshape(1, 4)
        t = t.reshape(1, 4)
        idx = np.zeros(1, np.int64)
        s = self.state
        reset_state(s.plaus)  # issue 25: tick 0's readings are checked too (range only: no previous one)
        bits = check_readings(0, np.asarray(raw, dtype=np.float64), self.params.plaus, s.plaus, s.readings)
        self.fe.start(idx, s.readings.reshape(1, -1).copy(), t)
        if self.params.law.on:
            start_residual(idx, t, s.fe, self.params.law, s.law)
        s.memory[:] = 0.0
        s.own[:] = 0.0
        s.own[OWN.cmd_id] = -1.0
        s.own[OWN.sensor] = bits
        self.safety.new_episode()
        self.log.reset()

    def observe(self, m: int, raw: np.ndarray, truth: np.ndarray | None) -> bool:
        t = NAN4 if truth is None else truth
        return bool(observe_tick(m, raw, t, self.params, self.state))

    def act(self, m: int, host_action: float, cmd_step: int, cmd_id: int, ticks_armed: int, raw: np.ndarray):
        return act_tick(m, int(ticks_armed), HostCommand(float(host_action), int(cmd_step), int(cmd_id)),
                        self.params, self.state, raw)

    @property
    def obs(self) -> np.ndarray:
        """The observation row of the last step (float32[size])."""
        return self.fe.obs[0]

    def counters(self) -> dict[str, int]:
        """The safety layer's per-episode counters (plain ints)."""
        return self.safety.counters()

    def drain(self, ticks: int) -> None:
        """Idle time between episodes: the RMS window cools by ``ticks`` zero ticks."""
        self.safety.drain(int(ticks))


# -- for the compiled real-time loop (impact_env.rig.rtloop) ------------------------------------
class EndCode(NamedTuple):
    """How the compiled loop ended an episode (its return value's end code)."""

    none: int  # at the horizon
    first_command: int
    safety: int
    fault: int
    stop: int  # asked to (a DISARM, a signal, a lost link)
    sensor_fault: int
    overrun: int


END = positions(EndCode)
class TickAccounts(NamedTuple):
    """The loop's tick accounts (int64[N_ACCT], kept across calls)."""

    unreported: int  # ticks skipped, not yet reported on a row
    skipped: int  # the episode's skipped ticks
    overruns: int  # rows flagged OVERRUN


ACCT = positions(TickAccounts)
N_ACCT = len(ACCT)


class TruthColumns(NamedTuple):
    """Where a virtual rig's log row keeps each true value (column indices; names and units in
    :data:`TRUTH_LOG`)."""

    command: int
    x1: int
    v1: int
    x2: int
    v2: int
    force_demand: int
    force_applied: int
    saturated: int
    contact_force: int
    status: int
    impact_energy: int
    impact_speed: int
    t_touch: int


# each field of TruthColumns: (its log column, unit)
TRUTH_LOG = {"command": ("command", ""), "x1": ("true_x1_m", "m"), "v1": ("true_v1_mps", "m/s"),
             "x2": ("true_x2_m", "m"), "v2": ("true_v2_mps", "m/s"),
             "force_demand": ("hw_force_demand_N", "N"), "force_applied": ("hw_force_applied_N", "N"),
             "saturated": ("hw_saturated", ""),
             "contact_force": ("hw_contact_force_N", "N"), "status": ("hw_status", ""),
             "impact_energy": ("impact_energy_J", "J"), "impact_speed": ("impact_speed_mps", "m/s"),
             "t_touch": ("t_touch_s", "s")}
assert tuple(TRUTH_LOG) == TruthColumns._fields
# a virtual rig's extra log columns: the truth the compiled tick writes, then the time Python adds
TRUTH_COLUMNS = tuple(col for col, _ in TRUTH_LOG.values()) + ("true_t_s",)
TRUTH_UNITS = {col: unit for col, unit in TRUTH_LOG.values() if unit} | {"true_t_s": "s"}


def truth_columns(log: tick_log.TickLog) -> TruthColumns:
    """The indices of the truth columns in ``log``."""
    return TruthColumns(*(log.col(TRUTH_LOG[f][0]) for f in TruthColumns._fields))


class DropConstants(NamedTuple):
    """The drop's constants a virtual rig logs on every row."""

    impact_energy: float  # J
    impact_speed: float  # m/s
    t_touch: float  # s


@jit(inline="always")
def true_record(trec, m, plant_states, info, u, detected, ok, rate):
    """The virtual rig's true record of tick m (:mod:`impact_env.sim.records`)."""
    r = trec[m]
    r[records.REC.t] = (m + 1.0) / rate
    r[records.REC.x1] = plant_states[0, STATE.x1]
    r[records.REC.v1] = plant_states[0, STATE.v1]
    r[records.REC.x2] = plant_states[0, STATE.x2]
    r[records.REC.v2] = plant_states[0, STATE.v2]
    r[records.REC.u] = u
    r[records.REC.f_demand] = info[0, INFO_F_DEMAND]
    r[records.REC.f_applied] = info[0, INFO_F_APPLIED]
    r[records.REC.saturated] = info[0, INFO_SATURATED]
    r[records.REC.contact_force] = info[0, INFO_CONTACT_FORCE]
    r[records.REC.detected] = detected
    r[records.REC.status] = 0.0 if ok else 1.0
