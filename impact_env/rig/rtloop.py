"""The target's real-time core: a whole episode in ONE compiled call that releases the GIL, for
every driver and both modes (:class:`impact_env.rig.episode.Episode` runs it in its own thread).

Each tick m: (real time) spin on the CPU's cycle counter to the tick's absolute deadline (host
mode: reading the host's datagrams meanwhile, :mod:`impact_env.rig.wire`; a SCHED_FIFO loop
sleeps first where the kernel throttles real-time threads); let the ticks that cannot run on
time pass (:func:`impact_env.rig.controller.skip_allowed`); read the driver; the front end
(:func:`~impact_env.rig.controller.observe_tick`); host mode, at a step boundary: the step's
observation into the observation ring (:mod:`impact_env.rig.ring`) and, as an OBSERVATION, to
the host; the host's newest accepted command for the step becomes the one in use, the tick
waiting for it up to ``Timing.command_wait``; the onboard policy or that command, the residual
law and the safety layer (:func:`~impact_env.rig.controller.act_tick`); apply; the log row,
then the row count published for the log's writer thread.

The driver is one of two kinds, chosen by the type of ``io`` (numba compiles one loop for each):

* :class:`VirtualIO`: the virtual rig's hardware stage, compiled into the loop (its truth columns
  and true records too);
* :class:`CIO`: a driver's ``read``/``apply`` called through their addresses: a C driver's
  (:mod:`impact_env.rig.cdriver`, ``impact_env/deploy/rt/impact_driver.h``), or a Python
  :class:`~impact_env.rig.driver.RigDriver`'s through ctypes callbacks
  (:class:`impact_env.rig.cdriver.PythonCallbacks`; lock-step only: each call takes the GIL).

Time is the clock's: a command's age and the first-command allowance count periods of the clock
(the tick the clock is in), not ticks run, so they hold in seconds whatever the loop skipped.  A
stretch of more than ``max_gap_ticks`` periods with no tick run (a preempted loop, a stalled
driver) drives 0 N and ends the episode OVERRUN.  ``hl.shared[SH.stop]`` set by another thread
(DISARM, SIGTERM, a lost link) is read before every tick: 0 N at once and the loop ends.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import types
from numba.extending import overload

from impact_env._borrow import borrow
from impact_env._jit import jit
from impact_env.hardware.stage import (
    INFO_CONTACT_FORCE,
    INFO_F_APPLIED,
    INFO_F_DEMAND,
    INFO_SATURATED,
    HardwareParams,
    HardwareState,
    state_ok,
    tick,
)
from impact_env.plant.layout import STATE
from impact_env.rig import log as tick_log
from impact_env.rig import ring, safety, wire
from impact_env.rig.cfunc import call_apply, call_read, call_usleep, call_write, fence
from impact_env.rig.controller import (
    ACCT,
    END,
    OWN,
    DropConstants,
    HostCommand,
    TruthColumns,
    act_tick,
    observe_tick,
    skip_allowed,
    true_record,
)
from impact_env.rig.cycles import cycles
from impact_env.sim import records as sim_records


class VirtualIO(NamedTuple):
    """The virtual rig as the loop's driver: its hardware stage and what it logs of the truth."""

    hw: HardwareParams
    state: HardwareState
    truth: TruthColumns
    drop: DropConstants
    records: np.ndarray  # float64[horizon + 1, N_REC]: the true record of every tick that passed
    t_col: int  # the log column of the true time (true_t_s)


class CIO(NamedTuple):
    """A driver called through addresses as the loop's driver: its functions' addresses and
    context."""

    read: int
    apply: int
    ctx: int
    raw: np.ndarray  # float64[4]: the readings of the current tick
    truth: np.ndarray  # float64[4] NaN: a physical rig measures no body-1 state
    command_col: int  # the log column of the command sent
    records: np.ndarray  # float64[0, N_REC]: a physical rig has no true records to send the host
    # float64[1]: the force the driver says it applied (N), written by a Python driver's apply;
    # float64[0] for a C driver, whose ABI returns none: the log then has the force demanded
    applied: np.ndarray


class Timing(NamedTuple):
    realtime: bool  # pace the ticks on the clock (else lock-step: as fast as they run)
    lockstep_host: bool  # lock-step host mode: a step's first tick waits for the step's command
    t0: float  # cycles added to the deadline of tick 0 (one period after the loop starts; 0 normally)
    cycles_per_tick: float
    ns_per_cycle: float
    max_gap_ticks: int  # more periods than this with no tick run: 0 N, the episode ends OVERRUN
    # real-time host mode: a tick whose step's command has not come waits for it this long after
    # its deadline before it acts (0: not at all); cycles
    command_wait: float = 0.0
    # lock-step host mode: the OBSERVATION is sent again after this long without the command; cycles
    resend: float = 0.0
    # real time: sleep (clock_nanosleep) until this long before each deadline, then spin (0: spin
    # only); for a thread of a real-time policy, which may not spin for ever; cycles
    sleep_margin: float = 0.0


# -- the driver's operations, one implementation per kind ---------------------------------------------
def io_read(io, m):
    """Read tick m's readings; 0 ok, else the driver's code."""


def io_raw(io):
    """The readings of the current tick (float64[4])."""


def io_truth(io):
    """x1, v1, x2, v2 of a virtual rig (NaN on a physical one)."""


def io_seen(io, m, detected):
    """The front end has seen tick m's readings: a virtual rig's record of tick m - 1 gets the
    detector bit of the readings it produced."""


def io_apply(io, m, out, f, row, rows, detected, rate):
    """Apply command ``out`` for tick m (``f`` N after safety); complete the log row; returns 0
    ok, else a fault code."""


def io_skip(io, m, k, u, detected, rate):
    """Ticks m .. m + k - 1 pass unrun with command ``u`` held (the DAC holds it)."""


def io_zero(io, m):
    """0 N now (a stop, an overrun)."""


def io_records(io):
    """The true records of the ticks that passed (float64[ticks, N_REC]; none on a physical rig)."""


def _is(io, cls) -> bool:
    return isinstance(io, types.BaseNamedTuple) and getattr(io, "instance_class", None) is cls


@overload(io_read)
def _ov_read(io, m):
    if _is(io, VirtualIO):
        return lambda io, m: 0
    if _is(io, CIO):
        return lambda io, m: call_read(io.read, io.ctx, m, io.raw)


@overload(io_raw)
def _ov_raw(io):
    if _is(io, VirtualIO):
        return lambda io: io.state.out.raw[0]
    if _is(io, CIO):
        return lambda io: io.raw


@overload(io_truth)
def _ov_truth(io):
    if _is(io, VirtualIO):
        return lambda io: io.state.plant.y[0, :4]
    if _is(io, CIO):
        return lambda io: io.truth


@overload(io_seen)
def _ov_seen(io, m, detected):
    if _is(io, VirtualIO):
        def impl(io, m, detected):
            if m > 0:
                io.records[m - 1, sim_records.REC.detected] = detected
        return impl
    if _is(io, CIO):
        return lambda io, m, detected: None


@overload(io_apply)
def _ov_apply(io, m, out, f, row, rows, detected, rate):
    if _is(io, VirtualIO):
        def impl(io, m, out, f, row, rows, detected, rate):
            hw_s = io.state
            tick(0, out, io.hw, hw_s)
            ok = state_ok(0, hw_s)
            info = hw_s.out.info
            plant_states = hw_s.plant.y
            if row >= 0:
                r = rows[row]
                tc = io.truth
                r[tick_log.COL.force_applied_N] = info[0, INFO_F_APPLIED]
                r[tc.command] = out
                r[tc.x1] = plant_states[0, STATE.x1]
                r[tc.v1] = plant_states[0, STATE.v1]
                r[tc.x2] = plant_states[0, STATE.x2]
                r[tc.v2] = plant_states[0, STATE.v2]
                r[tc.force_demand] = info[0, INFO_F_DEMAND]
                r[tc.force_applied] = info[0, INFO_F_APPLIED]
                r[tc.saturated] = info[0, INFO_SATURATED]
                r[tc.contact_force] = info[0, INFO_CONTACT_FORCE]
                r[tc.status] = 0.0 if ok else 1.0
                r[tc.impact_energy] = io.drop.impact_energy
                r[tc.impact_speed] = io.drop.impact_speed
                r[tc.t_touch] = io.drop.t_touch
                r[io.t_col] = (m + 1.0) / rate
            true_record(io.records, m, plant_states, info, out, detected, ok, rate)
            return 0 if ok else -1
        return impl
    if _is(io, CIO):
        def impl(io, m, out, f, row, rows, detected, rate):
            rc = call_apply(io.apply, io.ctx, m, out)
            if row >= 0:
                r = rows[row]
                r[tick_log.COL.force_applied_N] = io.applied[0] if io.applied.shape[0] > 0 else f
                r[io.command_col] = out
            return rc
        return impl


@overload(io_skip)
def _ov_skip(io, m, k, u, detected, rate):
    if _is(io, VirtualIO):
        def impl(io, m, k, u, detected, rate):
            hw_s = io.state
            for i in range(k):
                tick(0, u, io.hw, hw_s)
                ok = state_ok(0, hw_s)
                true_record(io.records, m + i, hw_s.plant.y, hw_s.out.info, u, detected, ok, rate)
        return impl
    if _is(io, CIO):
        return lambda io, m, k, u, detected, rate: None


@overload(io_records)
def _ov_records(io):
    if _is(io, VirtualIO) or _is(io, CIO):
        return lambda io: io.records


@overload(io_zero)
def _ov_zero(io, m):
    if _is(io, VirtualIO):
        return lambda io, m: 0  # the target idles the virtual rig as the call returns
    if _is(io, CIO):
        return lambda io, m: call_apply(io.apply, io.ctx, m, 0.0)


# -- the host's commands ---------------------------------------------------------------------------------
@jit(inline="always")
def _offer(hl, step, val):
    """A command the wire accepted: the newest for the latest step waits to be used (latest wins);
    each one it replaces is superseded."""
    cs, cc = hl.cs, hl.cc
    if step > cs[ring.CS.heard_step]:
        cs[ring.CS.heard_step] = step
    if cs[ring.CS.next_step] < 0 or step >= cs[ring.CS.next_step]:
        if cs[ring.CS.next_step] >= 0:
            cc[ring.CC.superseded] += 1
        cs[ring.CS.next_step] = step
        cs[ring.CS.next_val] = val
    else:
        cc[ring.CC.superseded] += 1


@jit(inline="always")
def _poll(w, hl, step):
    """One waiting datagram through the wire (:func:`impact_env.rig.wire.read_one`); an accepted
    COMMAND is offered.  Returns what the wire did (NONE: nothing was waiting)."""
    r = wire.read_one(w, step)
    if r == wire.COMMAND:
        _offer(hl, w.st.cmd_step[0], w.st.cmd_val[0])
    elif r == wire.LATE:
        hl.cs[ring.CS.late_heard] = 1.0
    return r


@jit(inline="always")
def _select_command(hl, step):
    """The waiting command for ``step`` becomes the one in use from this tick on; one whose step
    is over before a tick could run it expires."""
    cs, cc = hl.cs, hl.cc
    nxt = cs[ring.CS.next_step]
    if nxt < 0 or nxt > step:
        return
    cs[ring.CS.next_step] = -1.0
    if nxt < step:
        cc[ring.CC.expired] += 1
        return
    if cs[ring.CS.cur_acted] == 0.0:
        cc[ring.CC.superseded] += 1
    cs[ring.CS.n_cmd] += 1.0
    cs[ring.CS.cur_step] = nxt
    cs[ring.CS.cur_val] = cs[ring.CS.next_val]
    cs[ring.CS.cur_id] = cs[ring.CS.n_cmd]
    cs[ring.CS.cur_acted] = 0.0


@jit(inline="always")
def _wake(hl):
    if hl.wake[1] >= 0:
        call_write(hl.wake[0], hl.wake[1], hl.byte)


@jit
def _publish_observation(m, status_or, p, s, hl, w, records):
    """The observation of the step that starts at tick m, with its telemetry: into the ring (the
    target's record of it) and, as an OBSERVATION datagram, to the host."""
    step = m // p.hold
    j = step % ring.N_OBS
    meta = hl.obs_meta[j]
    n = s.log.filled[0]
    rows = s.log.rows
    meta[ring.OM.step] = step
    meta[ring.OM.tick] = m
    meta[ring.OM.status] = status_or
    meta[ring.OM.demand] = rows[n - 1, tick_log.COL.force_demand_N] if n > 0 else 0.0
    meta[ring.OM.applied] = rows[n - 1, tick_log.COL.force_applied_N] if n > 0 else 0.0
    cs = hl.cs
    acted = cs[ring.CS.cur_acted] != 0.0 and cs[ring.CS.cur_step] >= 0
    meta[ring.OM.age] = m - s.own[OWN.cmd_first] if acted else -1.0
    obs = s.obs.obs[0]
    for i in range(obs.shape[0]):
        hl.obs[j, i] = obs[i]
    tel = hl.telem
    tel[0] = meta[ring.OM.demand]
    tel[1] = meta[ring.OM.applied]
    tel[2] = meta[ring.OM.age]
    r0 = r1 = 0
    if m >= p.hold and records.shape[0] > 0:  # a virtual rig: the true records of the step's ticks
        r0, r1 = m - p.hold, m
    wire.send_observation(w, m, step, status_or, obs, tel, records, r0, r1)
    fence()
    hl.shared[ring.SH.obs_head] = step + 1


# -- the loop -----------------------------------------------------------------------------------------------
# a tick's deadline this close (ns), the spin stops reading datagrams: one read and its tag take
# a few microseconds, and the tick must start on time
POLL_MARGIN_NS = 5_000.0
LATE_READS = 8  # datagrams read at most per tick when the loop is behind (no spin to read them in)


@jit(nogil=True)
def run_episode(m1, p, s, io, tm, acct, hl, w):
    """Ticks 0 .. m1 - 1 of an episode and the readings of tick m1 (module doc).  ``p``, ``s``: the
    controller's params and state (the front end has seen tick 0's readings); ``io``: VirtualIO or
    CIO; ``tm``: Timing; ``acct``: int64[N_ACCT] tick accounts; ``hl``: the rings (HostLink);
    ``w``: the wire (:mod:`impact_env.rig.wire`; host mode reads and sends its datagrams through it).
    Returns (the tick reached, OR of the status bits, the end code: END.none at the horizon)."""
    p, s, io, tm, hl, w = borrow(p), borrow(s), borrow(io), borrow(tm), borrow(hl), borrow(w)
    margin = POLL_MARGIN_NS / tm.ns_per_cycle
    st = s.own
    rows = s.log.rows
    hold = p.hold
    host = not p.onboard
    realtime = tm.realtime
    cpt, nspc = tm.cycles_per_tick, tm.ns_per_cycle
    # tick 0 is due one period after the loop starts (plus ``tm.t0``, an offset in cycles for
    # tests): the set-up before it (threads, the log file) must not make the episode start late
    t0c = float(cycles()) + cpt + tm.t0
    c_ref, n_ref = float(cycles()), float(wire.now_ns(w))  # the cycle counter against CLOCK_MONOTONIC
    sh, cs, cc = hl.shared, hl.cs, hl.cc
    status_or = 0
    end = END.none
    m = 0
    prev = -1.0  # the start of the last tick run (none yet: no gap before the first)
    while True:
        if sh[ring.SH.stop] != 0:
            io_zero(io, m)
            end = END.stop
            break
        late = 0.0
        clock_tick = m
        if realtime:
            dl = t0c + m * cpt
            now = float(cycles())
            if tm.sleep_margin > 0.0 and dl - now > tm.sleep_margin:
                wire.sleep_until_ns(w, np.int64(n_ref + (dl - tm.sleep_margin - c_ref) * nspc))
                now = float(cycles())
            while now < dl:
                if host and dl - now > margin:  # the host's datagrams, as they come
                    _poll(w, hl, m // hold)
                now = float(cycles())
            late = now - dl
            if prev >= 0.0 and now - prev > (tm.max_gap_ticks + 1) * cpt:  # no tick for too long: 0 N, end
                io_zero(io, m)
                k = min(int(late // cpt), m1 - m)
                acct[ACCT.unreported] += k
                acct[ACCT.skipped] += k
                m += k
                end = END.overrun
                break
            k = skip_allowed(m, int(late // cpt), hold, m1, p.onboard) if late >= cpt else 0
            if k > 0:
                io_skip(io, m, k, st[OWN.command], s.fe.detected[0], p.rate)
                m += k
                acct[ACCT.unreported] += k
                acct[ACCT.skipped] += k
                late = now - (t0c + m * cpt)
            prev = now
            clock_tick = max(m, int((now - t0c) // cpt))  # time in periods of the clock
        w0 = cycles()
        sh[ring.SH.tick] = m
        if m > 0:
            if io_read(io, m) != 0:
                io_zero(io, m)
                end = END.fault
                break
            observe_tick(m, io_raw(io), io_truth(io), p, s)
            io_seen(io, m, s.fe.detected[0])
        boundary = m % hold == 0
        if host and boundary:
            _publish_observation(m, status_or, p, s, hl, w, io_records(io))
        if m >= m1:
            break
        if host:
            step = m // hold
            for _ in range(LATE_READS):  # what came since the spin stopped reading (or, behind, at all)
                if _poll(w, hl, step) == wire.NONE:
                    break
            if boundary and step > 0 and cs[ring.CS.heard_step] < step - 1:
                # nothing from the host for the step that just ended: its datagrams stopped coming
                if cc[ring.CC.silent_from] < 0:
                    cc[ring.CC.silent_from] = step - 1
                cc[ring.CC.silent_steps] += 1
            if tm.lockstep_host and boundary:  # lock-step: the step's command first
                sent = float(cycles())
                while cs[ring.CS.next_step] < step and sh[ring.SH.stop] == 0:
                    if _poll(w, hl, step) != wire.NONE:
                        continue
                    if tm.resend > 0.0 and float(cycles()) - sent >= tm.resend:  # lost? send it again
                        wire.resend_observation(w)
                        sent = float(cycles())
                    call_usleep(hl.wake[2], 20)
                if sh[ring.SH.stop] != 0:
                    continue
            _select_command(hl, step)
            if realtime and tm.command_wait > 0.0 and cs[ring.CS.cur_step] != step:
                # the step's command has not come: wait for it, up to command_wait into the period
                until = t0c + m * cpt + tm.command_wait
                while float(cycles()) < until and sh[ring.SH.stop] == 0:
                    if _poll(w, hl, step) == wire.COMMAND:
                        _select_command(hl, step)
                        if cs[ring.CS.cur_step] == step:
                            break
        cmd = HostCommand(cs[ring.CS.cur_val], int(cs[ring.CS.cur_step]), int(cs[ring.CS.cur_id]))
        out, f, status, row = act_tick(m, clock_tick, cmd, p, s, io_raw(io))
        if host and status & safety.FIRST_COMMAND_TIMEOUT and cs[ring.CS.late_heard] != 0.0:
            # the allowance is for the host to answer: one whose COMMANDs come, but each after its
            # step, is answering late, and is treated as a late host is later in an episode (0 N,
            # NO_COMMAND, until one acts), not disarmed
            status &= ~safety.FIRST_COMMAND_TIMEOUT
        if realtime and late >= cpt:
            status |= safety.OVERRUN
        if acct[ACCT.unreported] > 0:
            status |= safety.OVERRUN
        rc = io_apply(io, m, out, f, row, rows, s.fe.detected[0], p.rate)
        status_or |= status
        if row >= 0:
            r = rows[row]
            r[tick_log.COL.status] = status
            r[tick_log.COL.lateness_ns] = late * nspc
            r[tick_log.COL.skipped_ticks] = acct[ACCT.unreported]
        if status & safety.OVERRUN:
            acct[ACCT.overruns] += 1
        acct[ACCT.unreported] = 0
        if host and cs[ring.CS.cur_acted] == 0.0 and st[OWN.cmd_id] == cs[ring.CS.cur_id]:
            cs[ring.CS.cur_acted] = 1.0
            cc[ring.CC.acted] += 1
        if row >= 0:
            rows[row, tick_log.COL.compute_ns] = (cycles() - w0) * nspc
        fence()
        sh[ring.SH.rows] = s.log.filled[0]
        m += 1
        if status & safety.FIRST_COMMAND_TIMEOUT:
            end = END.first_command
            break
        if status & safety.SENSOR_TIMEOUT:  # implausible readings outlasted the scene's limit
            end = END.sensor_fault
            break
        if status & safety.LATCHING:
            end = END.safety
            break
        if rc != 0:
            io_zero(io, m)
            end = END.fault
            break
    sh[ring.SH.tick] = m
    fence()
    sh[ring.SH.done] = 1
    _wake(hl)
    return m, status_or, end
