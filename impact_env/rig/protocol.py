"""The rig's wire protocol: UDP datagrams in a fixed little-endian binary layout (version 4.0).

Every datagram is one message: a 42-byte header, a payload whose layout the message type fixes,
and a 16-byte tag (HMAC-SHA256, :func:`tag`).  Version 2.0 replaced 1.0's CRC-32 trailer with
the tag and appended session_nonce and keyed to INFO; 2.1 gave ARM's options bits 1-2, the
episode kind (:class:`EpisodeKind`: drops, or identification episodes with body 1 held); 3.0
opens a session by challenge and response (HELLO -> CHALLENGE, RESPONSE -> INFO, 128-bit
nonces from both sides), so that no recorded datagram opens one again; 4.0 gives each session a
socket of its own at the target, named in INFO (``session_port``), to which the host sends
everything after the handshake.  Integers are unsigned
little-endian, floats IEEE-754 little-endian.

Header (42 bytes) and trailer
=============================

======  ====  ==========  =================================================================
offset  size  type        field
======  ====  ==========  =================================================================
0       4     bytes       magic ``b"IMPR"``
4       1     u8          major version (4): a receiver drops any other major
5       1     u8          minor version (0): see *Versioning*
6       1     u8          message type (table below)
7       1     u8          flags: bit 0 ``FLAG_RETRY`` (a request sent again); others reserved
8       4     u32         session id, chosen by the host in HELLO (never 0 once a session is open)
12      4     u32         sequence number: one counter per sender and session, +1 per datagram
                          (a retry gets a new number)
16      8     u64         target tick: the target's tick counter (its only clock) when it sent
                          the message; host->target: the tick of the message being answered
24      8     u64         host timestamp, ns (host's ``perf_counter_ns`` at sending; echoed back
                          by the target in replies, so the host measures round trips)
32      8     u64         target timestamp, ns (target's ``perf_counter_ns`` at sending; echoed
                          by the host in COMMANDs answering an OBSERVATION)
40      2     u16         payload length L, bytes (at most ``MAX_PAYLOAD``)
42      L     bytes       payload
42+L    16    bytes       tag: HMAC-SHA256(key, nonce u64 LE + bytes 0 .. 42+L-1)[:16]; key the
                          shared key (b"" without one), nonce the session's (from INFO; 0 for
                          HELLO, CHALLENGE, RESPONSE, INFO and ERROR)
======  ====  ==========  =================================================================

Message types and payloads (offsets from the payload start; ``H`` host, ``T`` target)
====================================================================================

=====  ============  =====  ===========================================================================
code   type          dir    payload (offset type field [unit])
=====  ============  =====  ===========================================================================
1      HELLO         H->T   0 16s nonce (the host's, fresh per handshake); 16 64 zero bytes (padding:
                            no reply to a HELLO is larger).  Asks for a CHALLENGE; opens nothing.
                            = 80 B
15     CHALLENGE     T->H   0 16s nonce (the HELLO's); 16 16s target_nonce (fresh, ``secrets``).
                            In the HELLO's session id.  = 32 B
16     RESPONSE      H->T   0 16s nonce; 16 16s target_nonce (the CHALLENGE's); 32 48 zero bytes
                            (padding).  Its tag covers both nonces: it opens the header's session
                            (or confirms the open one) if it answers a live challenge sent to
                            its sender, once.  = 80 B
2      INFO          T->H   0 16s nonce (the RESPONSE's); 16 f64 control_rate_hz [Hz]; 24 u8 state
                            (0 idle, 1 armed, 2 running, 3 fault); 25 u8 driver (0 virtual, 1
                            hardware); 26 u8 lockstep (0/1); 27 u32 scene_size [B] (resource SCENE);
                            31 32s scene_sha256; 63 u64 session_nonce (drawn per session; in every
                            later tag); 71 u8 keyed; 72 u16 session_port (the session's own socket
                            at the target, 0: none; the host sends the session's datagrams there;
                            4.0).  = 74 B
3      ARM           H->T   0 u8 mode (1 host, 2 onboard); 1 u8 observation (0 sensors, 1 privileged,
                            2 both); 2 u8 history [frames, 1..64]; 3 u8 options (bit 0
                            ``ARM_TERMINATE_ON_CATCH``; bits 1-2 the ``EpisodeKind``: 0 drop, 1
                            identification drop, 2 shaker only, 3 quiet; 2.1); 4 u16 hold_ticks
                            [ticks per policy step, >= 1]; 6 u64 seed; 14 u32 horizon_ticks [ticks,
                            >= 1]; 18 u32
                            first_command_timeout_ticks [ticks; host mode; 0: the target's
                            safety.first_command_timeout_s]; 22 u32 link_timeout_ms [ms; 0 = none];
                            26 u32 policy_size [B; onboard, else 0]; 30 32s policy_sha256
                            (onboard: of the uploaded file; host mode: zeros).  = 62 B
4      ARMED         T->H   0 u32 episode; 4 u64 start_tick; 12 u16 obs_size [entries]; 14 u16
                            action_size; 16 u8 obs_dtype (4 float32, 8 float64); 17 u8 telemetry_size
                            [entries]; 18 u16 hold_ticks; 20 f64 control_rate_hz [Hz]; 28 32s
                            scene_sha256.  = 60 B
5      POLICY_CHUNK  H->T   0 u64 upload_id (first 8 bytes of the file's sha256, little-endian); 8 u32
                            total [B]; 12 u32 offset [B]; 16 u16 n [B]; 18 n bytes data.  Answered by ACK
                            (value = offset + n).  = 18 + n B
6      ACK           both   0 u8 acked_type; 1 u8 code (0 ok, else an ``ErrorCode``); 2 u32 acked_seq;
                            6 u64 value (type-specific).  = 14 B
7      COMMAND       H->T   0 u32 episode; 4 u32 step (policy step the action is for); 8 u16 n; 10 n x
                            f64 action [dimensionless, 1.0 = effects.command_scale N].  = 10 + 8n B
8      OBSERVATION   T->H   0 u32 episode; 4 u32 step; 8 u32 status (bits of :mod:`impact_env.rig.safety`);
                            12 u8 dtype (4 float32 / 8 float64); 13 u16 n; 15 u16 m; 17 n x dtype
                            observation [scaled units of :mod:`impact_env.control.observation`]; then m x
                            f64 telemetry: the ``TELEMETRY_FIELDS`` (force_demand_N, force_applied_N,
                            command_age_ticks), then, from a virtual rig, the true records of the step's
                            ticks (hold_ticks x N_REC, :mod:`impact_env.sim.records`).
                            = 17 + n dtype + 8m B
9      EPISODE_END   T->H   0 u32 episode; 4 u8 reason (``EndReason``); 5 u32 status (OR of the ticks'
                            status bits); 9 u64 n_ticks; 17 u32 n_steps; 21 u32 data_size [B] (resource
                            EPISODE); 25 32s data_sha256.  = 57 B
10     FETCH         H->T   0 u8 resource (1 SCENE, 2 EPISODE); 1 u32 item (episode number; 0 for
                            SCENE); 5 u32 offset [B]; 9 u16 max_len [B].  = 11 B
11     CHUNK         T->H   0 u8 resource; 1 u32 item; 5 u32 total [B]; 9 u32 offset [B]; 13 u16 n [B];
                            15 n bytes data.  = 15 + n B
12     DISARM        H->T   0 u8 reason (0 user, 1 host closing, 2 host error, 3 caught: the host's
                            task ended the episode, whose end reason is then CAUGHT).  Answered by
                            ACK.  = 1 B
13     HEARTBEAT     both   0 u8 state; 1 u32 episode; 5 u32 step; 9 u32 peer_seq (newest sequence
                            number accepted from the peer).  = 13 B
14     ERROR         both   0 u16 code (``ErrorCode``); 2 u32 ref_seq (the message it answers, or 0);
                            6 u16 n; 8 n bytes UTF-8 text (at most 1024).  = 8 + n B
=====  ============  =====  ===========================================================================

Sizes.  ``MAX_PAYLOAD`` (65449 B) fills the largest UDP datagram over IPv4.  Datagrams up to
``MTU_DATAGRAM`` (1472 B, an Ethernet frame) are never fragmented by IP; POLICY_CHUNK and CHUNK
carry at most ``CHUNK_DATA`` (1024 B) each so that they stay below it, and so does any
OBSERVATION below about 1400 B (175 float64 entries).  Larger observations are sent whole and IP
fragments them: losing one fragment loses the datagram.

Versioning.  A receiver drops another **major** (counted ``wrong_version``).  Within a major, a
newer minor may only append fields at the end of a payload (every variable part carries its
length, so fields can always be appended) and add message types.  A receiver decodes a
message of its own minor only if the payload ends exactly after the fields above (else
``corrupt``); of a newer minor, it ignores the bytes after the fields it knows, and counts an
unknown type as ``unexpected``.

Sessions, streams and loss (:class:`DatagramFilter`).  A sender numbers its datagrams of a
session with one counter.  The receiver keeps, per (session, message type) stream, the newest
sequence number it accepted and which of the 64 before it it accepted; anything not newer is
dropped (``duplicate`` if it was accepted before, else ``out_of_order``).  A COMMAND for a
(episode, step) before the target's current one is dropped as ``late``.  Latest command wins:
the target keeps only the newest accepted command; a command for a future step waits for it.
Requests (HELLO, RESPONSE, ARM, POLICY_CHUNK, FETCH, DISARM) are idempotent and retried with
new sequence numbers until their reply (CHALLENGE, INFO, ARMED, ACK, CHUNK, ACK) arrives
(:meth:`impact_env.rig.transport.Link.request`).

Authentication (:class:`DatagramFilter` with ``key``, ``nonce``, ``peer``, ``loopback_only``).
A datagram whose tag does not check is dropped first (``unauthenticated``); a receiver without
key takes loopback peers only (``not_loopback``); once a target's session is open it takes its
host's address and port only (``stranger``: a HELLO from elsewhere is answered ERROR BUSY by
the target, never evicting the session).  The session nonce in the tag makes a datagram of one
session fail in any other; the sequence window refuses a copy within the session.

Opening a session (:mod:`impact_env.rig.handshake`).  HELLO -> CHALLENGE (a fresh target nonce,
kept 5 s for the HELLO's sender), RESPONSE (both nonces, tagged) -> INFO.  A RESPONSE that
answers no live challenge sent to its sender is dropped (``no_challenge``): a recorded HELLO
replayed draws only a challenge to its sender, a recorded RESPONSE names a spent challenge, so
neither opens, holds nor evicts a session.  Without a key (loopback only) the round trip still
proves the peer is live and reads the target's answers.  What a target sends to a sender that
is not its session's host (CHALLENGE, ERROR BUSY, ERROR UNAUTHENTICATED) is never larger than
the datagram it answers (HELLO is padded for that), names no host, and is rate-limited per
source (token buckets: 32 at once, 50 per second; a HELLO past it is ``rate_limited``).
"""

from __future__ import annotations

import builtins
import enum
import functools
import hmac
import math
import struct
from collections.abc import Hashable
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, TypeVar, cast

from impact_env.rig import handshake

MAGIC = b"IMPR"
VERSION_MAJOR = 4
VERSION_MINOR = 0

HEADER = struct.Struct("<4sBBBBIIQQQH")
TAG_SIZE = 16  # bytes of HMAC-SHA256 kept (128 bits)
HEADER_SIZE = HEADER.size  # 42
OVERHEAD = HEADER_SIZE + TAG_SIZE  # 58
MAX_DATAGRAM = 65507  # largest UDP payload over IPv4, B
MAX_PAYLOAD = MAX_DATAGRAM - OVERHEAD  # 65449 B
MIN_KEY = 16  # bytes of a shared key, at least
# the types tagged with nonce 0: those sent before the session's nonce is known to both sides
OPEN_TYPES = frozenset({1, 2, 14, 15, 16})  # HELLO, INFO, ERROR, CHALLENGE, RESPONSE
NONCE_SIZE = handshake.NONCE_SIZE  # bytes of the host's and the target's handshake nonces
# zero bytes that pad HELLO and RESPONSE so that no reply to them is larger (anti-amplification)
HELLO_PAD, RESPONSE_PAD = 64, 48
MTU_DATAGRAM = 1472  # Ethernet MTU 1500 - IPv4 20 - UDP 8, B
CHUNK_DATA = 1024  # data bytes per POLICY_CHUNK / CHUNK
MAX_TEXT = 1024  # ERROR text, B (UTF-8)
MAX_VALUES = 4096  # entries of a COMMAND's action or an OBSERVATION
MAX_TRANSFER = 1 << 31  # bytes of one uploaded policy file or fetched resource

FLAG_RETRY = 1
ARM_TERMINATE_ON_CATCH = 1
ARM_KIND_SHIFT = 1  # options bits 1-2: the episode kind (EpisodeKind)
ARM_KIND_MASK = 0b110
# the other bits are reserved: an ARM with one is refused
ARM_OPTIONS_MAX = ARM_TERMINATE_ON_CATCH | ARM_KIND_MASK

U8, U16, U32, U64 = 0xFF, 0xFFFF, 0xFFFF_FFFF, 0xFFFF_FFFF_FFFF_FFFF
_FLT_MAX = 3.4028234663852886e38

# the first telemetry values of an OBSERVATION (then a virtual rig's tick records, see OBSERVATION)
TELEMETRY_FIELDS = ("force_demand_N", "force_applied_N", "command_age_ticks")


class MsgType(enum.IntEnum):
    HELLO = 1
    INFO = 2
    ARM = 3
    ARMED = 4
    POLICY_CHUNK = 5
    ACK = 6
    COMMAND = 7
    OBSERVATION = 8
    EPISODE_END = 9
    FETCH = 10
    CHUNK = 11
    DISARM = 12
    HEARTBEAT = 13
    ERROR = 14
    CHALLENGE = 15
    RESPONSE = 16


HOST_TO_TARGET = frozenset({MsgType.HELLO, MsgType.RESPONSE, MsgType.ARM, MsgType.POLICY_CHUNK,
                            MsgType.COMMAND, MsgType.FETCH, MsgType.DISARM, MsgType.ACK, MsgType.HEARTBEAT,
                            MsgType.ERROR})
TARGET_TO_HOST = frozenset({MsgType.INFO, MsgType.CHALLENGE, MsgType.ARMED, MsgType.OBSERVATION,
                            MsgType.EPISODE_END, MsgType.CHUNK, MsgType.ACK, MsgType.HEARTBEAT,
                            MsgType.ERROR})
# the target answers these itself, idle or running (:meth:`impact_env.rig.target.Target.handshake`)
HANDSHAKE_TYPES = frozenset({MsgType.HELLO, MsgType.RESPONSE})


class TargetState(enum.IntEnum):
    IDLE = 0
    ARMED = 1
    RUNNING = 2
    FAULT = 3


class Resource(enum.IntEnum):
    SCENE = 1  # the target's scene as TOML (UTF-8), item 0
    EPISODE = 2  # the episode log file (HDF5 bytes, impact_env.rig.log), item = episode number


class EndReason(enum.IntEnum):
    HORIZON = 1  # horizon_ticks reached
    CAUGHT = 2  # caught, with ARM_TERMINATE_ON_CATCH
    DISARMED = 3  # the host sent DISARM
    FIRST_COMMAND_TIMEOUT = 4  # host mode: no COMMAND (late ones count) within first_command_timeout_ticks
    SAFETY = 5  # a latched safety trip (travel limit, sensor fault)
    LINK_LOST = 6  # nothing authentic heard from the host within link_timeout_ms (late commands count)
    FAULT = 7  # the driver reported an error
    SENSOR_FAULT = 8  # implausible readings outlasted effects.sensors.fault_limit_s (issue 25)
    OVERRUN = 9  # real time: no tick ran for longer than the target's limit (max_gap_s): 0 N, ended


# DISARM's reasons: the user; the host closing (its session ends too); a host error; the host's
# task caught body 1 (terminate_on_catch): the episode's end reason is then CAUGHT, on both sides
DISARM_USER, DISARM_CLOSING, DISARM_ERROR, DISARM_CAUGHT = 0, 1, 2, 3


class EpisodeKind(enum.IntEnum):
    """What an ARMed episode does (ARM options bits 1-2; :mod:`impact_env.rig.excitation`)."""

    DROP = 0  # body 1 released: the drop the seed draws (a benchmark or host-mode episode)
    IDENT_DROP = 1  # body 1 released from the scene's nominal drop (the same body and height each time)
    SHAKER = 2  # body 1 held on the electromagnet; the uploaded excitation drives the shaker
    QUIET = 3  # body 1 held; the shaker at 0 N (the sensors' offsets and noise)


class ErrorCode(enum.IntEnum):
    OK = 0
    BAD_REQUEST = 1  # a field out of range for this target (e.g. history too long)
    BUSY = 2  # another session holds the target
    NOT_ARMED = 3
    POLICY_REJECTED = 4  # hash mismatch, or the file did not load
    DRIVER_FAULT = 5
    UNKNOWN_RESOURCE = 6
    OUT_OF_RANGE = 7  # a FETCH offset past the end
    UNAUTHENTICATED = 8  # a HELLO whose tag does not check with this side's key (or lack of one)


MODES = {"host": 1, "onboard": 2}
OBSERVATIONS = {"sensors": 0, "privileged": 1, "both": 2}
_MODE_NAMES = {v: k for k, v in MODES.items()}
_OBS_NAMES = {v: k for k, v in OBSERVATIONS.items()}


# -- errors ------------------------------------------------------------------------------------------
class ProtocolError(ValueError):
    """A datagram that cannot be decoded; ``reason`` is the :class:`DatagramFilter` counter it
    goes to, ``detail`` says why."""

    reason = "corrupt"

    def __init__(self, detail: str, message: str):
        super().__init__(message)
        self.detail = detail


class CorruptDatagram(ProtocolError):
    """Bad magic, length or payload (``detail``: truncated, magic, length, payload)."""


class FieldOutOfRange(CorruptDatagram):
    """An authenticated datagram with a field out of its range (``detail`` "field"): ``field``
    names it, ``refusal`` is the terse text of the ERROR that answers it (``field=value [range]``),
    ``mtype``, ``session``, ``seq`` are its header's."""

    def __init__(self, message: str, field: str, refusal: str, mtype: int = 0, session: int = 0,
                 seq: int = 0):
        super().__init__("field", message)
        self.field, self.refusal = field, refusal
        self.mtype, self.session, self.seq = mtype, session, seq


class FieldError(ValueError):
    """A field out of its range: ``field`` and the terse ``refusal`` (``field=value [range]``)."""

    def __init__(self, message: str, field: str, refusal: str):
        super().__init__(message)
        self.field, self.refusal = field, refusal


class WrongVersion(ProtocolError):
    reason = "wrong_version"


class Unauthenticated(ProtocolError):
    """The tag does not check (``detail``: the message type's name, or its number): the sender
    has no key, another key, or the datagram was altered or replayed into another session."""

    reason = "unauthenticated"


class UnknownType(ProtocolError):
    reason = "unexpected"


# -- field checks -------------------------------------------------------------------------------------
def _uint(name: str, value, hi: int, lo: int = 0) -> None:
    if type(value) is int and lo <= value <= hi:  # the common case, first: decoding runs it per field
        return
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise FieldError(f"{name} = {value!r} must be an integer in [{lo}, {hi}]", name,
                         f"{name}={value!r:.24} [{lo},{hi}]")


def _digest(name: str, value) -> None:
    if not isinstance(value, bytes) or len(value) != 32:
        raise ValueError(f"{name} must be 32 bytes (a sha256 digest), got {value!r:.80}")


def _floats(name: str, values, limit: int, lo: int = 0) -> None:
    if not isinstance(values, tuple) or not lo <= len(values) <= limit:
        n = len(values) if hasattr(values, '__len__') else '?'
        raise FieldError(f"{name} must be a tuple of {lo} to {limit} floats, got {type(values).__name__} "
                         f"of length {n}", name, f"n={n} [{lo},{limit}]")
    for v in values:
        if type(v) is not float:
            raise ValueError(f"{name} must hold Python floats, got {v!r} ({type(v).__name__})")


def _nonce(name: str, value) -> None:
    if not isinstance(value, bytes) or len(value) != NONCE_SIZE:
        raise ValueError(f"{name} must be {NONCE_SIZE} bytes (secrets.token_bytes), got {value!r:.80}")


def _data(name: str, value, limit: int) -> None:
    if not isinstance(value, bytes) or len(value) > limit:
        raise ValueError(f"{name} must be bytes of at most {limit} B, got {type(value).__name__}"
                         f"{'' if not isinstance(value, bytes) else f' of {len(value)} B'}")


# -- payloads -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Body:
    """A message payload.  Subclasses fix ``TYPE`` and the fixed-size part ``FMT``."""

    TYPE: ClassVar[MsgType]
    FMT: ClassVar[struct.Struct]

    def pack(self) -> bytes:
        return self.FMT.pack(*self._fixed())

    def _fixed(self) -> tuple:
        cls = cast(Hashable, type(self))  # a class is hashable (mypy reads the eq dataclass's instances)
        return tuple(getattr(self, name) for name in _names(cls))

    @classmethod
    def unpack(cls, payload: bytes | memoryview, newer: bool) -> Body:
        """Decode ``payload``; ``newer``: the sender's minor is newer (trailing bytes allowed)."""
        n = cls.FMT.size
        _need(payload, n, newer, exact=True)
        return cls(*cls.FMT.unpack_from(payload))



B = TypeVar("B", bound=Body)  # a payload class

@functools.cache
def _names(cls: Any) -> tuple[str, ...]:
    return tuple(f.name for f in fields(cls))


def _need(payload, n: int, newer: bool, exact: bool) -> None:
    if len(payload) < n or (exact and not newer and len(payload) != n):
        raise CorruptDatagram("payload", f"payload of {len(payload)} B where {n} B are needed")


@dataclass(frozen=True)
class Hello(Body):
    """The host's nonce, then ``HELLO_PAD`` zero bytes (the CHALLENGE or ERROR answering it is
    never larger)."""

    TYPE: ClassVar = MsgType.HELLO
    FMT: ClassVar = struct.Struct(f"<{NONCE_SIZE}s{HELLO_PAD}x")
    nonce: bytes = bytes(NONCE_SIZE)

    def __post_init__(self):
        _nonce("nonce", self.nonce)


@dataclass(frozen=True)
class Challenge(Body):
    """The target's answer to a HELLO: its nonce echoed, and a fresh one of the target's."""

    TYPE: ClassVar = MsgType.CHALLENGE
    FMT: ClassVar = struct.Struct(f"<{NONCE_SIZE}s{NONCE_SIZE}s")
    nonce: bytes = bytes(NONCE_SIZE)
    target_nonce: bytes = bytes(NONCE_SIZE)

    def __post_init__(self):
        _nonce("nonce", self.nonce)
        _nonce("target_nonce", self.target_nonce)


@dataclass(frozen=True)
class Response(Body):
    """The host's answer to a CHALLENGE: both nonces (so its tag is over both), then
    ``RESPONSE_PAD`` zero bytes (the INFO answering it is never larger)."""

    TYPE: ClassVar = MsgType.RESPONSE
    FMT: ClassVar = struct.Struct(f"<{NONCE_SIZE}s{NONCE_SIZE}s{RESPONSE_PAD}x")
    nonce: bytes = bytes(NONCE_SIZE)
    target_nonce: bytes = bytes(NONCE_SIZE)

    def __post_init__(self):
        _nonce("nonce", self.nonce)
        _nonce("target_nonce", self.target_nonce)


@dataclass(frozen=True)
class Info(Body):
    TYPE: ClassVar = MsgType.INFO
    FMT: ClassVar = struct.Struct(f"<{NONCE_SIZE}sdBBBI32sQBH")
    nonce: bytes = bytes(NONCE_SIZE)
    control_rate_hz: float = 1.0e4
    state: int = TargetState.IDLE
    driver: int = 0
    lockstep: bool = False
    scene_size: int = 0
    scene_sha256: bytes = bytes(32)
    session_nonce: int = 0
    keyed: bool = False
    session_port: int = 0  # the session's own socket at the target (0: none, use the target's address)

    def __post_init__(self):
        _nonce("nonce", self.nonce)
        if not (isinstance(self.control_rate_hz, float) and self.control_rate_hz > 0
                and math.isfinite(self.control_rate_hz)):
            raise ValueError(f"control_rate_hz = {self.control_rate_hz!r} Hz must be a finite float > 0 Hz")
        _uint("state", self.state, max(TargetState))
        _uint("driver", self.driver, 1)
        if not isinstance(self.lockstep, bool):
            raise ValueError(f"lockstep must be a bool, got {self.lockstep!r}")
        _uint("scene_size", self.scene_size, U32)
        _digest("scene_sha256", self.scene_sha256)
        _uint("session_nonce", self.session_nonce, U64)
        if not isinstance(self.keyed, bool):
            raise ValueError(f"keyed must be a bool, got {self.keyed!r}")
        _uint("session_port", self.session_port, U16)

    @classmethod
    def unpack(cls, payload, newer):
        _need(payload, cls.FMT.size, newer, exact=True)
        nonce, rate, state, driver, lock, size, sha, snonce, keyed, port = cls.FMT.unpack_from(payload)
        if lock > 1 or keyed > 1:
            raise CorruptDatagram("payload", f"INFO lockstep/keyed byte {lock}/{keyed} is not 0 or 1")
        return cls(nonce, rate, state, driver, bool(lock), size, sha, snonce, bool(keyed), port)


@dataclass(frozen=True)
class Arm(Body):
    TYPE: ClassVar = MsgType.ARM
    FMT: ClassVar = struct.Struct("<BBBBHQIIII32s")
    mode: str = "host"
    observation: str = "sensors"
    history: int = 1
    options: int = 0
    hold_ticks: int = 1
    seed: int = 0
    horizon_ticks: int = 1
    first_command_timeout_ticks: int = 1000
    link_timeout_ms: int = 0
    policy_size: int = 0
    policy_sha256: bytes = bytes(32)

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"mode = {self.mode!r} must be one of {', '.join(MODES)}")
        if self.observation not in OBSERVATIONS:
            raise ValueError(f"observation = {self.observation!r} must be one of {', '.join(OBSERVATIONS)}")
        _uint("history", self.history, 64, 1)
        _uint("options", self.options, U8)
        _uint("hold_ticks", self.hold_ticks, U16, 1)
        _uint("seed", self.seed, U64)
        _uint("horizon_ticks", self.horizon_ticks, U32, 1)
        _uint("first_command_timeout_ticks", self.first_command_timeout_ticks, U32)
        _uint("link_timeout_ms", self.link_timeout_ms, U32)
        _uint("policy_size", self.policy_size, U32)
        _digest("policy_sha256", self.policy_sha256)

    def _fixed(self):
        v = super()._fixed()
        return (MODES[self.mode], OBSERVATIONS[self.observation]) + v[2:]

    @property
    def kind(self) -> EpisodeKind:
        return EpisodeKind((self.options & ARM_KIND_MASK) >> ARM_KIND_SHIFT)

    @classmethod
    def unpack(cls, payload, newer):
        _need(payload, cls.FMT.size, newer, exact=True)
        mode, obs, *rest = cls.FMT.unpack_from(payload)
        if mode not in _MODE_NAMES:
            raise FieldError(f"ARM mode {mode} unknown: 1 host, 2 onboard", "mode", f"mode={mode} [1,2]")
        if obs not in _OBS_NAMES:
            raise FieldError(f"ARM observation {obs} unknown: 0 sensors, 1 privileged, 2 both", "observation",
                             f"observation={obs} [0,2]")
        return cls(_MODE_NAMES[mode], _OBS_NAMES[obs], *rest)


@dataclass(frozen=True)
class Armed(Body):
    TYPE: ClassVar = MsgType.ARMED
    FMT: ClassVar = struct.Struct("<IQHHBBHd32s")
    episode: int = 0
    start_tick: int = 0
    obs_size: int = 1
    action_size: int = 1
    obs_dtype: int = 4
    telemetry_size: int = 0
    hold_ticks: int = 1
    control_rate_hz: float = 1.0e4
    scene_sha256: bytes = bytes(32)

    def __post_init__(self):
        _uint("episode", self.episode, U32)
        _uint("start_tick", self.start_tick, U64)
        _uint("obs_size", self.obs_size, MAX_VALUES)
        _uint("action_size", self.action_size, MAX_VALUES)
        if self.obs_dtype not in (4, 8):
            raise ValueError(f"obs_dtype = {self.obs_dtype!r} must be 4 (float32) or 8 (float64)")
        _uint("telemetry_size", self.telemetry_size, U8)
        _uint("hold_ticks", self.hold_ticks, U16, 1)
        if not (isinstance(self.control_rate_hz, float) and self.control_rate_hz > 0
                and math.isfinite(self.control_rate_hz)):
            raise ValueError(f"control_rate_hz = {self.control_rate_hz!r} Hz must be a finite float > 0 Hz")
        _digest("scene_sha256", self.scene_sha256)


def _check_window(chunk) -> None:
    """A chunk's ``total``, ``offset`` and ``data`` (POLICY_CHUNK, CHUNK): the piece fits in one
    datagram and lies within the transfer."""
    _uint("total", chunk.total, MAX_TRANSFER)
    _uint("offset", chunk.offset, chunk.total)
    _data("data", chunk.data, min(U16, MAX_PAYLOAD - chunk.FMT.size))
    if chunk.offset + len(chunk.data) > chunk.total:
        raise ValueError(f"chunk [{chunk.offset}, {chunk.offset + len(chunk.data)}) B runs past the "
                         f"total {chunk.total} B")


@dataclass(frozen=True)
class PolicyChunk(Body):
    TYPE: ClassVar = MsgType.POLICY_CHUNK
    FMT: ClassVar = struct.Struct("<QIIH")
    upload_id: int = 0
    total: int = 0
    offset: int = 0
    data: bytes = b""

    def __post_init__(self):
        _uint("upload_id", self.upload_id, U64)
        _check_window(self)

    def pack(self):
        return self.FMT.pack(self.upload_id, self.total, self.offset, len(self.data)) + self.data

    @classmethod
    def unpack(cls, payload, newer):
        _need(payload, cls.FMT.size, newer, exact=False)
        uid, total, off, n = cls.FMT.unpack_from(payload)
        _need(payload, cls.FMT.size + n, newer, exact=True)
        return cls(uid, total, off, bytes(payload[cls.FMT.size:cls.FMT.size + n]))


@dataclass(frozen=True)
class Ack(Body):
    TYPE: ClassVar = MsgType.ACK
    FMT: ClassVar = struct.Struct("<BBIQ")
    acked_type: int = MsgType.HELLO
    code: int = ErrorCode.OK
    acked_seq: int = 0
    value: int = 0

    def __post_init__(self):
        _uint("acked_type", self.acked_type, U8)
        _uint("code", self.code, U8)
        _uint("acked_seq", self.acked_seq, U32)
        _uint("value", self.value, U64)


@dataclass(frozen=True)
class Command(Body):
    TYPE: ClassVar = MsgType.COMMAND
    FMT: ClassVar = struct.Struct("<IIH")
    episode: int = 0
    step: int = 0
    action: tuple[float, ...] = (0.0,)

    def __post_init__(self):
        _uint("episode", self.episode, U32)
        _uint("step", self.step, U32)
        _floats("action", self.action, MAX_VALUES, lo=1)

    def pack(self):
        n = len(self.action)
        return self.FMT.pack(self.episode, self.step, n) + struct.pack(f"<{n}d", *self.action)

    @classmethod
    def unpack(cls, payload, newer):
        _need(payload, cls.FMT.size, newer, exact=False)
        ep, step, n = cls.FMT.unpack_from(payload)
        _need(payload, cls.FMT.size + 8 * n, newer, exact=True)
        return cls(ep, step, struct.unpack_from(f"<{n}d", payload, cls.FMT.size))


@dataclass(frozen=True)
class Observation(Body):
    """``obs`` values are encoded as float32 when ``dtype = 4`` (rounded to nearest; decoding
    gives the rounded values), as float64 when 8; ``telemetry`` always as float64."""

    TYPE: ClassVar = MsgType.OBSERVATION
    FMT: ClassVar = struct.Struct("<IIIBHH")
    episode: int = 0
    step: int = 0
    status: int = 0
    dtype: int = 4
    obs: tuple[float, ...] = ()
    telemetry: tuple[float, ...] = ()

    def __post_init__(self):
        _uint("episode", self.episode, U32)
        _uint("step", self.step, U32)
        _uint("status", self.status, U32)
        if self.dtype not in (4, 8):
            raise ValueError(f"dtype = {self.dtype!r} must be 4 (float32) or 8 (float64)")
        _floats("obs", self.obs, MAX_VALUES)
        _floats("telemetry", self.telemetry, MAX_VALUES)
        if self.dtype == 4:
            for v in self.obs:
                if math.isfinite(v) and abs(v) > _FLT_MAX:
                    raise ValueError(f"obs value {v!r} overflows float32 (dtype 4)")

    def pack(self):
        n, m = len(self.obs), len(self.telemetry)
        code = "f" if self.dtype == 4 else "d"
        return (self.FMT.pack(self.episode, self.step, self.status, self.dtype, n, m)
                + struct.pack(f"<{n}{code}{m}d", *self.obs, *self.telemetry))

    @classmethod
    def unpack(cls, payload, newer):
        _need(payload, cls.FMT.size, newer, exact=False)
        ep, step, status, dtype, n, m = cls.FMT.unpack_from(payload)
        if dtype not in (4, 8) or m > MAX_VALUES or n > MAX_VALUES:
            raise CorruptDatagram("payload", f"OBSERVATION dtype {dtype}, size {n} or telemetry size {m} invalid")
        _need(payload, cls.FMT.size + dtype * n + 8 * m, newer, exact=True)
        vals = struct.unpack_from(f"<{n}{'f' if dtype == 4 else 'd'}{m}d", payload, cls.FMT.size)
        # every field is in range by construction (struct): skip the checks of __post_init__, the
        # larger part of a host's decoding time (one per policy step)
        out = object.__new__(cls)
        out.__dict__.update(episode=ep, step=step, status=status, dtype=dtype, obs=vals[:n],
                            telemetry=vals[n:])
        return out


@dataclass(frozen=True)
class EpisodeEnd(Body):
    TYPE: ClassVar = MsgType.EPISODE_END
    FMT: ClassVar = struct.Struct("<IBIQII32s")
    episode: int = 0
    reason: int = EndReason.HORIZON
    status: int = 0
    n_ticks: int = 0
    n_steps: int = 0
    data_size: int = 0
    data_sha256: bytes = bytes(32)

    def __post_init__(self):
        _uint("episode", self.episode, U32)
        _uint("reason", self.reason, U8)
        _uint("status", self.status, U32)
        _uint("n_ticks", self.n_ticks, U64)
        _uint("n_steps", self.n_steps, U32)
        _uint("data_size", self.data_size, U32)
        _digest("data_sha256", self.data_sha256)


@dataclass(frozen=True)
class Fetch(Body):
    TYPE: ClassVar = MsgType.FETCH
    FMT: ClassVar = struct.Struct("<BIIH")
    resource: int = Resource.SCENE
    item: int = 0
    offset: int = 0
    max_len: int = CHUNK_DATA

    def __post_init__(self):
        _uint("resource", self.resource, U8)
        _uint("item", self.item, U32)
        _uint("offset", self.offset, U32)
        _uint("max_len", self.max_len, U16, 1)


@dataclass(frozen=True)
class Chunk(Body):
    TYPE: ClassVar = MsgType.CHUNK
    FMT: ClassVar = struct.Struct("<BIIIH")
    resource: int = Resource.SCENE
    item: int = 0
    total: int = 0
    offset: int = 0
    data: bytes = b""

    def __post_init__(self):
        _uint("resource", self.resource, U8)
        _uint("item", self.item, U32)
        _check_window(self)

    def pack(self):
        return self.FMT.pack(self.resource, self.item, self.total, self.offset, len(self.data)) + self.data

    @classmethod
    def unpack(cls, payload, newer):
        _need(payload, cls.FMT.size, newer, exact=False)
        res, item, total, off, n = cls.FMT.unpack_from(payload)
        _need(payload, cls.FMT.size + n, newer, exact=True)
        return cls(res, item, total, off, bytes(payload[cls.FMT.size:cls.FMT.size + n]))


@dataclass(frozen=True)
class Disarm(Body):
    TYPE: ClassVar = MsgType.DISARM
    FMT: ClassVar = struct.Struct("<B")
    reason: int = 0  # DISARM_USER, DISARM_CLOSING, DISARM_ERROR, DISARM_CAUGHT

    def __post_init__(self):
        _uint("reason", self.reason, DISARM_CAUGHT)


@dataclass(frozen=True)
class Heartbeat(Body):
    TYPE: ClassVar = MsgType.HEARTBEAT
    FMT: ClassVar = struct.Struct("<BIII")
    state: int = TargetState.IDLE
    episode: int = 0
    step: int = 0
    peer_seq: int = 0

    def __post_init__(self):
        _uint("state", self.state, U8)
        _uint("episode", self.episode, U32)
        _uint("step", self.step, U32)
        _uint("peer_seq", self.peer_seq, U32)


@dataclass(frozen=True)
class Error(Body):
    TYPE: ClassVar = MsgType.ERROR
    FMT: ClassVar = struct.Struct("<HIH")
    code: int = ErrorCode.BAD_REQUEST
    ref_seq: int = 0
    text: str = ""

    def __post_init__(self):
        _uint("code", self.code, U16)
        _uint("ref_seq", self.ref_seq, U32)
        if not isinstance(self.text, str) or len(self.text.encode("utf-8", "surrogatepass")) > MAX_TEXT:
            raise ValueError(f"text must be a str of at most {MAX_TEXT} UTF-8 bytes")
        try:
            self.text.encode("utf-8")
        except UnicodeEncodeError as exc:
            raise ValueError(f"text is not encodable as UTF-8: {exc}") from None

    @classmethod
    def shorten(cls, code: int, ref_seq: int, text: str) -> Error:
        """An ERROR whose text is cut (at a character boundary) to fit ``MAX_TEXT`` bytes."""
        raw = text.encode("utf-8", "replace")[:MAX_TEXT]
        return cls(code, ref_seq, raw.decode("utf-8", "ignore"))

    @classmethod
    def fitting(cls, code: int, ref_seq: int, text: str, size: int) -> Error | None:
        """An ERROR whose datagram is at most ``size`` bytes (its text cut to fit, at a
        character boundary), or None when not even an empty one fits: the reply to a datagram
        from a sender not yet authenticated is never larger than that datagram."""
        room = min(size - OVERHEAD - cls.FMT.size, MAX_TEXT)
        if room < 0:
            return None
        return cls(code, ref_seq, text.encode("utf-8", "replace")[:room].decode("utf-8", "ignore"))

    def pack(self):
        raw = self.text.encode("utf-8")
        return self.FMT.pack(self.code, self.ref_seq, len(raw)) + raw

    @classmethod
    def unpack(cls, payload, newer):
        _need(payload, cls.FMT.size, newer, exact=False)
        code, ref, n = cls.FMT.unpack_from(payload)
        if n > MAX_TEXT:
            raise CorruptDatagram("payload", f"ERROR text of {n} B exceeds {MAX_TEXT} B")
        _need(payload, cls.FMT.size + n, newer, exact=True)
        try:
            text = bytes(payload[cls.FMT.size:cls.FMT.size + n]).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise CorruptDatagram("payload", f"ERROR text is not UTF-8: {exc}") from None
        return cls(code, ref, text)


BODIES: dict[int, type[Body]] = {cls.TYPE: cls for cls in (
    Hello, Info, Arm, Armed, PolicyChunk, Ack, Command, Observation, EpisodeEnd, Fetch, Chunk, Disarm,
    Heartbeat, Error, Challenge, Response)}


# -- messages -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Message:
    """One datagram: the header fields and a payload ``body`` (whose class fixes the type)."""

    body: Body
    session: int = 0
    seq: int = 0
    tick: int = 0
    host_ns: int = 0
    target_ns: int = 0
    flags: int = 0

    def __post_init__(self):
        if not isinstance(self.body, Body) or type(self.body) not in BODIES.values():
            raise ValueError(f"body must be one of the payload classes of this module, got {self.body!r:.80}")
        _uint("session", self.session, U32)
        _uint("seq", self.seq, U32)
        _uint("tick", self.tick, U64)
        _uint("host_ns", self.host_ns, U64)
        _uint("target_ns", self.target_ns, U64)
        _uint("flags", self.flags, U8)

    @property
    def type(self) -> MsgType:
        return self.body.TYPE

    def payload(self, cls: builtins.type[B]) -> B:
        """The body as ``cls``, for code that has checked the type code (``msg.type``): a
        message of another type is a TypeError, not a missing attribute later."""
        body = self.body
        if not isinstance(body, cls):
            raise TypeError(f"a {self.type.name} message carries {type(body).__name__}, not {cls.__name__}")
        return body


def tag(key: bytes, nonce: int, frame) -> bytes:
    """The datagram's tag: HMAC-SHA256 under ``key`` (b"": no key, an integrity check only) of
    the session nonce (u64 little-endian; 0 for HELLO, INFO and ERROR) and the header and payload
    bytes ``frame``, its first ``TAG_SIZE`` bytes."""
    return hmac.digest(key, nonce.to_bytes(8, "little") + frame, "sha256")[:TAG_SIZE]


_COMMAND1 = struct.Struct("<IIHd")  # a COMMAND's payload with one action


def command_datagram(episode: int, step: int, action: float, session: int, seq: int, host_ns: int,
                     target_ns: int = 0, key: bytes = b"", nonce: int = 0) -> bytes:
    """The datagram of a one-action COMMAND: ``encode(Message(Command(episode, step, (action,)),
    ...))`` byte for byte (``tests/test_rig_protocol.py``), without building the message: a host
    in real time sends one every policy step."""
    frame = HEADER.pack(MAGIC, VERSION_MAJOR, VERSION_MINOR, MsgType.COMMAND, 0, session, seq, 0, host_ns,
                        target_ns, _COMMAND1.size) + _COMMAND1.pack(episode, step, 1, action)
    return frame + tag(key, nonce, frame)


def encode(msg: Message, key: bytes = b"", nonce: int = 0) -> bytes:
    """The datagram of ``msg`` (header, payload, tag under ``key`` and the session ``nonce``)."""
    try:
        payload = msg.body.pack()
    except (struct.error, OverflowError) as exc:
        raise ValueError(f"cannot encode {msg.type.name}: {exc}") from None
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"{msg.type.name} payload of {len(payload)} B exceeds MAX_PAYLOAD = {MAX_PAYLOAD} B")
    head = HEADER.pack(MAGIC, VERSION_MAJOR, VERSION_MINOR, msg.type, msg.flags, msg.session, msg.seq,
                       msg.tick, msg.host_ns, msg.target_ns, len(payload))
    frame = head + payload
    return frame + tag(key, 0 if int(msg.type) in OPEN_TYPES else nonce, frame)


def decode(data: bytes, key: bytes = b"", nonce: int = 0) -> Message:
    """The message in datagram ``data``; raises :class:`ProtocolError` (never anything else).
    The tag is checked (under ``key`` and the session ``nonce``) before anything of the payload
    is read."""
    n = len(data)
    if n < OVERHEAD:
        raise CorruptDatagram("truncated", f"datagram of {n} B is shorter than the {OVERHEAD} B frame")
    magic, major, minor, mtype, flags, session, seq, tick, hns, tns, plen = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise CorruptDatagram("magic", f"bad magic {magic!r} (expected {MAGIC!r})")
    if major != VERSION_MAJOR:
        raise WrongVersion("major", f"protocol version {major}.{minor}, this side speaks "
                           f"{VERSION_MAJOR}.{VERSION_MINOR}")
    if HEADER_SIZE + plen + TAG_SIZE != n:
        raise CorruptDatagram("length", f"payload length {plen} B does not match the datagram's {n} B")
    end = HEADER_SIZE + plen
    mv = memoryview(data)
    if not hmac.compare_digest(tag(key, 0 if mtype in OPEN_TYPES else nonce, mv[:end]), bytes(mv[end:])):
        try:
            name = MsgType(mtype).name
        except ValueError:
            name = str(mtype)
        raise Unauthenticated(name, f"{name}: the tag does not check "
                              f"({'with this side' + chr(39) + 's key' if key else 'this side has no key'})")
    cls = BODIES.get(mtype)
    if cls is None:
        raise UnknownType("type", f"unknown message type {mtype} (minor {minor})")
    payload = mv[HEADER_SIZE:end]
    try:
        body = cls.unpack(payload, minor > VERSION_MINOR)
    except ProtocolError:
        raise
    except FieldError as exc:  # authenticated (the tag checked): the sender may be told which field
        raise FieldOutOfRange(f"{cls.TYPE.name} payload invalid: {exc}", exc.field, exc.refusal, mtype,
                              session, seq) from None
    except (ValueError, struct.error) as exc:
        raise CorruptDatagram("payload", f"{cls.TYPE.name} payload invalid: {exc}") from None
    # the header's fields are in range by construction (struct): skip Message's checks
    msg = object.__new__(Message)
    msg.__dict__.update(body=body, session=session, seq=seq, tick=tick, host_ns=hns, target_ns=tns,
                        flags=flags)
    return msg


def source(sender: tuple | None) -> tuple | None:
    """A sender's (host, port), the key of the per-source tables (IPv6's flow info and scope dropped)."""
    return None if sender is None else (sender[0], sender[1])


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address as the socket gives it) is a loopback address."""
    import ipaddress

    try:
        return ipaddress.ip_address(host.split("%")[0]).is_loopback
    except ValueError:
        return False


# -- receiver-side filter -----------------------------------------------------------------------------
_HALF = 1 << 31


@dataclass
class _Stream:
    newest: int
    mask: int  # bit i: newest - i was accepted


@dataclass
class DatagramFilter:
    """Decodes datagrams and drops, counting by reason, those a receiver must not act on.

    role: ``"target"`` accepts the host->target types, ``"host"`` the target->host ones (the
    other direction's types count as ``unexpected``).
    session: the open session id; None accepts only ``open_types`` (by default HELLO and RESPONSE
    at the target, so that a host can open a session).  Setting it forgets the streams.

    ``accept(data, episode, step)`` returns the :class:`Message` or None; for the target, a
    COMMAND for an (episode, step) before the given one is ``late`` (it still moves its stream
    on: a copy of it is then a ``duplicate``).  ``counts()`` is a dict of
    plain ints: ``accepted`` and one entry per reason in ``REASONS``, which add up to the number
    of datagrams seen; ``detail`` splits ``corrupt`` (truncated, magic, length, payload) and
    ``unauthenticated``, ``stranger`` (by message type).

    The target's handshake (:mod:`impact_env.rig.handshake`): a HELLO past the per-source
    ``limiter`` is ``rate_limited`` (not answered); a RESPONSE is accepted only if it answers a
    live challenge of ``challenges`` sent to its sender (or repeats the handshake that opened the
    session, ``opened``: its INFO was lost), else ``no_challenge``.  ``replies_limited`` counts
    the answers to strangers and unauthenticated HELLOs that the limiter withheld.
    On the host, an ERROR UNAUTHENTICATED whose tag does not check with this side's key is counted
    ``unauthenticated`` like any other, and ``unverified_refusals`` counts it when it claims to
    answer this session from its peer: a hint for the host's error message, never state.
    """

    REASONS: ClassVar[tuple[str, ...]] = ("corrupt", "wrong_version", "unauthenticated", "not_loopback",
                                          "stranger", "wrong_session", "unexpected", "duplicate",
                                          "out_of_order", "late", "rate_limited", "no_challenge",
                                          "queue_full")
    # counted by the real-time loop, which reads the socket during an episode (impact_env.rig.wire):
    # a datagram it could not hand to the network thread; never given by accept()
    LOOP_REASONS: ClassVar[tuple[str, ...]] = ("queue_full",)
    WINDOW: ClassVar[int] = 64
    MAX_STREAMS: ClassVar[int] = 1024  # other sessions' streams kept before the oldest is forgotten

    role: str
    session: int | None = None
    open_types: frozenset | None = None
    counters: dict = field(default_factory=dict)
    detail: dict = field(default_factory=dict)
    last_reason: str = ""
    last_error: str = ""
    key: bytes = b""
    nonce: int = 0
    peer: tuple | None = None
    # the host's filter: the target's session socket (INFO's session_port), a second address of its peer
    session_peer: tuple | None = None
    loopback_only: bool = False
    last_stranger: Message | None = None
    last_unauth: bool = False  # the last datagram dropped was a HELLO whose tag did not check
    unverified_refusals: int = 0
    replies_limited: int = 0
    # the open session's handshake: (source, session, host nonce, target nonce)
    opened: tuple | None = None
    limiter: handshake.RateLimiter = field(default_factory=handshake.RateLimiter)
    challenges: handshake.Challenges = field(default_factory=handshake.Challenges)
    # the target: the armed COMMAND's action count (ARMED's action_size); None: any count
    n_actions: int | None = None
    # the target: (ERROR code, seq, text, datagram size) of the last datagram dropped that its
    # session's host is to be told about (a field out of range); the link answers and clears it
    refusal: tuple | None = None
    # the answers to refusals, per source (their own buckets: a host's HELLOs keep theirs)
    refusal_limiter: handshake.RateLimiter = field(default_factory=handshake.RateLimiter)
    refusals_limited: int = 0
    # datagrams of the open session that authenticated from its peer, whatever their fate after
    # (accepted, or dropped as duplicate, out of order or late): a late COMMAND is still a host
    # that is alive, which is what a link timeout asks
    authentic: int = 0

    def __post_init__(self):
        if self.role not in ("host", "target"):
            raise ValueError(f"role = {self.role!r} must be 'host' or 'target'")
        self._types = HOST_TO_TARGET if self.role == "target" else TARGET_TO_HOST
        if self.open_types is None:
            self.open_types = HANDSHAKE_TYPES if self.role == "target" else frozenset()
        self.counters = {"accepted": 0, **{r: 0 for r in self.REASONS}}
        self._streams: dict[tuple[int, int], _Stream] = {}
        self._foreign: dict[tuple[int, int], _Stream] = {}

    def __setattr__(self, name, value):
        if name == "session" and value is not None:
            _uint("session", value, U32)
        super().__setattr__(name, value)
        if name == "key" and value and len(value) < MIN_KEY:
            raise ValueError(f"a key of {len(value)} B is too short: at least {MIN_KEY} B")
        if name == "session" and "_streams" in self.__dict__:
            self._streams.clear()
            self._foreign.clear()

    def counts(self) -> dict[str, int]:
        return dict(self.counters)

    @property
    def total(self) -> int:
        return sum(self.counters.values())

    def _drop(self, reason: str, why: str, detail: str = "") -> None:
        self.counters[reason] += 1
        if detail:
            key = f"{reason}.{detail}"
            self.detail[key] = self.detail.get(key, 0) + 1
        self.last_reason, self.last_error = reason, why

    def accept(self, data: bytes, episode: int | None = None, step: int | None = None,
               sender: tuple | None = None) -> Message | None:
        if self.loopback_only and sender is not None and not is_loopback(sender[0]):
            self._drop("not_loopback", f"{sender[0]} is not a loopback address and this side has no key")
            return None
        try:
            msg = decode(data, self.key, self.nonce)
        except ProtocolError as exc:
            self._drop(exc.reason, str(exc), exc.detail)
            if isinstance(exc, FieldOutOfRange) and self.role == "target":
                self._refuse(exc, len(data), sender)
            if isinstance(exc, Unauthenticated) and exc.detail == "ERROR" and self.role == "host":
                self._refusal(data, sender)
            self.last_unauth = isinstance(exc, Unauthenticated) and exc.detail == "HELLO"
            return None
        t = msg.type
        if sender is not None and not self.from_peer(sender):
            self._drop("stranger", f"{t.name} from {sender[0]}:{sender[1]}, not the session's host",
                       t.name)
            self.last_stranger = msg
            return None
        if t not in self._types:
            self._drop("unexpected", f"{t.name} is not for the {self.role}")
            return None
        if t not in (self.open_types or ()) and (self.session is None or msg.session != self.session):
            self._drop("wrong_session", f"{t.name} of session {msg.session:#x}, open: "
                       f"{'none' if self.session is None else f'{self.session:#x}'}")
            return None
        self.authentic += 1
        if not self._fresh(msg):
            return None
        if self.role == "target" and t == MsgType.HELLO and not self.limiter.allow(source(sender)):
            self._drop("rate_limited", f"HELLO from {sender}: over the per-source reply rate")
            return None
        if self.role == "target" and t == MsgType.RESPONSE and not self._redeem(msg, sender):
            self._drop("no_challenge", "RESPONSE that answers no live challenge sent to its sender "
                       "(replayed, expired, or never asked)")
            return None
        if t == MsgType.COMMAND and self.n_actions is not None and \
                len(msg.payload(Command).action) != self.n_actions:
            n, want = len(msg.payload(Command).action), self.n_actions
            self._drop("corrupt", f"COMMAND of {n} actions; the armed episode takes {want}", "action_count")
            self.refusal = (ErrorCode.OUT_OF_RANGE, msg.seq, f"n={n} [{want},{want}]", len(data))
            return None
        if (t == MsgType.COMMAND and episode is not None and step is not None
                and (msg.payload(Command).episode, msg.payload(Command).step) < (episode, step)):
            cmd = msg.payload(Command)
            self._drop("late", f"COMMAND for episode {cmd.episode} step {cmd.step} arrived at "
                       f"episode {episode} step {step}")
            return None
        self.counters["accepted"] += 1
        return msg

    def _refusal(self, data: bytes, sender: tuple | None) -> None:
        """A target refuses a HELLO whose tag does not check with an ERROR tagged without a key
        (the host may hold none, or another).  Anyone can make one, so nothing of it is kept:
        only counted, when it claims to answer this session from its peer, so that a host whose
        HELLO times out can say that a refusal came (its text is never read)."""
        if not self.from_peer(sender):
            return
        try:
            msg = decode(data)
        except ProtocolError:
            return
        if msg.payload(Error).code == ErrorCode.UNAUTHENTICATED and msg.session == self.session:
            self.unverified_refusals += 1

    def _refuse(self, exc: FieldOutOfRange, size: int, sender: tuple | None) -> None:
        """A field out of range in an authenticated request of the open session from its host:
        kept for the link to answer (an ERROR OUT_OF_RANGE naming the field and its range)."""
        if (self.session is not None and exc.session == self.session and self.peer is not None
                and self.from_peer(sender) and exc.mtype in self._types and exc.mtype not in HANDSHAKE_TYPES):
            self.refusal = (ErrorCode.OUT_OF_RANGE, exc.seq, exc.refusal, size)

    def allow_refusal(self, sender: tuple | None) -> bool:
        """Whether the per-source limiter of refusals lets this side answer one; counted if not."""
        if self.refusal_limiter.allow(source(sender)):
            return True
        self.refusals_limited += 1
        return False

    def from_peer(self, sender: tuple | None) -> bool:
        """Whether ``sender`` may speak for the peer: any sender while no peer is set, else the
        peer's address and port (or the session's socket's, ``session_peer``)."""
        if self.peer is None or sender is None:
            return True
        who = tuple(sender[:2])
        return who == tuple(self.peer[:2]) or (self.session_peer is not None
                                               and who == tuple(self.session_peer[:2]))

    def _redeem(self, msg: Message, sender: tuple | None) -> bool:
        b = msg.payload(Response)
        src = source(sender)
        if self.opened is not None and self.opened == (src, msg.session, b.nonce, b.target_nonce):
            return True  # the handshake that opened this session, again: its INFO was lost
        return self.challenges.redeem(src, msg.session, b.nonce, b.target_nonce)

    def allow_reply(self, sender: tuple | None) -> bool:
        """Whether the per-source limiter lets this side answer a datagram from ``sender`` that
        comes from no session's host (a stranger, an unauthenticated HELLO); counted if not."""
        if self.limiter.allow(source(sender)):
            return True
        self.replies_limited += 1
        return False

    def stream(self, session: int, mtype: int) -> tuple[int, int] | None:
        """The open session's window of one message type: (newest sequence number, mask of the
        last WINDOW accepted), or None before its first (the real-time loop takes the COMMAND
        stream for an episode: :mod:`impact_env.rig.wire`)."""
        s = self._streams.get((session, int(mtype)))
        return None if s is None else (s.newest, s.mask)

    def set_stream(self, session: int, mtype: int, newest: int, mask: int) -> None:
        """Hand a stream's window back (see :meth:`stream`)."""
        self._streams[(session, int(mtype))] = _Stream(int(newest), int(mask))

    def _fresh(self, msg: Message) -> bool:
        # the open session's streams are never evicted; other sessions' (open types only: a
        # flood of HELLOs) live in a bounded table of their own
        own = msg.session == self.session
        streams = self._streams if own else self._foreign
        key = (msg.session, int(msg.type))
        s = streams.get(key)
        seq = msg.seq
        if s is None:
            if not own and len(streams) >= self.MAX_STREAMS:
                streams.pop(next(iter(streams)))
            streams[key] = _Stream(seq, 1)
            return True
        ahead = (seq - s.newest) & U32
        if 0 < ahead < _HALF:
            s.mask = ((s.mask << ahead) | 1) & ((1 << self.WINDOW) - 1) if ahead < self.WINDOW else 1
            s.newest = seq
            return True
        back = (s.newest - seq) & U32
        if back < self.WINDOW and (s.mask >> back) & 1:
            self._drop("duplicate", f"{msg.type.name} seq {seq} accepted before")
        else:
            self._drop("out_of_order", f"{msg.type.name} seq {seq} is not newer than {s.newest}")
        return False
