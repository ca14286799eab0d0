"""One episode on the target: the tick loop, the host's commands, the observations sent back.

One loop for every driver: the whole episode is ONE compiled call
(:func:`impact_env.rig.rtloop.run_episode`: pacing on the CPU's cycle counter, read, front end,
policy or the host's newest command, safety, apply, the log row) in its own thread with the GIL
released.  The virtual rig's hardware stage is compiled into it; a C driver's ``read`` and
``apply`` are called through their addresses (:mod:`impact_env.rig.cdriver`), and so are a
Python :class:`~impact_env.rig.driver.RigDriver`'s, through ctypes callbacks
(:class:`impact_env.rig.cdriver.PythonCallbacks`: lock-step only, the target refuses it for real
time).  Python stays off the tick otherwise: the calling thread is the network (the datagrams the
loop hands over, the link's watch, a stop through a flag the loop reads every tick), and a third
thread streams the log to disk (:class:`impact_env.rig.log.LogStream`).  In host mode the loop
sends, at every step boundary, the OBSERVATION of that step with the telemetry of
:mod:`impact_env.rig.protocol` (and a virtual rig's true records of the step's ticks).
"""

from __future__ import annotations

import math
import select
import time

import numpy as np

from impact_env.rig import cfunc as CF
from impact_env.rig import controller as CT
from impact_env.rig import protocol as P
from impact_env.rig import ring as RG
from impact_env.rig import rtloop as RL
from impact_env.rig import safety as SF
from impact_env.rig import wire as WR
from impact_env.rig.cdriver import CDriver
from impact_env.rig.cycles import cached_ns_per_cycle
from impact_env.rig.driver import VirtualRig
from impact_env.sim import records as R

_END = {CT.END.first_command: P.EndReason.FIRST_COMMAND_TIMEOUT, CT.END.safety: P.EndReason.SAFETY,
        CT.END.fault: P.EndReason.FAULT, CT.END.stop: P.EndReason.DISARMED,
        CT.END.sensor_fault: P.EndReason.SENSOR_FAULT, CT.END.overrun: P.EndReason.OVERRUN}


class Episode:
    """The running episode ``ep`` of ``target`` (a :class:`impact_env.rig.target.Target`), armed by
    ``arm_msg`` with controller ``ctl``."""

    def __init__(self, target, arm_msg: P.Message, armed: P.Armed, ctl, hold: int, seed: int):
        self.t = target
        self.arm_msg, self.armed = arm_msg, armed
        self.a: P.Arm = arm_msg.body
        self.ctl, self.hold, self.seed = ctl, hold, seed
        self.ep = target.episode
        self.host = self.a.mode == "host"
        self.lockstep = target.cfg.lockstep
        self.horizon = self.a.horizon_ticks
        cfg = target.cfg
        self.link_timeout_s = self.a.link_timeout_ms / 1e3 if self.a.link_timeout_ms else (
            cfg.lockstep_link_timeout_s if self.lockstep else cfg.link_timeout_s)
        self.acct = np.zeros(CT.N_ACCT, dtype=np.int64)  # see rtloop.run_episode
        self.last_heard = time.perf_counter()
        self._authentic = target.link.filter.authentic
        self.status_or = 0
        self.m = 0
        self.obs_msg: P.Observation | None = None
        self.end_code = CT.END.none
        # a virtual rig's true record of every tick
        self.trec = np.full((self.horizon + 1, R.N_REC), np.nan) if target.driver.virtual else None
        log = ctl.log
        self.cols = {name: log.col(name) for name in log.names}
        self.hl = None  # the compiled loop's rings (impact_env.rig.ring), while it runs
        self.wire: WR.Wire | None = None  # host mode: the loop's wire (impact_env.rig.wire)
        self.stream = None  # the log streamed to disk (impact_env.rig.log.LogStream), if any
        self.stop_asked_tick = -1  # the tick the loop was at when it was asked to stop
        self.stop_tick = -1  # the tick it stopped at

    def prefault(self) -> None:
        """Write every page of the episode's arrays now (the log's rows and observations, the
        true records): fresh memory is mapped on its first write, a page fault each
        4 kB (or a huge page's zeroing), which in the loop's first ticks made the first episode of
        a target late by milliseconds (OVERRUN, FIRST_COMMAND_TIMEOUT)."""
        log = self.ctl.log
        for arr in (log.rows, log.obs):
            arr.fill(0.0)
        if self.trec is not None:
            self.trec.fill(np.nan)

    @property
    def overruns(self) -> int:
        """Rows flagged OVERRUN this episode (a tick that started a period or more late, or
        after skipped ticks)."""
        return int(self.acct[CT.ACCT.overruns])

    @property
    def skipped_ticks(self) -> int:
        """Ticks of this episode that did not run (overruns), each reported on the next row."""
        return int(self.acct[CT.ACCT.skipped])

    # -- messages ----------------------------------------------------------------------------------------
    def take(self, msg: P.Message) -> str | None:
        """An incoming message during the episode; returns an end reason's name, or None."""
        t, tg = msg.type, self.t
        self.last_heard = time.perf_counter()
        # (the loop takes the host's COMMANDs off the wire itself: impact_env.rig.wire)
        if t == P.MsgType.DISARM:
            tg.reply(P.Ack(P.MsgType.DISARM, P.ErrorCode.OK, msg.seq, self.ep), msg)
            if msg.body.reason == P.DISARM_CLOSING:  # the host is closing: its session ends with the episode
                tg.close_session_after_episode()
            # the host's task caught body 1: the episode ends CAUGHT, as the host says
            return "CAUGHT" if msg.body.reason == P.DISARM_CAUGHT else "DISARMED"
        elif t == P.MsgType.ARM:
            if msg.body == self.a:  # the same request again (its ARMED was lost): answer it again
                tg.reply(self.armed, msg)
                return None
            tg.queue_arm(msg)  # a new episode: this one ends, that one starts
            return "DISARMED"
        elif t == P.MsgType.FETCH:
            tg.serve_fetch(msg)
        elif t == P.MsgType.HEARTBEAT:
            tg.reply(P.Heartbeat(int(tg.state), self.ep, self.m // self.hold, msg.seq), msg)
        elif t == P.MsgType.HELLO and msg.session == tg.link.session:
            tg.reply(tg.info(msg.body.nonce), msg)
        return None

    def link_lost(self, now: float) -> bool:
        """Nothing authentic from the host for the link timeout: not even a late command (those
        are dropped by the filter, but a host that sends them is alive)."""
        heard = self.t.link.filter.authentic + (int(self.wire.c.authentic[0]) if self.wire is not None else 0)
        if heard != self._authentic:
            self._authentic = heard
            self.last_heard = now
        return now - self.last_heard > self.link_timeout_s

    def command_counters(self) -> dict[str, int]:
        """What became of this episode's commands (every accepted one is counted once), as the
        loop kept them (:mod:`impact_env.rig.rtloop`, :mod:`impact_env.rig.wire`)."""
        assert self.hl is not None and self.wire is not None, "command_counters() before the episode ran"
        cs, cc = self.hl.cs, self.hl.cc
        return {"commands_accepted": int(self.wire.c.commands[0]),
                "commands_acted": int(cc[RG.CC.acted]), "commands_superseded": int(cc[RG.CC.superseded]),
                "commands_expired": int(cc[RG.CC.expired]),
                "commands_unused_at_end": int(cs[RG.CS.next_step] >= 0) + int(cs[RG.CS.cur_acted] == 0.0),
                "host_silent_steps": int(cc[RG.CC.silent_steps]),
                "host_silent_from_step": int(cc[RG.CC.silent_from])}

    def final_row(self, raw: np.ndarray, stopped: bool = False) -> None:
        """The row of tick ``horizon``: its readings and observation, no command (and the ticks
        skipped just before it, if any, flagged on it).  ``stopped``: the row of the tick the
        loop stopped at (a stop, an overrun): 0 N, the readings of the last tick read."""
        if stopped:
            skipped = int(self.acct[CT.ACCT.unreported])
            self.ctl.log.record(obs=self.ctl.obs, tick=self.m, t_s=self.m / self.t.rate,
                                accelerometer_mps2=raw[0], force_N=raw[1], potentiometer_m=raw[2],
                                action=math.nan, step=self.m // self.hold, force_demand_N=0.0,
                                force_applied_N=0.0, contact_detected=self.ctl.fe.detected[0],
                                command_age_ticks=-1, command_step=-1, skipped_ticks=skipped,
                                status=SF.OVERRUN if skipped else 0)
            if skipped:
                self.acct[CT.ACCT.unreported] = 0
                self.acct[CT.ACCT.overruns] += 1
            return
        skipped = int(self.acct[CT.ACCT.unreported])
        self.ctl.log.record(obs=self.ctl.obs, tick=self.m, t_s=self.m / self.t.rate,
                            accelerometer_mps2=raw[0], force_N=raw[1], potentiometer_m=raw[2],
                            action=math.nan, step=self.m // self.hold,
                            contact_detected=self.ctl.fe.detected[0], command_age_ticks=-1, command_step=-1,
                            skipped_ticks=skipped, status=SF.OVERRUN if skipped else 0)
        if skipped:
            self.acct[CT.ACCT.unreported] = 0
            self.acct[CT.ACCT.overruns] += 1

    # -- the compiled loop (rtloop) -------------------------------------------------------------------
    def run(self) -> P.EndReason:
        """The whole episode in one compiled call (:func:`impact_env.rig.rtloop.run_episode`) in
        its own thread, the GIL released.  In host mode the loop reads the socket itself and
        takes the host's COMMANDs and sends the OBSERVATIONs (:mod:`impact_env.rig.wire`); this
        thread (the target's serve thread, the main thread under ``rig serve``, where SIGTERM's
        handler runs) is the rest of the network: the datagrams the loop queued for it (onboard:
        the socket itself), the link's watch, a stop.  A third thread streams the log to disk."""
        import os
        import threading

        drv, ctl, tg = self.t.driver, self.ctl, self.t
        nspc = cached_ns_per_cycle()
        cpt = 1e9 / tg.rate / nspc
        if not isinstance(drv, VirtualRig):  # a C driver, or a Python one through its callbacks
            raw0 = drv.read_tick(0) if isinstance(drv, CDriver) else drv.read().copy()
            read, apply, ctx = drv.addresses if isinstance(drv, CDriver) else tg.callbacks.addresses
            applied = tg.callbacks.applied if tg.callbacks is not None else np.zeros(0)
            io = RL.CIO(read, apply, ctx, raw0.copy(), np.full(4, np.nan), self.cols["command"],
                        np.zeros((0, R.N_REC)), applied)
            ctl.start(raw0, None)
        else:
            hw = drv.hw
            hw.set_noise_block(max(self.horizon + 1, hw.noise_block))
            hw.refill_noise(self.horizon)  # the whole episode's noise now: no draws in the loop
            io = RL.VirtualIO(hw.params, hw.state, CT.truth_columns(ctl.log),
                              CT.DropConstants(float(hw.impact_energy[0]), float(hw.impact_speed[0]),
                                               float(hw.t_touch[0])), self.trec, self.cols["true_t_s"])
            ctl.start(drv.read().copy(), drv.truth())
        wake_r, wake_w = os.pipe()
        os.set_blocking(wake_w, False)
        os.set_blocking(wake_r, False)
        hl = RG.host_link(ctl.layout.size, CF.libc_address("write"), wake_w, CF.libc_address("usleep"))
        self.hl = hl
        link, f = tg.link, tg.link.filter
        if self.host:  # the loop owns the session's socket (else the target's) for the episode
            fd = link.endpoint.session_fd
            link.endpoint.session_busy = fd >= 0  # the loop reads it, the network thread the target's
            self.wire = WR.make(fd if fd >= 0 else link.endpoint.fileno(), f.key, f.nonce, f.session or 0,
                                self.ep, link.last_sender,
                                f.stream(f.session or 0, P.MsgType.COMMAND), link.seq, wake_fd=wake_w)
        else:
            self.wire = WR.none()
        max_gap = int(round(tg.cfg.max_gap_s * tg.rate))
        wait = tg.command_wait_s * 1e9 / nspc if self.host and not self.lockstep else 0.0
        tm = RL.Timing(not self.lockstep, self.lockstep and self.host, 0.0, cpt, nspc, max_gap, wait,
                       tg.cfg.resend_s * 1e9 / nspc, tg.placement.sleep_margin_s * 1e9 / nspc)
        result: list = []

        def loop():
            tg.placement.loop_thread()
            w = self.wire
            result.append(RL.run_episode(self.horizon, ctl.params, ctl.state, io, tm, self.acct, hl, w))

        stream = tg.open_stream(self, hl.shared[RG.SH.rows:RG.SH.rows + 1])
        tg.running_link = hl
        rt = threading.Thread(target=loop, name="rig-rt-loop", daemon=True)
        restore = tg.placement.python_thread()
        rt.start()
        self.last_heard = time.perf_counter()  # the link's watch starts with the loop, not at ARM
        try:
            why = self._network(rt, hl, wake_r)
        finally:
            rt.join()
            link.endpoint.session_busy = False
            restore()
            tg.running_link = None
            os.close(wake_r)
            os.close(wake_w)
        if self.host:
            self._take_queued(None)  # what the loop queued after the network thread's last look
            WR.merge(self.wire, link)
            self._last_observation(hl)
        self.m, status, self.end_code = result[0]
        self.status_or |= status
        self.stop_tick = int(hl.shared[RG.SH.tick])
        if self.end_code == CT.END.none:
            self.final_row(io.raw if isinstance(io, RL.CIO) else drv.read())
            end = P.EndReason.HORIZON
        elif self.end_code == CT.END.stop:
            self.final_row(io.raw if isinstance(io, RL.CIO) else drv.read(), stopped=True)
            end = P.EndReason[why or "DISARMED"]
        elif self.end_code == RL.END.overrun:
            self.final_row(io.raw if isinstance(io, RL.CIO) else drv.read(), stopped=True)
            end = P.EndReason.OVERRUN
        else:
            end = _END[self.end_code]
        if tg.callbacks is not None and tg.callbacks.fault:  # what the Python driver raised or reported
            tg.note(f"episode {self.ep}: the driver {type(drv).__name__}: {tg.callbacks.take_fault()}")
        self.stream = stream
        return end

    def _network(self, rt, hl, wake_r) -> str | None:
        """The network while the loop runs (see :meth:`run_compiled`); returns the end reason's
        name it asked the loop to stop for, or None."""
        tg, link = self.t, self.t.link
        sh = hl.shared
        why: str | None = None
        own = link.endpoint.session_busy
        while True:
            done = sh[RG.SH.done] != 0 or not rt.is_alive()
            if self.host:
                why = self._take_queued(why)
            if done:
                return why
            if self.host and not own:  # the loop reads the target's socket
                ready = select.select([wake_r], [], [], 0.005)[0]
            else:  # the loop reads the session's socket (or nothing): the rest is the target's
                ready = link.endpoint.wait_readable(0.005 if self.host else 0.02, wake_r)
            if wake_r in ready:
                try:
                    os_read(wake_r)
                except BlockingIOError:
                    pass
            if why is not None:
                continue
            if not self.host or own:
                step = int(sh[RG.SH.tick]) // self.hold
                for msg in link.recv_all(episode=self.ep, step=step):
                    why = self.take(msg)
                    if why:
                        break
            now = time.perf_counter()
            if not why and self.host and self.link_lost(now):
                why = "LINK_LOST"
            if not why and tg.stopping:
                why = "DISARMED"
            if why:
                self.stop_asked_tick = int(sh[RG.SH.tick])
                sh[RG.SH.stop] = 1

    def _take_queued(self, why: str | None) -> str | None:
        """The datagrams the loop handed over (:func:`impact_env.rig.wire.queued`) through the
        link's filter, each accepted one taken; returns the first end reason one of them gave."""
        link, sh = self.t.link, self.hl.shared
        step = int(sh[RG.SH.tick]) // self.hold
        for data, addr in WR.queued(self.wire):
            msg = link.take(data, addr, self.ep, step)
            if msg is not None and why is None:
                why = self.take(msg)
                if why:
                    self.stop_asked_tick = int(sh[RG.SH.tick])
                    sh[RG.SH.stop] = 1
        return why

    def _last_observation(self, hl) -> None:
        """The last OBSERVATION the loop sent, as a message (the target sends it again to a host
        still stepping an episode that ended)."""
        got = RG.newest_observation(hl, 0)
        if got is None:
            return
        meta, obs = got
        m = int(meta[RG.OM.tick])
        telem = [float(meta[RG.OM.demand]), float(meta[RG.OM.applied]), float(meta[RG.OM.age])]
        if self.trec is not None and m >= self.hold:
            rec = self.trec[m - self.hold:m]
            if not np.isnan(rec).any():
                telem += rec.ravel().tolist()
        self.obs_msg = P.Observation(self.ep, int(meta[RG.OM.step]), int(meta[RG.OM.status]) & P.U32, 4,
                                     tuple(float(x) for x in obs[:self.ctl.layout.size]), tuple(telem))

def os_read(fd: int) -> bytes:
    import os

    return os.read(fd, 4096)
