"""The rig's wire protocol: UDP datagrams in a fixed little-endian binary layout (version 4.0).

Every datagram is one message: a 42-byte header (``HEADER_FIELDS``), a payload whose layout the
message type fixes (its class below), and a 16-byte tag (HMAC-SHA256, :func:`tag`).  Version 2.0
replaced 1.0's CRC-32 trailer with the tag and appended session_nonce and keyed to INFO; 2.1 gave
ARM's options bits 1-2, the episode kind (:class:`EpisodeKind`: drops, or identification
episodes with body 1 held); 3.0 opens a session by challenge and response (HELLO -> CHALLENGE,
RESPONSE -> INFO, 128-bit nonces from both sides), so that no recorded datagram opens one again;
4.0 gives each session a socket of its own at the target, named in INFO (``session_port``), to
which the host sends everything after the handshake.  Integers are unsigned little-endian, floats
IEEE-754 little-endian.

Layouts.  The header's fields and each payload's are declared once, as data (wire type, range,
unit, meaning: :mod:`impact_env.rig.layout`); their ``struct`` formats, checks, encoding and
decoding, the offsets the compiled wire reads and the docs' tables
(docs/reference/generated/protocol.md) all follow from those declarations.  After the payload
of L bytes comes the tag: HMAC-SHA256(key, nonce u64 LE + bytes 0 .. 42+L-1)[:16], key the
shared key (b"" without one), nonce the session's (from INFO; 0 for ``OPEN_TYPES``: HELLO,
CHALLENGE, RESPONSE, INFO and ERROR).  A variable part (COMMAND's actions, OBSERVATION's values,
a chunk's data, ERROR's text) follows the fixed fields, its count a u16 among them.

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
import hmac
import math
import struct
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

from impact_env.rig import handshake

# the integer limits, Body and the errors of layout are this module's too (protocol.U64, protocol.Body, ...)
from impact_env.rig.layout import (  # noqa: F401
    U8,
    U16,
    U32,
    U64,
    Body,
    CorruptDatagram,
    Field,
    FieldError,
    ProtocolError,
    check_uint,
    fmt_of,
    message,
    offsets_of,
    wire,
)

MAGIC = b"IMPR"
VERSION_MAJOR = 4
VERSION_MINOR = 0

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

_FLT_MAX = 3.4028234663852886e38  # the largest float32

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


# -- errors (ProtocolError, CorruptDatagram and FieldError: impact_env.rig.layout) -------------------
class FieldOutOfRange(CorruptDatagram):
    """An authenticated datagram with a field out of its range (``detail`` "field"): ``field``
    names it, ``refusal`` is the terse text of the ERROR that answers it (``field=value [range]``),
    ``mtype``, ``session``, ``seq`` are its header's."""

    def __init__(self, message: str, field: str, refusal: str, mtype: int = 0, session: int = 0,
                 seq: int = 0):
        super().__init__("field", message)
        self.field, self.refusal = field, refusal
        self.mtype, self.session, self.seq = mtype, session, seq


class WrongVersion(ProtocolError):
    reason = "wrong_version"


class Unauthenticated(ProtocolError):
    """The tag does not check (``detail``: the message type's name, or its number): the sender
    has no key, another key, or the datagram was altered or replayed into another session."""

    reason = "unauthenticated"


class UnknownType(ProtocolError):
    reason = "unexpected"


def _named(codes: type[enum.IntEnum]) -> str:
    return ", ".join(f"{int(c)} {c.name.lower()}" for c in codes)


# -- the header ---------------------------------------------------------------------------------------
HEADER_FIELDS = (
    Field("magic", "bytes", size=4, meaning='b"IMPR"'),
    Field("major", "u8", meaning=f"major version ({VERSION_MAJOR}): a receiver drops any other major"),
    Field("minor", "u8", meaning=f"minor version ({VERSION_MINOR}): a newer one only appends (Versioning)"),
    Field("type", "u8", meaning="message type (the tables below)"),
    Field("flags", "u8", meaning="bit 0 FLAG_RETRY (a request sent again); others reserved"),
    Field("session", "u32", meaning="session id, chosen by the host in HELLO (never 0 once a session is "
          "open)"),
    Field("seq", "u32", meaning="sequence number: one counter per sender and session, +1 per datagram "
          "(a retry gets a new number); the receiver checks it per (session, type) stream"),
    Field("tick", "u64", unit="ticks", meaning="the target's tick counter (its only clock) when it sent the "
          "message; host->target: the tick of the message being answered"),
    Field("host_ns", "u64", unit="ns", meaning="the host's perf_counter_ns at sending; echoed back by the "
          "target in replies, so that the host measures round trips"),
    Field("target_ns", "u64", unit="ns", meaning="the target's perf_counter_ns at sending; echoed by the "
          "host in COMMANDs answering an OBSERVATION"),
    Field("length", "u16", unit="B", meaning="payload length L (at most MAX_PAYLOAD); the payload, then the "
          "16-byte tag, follow"),
)
HEADER = fmt_of(HEADER_FIELDS)
HEADER_OFFSETS = offsets_of(HEADER_FIELDS)
TAG_SIZE = 16  # bytes of HMAC-SHA256 kept (128 bits)
HEADER_SIZE = HEADER.size  # 42
OVERHEAD = HEADER_SIZE + TAG_SIZE  # 58
MAX_DATAGRAM = 65507  # largest UDP payload over IPv4, B
MAX_PAYLOAD = MAX_DATAGRAM - OVERHEAD  # 65449 B
# the header fields a Message holds (the others: the frame's, set by encode)
_MESSAGE_FIELDS = tuple(f for f in HEADER_FIELDS if f.name in ("flags", "session", "seq", "tick", "host_ns",
                                                                "target_ns"))


# -- payloads -----------------------------------------------------------------------------------------
def _nonce(default_meaning: str) -> Any:
    return wire("bytes", bytes(NONCE_SIZE), size=NONCE_SIZE, meaning=default_meaning)


def _sha256(meaning: str) -> Any:
    return wire("bytes", bytes(32), size=32, meaning=f"a sha256 digest: {meaning}")


_RATE = "the target's control (tick) rate"
_DTYPES = {4: "float32", 8: "float64"}


@message
@dataclass(frozen=True)
class Hello(Body):
    """Asks for a CHALLENGE; opens nothing.  The host's nonce, then ``HELLO_PAD`` zero bytes (the
    CHALLENGE or ERROR answering it is never larger)."""

    TYPE: ClassVar = MsgType.HELLO
    PAD: ClassVar = HELLO_PAD
    nonce: bytes = _nonce("the host's, fresh per handshake (secrets.token_bytes)")


@message
@dataclass(frozen=True)
class Challenge(Body):
    """The target's answer to a HELLO, in its session id: its nonce echoed, and a fresh one of the
    target's."""

    TYPE: ClassVar = MsgType.CHALLENGE
    nonce: bytes = _nonce("the HELLO's")
    target_nonce: bytes = _nonce("the target's, fresh (secrets.token_bytes)")


@message
@dataclass(frozen=True)
class Response(Body):
    """The host's answer to a CHALLENGE: both nonces (so its tag is over both), then
    ``RESPONSE_PAD`` zero bytes (the INFO answering it is never larger).  It opens the header's
    session (or confirms the open one) if it answers a live challenge sent to its sender, once."""

    TYPE: ClassVar = MsgType.RESPONSE
    PAD: ClassVar = RESPONSE_PAD
    nonce: bytes = _nonce("the host's, as in its HELLO")
    target_nonce: bytes = _nonce("the CHALLENGE's")


@message
@dataclass(frozen=True)
class Info(Body):
    """The target's answer to a RESPONSE: what it is, and the session's nonce and socket."""

    TYPE: ClassVar = MsgType.INFO
    nonce: bytes = _nonce("the RESPONSE's")
    control_rate_hz: float = wire("f64", 1.0e4, unit="Hz", meaning=_RATE)
    state: int = wire("u8", TargetState.IDLE, high=max(TargetState), meaning=_named(TargetState))
    driver: int = wire("u8", 0, high=1, meaning="0 virtual, 1 hardware")
    lockstep: bool = wire("bool", False, meaning="the target waits for each step's command")
    scene_size: int = wire("u32", 0, unit="B", meaning="the scene's TOML (resource SCENE)")
    scene_sha256: bytes = _sha256("of the scene's TOML")
    session_nonce: int = wire("u64", 0, meaning="drawn per session; in every later tag")
    keyed: bool = wire("bool", False, meaning="the target holds a key")
    session_port: int = wire("u16", 0, meaning="the session's own socket at the target, to which the host "
                             "sends the session's datagrams (0: none, the target's address; 4.0)")


@message
@dataclass(frozen=True)
class Arm(Body):
    """Arms an episode (answered by ARMED, or by an ERROR naming the field out of range)."""

    TYPE: ClassVar = MsgType.ARM
    mode: str = wire("enum", "host", choices=MODES, meaning="who acts: the host's COMMANDs, or the "
                     "uploaded policy")
    observation: str = wire("enum", "sensors", choices=OBSERVATIONS, meaning="what an observation holds")
    history: int = wire("u8", 1, 1, 64, "frames", "observations stacked")
    options: int = wire("u8", 0, meaning="bit 0 ARM_TERMINATE_ON_CATCH; bits 1-2 the EpisodeKind (2.1); "
                        "the others reserved (refused)")
    hold_ticks: int = wire("u16", 1, 1, unit="ticks", meaning="ticks per policy step")
    seed: int = wire("u64", 0, meaning="draws the episode's drop")
    horizon_ticks: int = wire("u32", 1, 1, unit="ticks", meaning="the episode's length")
    first_command_timeout_ticks: int = wire("u32", 1000, unit="ticks", meaning="host mode: the first "
                                            "command's deadline (0: the target's "
                                            "safety.first_command_timeout_s)")
    link_timeout_ms: int = wire("u32", 0, unit="ms", meaning="the episode ends LINK_LOST when nothing "
                                "authentic came from the host for that long (0: none)")
    policy_size: int = wire("u32", 0, unit="B", meaning="onboard: the uploaded policy file's size (else 0)")
    policy_sha256: bytes = _sha256("onboard: of the uploaded file; host mode: zeros")

    @property
    def kind(self) -> EpisodeKind:
        return EpisodeKind((self.options & ARM_KIND_MASK) >> ARM_KIND_SHIFT)


@message
@dataclass(frozen=True)
class Armed(Body):
    """The target's answer to an ARM: the episode, and the sizes of its observations and actions."""

    TYPE: ClassVar = MsgType.ARMED
    episode: int = wire("u32", 0, meaning="the episode's number")
    start_tick: int = wire("u64", 0, unit="ticks", meaning="the target's tick at arming")
    obs_size: int = wire("u16", 1, high=MAX_VALUES, unit="entries", meaning="an observation's")
    action_size: int = wire("u16", 1, high=MAX_VALUES, unit="entries", meaning="a COMMAND's")
    obs_dtype: int = wire("choice", 4, choices=_DTYPES, unit="B", meaning="an observation entry's size")
    telemetry_size: int = wire("u8", 0, unit="entries", meaning="an OBSERVATION's telemetry "
                               "(TELEMETRY_FIELDS)")
    hold_ticks: int = wire("u16", 1, 1, unit="ticks", meaning="ticks per policy step")
    control_rate_hz: float = wire("f64", 1.0e4, unit="Hz", meaning=_RATE)
    scene_sha256: bytes = _sha256("of the scene's TOML")


class _Window(Body):
    """A piece of a transfer (POLICY_CHUNK, CHUNK): it lies within the transfer."""

    offset: int
    total: int
    data: bytes

    def check(self) -> None:
        check_uint("offset", self.offset, self.total, unit="B")
        if self.offset + len(self.data) > self.total:
            raise ValueError(f"chunk [{self.offset}, {self.offset + len(self.data)}) B runs past the "
                             f"total {self.total} B")


def _total() -> Any:
    return wire("u32", 0, high=MAX_TRANSFER, unit="B", meaning="the whole file's or resource's size")


@message
@dataclass(frozen=True)
class PolicyChunk(_Window):
    """A piece of the policy file to upload; answered by ACK (value = offset + n)."""

    TYPE: ClassVar = MsgType.POLICY_CHUNK
    upload_id: int = wire("u64", 0, meaning="the first 8 bytes of the file's sha256, little-endian")
    total: int = _total()
    offset: int = wire("u32", 0, unit="B", meaning="of the piece in the file, <= total")
    data: bytes = wire("data", b"", unit="B", meaning="the piece (at most CHUNK_DATA)")


@message
@dataclass(frozen=True)
class Ack(Body):
    """A request's answer: its type and sequence number, a code, a type-specific value."""

    TYPE: ClassVar = MsgType.ACK
    acked_type: int = wire("u8", MsgType.HELLO, meaning="the request's message type")
    code: int = wire("u8", ErrorCode.OK, meaning="0 ok, else an ErrorCode")
    acked_seq: int = wire("u32", 0, meaning="the request's sequence number")
    value: int = wire("u64", 0, meaning="type-specific (POLICY_CHUNK: bytes received)")


@message
@dataclass(frozen=True)
class Command(Body):
    """The host's action for a policy step."""

    TYPE: ClassVar = MsgType.COMMAND
    episode: int = wire("u32", 0, meaning="ARMED's")
    step: int = wire("u32", 0, meaning="the policy step the action is for")
    action: tuple[float, ...] = wire("floats", (0.0,), 1, MAX_VALUES, "1.0 = effects.command_scale N",
                                     "dimensionless; ARMED's action_size of them, as f64")


@message
@dataclass(frozen=True)
class Observation(Body):
    """A policy step's observation.  ``obs`` values are encoded as float32 when ``dtype = 4``
    (rounded to nearest; decoding gives the rounded values), as float64 when 8; ``telemetry``
    always as float64."""

    TYPE: ClassVar = MsgType.OBSERVATION
    episode: int = wire("u32", 0, meaning="ARMED's")
    step: int = wire("u32", 0, meaning="the policy step")
    status: int = wire("u32", 0, meaning="bits of impact_env.rig.safety")
    dtype: int = wire("choice", 4, choices=_DTYPES, unit="B", meaning="an obs entry's size")
    obs: tuple[float, ...] = wire("floats", (), high=MAX_VALUES, elem="dtype", unit="scaled units of "
                                  "impact_env.control.observation", meaning="the observation, dtype each")
    telemetry: tuple[float, ...] = wire("floats", (), high=MAX_VALUES, meaning="f64: the TELEMETRY_FIELDS "
                                        "(force_demand_N, force_applied_N, command_age_ticks), then, from a "
                                        "virtual rig, the true records of the step's ticks (hold_ticks x "
                                        "N_REC, impact_env.sim.records)")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.dtype == 4:
            for v in self.obs:
                if math.isfinite(v) and abs(v) > _FLT_MAX:
                    raise ValueError(f"obs value {v!r} overflows float32 (dtype 4)")


@message
@dataclass(frozen=True)
class EpisodeEnd(Body):
    """The end of an episode: why, and its log's size and digest (resource EPISODE)."""

    TYPE: ClassVar = MsgType.EPISODE_END
    episode: int = wire("u32", 0, meaning="ARMED's")
    reason: int = wire("u8", EndReason.HORIZON, meaning="an EndReason")
    status: int = wire("u32", 0, meaning="the OR of the ticks' status bits")
    n_ticks: int = wire("u64", 0, unit="ticks", meaning="ticks run")
    n_steps: int = wire("u32", 0, unit="steps", meaning="policy steps run")
    data_size: int = wire("u32", 0, unit="B", meaning="the episode's log (resource EPISODE)")
    data_sha256: bytes = _sha256("of the episode's log")


@message
@dataclass(frozen=True)
class Fetch(Body):
    """Asks for a piece of a resource; answered by CHUNK."""

    TYPE: ClassVar = MsgType.FETCH
    resource: int = wire("u8", Resource.SCENE, meaning=_named(Resource))
    item: int = wire("u32", 0, meaning="the episode's number (0 for SCENE)")
    offset: int = wire("u32", 0, unit="B", meaning="of the piece in the resource")
    max_len: int = wire("u16", CHUNK_DATA, 1, unit="B", meaning="the piece's size, at most")


@message
@dataclass(frozen=True)
class Chunk(_Window):
    """A piece of a resource, answering a FETCH."""

    TYPE: ClassVar = MsgType.CHUNK
    resource: int = wire("u8", Resource.SCENE, meaning=_named(Resource))
    item: int = wire("u32", 0, meaning="the FETCH's")
    total: int = _total()
    offset: int = wire("u32", 0, unit="B", meaning="of the piece in the resource, <= total")
    data: bytes = wire("data", b"", unit="B", meaning="the piece")


@message
@dataclass(frozen=True)
class Disarm(Body):
    """Ends the episode (answered by ACK)."""

    TYPE: ClassVar = MsgType.DISARM
    reason: int = wire("u8", DISARM_USER, high=DISARM_CAUGHT, meaning="0 user, 1 host closing (the session "
                       "ends too), 2 host error, 3 caught: the host's task ended the episode, whose end "
                       "reason is then CAUGHT")


@message
@dataclass(frozen=True)
class Heartbeat(Body):
    """Either side's sign of life."""

    TYPE: ClassVar = MsgType.HEARTBEAT
    state: int = wire("u8", TargetState.IDLE, meaning="a TargetState")
    episode: int = wire("u32", 0, meaning="the current episode")
    step: int = wire("u32", 0, meaning="the current policy step")
    peer_seq: int = wire("u32", 0, meaning="the newest sequence number accepted from the peer")


@message
@dataclass(frozen=True)
class Error(Body):
    """A refusal or a failure, answering the message ``ref_seq``."""

    TYPE: ClassVar = MsgType.ERROR
    code: int = wire("u16", ErrorCode.BAD_REQUEST, meaning="an ErrorCode")
    ref_seq: int = wire("u32", 0, meaning="the sequence number of the message it answers, or 0")
    text: str = wire("text", "", high=MAX_TEXT, unit="B", meaning="UTF-8")

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


BODIES: dict[int, type[Body]] = {cls.TYPE: cls for cls in (
    Hello, Info, Arm, Armed, PolicyChunk, Ack, Command, Observation, EpisodeEnd, Fetch, Chunk, Disarm,
    Heartbeat, Error, Challenge, Response)}
BodyType = TypeVar("BodyType", bound=Body)  # a payload class


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
        for f in _MESSAGE_FIELDS:
            f.check(getattr(self, f.name))

    @property
    def type(self) -> MsgType:
        return self.body.TYPE

    def payload(self, cls: builtins.type[BodyType]) -> BodyType:
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
            check_uint("session", value, U32)
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
