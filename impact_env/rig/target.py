"""The real-time target: ``impact-env rig serve``.  It owns the 10 kHz tick; its tick counter is
the only clock.

A session (one host at a time): HELLO -> INFO; the host may FETCH the scene (TOML) and upload a
policy file (POLICY_CHUNKs); ARM starts an episode (``driver.arm(seed)``, ``release()``); at its
end the target idles the driver, writes the episode's HDF5 log (``--log-dir``), sends
EPISODE_END, and serves the log to FETCH.

An episode, tick m = 0 .. horizon (H = hold_ticks; :mod:`impact_env.rig.controller`):

    read -> front end (filters, detector; observation at m % H == 0) -> [host mode: send the
    OBSERVATION of step m / H; take the host's latest COMMAND] -> onboard policy or the host's
    action (+ residual law) -> safety -> driver.apply -> log row

and at m = horizon the last observation only.  Modes:

* **host**: the host steps a Gymnasium env (:mod:`impact_env.rig.host`) and sends one COMMAND
  per policy step.  *Lock-step* (``--lockstep``): at a step boundary the target waits for the
  COMMAND of that step, re-sending the OBSERVATION every ``resend_s`` while it waits (lost
  datagrams cost time, never the episode), up to the link timeout.  *Real time*: the ticks run
  on the clock; the newest accepted command for the current step acts from the first tick at
  or after its arrival to the step's end, is repeated through the next step, then the force is
  0 (:mod:`impact_env.rig.safety`); a command for a step already over is counted late.
* **onboard**: the uploaded compiled policy (or a classic law) acts inside the tick; in
  lock-step the ticks run back to back.

A virtual rig (:class:`impact_env.rig.driver.VirtualRig`) adds to each OBSERVATION the true
records of the step's ticks (:mod:`impact_env.sim.records`), from which the host computes the
env's reward and termination with the env's own kernel, and logs the true state.

SIGTERM, SIGINT and :meth:`Target.close` leave the shaker at zero (``driver.idle()`` then
``shutdown()``).
"""

from __future__ import annotations

import hashlib
import secrets
import signal
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from impact_env.config import check_range
from impact_env.control.observation import make_layout
from impact_env.control.policy import CompiledPolicy
from impact_env.policy.registry import make_policy  # noqa: F401  (the policy registry loaded before serving)
from impact_env.rig import controller, excitation, protocol, ring, rtloop, safety, wire
from impact_env.rig import log as tick_log
from impact_env.rig.cdriver import CDriver, PythonCallbacks
from impact_env.rig.controller import TRUTH_COLUMNS, TRUTH_UNITS, Controller
from impact_env.rig.cycles import cached_ns_per_cycle
from impact_env.rig.driver import RigDriver, VirtualRig
from impact_env.rig.episode import Episode
from impact_env.rig.placement import Placement
from impact_env.rig.ring import SH
from impact_env.rig.safety import SafetyConfig
from impact_env.rig.transport import Endpoint, Link, UploadAssembler, chunk_reply
from impact_env.sim.records import N_REC

N_TELEMETRY = len(protocol.TELEMETRY_FIELDS)
NO_UPLOAD = "policy_sha256: no upload of that size and sha256"  # an ARM's refusal (fits its size)
N_ACTIONS = 1  # actions per COMMAND (ARMED's action_size): the shaker's one force
# real-time host mode's default wait for a step's command, in control periods: the host's round
# trip (about 50 us for ImpactCatchRig-v0 on a 2-core VM, scripts/bench_rig.py) must fit in it,
# and the tick's own work after it (act, safety, apply, the log row: 3-6 us at p99) in the rest
COMMAND_WAIT = 0.8
RCVBUF = 4 << 20  # bytes asked for the target's socket's receive buffer


@dataclass
class TargetConfig:
    """How the target runs (SI units)."""

    lockstep: bool = False
    log_dir: Path | None = None
    safety: SafetyConfig | None = None
    # host mode, when ARM gives none: no datagram from the host for this long ends the episode.  In
    # real time the watchdog has zeroed the force long before; in lock-step the rig waits (a
    # host may pause between steps, e.g. for a PPO update), so the timeout only frees the target.
    link_timeout_s: float = 0.5
    lockstep_link_timeout_s: float = 60.0
    # lock-step host mode: the OBSERVATION is sent again after this long without a command
    resend_s: float = 0.02
    # lock-step: idle time assumed between episodes (the coil cools in the RMS window)
    rearm_idle_s: float = 1.0
    seed_offset: int = 0  # added to every ARM's seed (0: the drops ImpactCatch-v0 meets for the same seeds)
    # the shared key (impact_env.rig.auth); b"": none, and then only loopback peers are answered
    key: bytes = b""
    # an idle session whose host has sent nothing for this long is closed (another host may open one)
    session_timeout_s: float = 60.0
    # real time: a stretch longer than this with no tick run (a preempted loop, a stalled driver)
    # drives 0 N and ends the episode OVERRUN; s
    max_gap_s: float = 1e-3
    # the longest episode ARM may ask for (s): a longer horizon is refused before anything moves
    max_horizon_s: float = 60.0
    # the log streamed to disk during the episode is flushed this often (s)
    log_flush_s: float = 0.05
    # real-time host mode: a tick whose step's command has not arrived waits for it this long
    # after its deadline before it acts (s; None: COMMAND_WAIT of the control period, leaving the
    # tick's own work the rest).  A host that answers an OBSERVATION within it acts in the step it was asked
    # for, 1 tick at hold 1 included; the force then changes that late in the tick (as a DAC
    # written then): the round trip is the host's sensor-to-actuator delay
    command_wait_s: float | None = None
    # the real-time loop's CPU (None: the last one allowed when there are two or more; -1: not
    # pinned) and its thread's nice value (0: unchanged): impact_env.rig.placement
    loop_cpu: int | None = None
    loop_nice: int = 0
    loop_fifo: int | None = 0  # SCHED_FIFO priority of the loop's thread (0: none; None: where permitted)

    def __post_init__(self):
        if self.command_wait_s is not None:
            check_range("command_wait_s", self.command_wait_s, "s", 0.0, 1.0)
        check_range("max_gap_s", self.max_gap_s, "s", 0.0, 10.0, lo_open=True)
        check_range("max_horizon_s", self.max_horizon_s, "s", 0.0, 3600.0, lo_open=True)
        check_range("log_flush_s", self.log_flush_s, "s", 0.0, 0.1, lo_open=True)


class Target:
    """The target process for one ``driver`` (see the module doc).  ``serve()`` runs until
    :meth:`stop`, SIGTERM or SIGINT (installed by :meth:`install_signal_handlers`)."""

    def __init__(self, driver: RigDriver, bind: str = "udp://127.0.0.1:0",
                 config: TargetConfig | None = None):
        self.driver = driver
        self.cfg = config or TargetConfig()
        #: a Python driver's read and apply as the compiled loop calls them (None: the virtual
        #: rig's hardware stage is compiled into the loop; a C driver's functions are called directly)
        self.callbacks = None if isinstance(driver, (VirtualRig, CDriver)) else PythonCallbacks(driver)
        if self.callbacks is not None and driver.virtual:
            raise ValueError(f"the Python driver {type(driver).__name__} says virtual = True: only "
                             "VirtualRig is a virtual rig (the loop runs its hardware stage and logs its truth); a "
                             "Python driver is seen through read() and apply() only (virtual = False)")
        if self.callbacks is not None and not self.cfg.lockstep:
            what = f"the Python driver {type(driver).__name__}"
            raise ValueError(f"{what} cannot keep real time: its read() and apply() would run Python on "
                             "every 100 us tick (the GIL, the garbage collector and the interpreter are late "
                             "by milliseconds under load). A Python RigDriver is for lock-step testing "
                             "(rig serve --lockstep). For real time write the driver in C against "
                             "impact_env/deploy/rt/impact_driver.h and load it with rig serve --driver "
                             "LIB.so (docs/rig/drivers.md)")
        self.running_link = None  # the running compiled loop's rings (impact_env.rig.ring)
        self.scene = driver.scene
        self.rate = float(self.scene.control_rate)
        wait = self.cfg.command_wait_s
        #: real-time host mode's wait for a step's command (s): TargetConfig.command_wait_s
        self.command_wait_s = COMMAND_WAIT / self.rate if wait is None else float(wait)
        if self.command_wait_s * self.rate > 0.9:
            raise ValueError(f"command_wait_s = {self.command_wait_s:g} s is more than 0.9 of the control "
                             f"period ({1 / self.rate:g} s): the tick's own work needs the rest")
        self.placement = Placement(self.cfg.loop_cpu, self.cfg.loop_nice, self.cfg.loop_fifo)
        # a receive buffer for a flood to fill while the loop cannot read (the kernel caps it at
        # net.core.rmem_max: 4 MB here, 208 kB on a stock kernel); the session's host gets a socket
        # of its own (Endpoint.open_session), so that a flood fills this buffer, not the host's
        self.endpoint = Endpoint(bind, rcvbuf=RCVBUF)
        self.link = Link(self.endpoint, "target", key=self.cfg.key, on_stranger=self._stranger)
        self.link.on_unauthenticated = self._unauthenticated
        self.link.on_handshake = self.handshake
        self.link.on_refused = self._refused
        self.link.filter.loopback_only = not self.cfg.key
        self.link.filter.n_actions = N_ACTIONS  # a COMMAND of another count is refused
        self._heard = 0.0  # perf_counter of the session host's last accepted datagram
        self._close_session = False
        self.scene_toml = self.scene.to_toml().encode()
        self.scene_sha = hashlib.sha256(self.scene_toml).digest()
        self.upload = UploadAssembler()
        self.state = protocol.TargetState.IDLE
        self.episode = 0
        self.episodes: dict[int, bytes] = {}  # episode -> its log file's bytes (the latest few)
        self.last_end: protocol.EpisodeEnd | None = None
        self._stop = threading.Event()
        self.signalled = 0  # the signal that stopped serve() (install_signal_handlers), 0 none
        self._pending: protocol.Message | None = None  # an ARM that ended the episode before it
        self._last_obs: protocol.Observation | None = None  # the last OBSERVATION of the last episode
        self._closed = False
        self.notes: list[str] = []  # what note() said (the last 64)
        self.on_note: Callable[[str], None] | None = None  # called with each note (rig serve prints it)
        # since the target started (the logs' counters are per episode)
        self.counters = {"episodes": 0, "sessions": 0, "overruns": 0, "skipped_ticks": 0, "watchdog_trips": 0,
                         "commands_after_end": 0, "overrun_episodes": 0}
        driver.initialise()
        self._warm_up()

    def _warm_up(self) -> None:
        """Compile (or load from the cache) the controller's kernels before serving, so that the
        first episode's first tick is not a compile: one tick of a throwaway controller on zero
        readings, driver untouched."""
        layout = make_layout(self.scene, "sensors", 1)
        law = CompiledPolicy.from_law("passive", {}, {}, self.scene, "sensors")
        ctl = Controller(self.scene, layout, 1, 4, "onboard", law, law, self.cfg.safety,
                         extra_columns=TRUTH_COLUMNS if self.driver.virtual else ("command",))
        ctl.start(np.zeros(4), None)
        ctl.drain(1)
        ctl.log.record(tick=0)
        self._warm_up_loop(ctl)
        self._warm_up_log(ctl)

    def _warm_up_log(self, ctl: Controller) -> None:
        """h5py imported and the HDF5 library started now, not in the first episode: a log
        streamed and finished, and one written, in a throwaway folder."""
        meta = tick_log.EpisodeMeta(
            scene_toml="",
            mode="onboard",
            hold_ticks=1,
            seed=0,
            control_rate_hz=self.rate,
            obs_names=ctl.layout.names,
        )
        with tempfile.TemporaryDirectory(prefix="impact-env-rig-warm-") as tmp:
            ctl.log.record(tick=0)
            stream = tick_log.LogStream(
                ctl.log, Path(tmp) / "warm.h5.partial", meta, np.ones(1, np.int64), 1.0
            )
            stream.finish(meta, tmp)
            tick_log.write_episode(ctl.log, tmp, meta, name="written.h5").read_bytes()
        ctl.log.reset()

    def _warm_up_loop(self, ctl: Controller) -> None:
        """Compile (or load) the loop for this driver's kind, both modes, on a throwaway
        controller in lock-step: one tick of a virtual rig's hardware on a throwaway drop; no
        tick of a driver called by address (it is not called before its first episode)."""
        cached_ns_per_cycle(refresh=True)
        if not isinstance(self.driver, VirtualRig):
            if isinstance(self.driver, CDriver):
                read, apply, ctx = self.driver.addresses
            else:
                assert self.callbacks is not None  # a Python driver's
                read, apply, ctx = self.callbacks.addresses
            io: rtloop.CIO | rtloop.VirtualIO = rtloop.CIO(
                read, apply, ctx, np.zeros(4), np.full(4, np.nan), ctl.log.col("command"),
                np.zeros((0, N_REC)), np.zeros(0 if self.callbacks is None else 1))
            m1 = 0
        else:
            hw = self.driver.hw
            hw.refill_noise(2)
            io = rtloop.VirtualIO(
                hw.params,
                hw.state,
                controller.truth_columns(ctl.log),
                controller.DropConstants(0.0, 0.0, 0.0),
                np.zeros((4, N_REC)),
                ctl.log.col("true_t_s"),
            )
            m1 = 1
        tm = rtloop.Timing(False, False, 0.0, 1.0, 1.0, 10, 0.0, 0.0, 0.0)
        for onboard in (True, False):
            hl = ring.host_link(ctl.layout.size)
            rtloop.run_episode(m1, ctl.params._replace(onboard=onboard), ctl.state, io, tm,
                           np.zeros(controller.N_ACCT, dtype=np.int64), hl, wire.none())
            ctl.log.reset()

    @property
    def address(self) -> str:
        return self.endpoint.address

    def note(self, text: str) -> None:
        """Something the operator should read (``rig serve`` prints it): kept in ``notes`` (the
        last 64) and passed to ``on_note``."""
        self.notes.append(text)
        del self.notes[:-64]
        if self.on_note is not None:
            self.on_note(text)

    def stop(self) -> None:
        """Stop serving; a running compiled loop sees it before its next tick (0 N, DISARMED)."""
        self._stop.set()
        hl = self.running_link
        if hl is not None:
            hl.shared[SH.stop] = 1

    def install_signal_handlers(self) -> None:
        """SIGTERM and SIGINT stop the serve loop, which zeroes the shaker on its way out
        (``signalled``: the signal's number)."""
        def handler(signum, _frame):
            self.signalled = signum
            self.stop()

        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, handler)

    def close(self) -> None:
        """Zero the shaker, close the driver and the socket (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            self.driver.idle()
        finally:
            self.driver.shutdown()
            self.endpoint.close()

    # -- the idle loop ---------------------------------------------------------------------------
    def serve(self, idle_poll_s: float = 0.05) -> None:
        """Answer requests and run episodes until stopped; leaves the shaker at zero."""
        try:
            while not self._stop.is_set():
                msg, self._pending = self._pending, None
                if msg is None:
                    msg = self.link.recv(idle_poll_s)
                if msg is not None:
                    self._heard = time.perf_counter()
                    self._handle_idle(msg)
                silent = time.perf_counter() - self._heard > self.cfg.session_timeout_s
                if self._close_session or (self.link.filter.peer is not None and silent):
                    self.end_session()
        finally:
            self.close()

    # -- sessions ----------------------------------------------------------------------------------
    @property
    def keyed(self) -> bool:
        return bool(self.cfg.key)

    def handshake(self, msg: protocol.Message, addr: tuple) -> None:
        """A HELLO or RESPONSE the filter accepted (the link's ``on_handshake``, idle or
        running).  A HELLO opens nothing: it is answered with a CHALLENGE (a fresh target nonce,
        the same one for a retried HELLO; the filter's per-source limit has let it through).  A
        RESPONSE that answers a live challenge sent to ``addr`` (the filter checked it, and spent
        the challenge) opens the session, or confirms it, and is answered with INFO."""
        f = self.link.filter
        if msg.type == protocol.MsgType.HELLO:
            nonce = msg.payload(protocol.Hello).nonce
            target_nonce = f.challenges.issue(protocol.source(addr), msg.session, nonce)
            self._send_raw(protocol.Challenge(nonce, target_nonce), msg.session, addr, self.cfg.key, msg)
            return
        if self.state == protocol.TargetState.RUNNING and msg.session != f.session:
            self._send_raw(protocol.Error(protocol.ErrorCode.BUSY, msg.seq, "busy: an episode is running"),
                           msg.session, addr, self.cfg.key, msg)
            return
        self.open_session(msg, addr)
        # from the target's own address, where the host waits for it: INFO names the session's port
        self._send_raw(self.info(msg.payload(protocol.Response).nonce), msg.session, addr, self.cfg.key, msg)

    def open_session(self, msg: protocol.Message, addr: tuple) -> None:
        """A RESPONSE that answers a live challenge (from the session's host, or any allowed peer
        while none is open): a new session id gets a fresh session nonce and pins the host's
        address and port; the same id again (the host says HELLO at every ARM) keeps them."""
        f = self.link.filter
        if f.session != msg.session or f.peer is None:
            self.link.session = msg.session  # a new session's streams start empty
            f.nonce = secrets.randbits(64) | 1
            f.peer = addr
            self.counters["sessions"] += 1
            # the session's own socket, connected to its host, bound without SO_REUSEPORT: no
            # other process can bind it, and only the host's datagrams reach it
            self.endpoint.open_session(addr)
        response = msg.payload(protocol.Response)
        f.opened = (protocol.source(addr), msg.session, response.nonce, response.target_nonce)
        self.link.last_sender = addr
        self._heard = time.perf_counter()

    def end_session(self) -> None:
        """Forget the session: the next handshake from any allowed peer opens one."""
        f = self.link.filter
        self.link.session = None
        f.peer, f.nonce, f.opened = None, 0, None
        self._close_session = False
        self.endpoint.close_session()

    def _stranger(self, msg: protocol.Message, addr: tuple) -> None:
        """A well-tagged datagram from another address than the session's host's: counted by the
        filter (``stranger``); a HELLO is answered with an ERROR (BUSY) that names no host, no
        larger than the HELLO, within the per-source reply rate; the session is kept."""
        if msg.type == protocol.MsgType.HELLO and self.link.filter.allow_reply(addr):
            err = protocol.Error.fitting(
                protocol.ErrorCode.BUSY,
                msg.seq,
                "busy: another host's session is open",
                protocol.OVERHEAD + protocol.Hello.FMT.size,
            )
            if err is not None:
                self._send_raw(err, msg.session, addr, self.cfg.key, msg)

    def _unauthenticated(self, data: bytes, addr: tuple) -> None:
        """A HELLO whose tag does not check: answered (tagged without a key, so that a host with
        none or another can read it) with an ERROR no larger than the datagram, within the
        per-source reply rate.  It says only which side lacks the key: a host cannot check who
        sent it, and composes its message to the user itself."""
        text = "refused: this target has a key" if self.keyed else "refused: this target has no key"
        try:
            head = protocol.HEADER.unpack_from(data)
        except Exception:  # noqa: BLE001 (a datagram shorter than a header: nothing to answer)
            return
        err = protocol.Error.fitting(protocol.ErrorCode.UNAUTHENTICATED, head[6], text, len(data))
        if err is not None and self.link.filter.allow_reply(addr):
            self._send_raw(err, head[5], addr, b"")

    def _refused(self, refusal: tuple, addr: tuple) -> None:
        """A request of the session's host with a field out of range (the link's ``on_refused``):
        answered with an ERROR naming the field and its range, no larger than the request, within
        the per-source rate of refusals."""
        code, seq, text, size = refusal
        err = protocol.Error.fitting(code, seq, text, size)
        if err is not None and self.link.filter.allow_refusal(addr):
            self.link.send(err, addr=addr)

    def _send_raw(self, body: protocol.Body, session: int, addr: tuple, key: bytes,
                  reply_to: protocol.Message | None = None) -> None:
        """Send ``body`` to ``addr`` in ``session`` (not necessarily the open one), numbered from
        the link's counter so that a host's stream of these never sees a number twice."""
        seq, self.link.seq = self.link.seq, (self.link.seq + 1) & protocol.U32
        msg = protocol.Message(body, session=session, seq=seq, host_ns=reply_to.host_ns if reply_to else 0,
                        target_ns=time.perf_counter_ns() & protocol.U64)
        self.endpoint.send(protocol.encode(msg, key, 0), addr, main=True)

    # -- what a running episode may ask of its target ----------------------------------------------
    @property
    def stopping(self) -> bool:
        """The target is shutting down: the episode ends before its next tick."""
        return self._stop.is_set()

    def queue_arm(self, msg: protocol.Message) -> None:
        """An ARM that ended the running episode: it starts the next one."""
        self._pending = msg

    def close_session_after_episode(self) -> None:
        """The host is closing: its session ends with the episode."""
        self._close_session = True

    def reply(self, body: protocol.Body, to: protocol.Message) -> None:
        self.link.send(body, reply_to=to, addr=self.link.last_sender)

    def _error(self, to: protocol.Message, code: int, text: str, fit: bool = False) -> None:
        """An ERROR answering ``to``.  ``fit`` (a refused ARM): no larger than ``to`` was (its
        text cut to fit: the field it names comes first), within the per-source rate of refusals."""
        if not fit:
            self.reply(protocol.Error.shorten(code, to.seq, text), to)
            return
        err = protocol.Error.fitting(code, to.seq, text, protocol.OVERHEAD + len(to.body.pack()))
        if err is not None and self.link.filter.allow_refusal(self.link.last_sender):
            self.reply(err, to)

    def _handle_idle(self, msg: protocol.Message) -> None:
        t = msg.type
        if t == protocol.MsgType.FETCH:
            self.serve_fetch(msg)
        elif t == protocol.MsgType.POLICY_CHUNK:
            self.reply(self.upload.add(msg.payload(protocol.PolicyChunk), msg.seq), msg)
        elif t == protocol.MsgType.ARM:
            self._arm(msg)
        elif t == protocol.MsgType.DISARM:
            self.reply(protocol.Ack(protocol.MsgType.DISARM, protocol.ErrorCode.OK, msg.seq, 0), msg)
            if msg.payload(protocol.Disarm).reason == protocol.DISARM_CLOSING:  # the host is closing
                self._close_session = True
        elif t == protocol.MsgType.COMMAND:
            self.counters["commands_after_end"] += 1  # for an episode already over: never applied
            if self._last_obs is not None and msg.payload(protocol.Command).episode == self._last_obs.episode:
                # a host still stepping the episode that ended: its last OBSERVATION or the
                # EPISODE_END was lost, send them again
                self.link.send(self._last_obs, addr=self.link.last_sender)
                if self.last_end is not None and self.last_end.episode == self._last_obs.episode:
                    self.link.send(self.last_end, addr=self.link.last_sender)
        elif t == protocol.MsgType.HEARTBEAT:
            self.reply(protocol.Heartbeat(int(self.state), self.episode, 0, msg.seq), msg)

    def serve_fetch(self, msg: protocol.Message) -> None:
        b = msg.payload(protocol.Fetch)
        if b.resource == protocol.Resource.SCENE:
            self.reply(chunk_reply(self.scene_toml, b, msg.seq), msg)
        elif b.resource == protocol.Resource.EPISODE and b.item in self.episodes:
            self.reply(chunk_reply(self.episodes[b.item], b, msg.seq), msg)
        elif (b.resource == protocol.Resource.EPISODE and b.item == self.episode
                and self.state == protocol.TargetState.RUNNING):
            self._error(msg, protocol.ErrorCode.BUSY, f"episode {b.item} is still running")
        else:
            self._error(msg, protocol.ErrorCode.UNKNOWN_RESOURCE, f"no resource {b.resource} item {b.item}")

    # -- arming ------------------------------------------------------------------------------------
    def _arm(self, msg: protocol.Message) -> None:
        a = msg.payload(protocol.Arm)
        try:
            self._check_bounds(a)
            policy = residual = None
            kind = a.kind
            if kind in (protocol.EpisodeKind.SHAKER, protocol.EpisodeKind.QUIET):
                policy = self._excitation(a, kind)
            elif a.policy_size:
                data = self.upload.data if self.upload.complete else b""
                if len(data) != a.policy_size or hashlib.sha256(data).digest() != a.policy_sha256:
                    raise _Refused(protocol.ErrorCode.POLICY_REJECTED, NO_UPLOAD)
                pol = CompiledPolicy.from_dict(__import__("json").loads(data.decode()), "the uploaded policy")
                pol.check_scene(self.scene)
                if a.mode == "onboard":
                    policy, residual = pol, pol.residual_policy()
                # host mode: an uploaded law is the residual under the host's actions
                elif pol.law is not None:
                    residual = pol
                else:
                    raise _Refused(protocol.ErrorCode.POLICY_REJECTED,
                                   "policy: host mode takes a classic law, not a network")
            elif a.mode == "onboard":
                raise _Refused(protocol.ErrorCode.BAD_REQUEST,
                               "policy_size=0: onboard mode needs an uploaded policy")
            if a.mode == "onboard":
                assert policy is not None  # onboard without one was refused above
                observation, history, hold = policy.observation, policy.history, policy.hold_ticks
            else:
                observation, history, hold = a.observation, a.history, a.hold_ticks
            if a.horizon_ticks % hold:
                raise _Refused(protocol.ErrorCode.BAD_REQUEST,
                               f"horizon_ticks={a.horizon_ticks} % hold_ticks={hold} != 0")
            layout = make_layout(self.scene, observation, history)
            ctl = Controller(self.scene, layout, hold, a.horizon_ticks, a.mode, policy, residual,
                             self.cfg.safety,
                             extra_columns=TRUTH_COLUMNS if self.driver.virtual else ("command",),
                             observation=observation)
            if a.mode == "host" and a.first_command_timeout_ticks > 0:
                # the host's own allowance for its first command (the force is 0 N until then)
                ctl.params.safety[safety.PARAM.first] = a.first_command_timeout_ticks
        except _Refused as exc:
            self._error(msg, exc.code, str(exc), fit=True)
            return
        except (ValueError, KeyError, UnicodeDecodeError) as exc:
            self._error(msg, protocol.ErrorCode.BAD_REQUEST, f"{type(exc).__name__}: {exc}", fit=True)
            return
        for k, v in TRUTH_UNITS.items():
            if k in ctl.log.extra_units:
                ctl.log.extra_units[k] = v
        self.episode += 1
        self._run_episode(msg, ctl, hold, policy)

    @property
    def max_horizon_ticks(self) -> int:
        """The longest episode ARM may ask for (``max_horizon_s``), in ticks: also the bound of
        its first-command and link timeouts."""
        return int(self.cfg.max_horizon_s * self.rate)

    def _check_bounds(self, a: protocol.Arm) -> None:
        """ARM's fields against this target's bounds (the protocol's ranges were checked when it
        was decoded): refused OUT_OF_RANGE naming the first field out, and its range."""
        top = self.max_horizon_ticks
        for name, value, hi in (("horizon_ticks", a.horizon_ticks, top),
                                ("first_command_timeout_ticks", a.first_command_timeout_ticks, top),
                                ("link_timeout_ms", a.link_timeout_ms, int(self.cfg.max_horizon_s * 1e3)),
                                ("options", a.options, protocol.ARM_OPTIONS_MAX)):
            if value > hi:
                raise _Refused(protocol.ErrorCode.OUT_OF_RANGE, f"{name}={value} [0,{hi}]")

    def _excitation(self, a: protocol.Arm, kind: protocol.EpisodeKind):
        """The open-loop "policy" of an identification episode with body 1 held: the uploaded
        excitation (:mod:`impact_env.rig.excitation`), or 0 N for a quiet one without upload."""
        if a.mode != "onboard":
            raise _Refused(
                protocol.ErrorCode.BAD_REQUEST, f"mode=host: a {kind.name.lower()} episode runs onboard"
            )
        exc = excitation.Excitation()
        if a.policy_size:
            data = self.upload.data if self.upload.complete else b""
            if len(data) != a.policy_size or hashlib.sha256(data).digest() != a.policy_sha256:
                raise _Refused(protocol.ErrorCode.POLICY_REJECTED, NO_UPLOAD)
            exc = excitation.Excitation.from_json(data, "the uploaded excitation")
        if kind == protocol.EpisodeKind.QUIET and exc.signal != "zero":
            raise _Refused(
                protocol.ErrorCode.BAD_REQUEST, f"policy: a quiet episode drives 0 N, not {exc.signal}"
            )
        cfg = self.cfg.safety or SafetyConfig()
        cmds = exc.commands(self.rate, a.horizon_ticks, float(self.scene.effects.command_scale), cfg.peak_n,
                            cfg.continuous_n)
        return excitation.ExcitationPolicy(exc, cmds, make_layout(self.scene, "sensors", 1).size,
                                   float(self.scene.effects.command_scale))

    # -- one episode ---------------------------------------------------------------------------------
    def _run_episode(self, arm_msg: protocol.Message, ctl: Controller, hold: int, policy) -> None:
        a = arm_msg.payload(protocol.Arm)
        datagrams0 = self._datagram_counts()
        datagrams0["accepted"] -= 1  # the ARM itself is the episode's
        datagrams0["received"] -= 1
        drv = self.driver
        seed = (a.seed + self.cfg.seed_offset) & protocol.U64
        drv.arm(seed)
        kind = a.kind
        if kind == protocol.EpisodeKind.IDENT_DROP:
            drv.nominal_drop()
        if self.cfg.lockstep:
            ctl.drain(int(self.cfg.rearm_idle_s * self.rate))
        self.state = protocol.TargetState.RUNNING
        armed = protocol.Armed(self.episode, 0, ctl.layout.size, N_ACTIONS, 4, N_TELEMETRY, hold, self.rate,
                        self.scene_sha)
        ep = Episode(self, arm_msg, armed, ctl, hold, seed, policy)
        ep.prefault()  # the episode's arrays in memory before ARMED: no page fault in its first ticks
        self.reply(armed, arm_msg)
        if kind in (protocol.EpisodeKind.SHAKER, protocol.EpisodeKind.QUIET):
            drv.hold()
        else:
            drv.release()
        ep.datagrams0 = datagrams0
        try:
            end = ep.run()
        finally:
            drv.idle()
            self.state = protocol.TargetState.IDLE
            self._heard = time.perf_counter()
        self._last_obs = ep.obs_msg
        self._finish(ep, end, policy)

    def lifetime_counts(self) -> dict[str, int]:
        """The datagram counters since the target started (the logs' are per episode)."""
        c = self._datagram_counts()
        return {"datagrams_received": c.pop("received"), "datagrams_accepted": c.pop("accepted"),
                **{f"dropped_{k}": v for k, v in c.items()}}

    def _datagram_counts(self) -> dict[str, int]:
        """The link's datagram counters since the target started (see :meth:`_finish`)."""
        # kernel: datagrams the kernel dropped on a full receive buffer (SO_RXQ_OVFL; 0 where unknown)
        return {**self.link.filter.counts(), "received": self.endpoint.received,
                "kernel": self.endpoint.kernel_drops()}

    def _finish(self, ep: Episode, end, policy) -> None:
        ctl = ep.ctl
        # every counter of the log is of this episode alone (ARM to EPISODE_END)
        now = self._datagram_counts()
        counts = {k: v - ep.datagrams0.get(k, 0) for k, v in now.items()}
        counters = {**{f"dropped_{k}": v for k, v in counts.items() if k not in ("accepted", "received")},
                    "datagrams_accepted": counts["accepted"], "datagrams_received": counts["received"],
                    **ctl.counters(), "overruns": ep.overruns,
                    "skipped_ticks": ep.skipped_ticks,
                    **(ep.command_counters() if ep.host else {})}
        if ep.host:
            counters["commands_late"] = counts["late"]
        silent = counters.get("host_silent_steps", 0)
        if silent:
            self.note(f"episode {ep.ep}: HOST_SILENT: no COMMAND of the host's "
                      f"{self.link.peer_name} arrived in time for {silent} of {ep.m // ctl.hold} steps (the "
                      f"first: step {counters['host_silent_from_step']}); {counts['late']} came late: "
                      "its datagrams stopped arriving (lost, delayed, or taken by another process)")
        if ep.stop_asked_tick >= 0:  # asked to stop (DISARM, a signal, a lost link) at this tick; stopped at
            counters["stop_asked_tick"] = ep.stop_asked_tick
            counters["stop_tick"] = ep.stop_tick
        meta = self._meta(ep, policy, end.name, counters)
        self._write(ep, meta, end)

    def _meta(self, ep: Episode, policy, end_reason: str, counters: dict) -> tick_log.EpisodeMeta:
        ctl, a = ep.ctl, ep.a
        return tick_log.EpisodeMeta(
            scene_toml=self.scene_toml.decode(),
            mode=a.mode,
            hold_ticks=ctl.hold,
            seed=ep.seed,
            control_rate_hz=self.rate,
            episode=ep.ep,
            session=self.link.session or 0,
            policy="" if policy is None else policy.name,
            policy_sha256=(
                "" if policy is None or not a.policy_size else hashlib.sha256(self.upload.data).hexdigest()
            ),
            observation=ctl.observation,
            history=ctl.layout.history,
            obs_names=ctl.layout.names,
            end_reason=end_reason,
            counters=counters,
            kind=a.kind.name.lower(),
            excitation=(
                policy.excitation.to_json() if isinstance(policy, excitation.ExcitationPolicy) else ""
            ),
            physics_toml=getattr(self.driver, "physics_toml", ""),
        )

    def open_stream(self, ep: Episode, published: np.ndarray) -> tick_log.LogStream | None:
        """The episode's log streamed to ``log_dir`` while it runs (None without a log dir)."""
        if self.cfg.log_dir is None:
            return None
        meta = self._meta(ep, ep.policy, tick_log.INCOMPLETE, {})
        name = tick_log.episode_filename(ep.ep, self.link.session or 0) + tick_log.PARTIAL_SUFFIX
        Path(self.cfg.log_dir).mkdir(parents=True, exist_ok=True)
        return tick_log.LogStream(
            ep.ctl.log,
            Path(self.cfg.log_dir) / name,
            meta,
            published,
            self.cfg.log_flush_s,
            self.placement.background_thread,
        )

    def _write(self, ep: Episode, meta: tick_log.EpisodeMeta, end) -> None:
        ctl = ep.ctl
        if self.stopping and ep.stream is not None and self.cfg.log_dir is not None:
            # asked to stop (SIGTERM, SIGINT): the streamed file becomes the log (its last rows,
            # its end and counters), not written again: the process exits within a second
            data = ep.stream.finish(meta, self.cfg.log_dir).read_bytes()
        elif self.cfg.log_dir is not None:
            if ep.stream is not None:
                ep.stream.close()
            data = tick_log.write_episode(ctl.log, self.cfg.log_dir, meta).read_bytes()
            if ep.stream is not None:
                ep.stream.discard()  # the finished file replaces what was streamed
        else:
            with tempfile.TemporaryDirectory(prefix="impact-env-rig-") as tmp:
                data = tick_log.write_episode(ctl.log, tmp, meta).read_bytes()
        self.episodes[ep.ep] = data
        for old in [k for k in self.episodes if k < ep.ep - 8]:
            del self.episodes[old]
        self.counters["episodes"] += 1
        self.counters["overruns"] += ep.overruns
        self.counters["skipped_ticks"] += ep.skipped_ticks
        self.counters["overrun_episodes"] += end == protocol.EndReason.OVERRUN
        self.counters["watchdog_trips"] += meta.counters.get("watchdog_trips", 0)
        self.last_end = protocol.EpisodeEnd(ep.ep, int(end), int(ep.status_or) & protocol.U32, ctl.log.n,
                                     ep.m // ctl.hold, len(data), hashlib.sha256(data).digest())
        self.link.send(self.last_end, addr=self.link.last_sender)

    def info(self, nonce: bytes) -> protocol.Info:
        return protocol.Info(
            nonce,
            self.rate,
            int(self.state),
            0 if self.driver.virtual else 1,
            self.cfg.lockstep,
            len(self.scene_toml),
            self.scene_sha,
            self.link.filter.nonce,
            self.keyed,
            self.endpoint.session_port,
        )


class _Refused(Exception):
    def __init__(self, code: int, text: str):
        super().__init__(text)
        self.code = code
