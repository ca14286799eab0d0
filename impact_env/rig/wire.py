"""The wire inside the real-time loop: the host's COMMANDs read, authenticated and taken, and each
step's OBSERVATION made, tagged and sent, by the compiled loop itself (:mod:`impact_env.rig.rtloop`),
so that no Python thread stands between the host and the tick.

While an episode runs the loop owns the session's socket (its own socket at the target, connected
to the host: :meth:`impact_env.rig.transport.Endpoint.open_session`; where there is none, the
target's socket).
Whenever it waits (spinning to a
tick's deadline, or for a step's command) it reads every datagram waiting (``recvfrom`` with
``MSG_DONTWAIT``, called by address: :mod:`impact_env.rig.cfunc`):

* a datagram from the session's host whose type byte says COMMAND is classified here, in the
  order and with the reasons of :class:`impact_env.rig.protocol.DatagramFilter` (length, tag
  under the session's key and nonce by OpenSSL's ``HMAC``, payload, session, the COMMAND stream's
  64-number window, late): the one fast path, the one a host's round trip depends on (an
  authentic one with another action count than the armed one goes to the network thread, which
  refuses it with an ERROR naming the count);
* every other datagram (other types, other senders, junk) goes, bytes and sender, into a queue
  for the target's network thread, which puts it through the Python filter as before (a
  HELLO's challenge, DISARM, FETCH, the counts by reason).  A full queue (a flood faster than
  Python) drops it counted ``queue_full``; junk never queues ahead of the host's commands,
  because the loop reads them all.

At the end of the episode :func:`merge` adds the loop's counts to the filter's (one set of
counters, the same names) and hands the COMMAND stream's window back to it.

The OBSERVATION of a step is encoded here (the byte layout of ``protocol.Observation``: obs as
float32, telemetry as float64, the virtual rig's true records of the step's ticks), numbered
from the OBSERVATION stream's own counter (the host checks freshness per session and type) and
sent by ``sendto`` from the loop at the step's first tick.
"""

from __future__ import annotations

import ctypes
import socket
import struct
from typing import NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env.rig import protocol
from impact_env.rig.cfunc import (
    call_clock_gettime,
    call_clock_nanosleep,
    call_hmac,
    call_recvfrom,
    call_sendto,
    call_write,
    fence,
    libc_address,
    libcrypto_addresses,
)

SOCKADDR = 128  # bytes of a sockaddr_storage
RX_MAX = 65536  # the largest datagram read (UDP's own limit is 65507 B)
N_Q = 256  # datagrams the loop can hand the network thread before it has read them
MSG_DONTWAIT = 0x40  # Linux
CLOCK_MONOTONIC = 1  # Linux: what time.perf_counter_ns reads
NONCE = 8  # bytes of the session nonce in front of every tagged frame
# offsets in the header and in the COMMAND and OBSERVATION payloads: the protocol's declarations'
# (protocol.HEADER_FIELDS, protocol.Command, protocol.Observation), whose wire types the reads
# below assume (asserted: a changed declaration stops the import, not the loop)
_H = protocol.HEADER_OFFSETS
H_MAJOR, H_MINOR, H_TYPE, H_FLAGS, H_SESSION, H_SEQ, H_TICK, H_HOST_NS, H_TARGET_NS, H_PLEN = (
    _H[name] for name in ("major", "minor", "type", "flags", "session", "seq", "tick", "host_ns", "target_ns",
                          "length"))
C_EPISODE, C_STEP, C_COUNT = (protocol.Command.OFFSETS[name] for name in ("episode", "step", "action"))
C_FIXED = protocol.Command.FMT.size  # the actions (f64) follow
O_EPISODE, O_STEP, O_STATUS, O_DTYPE, O_COUNT, O_TELEMETRY = (
    protocol.Observation.OFFSETS[name] for name in ("episode", "step", "status", "dtype", "obs", "telemetry"))
O_FIXED = protocol.Observation.FMT.size  # the obs (dtype each), then the telemetry (f64) follow
assert [f.kind for f in protocol.HEADER_FIELDS] == ["bytes"] + ["u8"] * 4 + ["u32"] * 2 + ["u64"] * 3 + [
    "u16"]
assert [f.kind for f in protocol.Command.FIELDS] == ["u32", "u32", "floats"]
assert [f.kind for f in protocol.Observation.FIELDS] == ["u32"] * 3 + ["choice", "floats", "floats"]
T_COMMAND = int(protocol.MsgType.COMMAND)
T_OBSERVATION = int(protocol.MsgType.OBSERVATION)
MAGIC = np.frombuffer(protocol.MAGIC, np.uint8)
_HALF = 1 << 31
_U32 = 0xFFFFFFFF
_WINDOW = 64  # DatagramFilter.WINDOW
assert protocol.DatagramFilter.WINDOW == _WINDOW and protocol.HEADER_SIZE == 42 and protocol.TAG_SIZE == 16


class Calls(NamedTuple):
    """Addresses of the C functions the loop calls (:mod:`impact_env.rig.cfunc`)."""

    recvfrom: int
    sendto: int
    hmac: int
    sha256: int  # the EVP_MD of EVP_sha256()
    clock_gettime: int
    poll: int
    clock_nanosleep: int


class WireCounts(NamedTuple):
    """What the loop did with the datagrams it read (int64[1] each; the network thread reads
    them live, :func:`merge` adds them to the filter's at the end)."""

    received: np.ndarray  # every datagram read
    queued: np.ndarray  # handed to the network thread
    queue_full: np.ndarray  # dropped: the network thread's queue was full
    corrupt: np.ndarray
    unauthenticated: np.ndarray
    wrong_session: np.ndarray
    duplicate: np.ndarray
    out_of_order: np.ndarray
    late: np.ndarray
    accepted: np.ndarray  # the filter's "accepted"
    commands: np.ndarray  # accepted COMMANDs of this episode ("commands_accepted")
    authentic: np.ndarray  # tag and session right (the link is alive), whatever came after
    sent: np.ndarray  # datagrams sent (the target's OBSERVATIONs, re-sends included; the host's COMMANDs)
    send_dropped: np.ndarray  # datagrams the socket refused


class WireState(NamedTuple):
    """The COMMAND stream's window and the OBSERVATION stream's counter (int64[1] each)."""

    known: np.ndarray  # 1 once the COMMAND stream of the session has a newest number
    newest: np.ndarray
    mask: np.ndarray  # bit i: newest - i accepted (64 bits, as DatagramFilter's)
    obs_seq: np.ndarray  # the next OBSERVATION's sequence number
    host_ns: np.ndarray  # the newest accepted COMMAND's host timestamp, echoed
    obs_len: np.ndarray  # bytes of the last OBSERVATION's frame in ``tx`` (0: none yet)
    cmd_step: np.ndarray  # the COMMAND :func:`read_one` just accepted: its step
    cmd_val: np.ndarray  # float64[1]: and its action
    # the host's side (impact_env.rig.host_wire): the newest OBSERVATION taken, its fields
    got: np.ndarray  # 1 once one is in ``Wire.out``
    out_step: np.ndarray
    out_status: np.ndarray
    out_dtype: np.ndarray
    out_n: np.ndarray  # observation values in ``Wire.out[:out_n]``
    out_m: np.ndarray  # telemetry values after them


class Wire(NamedTuple):
    """Everything the loop needs to read and write datagrams (see the module doc)."""

    fd: int  # the target's socket (-1: none, e.g. the warm-up: nothing is read, sends fail)
    calls: Calls
    wake_fd: int  # the pipe written when the network thread's queue gets its first entry (-1: none)
    wake_write: int  # libc write's address
    byte: np.ndarray  # uint8[1]: what is written to the pipe
    key: np.ndarray  # uint8[max(1, key_len)]
    key_len: int
    peer: np.ndarray  # uint8[SOCKADDR]: the session host's sockaddr
    peer_mask: np.ndarray  # uint8[SOCKADDR]: 1 where a sender's sockaddr must equal the host's
    peer_len: int
    session: int
    episode: int
    n_actions: int  # the armed COMMAND's action count: another count goes to the network thread (refused)
    rx: np.ndarray  # uint8[NONCE + RX_MAX]: the session nonce, then the datagram read
    tx: np.ndarray  # uint8[NONCE + MAX_DATAGRAM]: the session nonce, then the OBSERVATION
    src: np.ndarray  # uint8[SOCKADDR]: the sender of the datagram read
    srclen: np.ndarray  # uint32[1]
    md: np.ndarray  # uint8[64]: HMAC's output
    mdlen: np.ndarray  # uint32[1]
    ts: np.ndarray  # int64[2]: clock_gettime's timespec
    f8: np.ndarray  # float64[1] and b8 uint8[8]: one value and its bytes
    b8: np.ndarray
    f4: np.ndarray  # float32[1] and b4 uint8[4]
    b4: np.ndarray
    c: WireCounts
    st: WireState
    q_data: np.ndarray  # uint8[N_Q, RX_MAX]: datagrams for the network thread
    q_len: np.ndarray  # int64[N_Q]
    q_src: np.ndarray  # uint8[N_Q, SOCKADDR]
    q_srclen: np.ndarray  # int64[N_Q]
    q_head: np.ndarray  # int64[1]: entries written (the loop)
    q_tail: np.ndarray  # int64[1]: entries read (the network thread)
    out: np.ndarray  # float64[2 MAX_VALUES]: the host's newest OBSERVATION's values (host_wire)
    pfd: np.ndarray  # int32[2]: a struct pollfd on ``fd`` (POLLIN), for poll()


# -- bytes ---------------------------------------------------------------------------------------------
@jit(inline="always")
def get_uint(buf, o, n):
    v = 0
    for k in range(n - 1, -1, -1):
        v = (v << 8) | np.int64(buf[o + k])
    return v


@jit(inline="always")
def put_uint(buf, o, n, v):
    for k in range(n):
        buf[o + k] = (v >> (8 * k)) & 0xFF


@jit(inline="always")
def get_f64(buf, o, w):
    for k in range(8):
        w.b8[k] = buf[o + k]
    return w.f8[0]


@jit(inline="always")
def put_f64(buf, o, x, w):
    w.f8[0] = x
    for k in range(8):
        buf[o + k] = w.b8[k]


@jit(inline="always")
def get_f32(buf, o, w):
    for k in range(4):
        w.b4[k] = buf[o + k]
    return w.f4[0]


@jit(inline="always")
def put_f32(buf, o, x, w):
    w.f4[0] = x
    for k in range(4):
        buf[o + k] = w.b4[k]


@jit(inline="always")
def tag_of(w, buf, n):
    """HMAC-SHA256 of buf[0:n] (the nonce, then the frame) into w.md; False on failure."""
    w.mdlen[0] = 64
    return call_hmac(w.calls.hmac, w.calls.sha256, w.key, w.key_len, buf, n, w.md, w.mdlen) != 0


@jit(inline="always")
def tag_checks(w, end):
    """Whether the tag after the frame of ``end`` bytes in ``w.rx`` is the frame's (under the key
    and the nonce in front of it); compared in constant time."""
    if not tag_of(w, w.rx, NONCE + end):
        return False
    diff = 0
    for k in range(protocol.TAG_SIZE):
        diff |= w.md[k] ^ w.rx[NONCE + end + k]
    return diff == 0


@jit(inline="always")
def now_ns(w):
    call_clock_gettime(w.calls.clock_gettime, CLOCK_MONOTONIC, w.ts)
    return w.ts[0] * 1_000_000_000 + w.ts[1]


@jit(inline="always")
def sleep_until_ns(w, t_ns):
    """Sleep until CLOCK_MONOTONIC reads ``t_ns`` (clock_nanosleep, TIMER_ABSTIME)."""
    w.ts[0] = t_ns // 1_000_000_000
    w.ts[1] = t_ns % 1_000_000_000
    call_clock_nanosleep(w.calls.clock_nanosleep, CLOCK_MONOTONIC, 1, w.ts)


# -- receiving -----------------------------------------------------------------------------------------
@jit(inline="always")
def from_peer(w):
    if w.srclen[0] != w.peer_len:
        return False
    for k in range(w.peer_len):
        if w.peer_mask[k] and w.src[k] != w.peer[k]:
            return False
    return True


@jit
def enqueue(w, n):
    """The datagram in w.rx for the network thread (dropped, counted, when its queue is full); the
    thread is woken when the queue was empty."""
    h = w.q_head[0]
    t = w.q_tail[0]
    if h - t >= N_Q:
        w.c.queue_full[0] += 1
        return
    j = h % N_Q
    row = w.q_data[j]
    for k in range(n):
        row[k] = w.rx[NONCE + k]
    w.q_len[j] = n
    for k in range(SOCKADDR):
        w.q_src[j, k] = w.src[k]
    w.q_srclen[j] = w.srclen[0]
    w.c.queued[0] += 1
    fence()
    w.q_head[0] = h + 1
    if h == t and w.wake_fd >= 0:
        call_write(w.wake_write, w.wake_fd, w.byte)


@jit
def fresh(w, seq):
    """The COMMAND stream's window (DatagramFilter._fresh): 1 new, 0 duplicate, -1 out of order."""
    st = w.st
    if st.known[0] == 0:
        st.known[0] = 1
        st.newest[0] = seq
        st.mask[0] = 1
        return 1
    ahead = (seq - st.newest[0]) & _U32
    if 0 < ahead < _HALF:
        st.mask[0] = ((st.mask[0] << ahead) | 1) if ahead < _WINDOW else 1
        st.newest[0] = seq
        return 1
    back = (st.newest[0] - seq) & _U32
    if back < _WINDOW and (st.mask[0] >> back) & 1:
        return 0
    return -1


# what read_one did: nothing waiting; a datagram read; a COMMAND taken; a COMMAND of this episode
# whose step was over (counted late: the host is answering, too late to act)
NONE, READ, COMMAND, LATE = 0, 1, 2, 3


@jit
def read_one(w, cur_step):
    """Read one waiting datagram, if any.  A COMMAND of the session's host is classified here;
    an accepted one of this episode returns COMMAND with its step and action in
    ``w.st.cmd_step``, ``w.st.cmd_val``; any other datagram goes to the network thread's queue
    (:func:`_queue`).  Returns NONE, READ, COMMAND or LATE."""
    if w.fd < 0:
        return NONE
    w.srclen[0] = SOCKADDR
    n = call_recvfrom(w.calls.recvfrom, w.fd, w.rx, NONCE, RX_MAX, MSG_DONTWAIT, w.src, w.srclen)
    if n < 0:
        return NONE
    w.c.received[0] += 1
    return classify(w, n, cur_step)


@jit
def classify(w, n, cur_step):
    """What :func:`read_one` does with the datagram of ``n`` bytes in ``w.rx`` (after the nonce)
    from ``w.src``: READ (counted, or queued), COMMAND (accepted for this episode) or LATE (a
    COMMAND of this episode for a step already over, counted ``late``)."""
    c = w.c
    d = w.rx
    o = NONCE
    if (
        n < protocol.OVERHEAD
        or not from_peer(w)
        or d[o + H_TYPE] != T_COMMAND
        or d[o + H_MAJOR] != protocol.VERSION_MAJOR
        or d[o] != MAGIC[0]
        or d[o + 1] != MAGIC[1]
        or d[o + 2] != MAGIC[2]
        or d[o + 3] != MAGIC[3]
    ):
        enqueue(w, n)
        return READ
    # the host's COMMAND: the filter's checks, in its order
    plen = get_uint(d, o + H_PLEN, 2)
    if protocol.HEADER_SIZE + plen + protocol.TAG_SIZE != n:
        c.corrupt[0] += 1
        return READ
    if not tag_checks(w, protocol.HEADER_SIZE + plen):
        c.unauthenticated[0] += 1
        return READ
    newer = d[o + H_MINOR] > protocol.VERSION_MINOR
    pl = o + protocol.HEADER_SIZE
    if plen < C_FIXED:
        c.corrupt[0] += 1
        return READ
    n_act = get_uint(d, pl + C_COUNT, 2)
    need = C_FIXED + 8 * n_act
    if plen < need or (not newer and plen != need):
        c.corrupt[0] += 1
        return READ
    if n_act != w.n_actions:  # authenticated, of another count: refused, answered by the network thread
        enqueue(w, n)
        return READ
    if get_uint(d, o + H_SESSION, 4) != w.session:
        c.wrong_session[0] += 1
        return READ
    c.authentic[0] += 1
    new = fresh(w, get_uint(d, o + H_SEQ, 4))
    if new == 0:
        c.duplicate[0] += 1
        return READ
    if new < 0:
        c.out_of_order[0] += 1
        return READ
    ep = get_uint(d, pl + C_EPISODE, 4)
    step = get_uint(d, pl + C_STEP, 4)
    if ep < w.episode or (ep == w.episode and step < cur_step):
        c.late[0] += 1
        return LATE if ep == w.episode else READ
    c.accepted[0] += 1
    if ep == w.episode:
        c.commands[0] += 1
        w.st.host_ns[0] = get_uint(d, o + H_HOST_NS, 8)
        w.st.cmd_step[0] = step
        w.st.cmd_val[0] = get_f64(d, pl + C_FIXED, w)
        return COMMAND
    return READ


# -- sending -------------------------------------------------------------------------------------------
@jit
def send_frame(w, n):
    """Tag the frame of ``n`` bytes in w.tx (after the nonce) and send it to the host."""
    t = w.tx
    if not tag_of(w, t, NONCE + n):
        w.c.send_dropped[0] += 1
        return
    for k in range(protocol.TAG_SIZE):
        t[NONCE + n + k] = w.md[k]
    sent = call_sendto(
        w.calls.sendto, w.fd, t, NONCE, n + protocol.TAG_SIZE, MSG_DONTWAIT, w.peer, w.peer_len
    )
    if sent == n + protocol.TAG_SIZE:
        w.c.sent[0] += 1
    else:
        w.c.send_dropped[0] += 1


@jit
def send_observation(w, tick, step, status, obs, telem, records, r0, r1):
    """The OBSERVATION of ``step`` (made at ``tick``): ``obs`` (float32 on the wire), then the
    telemetry ``telem`` and the records ``records[r0:r1]`` (float64; left out when they would not
    fit a datagram, or hold a NaN: the host then marks the step), sent to the host."""
    t = w.tx
    o = NONCE
    nrec = 0
    if r1 > r0:
        ok = (
            obs.shape[0] * 4 + (telem.shape[0] + (r1 - r0) * records.shape[1]) * 8 + O_FIXED
            + protocol.OVERHEAD <= protocol.MAX_DATAGRAM
        ) and telem.shape[0] + (r1 - r0) * records.shape[1] <= protocol.MAX_VALUES
        if ok:
            for i in range(r0, r1):
                for j in range(records.shape[1]):
                    if np.isnan(records[i, j]):
                        ok = False
        if ok:
            nrec = (r1 - r0) * records.shape[1]
    n_obs = obs.shape[0]
    m = telem.shape[0] + nrec
    plen = O_FIXED + 4 * n_obs + 8 * m
    for k in range(4):
        t[o + k] = MAGIC[k]
    t[o + H_MAJOR] = protocol.VERSION_MAJOR
    t[o + H_MINOR] = protocol.VERSION_MINOR
    t[o + H_TYPE] = T_OBSERVATION
    t[o + H_FLAGS] = 0
    put_uint(t, o + H_SESSION, 4, w.session)
    put_uint(t, o + H_SEQ, 4, w.st.obs_seq[0] & _U32)
    w.st.obs_seq[0] += 1
    put_uint(t, o + H_TICK, 8, tick)
    put_uint(t, o + H_HOST_NS, 8, w.st.host_ns[0])
    put_uint(t, o + H_TARGET_NS, 8, now_ns(w))
    put_uint(t, o + H_PLEN, 2, plen)
    p = o + protocol.HEADER_SIZE
    put_uint(t, p + O_EPISODE, 4, w.episode)
    put_uint(t, p + O_STEP, 4, step)
    put_uint(t, p + O_STATUS, 4, status & _U32)
    t[p + O_DTYPE] = 4
    put_uint(t, p + O_COUNT, 2, n_obs)
    put_uint(t, p + O_TELEMETRY, 2, m)
    q = p + O_FIXED
    for i in range(n_obs):
        put_f32(t, q, obs[i], w)
        q += 4
    for i in range(telem.shape[0]):
        put_f64(t, q, telem[i], w)
        q += 8
    if nrec:
        for i in range(r0, r1):
            for j in range(records.shape[1]):
                put_f64(t, q, records[i, j], w)
                q += 8
    w.st.obs_len[0] = protocol.HEADER_SIZE + plen
    send_frame(w, protocol.HEADER_SIZE + plen)


@jit
def resend_observation(w):
    """The last OBSERVATION again, with the next sequence number (lock-step: the host waits for it)."""
    n = w.st.obs_len[0]
    if n == 0:
        return
    put_uint(w.tx, NONCE + H_SEQ, 4, w.st.obs_seq[0] & _U32)
    w.st.obs_seq[0] += 1
    put_uint(w.tx, NONCE + H_TARGET_NS, 8, now_ns(w))
    send_frame(w, n)


# -- the Python side --------------------------------------------------------------------------------
_CALLS: list[Calls] = []


def calls() -> Calls:
    """The C functions' addresses (looked up once per process)."""
    if not _CALLS:
        hmac_fn, sha256 = libcrypto_addresses()
        _CALLS.append(Calls(libc_address("recvfrom"), libc_address("sendto"), hmac_fn, sha256,
                            libc_address("clock_gettime"), libc_address("poll"),
                            libc_address("clock_nanosleep")))
    return _CALLS[0]


def sockaddr(addr: tuple | None) -> tuple[bytes, bytes]:
    """The sockaddr bytes ``recvfrom`` fills for a sender ``addr`` (as Python's socket module gives
    it) and the mask of the bytes that identify it (family, port, address, IPv6 scope: not the
    IPv4 padding or the IPv6 flow label)."""
    if addr is None:
        return b"", b""
    host = addr[0]
    if ":" in host:
        ip = socket.inet_pton(socket.AF_INET6, host.split("%")[0])
        scope = addr[3] if len(addr) > 3 else 0
        raw = struct.pack("=H", socket.AF_INET6) + struct.pack("!H", addr[1]) + b"\0" * 4 + ip \
            + struct.pack("=I", scope)
        mask = b"\1" * 4 + b"\0" * 4 + b"\1" * 20
    else:
        ip = socket.inet_pton(socket.AF_INET, host)
        raw = struct.pack("=H", socket.AF_INET) + struct.pack("!H", addr[1]) + ip + b"\0" * 8
        mask = b"\1" * 8 + b"\0" * 8
    return raw, mask


def address(raw: np.ndarray, n: int) -> tuple:
    """A sender's address as Python's socket module gives it, from its sockaddr bytes."""
    b = bytes(raw[:n])
    family = struct.unpack_from("=H", b)[0]
    if family == socket.AF_INET6 and n >= 28:
        port, flow = struct.unpack_from("!HI", b, 2)
        return (socket.inet_ntop(socket.AF_INET6, b[8:24]), port, flow, struct.unpack_from("=I", b, 24)[0])
    if family == socket.AF_INET and n >= 8:
        return (socket.inet_ntop(socket.AF_INET, b[4:8]), struct.unpack_from("!H", b, 2)[0])
    return ("?", 0)


def make(fd: int, key: bytes, nonce: int, session: int, episode: int, peer: tuple | None,
         stream: tuple[int, int] | None, obs_seq: int, functions: Calls | None = None,
         wake_fd: int = -1, n_actions: int = 1) -> Wire:
    """The loop's wire for an episode: the socket ``fd`` (-1: none), the session's ``key``,
    ``nonce``, id and host address ``peer``, this ``episode``, the COMMAND stream's window as the
    filter has it (``(newest, mask)``, None: no COMMAND yet this session) and the OBSERVATION
    stream's first sequence number."""
    raw, mask = sockaddr(peer)
    pr = np.zeros(SOCKADDR, np.uint8)
    pm = np.zeros(SOCKADDR, np.uint8)
    pr[:len(raw)] = np.frombuffer(raw, np.uint8)
    pm[:len(mask)] = np.frombuffer(mask, np.uint8)
    k = np.frombuffer(key, np.uint8).copy() if key else np.zeros(1, np.uint8)
    nb = np.frombuffer(int(nonce & protocol.U64).to_bytes(8, "little"), np.uint8)
    rx = np.zeros(NONCE + RX_MAX, np.uint8)
    tx = np.zeros(NONCE + protocol.MAX_DATAGRAM, np.uint8)
    rx[:NONCE] = nb
    tx[:NONCE] = nb
    f8, f4 = np.zeros(1), np.zeros(1, np.float32)
    counts = WireCounts(*(np.zeros(1, np.int64) for _ in WireCounts._fields))
    newest, m = stream if stream is not None else (0, 0)
    st = WireState(
        np.array([stream is not None], np.int64),
        np.array([newest], np.int64),
        np.array([ctypes.c_int64(m & protocol.U64).value], np.int64),
        np.array([obs_seq], np.int64),
        np.zeros(1, np.int64),
        np.zeros(1, np.int64),
        np.zeros(1, np.int64),
        np.zeros(1),
        *(np.zeros(1, np.int64) for _ in range(6)),
    )
    return Wire(
        fd=int(fd),
        calls=functions or calls(),
        wake_fd=int(wake_fd),
        wake_write=libc_address("write"),
        byte=np.ones(1, np.uint8),
        key=k,
        key_len=len(key),
        peer=pr,
        peer_mask=pm,
        peer_len=len(raw),
        session=int(session),
        episode=int(episode),
        n_actions=int(n_actions),
        rx=rx,
        tx=tx,
        src=np.zeros(SOCKADDR, np.uint8),
        srclen=np.zeros(1, np.uint32),
        md=np.zeros(64, np.uint8),
        mdlen=np.zeros(1, np.uint32),
        ts=np.zeros(2, np.int64),
        f8=f8,
        b8=f8.view(np.uint8),
        f4=f4,
        b4=f4.view(np.uint8),
        c=counts,
        st=st,
        q_data=np.zeros((N_Q, RX_MAX), np.uint8),
        q_len=np.zeros(N_Q, np.int64),
        q_src=np.zeros((N_Q, SOCKADDR), np.uint8),
        q_srclen=np.zeros(N_Q, np.int64),
        q_head=np.zeros(1, np.int64),
        q_tail=np.zeros(1, np.int64),
        out=np.zeros(2 * protocol.MAX_VALUES),
        pfd=np.array([fd, 1], np.int32),
    )


def set_peer(w: Wire, peer: tuple) -> None:
    """Point ``w`` at another address of the same family (a host learns the session's port from
    INFO): where it sends, and whose datagrams it takes."""
    raw, mask = sockaddr(peer)
    if len(raw) != w.peer_len:
        raise ValueError(f"peer {peer!r} is not of the wire's address family")
    w.peer[:] = 0
    w.peer_mask[:] = 0
    w.peer[:len(raw)] = np.frombuffer(raw, np.uint8)
    w.peer_mask[:len(mask)] = np.frombuffer(mask, np.uint8)


def none(functions: Calls | None = None) -> Wire:
    """A wire with no socket (the loop's warm-up)."""
    return make(-1, b"", 0, 0, 0, None, None, 0, functions)


def queued(w: Wire):
    """The datagrams the loop queued that the network thread has not read: (bytes, sender) each,
    the queue's tail moved past them."""
    out = []
    head = int(w.q_head[0])
    tail = int(w.q_tail[0])
    while tail < head:
        j = tail % N_Q
        out.append((bytes(w.q_data[j, :int(w.q_len[j])]), address(w.q_src[j], int(w.q_srclen[j]))))
        tail += 1
    w.q_tail[0] = tail
    return out


def merge(w: Wire, link) -> None:
    """The loop's counts into the link's filter and endpoint (after the episode), and the
    COMMAND stream's window and the OBSERVATION counter back to them."""
    f, c = link.filter, w.c
    for reason in ("corrupt", "unauthenticated", "wrong_session", "duplicate", "out_of_order", "late",
                   "accepted", "queue_full"):
        f.counters[reason] += int(getattr(c, reason)[0])
    f.authentic += int(c.authentic[0])
    link.endpoint.received += int(c.received[0])
    link.endpoint.sent += int(c.sent[0])
    link.endpoint.send_dropped += int(c.send_dropped[0])
    st = w.st
    if st.known[0] and f.session == w.session:
        f.set_stream(w.session, T_COMMAND, int(st.newest[0]), int(st.mask[0]) & protocol.U64)
    link.seq = max(link.seq, int(st.obs_seq[0]) & protocol.U32)


