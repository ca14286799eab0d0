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
  on the clock; a command takes effect at the first tick after it arrives, is held H ticks and
  repeated at most once more, then the force is 0 (:mod:`impact_env.rig.safety`).
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
import math
import signal
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from impact_env.control.observation import make_layout
from impact_env.control.policy import CompiledPolicy
from impact_env.hardware import stage as HS
from impact_env.rig import log as LG
from impact_env.rig import protocol as P
from impact_env.rig import safety as SF
from impact_env.rig.clock import TickClock, lateness_summary
from impact_env.rig.controller import Controller
from impact_env.rig.driver import RigDriver
from impact_env.rig.safety import SafetyConfig
from impact_env.rig.transport import Endpoint, Link, UploadAssembler, chunk_reply
from impact_env.sim import records as R

TRUTH_COLUMNS = ("command", "true_x1_m", "true_v1_mps", "true_x2_m", "true_v2_mps", "hw_force_demand_N",
                 "hw_force_applied_N", "hw_saturated", "hw_contact_force_N", "hw_status", "impact_energy_J",
                 "impact_speed_mps", "t_touch_s")
TRUTH_UNITS = {"true_x1_m": "m", "true_v1_mps": "m/s", "true_x2_m": "m", "true_v2_mps": "m/s",
               "hw_force_demand_N": "N", "hw_force_applied_N": "N", "hw_contact_force_N": "N",
               "impact_energy_J": "J", "impact_speed_mps": "m/s", "t_touch_s": "s"}
N_TELEMETRY = len(P.TELEMETRY_FIELDS)


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
    resend_s: float = 0.02  # lock-step host mode: the OBSERVATION is sent again after this long without a command
    rearm_idle_s: float = 1.0  # lock-step: idle time assumed between episodes (the coil cools in the RMS window)
    poll_every: int = 64  # onboard lock-step: ticks between checks for DISARM
    seed_offset: int = 0  # added to every ARM's seed (0: the drops ImpactCatch-v0 meets for the same seeds)


class Target:
    """The target process for one ``driver`` (see the module doc).  ``serve()`` runs until
    :meth:`stop`, SIGTERM or SIGINT (installed by :meth:`install_signal_handlers`)."""

    def __init__(self, driver: RigDriver, bind: str = "udp://127.0.0.1:0", config: TargetConfig | None = None):
        self.driver = driver
        self.cfg = config or TargetConfig()
        self.scene = driver.scene
        self.rate = float(self.scene.control_rate)
        self.endpoint = Endpoint(bind)
        self.link = Link(self.endpoint, "target")
        self.scene_toml = self.scene.to_toml().encode()
        self.scene_sha = hashlib.sha256(self.scene_toml).digest()
        self.upload = UploadAssembler()
        self.state = P.TargetState.IDLE
        self.episode = 0
        self.episodes: dict[int, bytes] = {}  # episode -> its log file's bytes (the latest few)
        self.last_end: P.EpisodeEnd | None = None
        self._stop = threading.Event()
        self._pending: P.Message | None = None  # an ARM that ended the episode before it
        self._closed = False
        self.counters = {"episodes": 0, "overruns": 0, "watchdog_trips": 0}
        driver.initialise()
        self._warm_up()

    def _warm_up(self) -> None:
        """Compile (or load from the cache) the controller's kernels before serving, so that the
        first episode's first tick is not a compile: one tick of a throwaway controller on zero
        readings, driver untouched."""
        from impact_env.policy.registry import make_policy  # noqa: F401  (load the policy registry now)

        layout = make_layout(self.scene, "sensors", 1)
        law = CompiledPolicy.from_law("passive", {}, {}, self.scene, "sensors")
        ctl = Controller(self.scene, layout, 1, 2, "onboard", law, law, self.cfg.safety, extra_columns=("command",))
        raw = np.zeros(4)
        ctl.start(raw, None)
        ctl.observe(1, raw, None)
        ctl.act(1, 0.0, 0, 1, raw)

    @property
    def address(self) -> str:
        return self.endpoint.address

    def stop(self) -> None:
        self._stop.set()

    def install_signal_handlers(self) -> None:
        """SIGTERM and SIGINT stop the serve loop, which zeroes the shaker on its way out."""
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: self.stop())

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
                    self._handle_idle(msg)
        finally:
            self.close()

    def _reply(self, body: P.Body, to: P.Message) -> None:
        self.link.send(body, reply_to=to, addr=self.link.last_sender)

    def _error(self, to: P.Message, code: int, text: str) -> None:
        self._reply(P.Error.shorten(code, to.seq, text), to)

    def _handle_idle(self, msg: P.Message) -> None:
        t = msg.type
        if t == P.MsgType.HELLO:
            self.link.session = msg.session  # a new session's streams start empty
            self._reply(P.Info(msg.body.nonce, self.rate, int(self.state), 0 if self.driver.virtual else 1,
                               self.cfg.lockstep, len(self.scene_toml), self.scene_sha), msg)
        elif t == P.MsgType.FETCH:
            self._serve_fetch(msg)
        elif t == P.MsgType.POLICY_CHUNK:
            self._reply(self.upload.add(msg.body, msg.seq), msg)
        elif t == P.MsgType.ARM:
            self._arm(msg)
        elif t == P.MsgType.DISARM:
            self._reply(P.Ack(P.MsgType.DISARM, P.ErrorCode.OK, msg.seq, 0), msg)
        elif t == P.MsgType.HEARTBEAT:
            self._reply(P.Heartbeat(int(self.state), self.episode, 0, msg.seq), msg)

    def _serve_fetch(self, msg: P.Message) -> None:
        b = msg.body
        if b.resource == P.Resource.SCENE:
            self._reply(chunk_reply(self.scene_toml, b, msg.seq), msg)
        elif b.resource == P.Resource.EPISODE and b.item in self.episodes:
            self._reply(chunk_reply(self.episodes[b.item], b, msg.seq), msg)
        elif b.resource == P.Resource.EPISODE and b.item == self.episode and self.state == P.TargetState.RUNNING:
            self._error(msg, P.ErrorCode.BUSY, f"episode {b.item} is still running")
        else:
            self._error(msg, P.ErrorCode.UNKNOWN_RESOURCE, f"no resource {b.resource} item {b.item}")

    # -- arming ------------------------------------------------------------------------------------
    def _arm(self, msg: P.Message) -> None:
        a: P.Arm = msg.body
        try:
            policy = residual = None
            if a.policy_size:
                data = self.upload.data if self.upload.complete else b""
                if len(data) != a.policy_size or hashlib.sha256(data).digest() != a.policy_sha256:
                    raise _Refused(P.ErrorCode.POLICY_REJECTED, "the uploaded policy file does not match ARM's size "
                                   "and sha256 (upload it first)")
                pol = CompiledPolicy.from_dict(__import__("json").loads(data.decode()), "the uploaded policy")
                pol.check_scene(self.scene)
                if a.mode == "onboard":
                    policy, residual = pol, pol.residual_policy()
                elif pol.law is not None:  # host mode: an uploaded law is the residual under the host's actions
                    residual = pol
                else:
                    raise _Refused(P.ErrorCode.POLICY_REJECTED, "host mode takes a classic law as the residual, "
                                   "not a network")
            elif a.mode == "onboard":
                raise _Refused(P.ErrorCode.BAD_REQUEST, "onboard mode needs an uploaded policy")
            if a.mode == "onboard":
                observation, history, hold = policy.observation, policy.history, policy.hold_ticks
            else:
                observation, history, hold = a.observation, a.history, a.hold_ticks
            if a.horizon_ticks % hold:
                raise _Refused(P.ErrorCode.BAD_REQUEST, f"horizon_ticks = {a.horizon_ticks} is not a whole "
                               f"number of policy steps of {hold} ticks")
            layout = make_layout(self.scene, observation, history)
            ctl = Controller(self.scene, layout, hold, a.horizon_ticks, a.mode, policy, residual, self.cfg.safety,
                             extra_columns=TRUTH_COLUMNS if self.driver.virtual else ("command",),
                             observation=observation)
        except _Refused as exc:
            self._error(msg, exc.code, str(exc))
            return
        except (ValueError, KeyError, UnicodeDecodeError) as exc:
            self._error(msg, P.ErrorCode.BAD_REQUEST, f"{type(exc).__name__}: {exc}")
            return
        for k, v in TRUTH_UNITS.items():
            if k in ctl.log.extra_units:
                ctl.log.extra_units[k] = v
        self.episode += 1
        self._run_episode(msg, ctl, hold, policy)

    # -- one episode ---------------------------------------------------------------------------------
    def _run_episode(self, arm_msg: P.Message, ctl: Controller, hold: int, policy) -> None:
        a: P.Arm = arm_msg.body
        drv = self.driver
        host = a.mode == "host"
        lockstep = self.cfg.lockstep
        ep = self.episode
        seed = (a.seed + self.cfg.seed_offset) & P.U64
        drv.arm(seed)
        if lockstep:
            ctl.drain(int(self.cfg.rearm_idle_s * self.rate))
        link_timeout_s = a.link_timeout_ms / 1e3 if a.link_timeout_ms else (
            self.cfg.lockstep_link_timeout_s if lockstep else self.cfg.link_timeout_s)
        self.state = P.TargetState.RUNNING
        armed = P.Armed(ep, 0, ctl.layout.size, 1, 4, N_TELEMETRY, hold, self.rate, self.scene_sha)
        self._reply(armed, arm_msg)
        drv.release()
        virtual = drv.virtual
        hw = getattr(drv, "hw", None)
        horizon = a.horizon_ticks
        step_recs = np.zeros((hold, R.N_REC))
        cmd = {"value": math.nan, "step": -1, "first": -1, "next": None}
        last_heard = time.perf_counter()
        clock = TickClock(self.rate, lockstep=lockstep)
        end = P.EndReason.HORIZON
        status_or = 0
        lateness = np.zeros(horizon + 1, dtype=np.int64)
        obs_msg: P.Observation | None = None
        log = ctl.log
        c = {name: log.col(name) for name in log.names}

        def take(msg: P.Message) -> str | None:
            """An incoming message during the episode; returns an end reason's name, or None."""
            nonlocal last_heard
            last_heard = time.perf_counter()
            t = msg.type
            if t == P.MsgType.COMMAND and msg.body.episode == ep:
                nxt = cmd["next"]
                if nxt is None or msg.body.step >= nxt[0]:
                    cmd["next"] = (msg.body.step, float(msg.body.action[0]))
            elif t == P.MsgType.DISARM:
                self._reply(P.Ack(P.MsgType.DISARM, P.ErrorCode.OK, msg.seq, ep), msg)
                return "DISARMED"
            elif t == P.MsgType.ARM:
                if msg.body == a:  # the same request again (its ARMED was lost): answer it again
                    self._reply(armed, msg)
                    return None
                self._pending = msg  # a new episode: this one ends, that one starts
                return "DISARMED"
            elif t == P.MsgType.FETCH:
                self._serve_fetch(msg)
            elif t == P.MsgType.HEARTBEAT:
                self._reply(P.Heartbeat(int(self.state), ep, m // hold, msg.seq), msg)
            elif t == P.MsgType.HELLO and msg.session == self.link.session:
                self._reply(P.Info(msg.body.nonce, self.rate, int(self.state), 0 if virtual else 1, lockstep,
                                   len(self.scene_toml), self.scene_sha), msg)
            return None

        def drain(budget_s: float = 0.0) -> str | None:
            deadline = time.perf_counter() + budget_s
            while True:
                msg = self.link.recv(max(deadline - time.perf_counter(), 0.0), episode=ep, step=m // hold)
                if msg is None:
                    return None
                why = take(msg)
                if why:
                    return why
                if time.perf_counter() >= deadline:
                    return None

        raw0 = drv.read().copy()
        ctl.start(raw0, drv.truth())
        clock.start()
        m = 0
        missed = 0
        while True:
            t_work = time.perf_counter_ns()
            raw = drv.read()
            truth = drv.truth()
            boundary = ctl.observe(m, raw, truth) if m > 0 else True
            if virtual and m > 0:  # the last tick's record is complete with its detector bit
                step_recs[(m - 1) % hold, R.REC_DETECTED] = ctl.fe.detected[0]
            if boundary and host:
                telem = [float(log.rows[log.n - 1, LG.FORCE_DEMAND]) if log.n else 0.0,
                         float(log.rows[log.n - 1, LG.FORCE_APPLIED]) if log.n else 0.0,
                         float(m - cmd["first"]) if cmd["first"] >= 0 else -1.0]
                if virtual and m > 0:
                    telem += step_recs.ravel().tolist()
                obs_msg = P.Observation(ep, m // hold, int(status_or), 4, tuple(float(x) for x in ctl.obs), tuple(telem))
                self.link.send(obs_msg, tick=m, addr=self.link.last_sender)
            if m >= horizon:
                log.record(obs=ctl.obs, tick=m, t_s=m / self.rate, accelerometer_mps2=raw[0], force_N=raw[1],
                           potentiometer_m=raw[2], action=math.nan, step=m // hold,
                           contact_detected=ctl.fe.detected[0], command_age_ticks=-1)
                break
            # the command of this tick
            why = None
            if host:
                if lockstep and boundary:
                    waited = time.perf_counter()
                    sent = waited
                    while not (cmd["next"] is not None and cmd["next"][0] >= m // hold):
                        why = drain(min(self.cfg.resend_s, 0.005))
                        if why:
                            break
                        now = time.perf_counter()
                        if now - last_heard > link_timeout_s:
                            why = "LINK_LOST"
                            break
                        if now - sent >= self.cfg.resend_s and obs_msg is not None:
                            self.link.send(obs_msg, tick=m, addr=self.link.last_sender)
                            sent = now
                else:
                    why = drain(0.0)
                    if not why and time.perf_counter() - last_heard > link_timeout_s:
                        why = "LINK_LOST"
                nxt = cmd["next"]
                if nxt is not None and nxt[0] <= m // hold and nxt[0] != cmd["step"]:
                    cmd["step"], cmd["value"], cmd["first"] = nxt[0], nxt[1], m
            elif lockstep and m % self.cfg.poll_every == 0:
                why = drain(0.0)
            if why:
                end = P.EndReason[why]
                break
            age = m - cmd["first"] if (host and cmd["first"] >= 0) else (-1 if host else 0)
            u, f_dem, status, row = ctl.act(m, cmd["value"], age, m, raw)
            status |= SF.OVERRUN if missed else 0
            f_applied = drv.apply(u)
            status_or |= status
            if row >= 0:
                r = log.rows[row]
                r[LG.FORCE_APPLIED] = f_applied
                r[LG.STATUS] = status
                r[LG.LATENESS_NS] = lateness[m]
                r[c["command"]] = u
                if virtual:
                    info, y = drv.last_info, drv.truth()
                    r[c["true_x1_m"]:c["true_v2_mps"] + 1] = y
                    r[c["hw_force_demand_N"]] = info[HS.INFO_F_DEMAND]
                    r[c["hw_force_applied_N"]] = info[HS.INFO_F_APPLIED]
                    r[c["hw_saturated"]] = info[HS.INFO_SATURATED]
                    r[c["hw_contact_force_N"]] = info[HS.INFO_CONTACT_FORCE]
                    r[c["hw_status"]] = 0.0 if (info[HS.INFO_STATUS] == 0 and np.all(np.isfinite(y))) else 1.0
                    r[c["impact_energy_J"]] = hw.impact_energy[0]
                    r[c["impact_speed_mps"]] = hw.impact_speed[0]
                    r[c["t_touch_s"]] = hw.t_touch[0]
                    rec = step_recs[m % hold]
                    rec[R.REC_T] = hw.t[0]
                    rec[R.REC_X1:R.REC_V2 + 1] = y
                    rec[R.REC_U] = u
                    rec[R.REC_F_DEMAND] = info[HS.INFO_F_DEMAND]
                    rec[R.REC_F_APPLIED] = info[HS.INFO_F_APPLIED]
                    rec[R.REC_SATURATED] = info[HS.INFO_SATURATED]
                    rec[R.REC_CONTACT_FORCE] = info[HS.INFO_CONTACT_FORCE]
                    rec[R.REC_STATUS] = r[c["hw_status"]]
                r[LG.COMPUTE_NS] = time.perf_counter_ns() - t_work
            fault = drv.error()
            if fault:
                end = P.EndReason.FAULT
                break
            if status & SF.FIRST_COMMAND_TIMEOUT:
                end = P.EndReason.FIRST_COMMAND_TIMEOUT
                break
            if status & SF.LATCHING:
                end = P.EndReason.SAFETY
                break
            m += 1
            missed = 0
            if not lockstep:
                tick = clock.wait(poll=lambda budget: drain(budget) and None)
                if tick.missed:  # the ticks that could not run on time pass with the command held
                    missed = min(tick.missed, horizon - m)
                    drv.apply(u, missed)
                    m += missed
                lateness[m] = tick.lateness_ns
            if self._stop.is_set():
                end = P.EndReason.DISARMED
                break
        drv.idle()
        self.state = P.TargetState.IDLE
        self._finish(ep, a, seed, ctl, end, status_or, clock, policy)

    def _finish(self, ep: int, a: P.Arm, seed: int, ctl: Controller, end, status_or: int, clock: TickClock,
                policy) -> None:
        sf = SF.COUNTERS
        counters = {**{f"dropped_{k}": v for k, v in self.link.filter.counts().items() if k != "accepted"},
                    "datagrams_accepted": self.link.filter.counts()["accepted"],
                    **{k: int(ctl.safety[1][i]) for k, i in sf.items()},
                    "overruns": clock.overruns, "missed_ticks": clock.missed}
        meta = LG.EpisodeMeta(scene_toml=self.scene_toml.decode(), mode=a.mode, hold_ticks=ctl.hold, seed=seed,
                              control_rate_hz=self.rate, episode=ep, session=self.link.session or 0,
                              policy="" if policy is None else policy.name,
                              policy_sha256="" if policy is None else hashlib.sha256(
                                  self.upload.data).hexdigest(),
                              observation=ctl.observation, history=ctl.layout.history, obs_names=ctl.layout.names, end_reason=end.name,
                              counters=counters)
        if self.cfg.log_dir is not None:
            path = LG.write_episode(ctl.log, self.cfg.log_dir, meta)
        else:
            tmp = Path(tempfile.mkdtemp(prefix="impact-env-rig-"))
            path = LG.write_episode(ctl.log, tmp, meta)
        data = path.read_bytes()
        if self.cfg.log_dir is None:
            path.unlink()
            path.parent.rmdir()
        self.episodes[ep] = data
        for old in [k for k in self.episodes if k < ep - 8]:
            del self.episodes[old]
        self.counters["episodes"] += 1
        self.counters["overruns"] += clock.overruns
        self.counters["watchdog_trips"] += counters.get("watchdog_trips", 0)
        self.last_lateness = lateness_summary(np.maximum(clock_lateness(ctl), 0), overruns=clock.overruns) \
            if ctl.log.n else None
        self.last_end = P.EpisodeEnd(ep, int(end), int(status_or) & P.U32, ctl.log.n, ctl.log.n // ctl.hold,
                                     len(data), hashlib.sha256(data).digest())
        self.link.send(self.last_end, addr=self.link.last_sender)


def clock_lateness(ctl: Controller) -> np.ndarray:
    return ctl.log.rows[:ctl.log.n, LG.LATENESS_NS]


class _Refused(Exception):
    def __init__(self, code: int, text: str):
        super().__init__(text)
        self.code = code
