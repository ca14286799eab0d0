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

from impact_env.rig import cfunc, controller, protocol, ring, rtloop, safety, wire
from impact_env.rig.cdriver import CDriver
from impact_env.rig.cycles import cached_ns_per_cycle
from impact_env.rig.driver import VirtualRig
from impact_env.sim import records

_END = {
    controller.END.first_command: protocol.EndReason.FIRST_COMMAND_TIMEOUT,
    controller.END.safety: protocol.EndReason.SAFETY,
    controller.END.fault: protocol.EndReason.FAULT,
    controller.END.stop: protocol.EndReason.DISARMED,
    controller.END.sensor_fault: protocol.EndReason.SENSOR_FAULT,
    controller.END.overrun: protocol.EndReason.OVERRUN,
}


class Episode:
    """The running episode ``ep`` of ``target`` (a :class:`impact_env.rig.target.Target`), armed by
    ``arm_msg`` with controller ``ctl``."""

    def __init__(self, target, arm_msg: protocol.Message, armed: protocol.Armed, ctl, hold: int, seed: int,
                 policy=None):
        self.t = target
        self.arm_msg, self.armed = arm_msg, armed
        self.a = arm_msg.payload(protocol.Arm)
        self.ctl, self.hold, self.seed = ctl, hold, seed
        self.policy = policy  # the onboard policy or excitation (None: the host's commands), for the log
        self.datagrams0: dict[str, int] = {}  # the target's datagram counters at ARM
        self.ep = target.episode
        self.host = self.a.mode == "host"
        self.lockstep = target.cfg.lockstep
        self.horizon = self.a.horizon_ticks
        cfg = target.cfg
        self.link_timeout_s = self.a.link_timeout_ms / 1e3 if self.a.link_timeout_ms else (
            cfg.lockstep_link_timeout_s if self.lockstep else cfg.link_timeout_s)
        self.acct = np.zeros(controller.N_ACCT, dtype=np.int64)  # see rtloop.run_episode
        self.last_heard = time.perf_counter()
        self._authentic = target.link.filter.authentic
        self.status_or = 0
        self.m = 0
        self.obs_msg: protocol.Observation | None = None
        self.end_code = controller.END.none
        # a virtual rig's true record of every tick
        self.trec = np.full((self.horizon + 1, records.N_REC), np.nan) if target.driver.virtual else None
        log = ctl.log
        self.cols = {name: log.col(name) for name in log.names}
        self.hl: ring.HostLink | None = None  # the compiled loop's rings (impact_env.rig.ring), while it runs
        self.wire: wire.Wire | None = None  # host mode: the loop's wire (impact_env.rig.wire)
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
        return int(self.acct[controller.ACCT.overruns])

    @property
    def skipped_ticks(self) -> int:
        """Ticks of this episode that did not run (overruns), each reported on the next row."""
        return int(self.acct[controller.ACCT.skipped])

    # -- messages ----------------------------------------------------------------------------------------
    def take(self, msg: protocol.Message) -> str | None:
        """An incoming message during the episode; returns an end reason's name, or None."""
        t, tg = msg.type, self.t
        self.last_heard = time.perf_counter()
        # (the loop takes the host's COMMANDs off the wire itself: impact_env.rig.wire)
        if t == protocol.MsgType.DISARM:
            tg.reply(protocol.Ack(protocol.MsgType.DISARM, protocol.ErrorCode.OK, msg.seq, self.ep), msg)
            reason = msg.payload(protocol.Disarm).reason
            if reason == protocol.DISARM_CLOSING:  # the host is closing: its session ends with the episode
                tg.close_session_after_episode()
            # the host's task caught body 1: the episode ends CAUGHT, as the host says
            return "CAUGHT" if reason == protocol.DISARM_CAUGHT else "DISARMED"
        elif t == protocol.MsgType.ARM:
            if msg.body == self.a:  # the same request again (its ARMED was lost): answer it again
                tg.reply(self.armed, msg)
                return None
            tg.queue_arm(msg)  # a new episode: this one ends, that one starts
            return "DISARMED"
        elif t == protocol.MsgType.FETCH:
            tg.serve_fetch(msg)
        elif t == protocol.MsgType.HEARTBEAT:
            tg.reply(protocol.Heartbeat(int(tg.state), self.ep, self.m // self.hold, msg.seq), msg)
        elif t == protocol.MsgType.HELLO and msg.session == tg.link.session:
            tg.reply(tg.info(msg.payload(protocol.Hello).nonce), msg)
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
                "commands_acted": int(cc[ring.CC.acted]), "commands_superseded": int(cc[ring.CC.superseded]),
                "commands_expired": int(cc[ring.CC.expired]),
                "commands_unused_at_end": int(cs[ring.CS.next_step] >= 0) + int(cs[ring.CS.cur_acted] == 0.0),
                "host_silent_steps": int(cc[ring.CC.silent_steps]),
                "host_silent_from_step": int(cc[ring.CC.silent_from])}

    def final_row(self, raw: np.ndarray) -> None:
        """The row of the tick the loop ended at (the horizon, or a stop, an overrun): its
        readings (the last ones read) and observation, no command, 0 N (and the ticks skipped just
        before it, if any, flagged on it)."""
        skipped = int(self.acct[controller.ACCT.unreported])
        self.ctl.log.record(obs=self.ctl.obs, tick=self.m, t_s=self.m / self.t.rate,
                            accelerometer_mps2=raw[0], force_N=raw[1], potentiometer_m=raw[2],
                            action=math.nan, step=self.m // self.hold,
                            contact_detected=self.ctl.fe.detected[0], command_age_ticks=-1, command_step=-1,
                            skipped_ticks=skipped, status=safety.OVERRUN if skipped else 0)
        if skipped:
            self.acct[controller.ACCT.unreported] = 0
            self.acct[controller.ACCT.overruns] += 1

    # -- the compiled loop (rtloop) -------------------------------------------------------------------
    def run(self) -> protocol.EndReason:
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
            io: rtloop.CIO | rtloop.VirtualIO = rtloop.CIO(
                read, apply, ctx, raw0.copy(), np.full(4, np.nan), self.cols["command"],
                np.zeros((0, records.N_REC)), applied)
            ctl.start(raw0, None)
        else:
            hw = drv.hw
            hw.set_noise_block(max(self.horizon + 1, hw.noise_block))
            hw.refill_noise(self.horizon)  # the whole episode's noise now: no draws in the loop
            assert self.trec is not None  # a virtual rig's
            drop = controller.DropConstants(float(hw.impact_energy[0]), float(hw.impact_speed[0]),
                                            float(hw.t_touch[0]))
            io = rtloop.VirtualIO(hw.params, hw.state, controller.truth_columns(ctl.log), drop, self.trec,
                                  self.cols["true_t_s"])
            ctl.start(drv.read().copy(), drv.truth())
        wake_r, wake_w = os.pipe()
        os.set_blocking(wake_w, False)
        os.set_blocking(wake_r, False)
        hl = ring.host_link(ctl.layout.size, cfunc.libc_address("write"), wake_w,
                            cfunc.libc_address("usleep"))
        self.hl = hl
        link, f = tg.link, tg.link.filter
        if self.host:  # the loop owns the session's socket (else the target's) for the episode
            fd = link.endpoint.session_fd
            link.endpoint.session_busy = fd >= 0  # the loop reads it, the network thread the target's
            self.wire = wire.make(fd if fd >= 0 else link.endpoint.fileno(), f.key, f.nonce, f.session or 0,
                                self.ep, link.last_sender,
                                f.stream(f.session or 0, protocol.MsgType.COMMAND), link.seq, wake_fd=wake_w)
        else:
            self.wire = wire.none()
        max_gap = int(round(tg.cfg.max_gap_s * tg.rate))
        wait = tg.command_wait_s * 1e9 / nspc if self.host and not self.lockstep else 0.0
        sleep_margin_s = tg.placement.sleep_margin_for(self.horizon / tg.rate)
        tm = rtloop.Timing(not self.lockstep, self.lockstep and self.host, 0.0, cpt, nspc, max_gap, wait,
                           tg.cfg.resend_s * 1e9 / nspc, sleep_margin_s * 1e9 / nspc)
        result: list = []

        def loop():
            tg.placement.loop_thread()
            w = self.wire
            try:
                result.append(rtloop.run_episode(self.horizon, ctl.params, ctl.state, io, tm, self.acct, hl, w))
            finally:
                tg.placement.loop_done()

        stream = tg.open_stream(self, hl.shared[ring.SH.rows:ring.SH.rows + 1])
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
            wire.merge(self.wire, link)
            self._last_observation(hl)
        self.m, status, self.end_code = result[0]
        self.status_or |= status
        self.stop_tick = int(hl.shared[ring.SH.tick])
        if self.end_code in (controller.END.none, controller.END.stop, controller.END.overrun):
            self.final_row(io.raw if isinstance(io, rtloop.CIO) else drv.read())
        if self.end_code == controller.END.none:
            end = protocol.EndReason.HORIZON
        elif self.end_code == controller.END.stop:
            end = protocol.EndReason[why or "DISARMED"]
        else:
            end = _END[self.end_code]
        if tg.callbacks is not None and tg.callbacks.fault:  # what the Python driver raised or reported
            tg.note(f"episode {self.ep}: the driver {type(drv).__name__}: {tg.callbacks.take_fault()}")
        self.stream = stream
        return end

    def _network(self, rt, hl, wake_r) -> str | None:
        """The network while the loop runs (see :meth:`run`); returns the end reason's
        name it asked the loop to stop for, or None."""
        tg, link = self.t, self.t.link
        sh = hl.shared
        why: str | None = None
        own = link.endpoint.session_busy
        while True:
            done = sh[ring.SH.done] != 0 or not rt.is_alive()
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
                step = int(sh[ring.SH.tick]) // self.hold
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
                self.stop_asked_tick = int(sh[ring.SH.tick])
                sh[ring.SH.stop] = 1

    def _take_queued(self, why: str | None) -> str | None:
        """The datagrams the loop handed over (:func:`impact_env.rig.wire.queued`) through the
        link's filter, each accepted one taken; returns the first end reason one of them gave."""
        assert self.hl is not None and self.wire is not None, "the loop's rings and wire: only while it runs"
        link, sh = self.t.link, self.hl.shared
        step = int(sh[ring.SH.tick]) // self.hold
        for data, addr in wire.queued(self.wire):
            msg = link.take(data, addr, self.ep, step)
            if msg is not None and why is None:
                why = self.take(msg)
                if why:
                    self.stop_asked_tick = int(sh[ring.SH.tick])
                    sh[ring.SH.stop] = 1
        return why

    def _last_observation(self, hl) -> None:
        """The last OBSERVATION the loop sent, as a message (the target sends it again to a host
        still stepping an episode that ended)."""
        got = ring.newest_observation(hl, 0)
        if got is None:
            return
        meta, obs = got
        m = int(meta[ring.OM.tick])
        telem = [float(meta[ring.OM.demand]), float(meta[ring.OM.applied]), float(meta[ring.OM.age])]
        if self.trec is not None and m >= self.hold:
            rec = self.trec[m - self.hold:m]
            if not np.isnan(rec).any():
                telem += rec.ravel().tolist()
        self.obs_msg = protocol.Observation(
            self.ep,
            int(meta[ring.OM.step]),
            int(meta[ring.OM.status]) & protocol.U32,
            4,
            tuple(float(x) for x in obs[: self.ctl.layout.size]),
            tuple(telem),
        )

def os_read(fd: int) -> bytes:
    import os

    return os.read(fd, 4096)
