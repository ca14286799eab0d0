"""The host's side: a client of the target (:class:`RigClient`) and the Gymnasium env
``ImpactCatchRig-v0`` (:class:`RigEnv`).

``gymnasium.make("ImpactCatchRig-v0", address="udp://HOST:PORT", ...)`` is a :class:`RigEnv`
whose spaces equal ``ImpactCatch-v0``'s on the target's scene (fetched from the target), with
the same keyword arguments where they apply and the same defaults.

Timing contract (host mode; H = ``hold_ticks``, T the control period):

* ``reset(seed=s)`` arms an episode with seed s (a virtual rig then meets the drop and the noise
  ``ImpactCatch-v0`` reset with s meets) and returns the observation of tick 0: the readings at
  the release.
* ``step(a)`` sends a at policy step n; the target applies it over ticks nH .. nH + H - 1 and
  returns the observation of tick (n + 1) H, made from the readings after tick (n + 1) H - 1.
  In lock-step that is exact; in real time a acts from the first tick at or after its arrival
  (one round trip after the observation it answers) to the end of step n, is repeated through
  step n + 1, after which the target zeroes the force (its watchdog); arriving after step n
  is over it is counted late by the target and never applied.
* Episodes end as ``ImpactCatch-v0``'s (truncated at the horizon, terminated on a catch), or as
  the target ends them: an EPISODE_END received while waiting for an observation returns at
  once, terminated for SAFETY, truncated otherwise, with ``info["end_reason"]``.
* ``key``: the session key (:mod:`impact_env.rig.auth`), the same file as the target's
  ``rig serve --key FILE``.
* Reward and termination: from a virtual rig, which reports the true records of each step's
  ticks, they are computed here by the env's own kernel (:mod:`impact_env.env.task_kernel`), so
  they equal ``ImpactCatch-v0``'s; a physical rig measures no body-1 state: the reward is 0.0,
  ``info["reward_available"]`` is False, and episodes end at the horizon (the episode's
  metrics come from its log: :func:`impact_env.rig.flight_energy`).
"""

from __future__ import annotations

import functools
import hashlib
import hmac
import math
import os
import secrets
import time
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from impact_env._jit import bound_call, entry_point
from impact_env.control.observation import OBS_LIMIT, make_layout
from impact_env.control.policy import CompiledPolicy
from impact_env.env import task_kernel
from impact_env.env.task import (
    TaskConfig,
    check_actions,
    info_from_row,
    new_task_out,
    new_task_state,
    options_doc,
)
from impact_env.hardware.batch import Hardware
from impact_env.policy.export import export_policy
from impact_env.rig import host_wire, protocol, safety, wire
from impact_env.rig.auth import key_from
from impact_env.rig.log import read_episode
from impact_env.rig.placement import keep_off_loop_cpu
from impact_env.rig.transport import Endpoint, Link, RigError, RigTimeout, fetch, parse_address, upload
from impact_env.scene import scene_from_dict
from impact_env.sim import records

N_TEL = len(protocol.TELEMETRY_FIELDS)
# this many steps in a row on which the target acted on none of the host's recent COMMANDs (the
# watchdog had zeroed the force) and the host warns, once per episode (RigCommandsUnheard)
UNHEARD_WARN_STEPS = 3


class HostRun(NamedTuple):
    """A host-mode episode run by :meth:`RigClient.run_policy`."""

    end: protocol.EpisodeEnd  # how the target ended it
    actions: np.ndarray  # float64[n_steps]: the command sent for each step, NaN where none was


class RigCommandsUnheard(UserWarning):
    """The target's OBSERVATIONs say that this host's COMMANDs are not reaching it."""
SPIN_STEPS = 4  # a real-time host polls for the next OBSERVATION this many policy periods, then sleeps


def status_names(status: int) -> list[str]:
    """The names of the status bits set in ``status`` (:data:`impact_env.rig.safety.STATUS_BITS`)."""
    return list(_status_names(int(status)))


@functools.lru_cache(maxsize=256)
def _status_names(status: int) -> tuple[str, ...]:
    return tuple(name for name, bit in safety.STATUS_BITS.items() if status & bit)


class RigClient:
    """One session with a target at ``address`` (``udp://HOST:PORT``): HELLO on construction,
    then :meth:`arm`, :meth:`command`, :meth:`observation`, :meth:`wait_end`, :meth:`fetch_log`.
    Every wait is bounded (``timeout_s`` per try, ``retries`` tries): a dead target raises
    :class:`~impact_env.rig.transport.RigTimeout`, and :meth:`close` never blocks."""

    def __init__(self, address: str, timeout_s: float = 0.05, retries: int = 10, key=None,
                 spin_s: float = 0.0):
        key = key_from(key, "key")
        host, port = parse_address(address)
        local = "udp://[::1]:0" if ":" in host else ("udp://127.0.0.1:0" if host in ("127.0.0.1", "localhost")
                                                      else "udp://0.0.0.0:0")
        self.address = address
        self.timeout_s, self.retries = float(timeout_s), int(retries)
        # waiting for an OBSERVATION, poll this long before sleeping (see Endpoint.recv)
        self.spin_s = float(spin_s)
        self.endpoint = Endpoint(local, peer=address)
        # the target's own address: the handshake's; the session's datagrams go to the port INFO names
        self.target_address = self.endpoint.peer
        self.link = Link(self.endpoint, "host", session=int.from_bytes(os.urandom(4), "little") | 1, key=key)
        self.link.filter.peer = self.endpoint.peer  # only the target's replies count
        self.link.on_accept = self._seen
        # the compiled path of a policy step (impact_env.rig.host_wire): its COMMAND out, the
        # next OBSERVATION in
        f = self.link.filter
        self.wire = wire.make(self.endpoint.fileno(), f.key, 0, self.link.session or 0, 0, self.endpoint.peer,
                            None, 0)
        try:
            info = self.hello()
            self.lockstep = bool(info.lockstep)
            self.virtual = info.driver == 0
            toml = fetch(
                self.link, protocol.Resource.SCENE, 0, info.scene_sha256, self.timeout_s, self.retries
            )
            import tomllib

            self.scene = scene_from_dict(tomllib.loads(toml.decode()))
            # compile (or load) the compiled path now, not in an episode's first step: one call
            # that sends nothing and waits for nothing, then bound (numba's typing skipped after)
            args = (self.wire, False, 0, 0, 0.0, 0, 1 << 31, 0, 0)
            host_wire.exchange(*args)
            self._exchange = entry_point(host_wire.exchange, args)
            self._take_wire()
        except BaseException:
            self.endpoint.close()
            raise
        self.episode = 0
        self.step = 0
        # a target on this machine: this thread keeps off its loop's CPU while the session lasts
        self._restore_cpus = keep_off_loop_cpu(host, port)

    def hello(self) -> protocol.Info:
        """HELLO -> CHALLENGE, RESPONSE -> INFO: opens the session (or confirms it: the same
        session id again keeps it; one that the target closed after its idle timeout is opened
        anew, with a new session nonce).  Both nonces are fresh (``secrets``), so no recorded
        handshake opens anything again."""
        nonce = secrets.token_bytes(protocol.NONCE_SIZE)
        f = self.link.filter
        refusals = f.unverified_refusals
        to = self.target_address
        assert to is not None  # the endpoint's peer, given at construction
        try:
            challenge = self.link.request(
                protocol.Hello(nonce),
                lambda m: isinstance(m.body, protocol.Challenge) and hmac.compare_digest(m.body.nonce, nonce),
                "CHALLENGE (answer to HELLO)", self.timeout_s, self.retries,
                addr=to).payload(protocol.Challenge)
            info = self.link.request(
                protocol.Response(nonce, challenge.target_nonce),
                lambda m: isinstance(m.body, protocol.Info) and hmac.compare_digest(m.body.nonce, nonce),
                "INFO (answer to RESPONSE)", self.timeout_s, self.retries, addr=to).payload(protocol.Info)
        except (RigTimeout, RigError) as exc:
            # a host without key reads the target's refusal (tagged without key) as authentic; a
            # host with one cannot check it, and only counts it: the text is this side's own
            if ((isinstance(exc, RigError) and exc.code == protocol.ErrorCode.UNAUTHENTICATED)
                    or (isinstance(exc, RigTimeout) and f.unverified_refusals > refusals)):
                raise RigError(
                    "the session (HELLO)", protocol.ErrorCode.UNAUTHENTICATED, self._refused()
                ) from None
            raise
        f.nonce = info.session_nonce
        # the session's own socket at the target (its port authenticated in INFO): everything else
        # goes there, and the target's replies come from there; no other process can bind it
        session = (to[0], info.session_port, *to[2:]) if info.session_port else to
        f.session_peer = session
        self.endpoint.peer = session
        wire.set_peer(self.wire, session)
        nb = np.frombuffer(int(f.nonce).to_bytes(8, "little"), np.uint8)
        self.wire.rx[:wire.NONCE] = nb  # the compiled path's tags are under the session's nonce too
        self.wire.tx[:wire.NONCE] = nb
        self.info = info
        return info

    def _refused(self) -> str:
        if self.link.filter.key:
            return ("the target refused this host's HELLO as unauthenticated (an unverifiable reply): it was "
                    "started with another key or without one; start it with rig serve --key FILE using this "
                    "host's key file, or give the host no key for a target without one (this host has a key)")
        return ("the target refused this host's HELLO as unauthenticated: it was started with a key "
                "(rig serve --key FILE); give the host the same key file (ImpactCatchRig-v0(key=FILE), "
                "compare --key FILE) (this host has no key)")

    def arm(self, mode: str, seed: int, horizon_ticks: int, observation: str = "sensors", history: int = 1,
            hold_ticks: int = 1, policy: CompiledPolicy | None = None, link_timeout_ms: int = 0,
            first_command_timeout_ticks: int = 1000, kind: protocol.EpisodeKind = protocol.EpisodeKind.DROP,
            excitation=None) -> protocol.Armed:
        """Upload ``policy`` (onboard: the policy; host mode: a residual law) or, for an
        identification episode of ``kind`` shaker, its ``excitation``
        (:class:`impact_env.rig.excitation.Excitation`), and arm an episode (the session
        confirmed first: a host may have paused longer than the target's session timeout, e.g.
        for a training update)."""
        self.hello()
        data = b""
        if excitation is not None:
            data = (excitation.to_json() + "\n").encode()
        elif policy is not None:
            import json

            data = (json.dumps(policy.to_dict()) + "\n").encode()
        if data:
            upload(self.link, data, self.timeout_s, self.retries)
        options = int(protocol.EpisodeKind(kind)) << protocol.ARM_KIND_SHIFT
        arm = protocol.Arm(
            mode,
            observation,
            int(history),
            options,
            int(hold_ticks),
            int(seed) & protocol.U64,
            int(horizon_ticks),
            int(first_command_timeout_ticks),
            int(link_timeout_ms),
            len(data),
            hashlib.sha256(data).digest() if data else bytes(32),
        )
        # arming builds the target's controller and readies the rig: allow it a quarter second a try
        armed = self.link.request(arm, lambda m: m.type == protocol.MsgType.ARMED, "ARMED (answer to ARM)",
                                  max(self.timeout_s, 0.25), self.retries).payload(protocol.Armed)
        self.episode, self.step = armed.episode, 0
        return armed

    def command(self, step: int, action: float) -> None:
        """Send the COMMAND of ``step`` (one datagram, not acknowledged)."""
        link, f = self.link, self.link.filter
        seq = link.seq
        link.seq = (seq + 1) & protocol.U32
        self.endpoint.send(
            protocol.command_datagram(
                self.episode,
                int(step),
                float(action),
                link.session or 0,
                seq,
                time.perf_counter_ns() & protocol.U64,
                0,
                f.key,
                f.nonce,
            )
        )

    def observation(
        self, step: int, timeout_s: float, send: tuple[int, float] | None = None
    ) -> protocol.Observation | protocol.EpisodeEnd | None:
        """The newest OBSERVATION of the current episode that has come, of ``step`` or later (a
        host slower than the target's steps skips the older ones: in real time the newest is the
        one to answer), the EPISODE_END of the current episode if the target ended it before that
        step's observation (also kept in ``last_end``), or None after ``timeout_s``.  An episode
        that reached its horizon has a last OBSERVATION: its EPISODE_END is kept, and the wait goes
        on for it.  ``send``: (step, action) of a COMMAND sent first, in the same compiled call
        (:func:`impact_env.rig.host_wire.exchange`: the GIL released, the socket polled for
        ``spin_s``, then slept on)."""
        end = self.last_end
        if end is not None and end.episode == self.episode and not self._has_last_obs(end, step):
            return end
        deadline = time.perf_counter() + timeout_s
        while (left := deadline - time.perf_counter()) > 0 or send is not None:
            cmd_step, action = send if send is not None else (0, 0.0)
            seq = self.link.seq
            if send is not None:
                self.link.seq = (seq + 1) & protocol.U32
            code = self._exchange(self.wire, send is not None, self.episode, int(cmd_step), float(action), seq,
                                  int(step), int(self.spin_s * 1e9), int(max(left, 0.0) * 1e9))
            send = None
            self._take_wire()
            if code == host_wire.OBSERVED:
                return self._wire_observation()
            end = self.last_end
            if end is not None and end.episode == self.episode and not self._has_last_obs(end, step):
                return end
            if code == host_wire.TIMEOUT:
                return None
        return None

    def run_policy(self, policy: CompiledPolicy, seed: int, n_steps: int, spin_s: float | None = None,
                   **arm: Any) -> HostRun:
        """One host-mode episode of ``n_steps`` policy steps, ``policy`` acting on this host in
        compiled code (:func:`impact_env.rig.host_wire.run_policy`): each OBSERVATION is answered
        by its COMMAND within the same compiled call that read it, with no Python in between, so
        that a host in real time answers within the target's command wait at hold 1 too, where a
        Python policy step (``ImpactCatchRig-v0``) does not (docs/rig/timing.md).  The policy's
        residual law, if it has one, is uploaded at ARM and runs under the commands in the
        target's tick, as onboard.  ``spin_s``: poll for
        each OBSERVATION this long before sleeping (None: 4 policy periods against a real-time
        target, as ``ImpactCatchRig-v0``; 0 in lock-step); ``arm``: more of
        :meth:`arm`'s options (``first_command_timeout_ticks``, ``link_timeout_ms``).  Returns the
        episode's end and the command sent for each step (NaN: the step's OBSERVATION was
        superseded by a newer one before this host read it, or lost)."""
        pi, pf, mem_size = policy.arrays()
        loop = self._policy_loop
        if loop is None:
            # compile (or load) the loop before any episode waits on it: one call in an episode no
            # OBSERVATION has (0), sending nothing and waiting for nothing, then bound
            args = (self.wire, pi, pf, np.zeros(mem_size), 0, 0, False, 1, 0, 0, 0, np.zeros(1))
            host_wire.run_policy(*args)
            loop = self._policy_loop = entry_point(host_wire.run_policy, args)
            self._take_wire()
        hold = int(policy.hold_ticks)
        self.arm("host", seed, n_steps * hold, policy.observation, policy.layout.history, hold,
                 policy.residual_policy(), **arm)
        actions = np.full(n_steps + 1, np.nan)
        mem = np.zeros(mem_size)
        first = self.observation(0, (self.retries + 1) * self.timeout_s)
        if not isinstance(first, protocol.Observation):
            raise RigTimeout("the episode's first OBSERVATION", (self.retries + 1) * self.timeout_s,
                             self.address)
        w = self.wire
        w.out[:len(first.obs)] = first.obs  # the loop acts on what w.out holds
        w.st.out_n[0] = len(first.obs)
        if spin_s is None:
            spin_s = 0.0 if self.lockstep else SPIN_STEPS * hold / self.scene.control_rate
        spin_ns, timeout_ns = int(spin_s * 1e9), int(self.timeout_s * 1e9)
        step, send, tries, waited = int(first.step), True, 0, -1
        while step < n_steps:
            seq = self.link.seq
            code, step, self.link.seq = loop(w, pi, pf, mem, self.episode, step, send, n_steps, seq, spin_ns,
                                             timeout_ns, actions)
            self._take_wire()
            end = self.last_end
            if code == host_wire.LAST or (end is not None and end.episode == self.episode
                                          and not self._has_last_obs(end, step + 1)):
                break
            send = False  # QUEUED or TIMEOUT: the step's COMMAND is out; wait on
            if code == host_wire.TIMEOUT:
                tries = tries + 1 if step == waited else 1  # the tries of this step's wait
                waited = step
                if tries > self.retries:
                    raise RigTimeout(f"OBSERVATION of step {step + 1}", tries * self.timeout_s, self.address,
                                     tries)
                if self.lockstep:  # the target waits with its observation: the COMMAND again
                    self.command(step, float(actions[step]))
        last = float(actions[n_steps - 1])
        end = self._wait_end_resending(n_steps - 1, last if np.isfinite(last) else 0.0)
        return HostRun(end, actions[:n_steps])

    def _wait_end_resending(self, step: int, action: float) -> protocol.EpisodeEnd:
        """The EPISODE_END of a host-mode episode whose last COMMAND (``action`` of ``step``) is
        out: each ``timeout_s`` without it, that COMMAND again, to which a target whose episode has
        ended answers with its last OBSERVATION and EPISODE_END again (a lossy link lost them)."""
        for _ in range(self.retries):
            try:
                return self.wait_end(timeout_s=self.timeout_s)
            except RigTimeout:
                self.command(step, action)
        return self.wait_end(timeout_s=10.0)

    _policy_loop: Any = None  # host_wire.run_policy's entry point, bound at the first run_policy

    def _take_wire(self) -> None:
        """The compiled path's datagrams for Python through the link's filter (an EPISODE_END is
        kept by ``_seen``), and its counts into the filter's and the endpoint's."""
        w = self.wire
        if w.q_head[0] != w.q_tail[0]:
            for data, addr in wire.queued(w):
                self.link.take(data, addr)
        c = w.c
        f = self.link.filter
        received, accepted, queued = c.received.item(), c.accepted.item(), c.queued.item()
        if received != accepted + queued or c.send_dropped[0]:  # something was dropped: by reason
            for reason in ("corrupt", "unauthenticated", "wrong_session", "duplicate", "out_of_order",
                           "queue_full"):
                v = getattr(c, reason)
                f.counters[reason] += v.item()
                v[0] = 0
            self.endpoint.send_dropped += c.send_dropped.item()
            c.send_dropped[0] = 0
        f.counters["accepted"] += accepted
        self.endpoint.received += received
        self.endpoint.sent += c.sent.item()
        c.received[0] = c.accepted[0] = c.queued[0] = c.sent[0] = 0

    def _wire_observation(self) -> protocol.Observation:
        """The OBSERVATION the compiled path took (its values copied out of the wire)."""
        st, out = self.wire.st, self.wire.out
        n, m = int(st.out_n[0]), int(st.out_m[0])
        vals = out[:n + m].tolist()
        obs = object.__new__(protocol.Observation)  # fields in range by construction, as protocol.decode's
        obs.__dict__.update(episode=self.episode, step=int(st.out_step[0]), status=int(st.out_status[0]),
                            dtype=int(st.out_dtype[0]), obs=tuple(vals[:n]), telemetry=tuple(vals[n:]))
        return obs

    def _seen(self, msg: protocol.Message) -> None:
        """Every accepted message: an EPISODE_END is kept even when a request (a FETCH, an
        ARM's retry) was waiting when it came."""
        if isinstance(msg.body, protocol.EpisodeEnd):
            self.last_end = msg.body

    @staticmethod
    def _has_last_obs(end: protocol.EpisodeEnd, step: int) -> bool:
        """Whether the target sent an OBSERVATION of ``step`` before ending (at the horizon it
        sends the last step's)."""
        return end.reason == protocol.EndReason.HORIZON and step <= end.n_steps

    last_end: protocol.EpisodeEnd | None = None

    def wait_end(self, timeout_s: float) -> protocol.EpisodeEnd:
        """The EPISODE_END of the current episode (an onboard episode runs to its end)."""
        deadline = time.perf_counter() + timeout_s
        while (self.last_end is None or self.last_end.episode != self.episode):
            left = deadline - time.perf_counter()
            if left <= 0:
                raise RigTimeout(f"EPISODE_END of episode {self.episode}", timeout_s, self.address)
            msg = self.link.recv(left)
            body = None if msg is None else msg.body
            if isinstance(body, protocol.EpisodeEnd) and body.episode == self.episode:
                self.last_end = body
        return self.last_end

    def fetch_log(self, episode: int | None = None, sha256: bytes | None = None):
        """The episode's log (:class:`impact_env.rig.log.EpisodeLog`), fetched from the target."""
        ep = self.episode if episode is None else episode
        deadline = time.perf_counter() + 10.0
        while True:
            try:
                data = fetch(self.link, protocol.Resource.EPISODE, ep, sha256, self.timeout_s, self.retries)
                break
            except Exception as exc:  # the episode may still be running (BUSY): wait, boundedly
                if "BUSY" not in str(exc) or time.perf_counter() > deadline:
                    raise
                time.sleep(0.01)
        import tempfile

        with tempfile.TemporaryDirectory() as d:
            path = os.path.join(d, "episode.h5")
            with open(path, "wb") as fh:
                fh.write(data)
            return read_episode(path)

    def disarm(self, wait: bool = False, closing: bool = False, caught: bool = False) -> None:
        """Stop the episode (best effort: one datagram, or a bounded request with ``wait``);
        ``closing``: the session ends too (another host may then open one at once); ``caught``:
        the host's task caught body 1, and the target's log says so (end reason CAUGHT)."""
        if self.endpoint.closed:
            return
        reason = (
            protocol.DISARM_CLOSING if closing else protocol.DISARM_CAUGHT if caught else protocol.DISARM_USER
        )
        if wait or caught:  # a catch is acknowledged: a lost one would leave the log's end another
            self.link.request(
                protocol.Disarm(reason),
                lambda m: isinstance(m.body, protocol.Ack) and m.body.acked_type == protocol.MsgType.DISARM,
                "ACK of DISARM",
                self.timeout_s,
                self.retries,
            )
        else:
            self.link.send(protocol.Disarm(reason))

    def close(self, budget_s: float = 0.3) -> None:
        """End the session (DISARM "host closing", acknowledged, so that the target frees it for
        another host at once; retried for at most ``budget_s`` s: a lost datagram would otherwise
        hold the target for its session timeout) and close the socket.  Never raises."""
        if not self.endpoint.closed:
            tries = max(1, min(self.retries + 1, int(budget_s / self.timeout_s)))
            try:
                self.link.request(
                    protocol.Disarm(1),
                    lambda m: (isinstance(m.body, protocol.Ack)
                               and m.body.acked_type == protocol.MsgType.DISARM),
                    "ACK of DISARM",
                    min(self.timeout_s, budget_s),
                    tries - 1,
                )
            except (RigTimeout, RigError, OSError):
                pass
        self.endpoint.close()
        getattr(self, "_restore_cpus", lambda: None)()


class RigEnv(gym.Env):
    """``ImpactCatchRig-v0``: ``ImpactCatch-v0``'s interface on a rig behind a target (see the
    module doc for the timing contract).

    The task's options, as ``ImpactCatch-v0``'s (``observation`` "sensors" only: a rig measures
    no body-1 state; this list is written from :class:`~impact_env.env.task.TaskConfig`):

TASK_OPTIONS_DOC

    plus ``address`` (``udp://HOST:PORT``), ``timeout_s``
    (per try; a step waits at most ``(retries + 1) timeout_s`` in all, then raises RigTimeout),
    ``retries``, ``key`` (the path of the key file the target was started with, ``rig serve
    --key FILE``, or the key's bytes; None: no key, for a target without one on loopback) and
    ``first_command_timeout_s`` (s: the target disarms an episode whose first COMMAND has not
    arrived by then; the safety layer's own 0.1 s by default) and ``link_timeout_s`` (s: the
    target ends an episode LINK_LOST when it hears nothing from the host for that long; None: the
    target's own, 0.5 s in real time) and ``spin_s`` (s: waiting for an OBSERVATION, poll the
    socket this long before sleeping; None: 4 policy periods against a real-time target, 0 in
    lock-step).  In real time ``step`` returns the newest OBSERVATION that has come: a host
    slower than the target's steps skips the ones between (``info["steps_missed"]``).
    """

    metadata = {"render_modes": []}

    def __init__(self, address: str, *, timeout_s: float = 0.05, retries: int = 20, key=None,
                 first_command_timeout_s: float = 0.1, link_timeout_s: float | None = None,
                 spin_s: float | None = None, **task: Any):
        if not (isinstance(first_command_timeout_s, (int, float)) and 0.0 < first_command_timeout_s <= 60.0):
            raise ValueError(f"first_command_timeout_s = {first_command_timeout_s!r} s is out of range: "
                             "must be > 0 s and <= 60 s")
        if link_timeout_s is not None and not (isinstance(link_timeout_s, (int, float))
                                               and 1e-3 <= link_timeout_s <= 60.0):
            raise ValueError(f"link_timeout_s = {link_timeout_s!r} s is out of range: must be >= 0.001 s and "
                             "<= 60 s (or None: the target's own)")
        # ARM carries it in whole ms; 0 asks for the target's own
        self._link_ms = 0 if link_timeout_s is None else max(1, int(round(link_timeout_s * 1e3)))
        if spin_s is not None and not (isinstance(spin_s, (int, float)) and 0.0 <= spin_s <= 1.0):
            raise ValueError(f"spin_s = {spin_s!r} s is out of range: must be >= 0 s and <= 1 s (or None)")
        self.config = config = TaskConfig.from_options(task)
        self.client = RigClient(address, timeout_s, retries, key=key)
        # a real-time host polls for its next OBSERVATION rather than sleep (Endpoint.recv): up to
        # a few policy steps, then it sleeps
        self.client.spin_s = (0.0 if self.client.lockstep else SPIN_STEPS * config.hold_ticks
                              / self.client.scene.control_rate) if spin_s is None else float(spin_s)
        self.scene = scene = self.client.scene
        self.layout = make_layout(scene, config.observation, config.history)
        if self.layout.privileged:
            self.client.close()
            raise ValueError("observation must be 'sensors' on a rig: it measures no body-1 state")
        self.residual = None
        if config.residual is not None:
            self.residual = export_policy(config.residual, scene)
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.observation_space = spaces.Box(-OBS_LIMIT, OBS_LIMIT, (self.layout.size,), np.float32)
        self.hold = config.hold_ticks
        self._first_ticks = int(math.ceil(first_command_timeout_s * scene.control_rate - 1e-9))
        self.tp = config.params(scene)
        self.max_steps = int(self.tp.max_steps)
        self._a1 = np.zeros(1)
        self._y = np.zeros((1, 4))  # body 1's and 2's state at the step's end, for the task kernel
        self._active = np.ones(1, bool)
        self._task_fn = None  # the task kernel's compiled entry point (bound_call)
        self._hw = Hardware(scene, 1) if self.client.virtual else None
        self._state = new_task_state(1)
        self._out = new_task_out(1)
        self._rows = self._out.rows
        self._n = 0
        self._running = False
        if self._hw is not None:
            self._warm_up()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        ep_seed = int(seed) if seed is not None else int(self.np_random.integers(0, 2**63 - 1))
        if self._running:
            self.client.disarm()
        if self._hw is not None:  # before ARM: nothing of the host's may stall a running episode
            self._start_drop(ep_seed, self._state, self._rows)
        c = self.client
        c.arm("host", ep_seed, self.max_steps * self.hold, self.config.observation, self.config.history,
              self.hold, self.residual, first_command_timeout_ticks=self._first_ticks,
              link_timeout_ms=self._link_ms)
        self._running = True
        self._n = 0
        self._last_obs: protocol.Observation | None = None
        self._unheard = self._unheard_run = 0
        self._unheard_warned = False
        obs = self._wait_obs(0, resend=None)
        if isinstance(obs, protocol.EpisodeEnd):
            raise RuntimeError(f"the target ended episode {obs.episode} at once: "
                               f"{protocol.EndReason(obs.reason).name}")
        # in real time the newest OBSERVATION that has come: a host that reached it late (its
        # reset slower than the target's first steps) answers that step, as step() does, not step
        # 0, whose command could only come late
        self._n = int(obs.step)
        return np.asarray(obs.obs, dtype=np.float32), self._info(obs)

    def _start_drop(self, ep_seed: int, state: task_kernel.TaskState, rows: np.ndarray) -> None:
        """The drop's constants, as the virtual rig draws them from the seed, and the task's rows."""
        from gymnasium.utils import seeding

        hw = self._hw
        assert hw is not None  # a virtual rig's drop
        hw.reset([seeding.np_random(ep_seed)[0]])
        rows[0, task_kernel.INFO.t_touch] = hw.t_touch[0]
        task_kernel.task_reset_rows(
            np.zeros(1, np.int64),
            np.zeros((1, 1, records.N_REC)),
            task_kernel.Drop(hw.Y, hw.P, hw.impact_energy, hw.impact_speed),
            self.tp,
            state,
            rows,
        )

    def _task_step(self, recs: np.ndarray, state: task_kernel.TaskState, out: task_kernel.TaskOut) -> None:
        hw = self._hw
        assert hw is not None  # a virtual rig's records
        self._y[:] = recs[:, -1, records.REC.x1:records.REC.v2 + 1]
        drop = task_kernel.Drop(self._y, hw.P, hw.impact_energy, hw.impact_speed)
        args = (self._active, recs, drop, self.tp, state, out)
        if self._task_fn is None:  # the first call runs it and binds it (numba's typing skipped after)
            self._task_fn = bound_call(task_kernel.task_step, args)
        else:
            self._task_fn(*args)

    def _warm_up(self) -> None:
        """Compile (or load) the reward kernels now, on copies, so that no episode waits for them:
        a host that stalls mid-episode loses ticks of control to the watchdog."""
        state = task_kernel.TaskState(*(a.copy() for a in self._state))
        out = task_kernel.TaskOut(*(a.copy() for a in self._out))
        self._start_drop(0, state, out.rows)
        self._task_step(np.zeros((1, self.hold, records.N_REC)), state, out)

    def _wait_obs(
        self, step: int, resend, send: tuple[int, float] | None = None
    ) -> protocol.Observation | protocol.EpisodeEnd:
        c = self.client
        for _ in range(c.retries + 1):
            got = c.observation(step, c.timeout_s, send)
            send = None
            if got is not None:
                return got
            ended = c.last_end is not None and c.last_end.episode == c.episode
            # a COMMAND again: in lock-step the target re-sends the observation it waits with; after
            # the episode's end the last one (real time: a resent command would only be late)
            if resend is not None and (c.lockstep or ended):
                c.command(step - 1, resend)
        if c.last_end is not None and c.last_end.episode == c.episode:
            return c.last_end  # its last observation never came: the step is marked, not a timeout
        raise RigTimeout(f"OBSERVATION of step {step}", (c.retries + 1) * c.timeout_s, c.address,
                         c.retries + 1)

    def step(self, action):
        if not self._running:
            raise RuntimeError("call reset() before step() (the episode has ended)")
        u = float(check_actions(action, 1, self.config.action_bounds, self.scene.effects.command_scale,
                                self._a1)[0])
        self._n += 1
        got = self._wait_obs(self._n, resend=u, send=(self._n - 1, u))  # the COMMAND, then the next OBSERVATION
        if isinstance(got, protocol.EpisodeEnd):
            return self._ended(got)
        obs = got
        extra: dict[str, Any] = {}
        if obs.step > self._n:  # the OBSERVATIONs of the steps between were lost on the way
            extra["steps_missed"] = obs.step - self._n
            self._n = obs.step
        tel = obs.telemetry
        self._count_unheard(obs.step, tel)
        extra["commands_unheard_steps"] = self._unheard
        if self._hw is not None and len(tel) > N_TEL:
            recs = np.asarray(tel[N_TEL:], dtype=np.float64).reshape(1, self.hold, records.N_REC)
            self._task_step(recs, self._state, self._out)
            reward, term, trunc = float(self._out.rewards[0]), bool(self._out.terminated[0]), \
                bool(self._out.truncated[0])
            extra["reward_available"] = True
        else:  # a physical rig, or a step whose true records are incomplete (ticks the target skipped)
            reward, term, trunc = 0.0, False, False
            extra["reward_available"] = False
        trunc = trunc or (not term and self._n >= self.max_steps)
        if term or trunc:
            self._running = False
            if term:  # one end reason on both sides: the target's log says CAUGHT too
                self.client.disarm(caught=True)
        info = self._info(obs)
        info.update(extra)
        if term or trunc:
            info["end_reason"] = "CAUGHT" if term else "HORIZON"
        return np.asarray(obs.obs, dtype=np.float32), reward, term, trunc, info

    def _count_unheard(self, step: int, tel) -> None:
        """The OBSERVATION of ``step`` says how old the command the target acts on is (telemetry
        ``command_age_ticks``; -1 none): from step 2 on, older than two policy steps (or none)
        means that none of this host's COMMANDs of the last two steps acted: counted
        (``info["commands_unheard_steps"]``), and a run of UNHEARD_WARN_STEPS is named in a
        :class:`RigCommandsUnheard` warning, once per episode."""
        if step < 2 or len(tel) < N_TEL:
            return
        age = tel[2]
        if 0 <= age <= 2 * self.hold:
            self._unheard_run = 0
            return
        self._unheard += 1
        self._unheard_run += 1
        if self._unheard_run >= UNHEARD_WARN_STEPS and not self._unheard_warned:
            import warnings

            self._unheard_warned = True
            client = self.client
            warnings.warn(f"episode {client.episode}: the target at {client.address} acted on none of "
                          f"this host's COMMANDs for {self._unheard_run} steps up to step {step} (its "
                          "watchdog "
                          "drove 0 N): they are not reaching it in time (lost, delayed, or taken by another "
                          "process on its machine)", RigCommandsUnheard, stacklevel=3)

    # the target's end reasons that are the task's own terminal states; any other end (the host
    # disarmed, the link, a fault, no first command) cuts the episode short: truncated
    TERMINAL_REASONS = frozenset({"CAUGHT", "SAFETY"})

    def _ended(self, end: protocol.EpisodeEnd):
        """The step the target ended the episode in (EPISODE_END before the step's OBSERVATION):
        the last observation again, no reward (no records came), terminated or truncated by the
        reason."""
        self._running = False
        try:
            reason = protocol.EndReason(end.reason).name
        except ValueError:
            reason = f"reason {end.reason}"
        term = reason in self.TERMINAL_REASONS
        obs = self._last_obs
        info: dict[str, Any] = self._info(obs) if obs is not None else {}
        info.update(end_reason=reason, reward_available=False, status=int(end.status),
                    status_flags=status_names(end.status), ticks=int(end.n_ticks),
                    commands_unheard_steps=self._unheard)  # the episode's count, as on every step
        o = np.asarray(obs.obs if obs is not None else np.zeros(self.layout.size), dtype=np.float32)
        return o, 0.0, term, not term, info

    def _info(self, obs: protocol.Observation) -> dict[str, Any]:
        self._last_obs = obs
        tel = obs.telemetry
        out: dict[str, Any] = {"step": obs.step, "status": obs.status,
                               "status_flags": status_names(obs.status),
                               "reward_available": self._hw is not None,
                               "force_demand": tel[0] if tel else 0.0,
                               "force_applied": tel[1] if len(tel) > 1 else 0.0,
                               "command_age_ticks": tel[2] if len(tel) > 2 else -1.0}
        if self._hw is not None:
            out.update(info_from_row(self._rows[0]))
        return out

    def close(self):
        self.client.close()
        self._running = False


RigEnv.__doc__ = (RigEnv.__doc__ or "").replace("TASK_OPTIONS_DOC", options_doc("    "))
