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

import numpy as np

from impact_env._jit import jit
from impact_env.control.front_end import FrontEnd, condition, observation_buffers, observe, start_rows
from impact_env.control.observation import ObservationLayout
from impact_env.control.policy import CompiledPolicy, act
from impact_env.effects.sensors import POT
from impact_env.hardware.stage import (
    INFO_CONTACT_FORCE,
    INFO_F_APPLIED,
    INFO_F_DEMAND,
    INFO_SATURATED,
    hardware_tick,
    state_ok,
)
from impact_env.rig import log as LG
from impact_env.rig import safety as SF
from impact_env.rig.cycles import cycles
from impact_env.rig.safety import SafetyConfig, safety_params, safety_step
from impact_env.sim import records as R

# the controller's own state (float64[N_STATE]): the action and the command sent of the last
# tick, the id of the host command in use and the tick it first acted at
ST_ACTION, ST_COMMAND, ST_CMD_ID, ST_CMD_FIRST = range(4)
N_STATE = 4
# the safety bits after which the command sent is the safety layer's force, not the demand
MODIFIED = SF.FORCE_ZEROED | SF.CLAMP_PEAK | SF.CLAMP_RMS | SF.LATCHING
NAN4 = np.full(4, np.nan)


@jit
def observe_tick(m, raw, hold, fe, ob, law, truth, st):
    """Step 1 of tick m (module doc); ``truth``: x1, v1, x2, v2 for privileged entries (NaN on
    a physical rig).  Returns True at a step boundary."""
    r = raw.reshape((1, raw.shape[0]))
    if m > 0:
        condition(0, r, fe)
        if law[0]:
            observe(0, False, 0.0, truth, fe, law[4])
        if m % hold == 0:
            observe(0, True, st[ST_ACTION], truth, fe, ob)
    return m % hold == 0


@jit
def act_tick(m, onboard, host_action, cmd_step, cmd_id, ticks_armed, hold, fe, ob, law, pol, safety, scale,
             raw, st, rows, obs_log, count):
    """Step 2 of tick m: returns (command for the driver, force demanded after safety N, status
    bits, log row index or -1 when the log is full).

    Host mode: ``host_action`` is the command the target chose for this tick (the newest
    accepted one for the current step, :class:`impact_env.rig.episode.Episode`), for policy step
    ``cmd_step`` (-1: none yet: 0 N, NO_COMMAND), ``cmd_id`` its serial number (the tick it
    first acts at is kept in ``st[ST_CMD_FIRST]``, the id in ``st[ST_CMD_ID]``: so the caller
    sees whether it acted).  It acts from this tick on, whatever tick of its step that is; the
    watchdog's age counts from its step's first tick (``m - cmd_step H``), so a command is held
    for the rest of its step, repeated through the next one (REPEATED) and zeroed after."""
    if onboard:
        if m % hold == 0:
            st[ST_ACTION] = act(pol[0], pol[1], ob[7][0], pol[2][0])
        age = 0
        log_age = 0
        log_step = m // hold
    elif cmd_step < 0:
        st[ST_ACTION] = 0.0
        age = -1
        log_age = -1
        log_step = -1
    else:
        if st[ST_CMD_ID] != cmd_id:
            st[ST_CMD_ID] = cmd_id
            st[ST_CMD_FIRST] = m
        st[ST_ACTION] = host_action
        age = m - cmd_step * hold
        log_age = m - int(st[ST_CMD_FIRST])
        log_step = cmd_step
    u = st[ST_ACTION]
    if law[0]:
        u = u + act(law[1], law[2], law[4][7][0], law[3][0])
        u = -1.0 if u < -1.0 else (1.0 if u > 1.0 else u)
    f, status = safety_step(u, age, ticks_armed, raw[POT], safety[0], safety[1])
    cmd = f / scale if status & MODIFIED else u
    st[ST_COMMAND] = cmd
    i = LG.claim_row(rows, count)
    if i >= 0:
        row = rows[i]
        row[LG.TICK] = m
        row[LG.T_S] = m / safety[2]
        row[LG.ACCEL] = raw[0]
        row[LG.FORCE] = raw[1]
        row[LG.POT] = raw[2]
        row[LG.ACTION] = u
        row[LG.FORCE_DEMAND] = f
        row[LG.COMMAND_AGE] = log_age
        row[LG.STATUS] = status
        row[LG.STEP] = m // hold
        row[LG.DETECTED] = fe[6][0]
        row[LG.COMMAND_STEP] = log_step
        row[LG.SKIPPED] = 0
        obs = ob[7][0]
        for j in range(obs.shape[0]):
            obs_log[i, j] = obs[j]
    return cmd, f, status, i


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
    :meth:`observe` and :meth:`act`."""

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
            self.pol = (pi, pf, np.zeros((1, m)))
        else:
            self.pol = (np.zeros(1, np.int64), np.zeros(1), np.zeros((1, 1)))
        self.residual = residual
        if residual is not None:
            pi, pf, m = residual.arrays()
            self.law = (True, pi, pf, np.zeros((1, m)), observation_buffers(residual.layout, 1))
        else:
            self.law = (False, np.zeros(1, np.int64), np.zeros(1), np.zeros((1, 1)),
                        observation_buffers(layout, 1))
        self.safety_cfg = safety or SafetyConfig()
        params = safety_params(self.safety_cfg, self.scale, self.rate, self.hold, mode)
        self.safety = (params, SF.make_safety_state(params), self.rate)
        self.st = np.zeros(N_STATE)
        self.log = LG.TickLog(int(horizon_ticks) + 1, layout.size, extra=extra_columns)

    def start(self, raw: np.ndarray, truth: np.ndarray | None) -> None:
        """The release: the front end (and a residual law's frame) start from these readings,
        the onboard policy's memory and the log are cleared; the safety layer's latches too
        (its RMS window, the coil's heat, is kept)."""
        t = NAN4 if truth is None else np.asarray(truth, dtype=np.float64).reshape(1, 4)
        t = t.reshape(1, 4)
        self.fe.start(np.zeros(1, np.int64), np.asarray(raw, dtype=np.float64).reshape(1, -1), t)
        if self.law[0]:
            self.law[3][:] = 0.0
            start_rows(np.zeros(1, np.int64), t, self.fe.fe, self.law[4])
        self.pol[2][:] = 0.0
        self.st[:] = 0.0
        self.st[ST_CMD_ID] = -1.0
        SF.new_episode(self.safety[1])
        self.log.reset()

    def observe(self, m: int, raw: np.ndarray, truth: np.ndarray | None) -> bool:
        t = NAN4 if truth is None else truth
        return bool(observe_tick(m, raw, self.hold, self.fe.fe, self.fe.ob, self.law, t, self.st))

    def act(self, m: int, host_action: float, cmd_step: int, cmd_id: int, ticks_armed: int, raw: np.ndarray):
        log = self.log
        return act_tick(m, self.mode == "onboard", float(host_action), int(cmd_step), int(cmd_id),
                        int(ticks_armed), self.hold,
                        self.fe.fe, self.fe.ob, self.law, self.pol, self.safety, self.scale, raw, self.st,
                        log.rows, log.obs, log.count)

    @property
    def obs(self) -> np.ndarray:
        """The observation row of the last step (float32[size])."""
        return self.fe.obs[0]

    def drain(self, ticks: int) -> None:
        """Idle time between episodes: the RMS window cools by ``ticks`` zero ticks."""
        SF.drain_window(self.safety[1], self.safety[0], int(ticks))


# -- the virtual rig's compiled tick loop ---------------------------------------------------------
END_NONE, END_FIRST_COMMAND, END_SAFETY, END_FAULT, END_STOP = range(5)
# the truth columns a virtual rig logs (their indices in ``tc``, :data:`impact_env.rig.target.TRUTH_COLUMNS`)
(TC_COMMAND, TC_X1, TC_V1, TC_X2, TC_V2, TC_FD, TC_FA, TC_SAT, TC_FC, TC_STATUS, TC_E0, TC_V0,
 TC_TT) = range(13)


@jit(nogil=True)
def run_ticks(m0, m1, hold, onboard, host_action, cmd_step, cmd_id, fe, ob, law, pol, safety, scale, st, rows,
              obs_log, count, hw, tc, tvals, pace, lateness, stop, acct, trec):
    """Ticks m0 .. m1 - 1 of a virtual rig, each: (real time: spin to its deadline) act -> safety
    -> the hardware stage -> the log row with the truth -> the front end on the new readings.
    The front end has seen tick m0's readings already.  ``pace`` = (real time, deadline of tick 0
    in cycles, cycles per tick, ns per cycle).  A tick that starts one period or more late lets
    the ticks that cannot run on time pass (:func:`skip_allowed`: in host mode never a step's first
    tick): the DAC holds the last command sent (the hardware stage runs them with it), the controller
    and the safety layer do not run and they get no log row; the front end then conditions the
    readings after them, and the next row carries OVERRUN and their number in ``skipped_ticks``.
    ``acct`` (int64[3], kept across calls): ticks skipped not yet reported on a row, the
    episode's skipped ticks, rows flagged OVERRUN.  ``trec`` (float64[horizon + 1, N_REC]): the
    virtual rig's true record of every tick that passed, run or skipped
    (:mod:`impact_env.sim.records`).  ``stop[0]`` set (by another thread: the GIL is released
    here) ends the loop before the next tick.  Returns (the next tick, OR of the status bits, an
    end code: END_NONE, or why the episode must end)."""
    cfg, plant, fx, noise, out = hw
    raw_all = out[0]
    info = out[1]
    Y = plant[0]
    realtime = pace[0] != 0.0
    t0c, cpt, nspc = pace[1], pace[2], pace[3]
    rate = safety[2]
    status_or = 0
    m = m0
    while m < m1:
        if stop[0] != 0:
            return m, status_or, END_STOP
        late = 0.0
        if realtime:
            dl = t0c + m * cpt
            now = float(cycles())
            while now < dl:
                now = float(cycles())
            late = now - dl
            k = skip_allowed(m, int(late // cpt), hold, m1, onboard) if late >= cpt else 0
            if k > 0:
                for _ in range(k):
                    hardware_tick(0, st[ST_COMMAND], cfg, plant, fx, noise, out)
                    _true_record(trec, m, Y, info, st[ST_COMMAND], fe[6][0], state_ok(0, plant, info), rate)
                    m += 1
                acct[0] += k
                acct[1] += k
                observe_tick(m, raw_all[0], hold, fe, ob, law, Y[0, :4], st)
                if m >= m1:
                    break
                late = now - (t0c + m * cpt)
            lateness[m] = late * nspc
        w0 = cycles()
        raw = raw_all[0]
        cmd, f, status, row = act_tick(m, onboard, host_action, cmd_step, cmd_id, m, hold, fe, ob, law, pol,
                                       safety, scale, raw, st, rows, obs_log, count)
        if realtime and late >= cpt:
            status |= SF.OVERRUN
        if acct[0] > 0:
            status |= SF.OVERRUN
        hardware_tick(0, cmd, cfg, plant, fx, noise, out)
        ok = state_ok(0, plant, info)
        status_or |= status
        if row >= 0:
            r = rows[row]
            r[LG.FORCE_APPLIED] = info[0, INFO_F_APPLIED]
            r[LG.STATUS] = status
            r[LG.LATENESS_NS] = late * nspc
            r[LG.SKIPPED] = acct[0]
            r[tc[TC_COMMAND]] = cmd
            r[tc[TC_X1]] = Y[0, 0]
            r[tc[TC_V1]] = Y[0, 1]
            r[tc[TC_X2]] = Y[0, 2]
            r[tc[TC_V2]] = Y[0, 3]
            r[tc[TC_FD]] = info[0, INFO_F_DEMAND]
            r[tc[TC_FA]] = info[0, INFO_F_APPLIED]
            r[tc[TC_SAT]] = info[0, INFO_SATURATED]
            r[tc[TC_FC]] = info[0, INFO_CONTACT_FORCE]
            r[tc[TC_STATUS]] = 0.0 if ok else 1.0
            r[tc[TC_E0]] = tvals[0]
            r[tc[TC_V0]] = tvals[1]
            r[tc[TC_TT]] = tvals[2]
        if status & SF.OVERRUN:
            acct[2] += 1
        acct[0] = 0
        mt = m
        m += 1
        if status & SF.FIRST_COMMAND_TIMEOUT:
            _true_record(trec, mt, Y, info, cmd, fe[6][0], ok, rate)
            return m, status_or, END_FIRST_COMMAND
        if status & SF.LATCHING:
            _true_record(trec, mt, Y, info, cmd, fe[6][0], ok, rate)
            return m, status_or, END_SAFETY
        if not ok:
            _true_record(trec, mt, Y, info, cmd, fe[6][0], ok, rate)
            return m, status_or, END_FAULT
        observe_tick(m, raw_all[0], hold, fe, ob, law, Y[0, :4], st)
        # a tick's detector bit is the one of the readings it produced
        _true_record(trec, mt, Y, info, cmd, fe[6][0], ok, rate)
        if row >= 0:
            rows[row, LG.COMPUTE_NS] = (cycles() - w0) * nspc
    return m, status_or, END_NONE


@jit(inline="always")
def _true_record(trec, m, Y, info, u, detected, ok, rate):
    """The virtual rig's true record of tick m (:mod:`impact_env.sim.records`)."""
    r = trec[m]
    r[R.REC_T] = (m + 1.0) / rate
    r[R.REC_X1] = Y[0, 0]
    r[R.REC_V1] = Y[0, 1]
    r[R.REC_X2] = Y[0, 2]
    r[R.REC_V2] = Y[0, 3]
    r[R.REC_U] = u
    r[R.REC_F_DEMAND] = info[0, INFO_F_DEMAND]
    r[R.REC_F_APPLIED] = info[0, INFO_F_APPLIED]
    r[R.REC_SATURATED] = info[0, INFO_SATURATED]
    r[R.REC_CONTACT_FORCE] = info[0, INFO_CONTACT_FORCE]
    r[R.REC_DETECTED] = detected
    r[R.REC_STATUS] = 0.0 if ok else 1.0
