"""The real-time loop's wire (impact_env.rig.wire) against the protocol's Python side, its oracle:
every datagram the compiled classifier takes from the session's host gets the reason the Python
filter gives it (fuzzed), every other datagram is queued for the network thread, a full queue is
counted, and the OBSERVATION the loop encodes and tags decodes with protocol.decode."""

from __future__ import annotations

import random
import socket
import struct

import numpy as np
import pytest

from impact_env.rig import protocol, wire

KEY = bytes(range(32))
NONCE = 0x1234_5678_9ABC_DEF1
SESSION = 0xC0FFEE
EPISODE = 3
HOST = ("127.0.0.1", 40001)
STRANGER = ("127.0.0.1", 40002)


def _wire(fd: int = -1, peer=HOST, key: bytes = KEY) -> wire.Wire:
    return wire.make(fd, key, NONCE, SESSION, EPISODE, peer, None, 100)


def _put(w: wire.Wire, data: bytes, sender: tuple) -> None:
    """``data`` from ``sender`` where recvfrom would have left them."""
    raw, _mask = wire.sockaddr(sender)
    w.src[:] = 0
    w.src[:len(raw)] = np.frombuffer(raw, np.uint8)
    w.srclen[0] = len(raw)
    w.rx[wire.NONCE:wire.NONCE + len(data)] = np.frombuffer(data, np.uint8)


def _feed(w: wire.Wire, data: bytes, sender: tuple, step: int) -> tuple[str, tuple | None]:
    """One datagram through the compiled classifier: its outcome (a reason, "accepted", or
    "queued") and, for an accepted COMMAND of the episode, (step, action)."""
    _put(w, data, sender)
    before = {f: int(getattr(w.c, f)[0]) for f in wire.WireCounts._fields}
    code = wire.classify(w, len(data), step)
    moved = [f for f in wire.WireCounts._fields if int(getattr(w.c, f)[0]) != before[f] and f != "commands"
             and f != "authentic"]
    assert len(moved) == 1, moved  # one outcome per datagram
    what = moved[0]
    if what == "queued":
        assert wire.queued(w) == [(data, sender)]  # the network thread gets it as it came
    got = (int(w.st.cmd_step[0]), float(w.st.cmd_val[0])) if code == wire.COMMAND else None
    return what, got


def _command(seq: int, episode: int = EPISODE, step: int = 0, action: float = 0.25, session: int = SESSION,
             key: bytes = KEY, nonce: int = NONCE) -> bytes:
    return protocol.encode(
        protocol.Message(
            protocol.Command(episode, step, (action,)), session=session, seq=seq, host_ns=seq * 7
        ),
        key,
        nonce,
    )


def test_the_compiled_classifier_gives_every_datagram_the_filters_reason():
    """20 000 seeded datagrams from the host and a stranger (valid commands, replays, older
    numbers, flipped bits, cuts, wrong session, another key, late steps, bad payloads, other
    types): each host COMMAND gets the Python filter's reason, each other datagram is queued,
    and an accepted command carries its step and action."""
    r = random.Random(25)
    w = _wire()
    f = protocol.DatagramFilter("target", session=SESSION, key=KEY)
    f.nonce, f.peer, f.n_actions = NONCE, HOST, 1
    seq, step, sent = 0, 0, []
    outcomes: dict[str, int] = {}
    for i in range(20_000):
        if i % 40 == 0:
            step += 1
        kind = r.randrange(11)
        seq += 1
        sender = HOST
        if kind <= 2:  # valid, for this step or a later one
            data = _command(seq, step=step + r.randint(0, 2), action=r.uniform(-1, 1))
        elif kind == 3 and sent:  # a replay
            data = r.choice(sent[-80:])
        elif kind == 4:  # an older number never sent
            data = _command((seq - 1 - r.randint(0, 100)) & protocol.U32, step=step)
            seq -= 1
        elif kind == 5:  # flipped bits
            b = bytearray(_command(seq, step=step))
            for bit in r.sample(range(8 * len(b)), r.randint(1, 3)):
                b[bit // 8] ^= 1 << (bit % 8)
            data = bytes(b)
        elif kind == 6:  # cut or extended
            base = _command(seq, step=step)
            data = base[:r.randint(0, len(base) - 1)] if r.random() < 0.5 else base + bytes(r.randint(1, 9))
        elif kind == 7:  # wrong session, another key, or a step already over
            data = r.choice([_command(seq, session=SESSION ^ 1, step=step),
                             _command(seq, key=b"x" * 32, step=step),
                             _command(seq, step=max(0, step - r.randint(1, 3))),
                             _command(seq, episode=EPISODE - 1, step=step)])
        elif kind == 8:  # a payload the protocol refuses (no action), well tagged
            head = protocol.HEADER.pack(
                protocol.MAGIC, protocol.VERSION_MAJOR, 0, 7, 0, SESSION, seq, 0, 0, 0, 10
            )
            frame = head + struct.pack("<IIH", EPISODE, step, 0)
            data = frame + protocol.tag(KEY, NONCE, frame)
        elif kind == 9:  # other types from the host: the network thread's
            data = protocol.encode(
                protocol.Message(
                    r.choice([protocol.Heartbeat(2, EPISODE, step, 0), protocol.Disarm(0)]),
                    session=SESSION,
                    seq=seq,
                ),
                KEY,
                NONCE,
            )
        else:  # a stranger's well-tagged command
            data, sender = _command(seq, step=step), STRANGER
        what, got = _feed(w, data, sender, step)
        if what == "queued":
            if not (sender != HOST or len(data) < protocol.OVERHEAD or data[6] != protocol.MsgType.COMMAND
                    or data[:4] != protocol.MAGIC or data[4] != protocol.VERSION_MAJOR):
                # the host's authentic COMMAND of another action count: the network thread's
                # filter refuses it, to be answered with an ERROR naming the count
                assert f.accept(data, EPISODE, step, sender) is None and f.last_reason == "corrupt"
                assert f.refusal is not None and f.refusal[2].startswith("n=")
                f.refusal = None
                outcomes["refused"] = outcomes.get("refused", 0) + 1
        else:
            msg = f.accept(data, EPISODE, step, sender)
            want = "accepted" if msg is not None else f.last_reason
            assert what == want, (i, kind, what, want, f.last_error)
            if msg is not None:
                sent.append(data)
                if msg.body.episode == EPISODE:
                    assert got == (msg.body.step, msg.body.action[0])
                else:
                    assert got is None
        outcomes[what] = outcomes.get(what, 0) + 1
    for reason in ("accepted", "corrupt", "unauthenticated", "wrong_session", "duplicate", "out_of_order",
                   "late", "queued", "refused"):
        assert outcomes.get(reason, 0) > 0, outcomes  # every outcome was exercised
    assert int(w.c.accepted[0]) == f.counts()["accepted"]
    print("wire fuzz:", outcomes)


def test_a_full_queue_drops_and_counts():
    """The network thread reads nothing: the first N_Q datagrams wait in the queue, the rest are
    counted queue_full; once it has read them, the queue takes datagrams again."""
    w = _wire()
    junk = b"\x00" * 70
    for _ in range(wire.N_Q + 5):
        _put(w, junk, STRANGER)
        wire.classify(w, len(junk), 0)
    assert int(w.c.queued[0]) == wire.N_Q and int(w.c.queue_full[0]) == 5
    got = wire.queued(w)
    assert len(got) == wire.N_Q and got[0] == (junk, STRANGER)
    assert _feed(w, junk, STRANGER, 0)[0] == "queued"


def test_the_loops_observation_decodes_with_the_protocol_and_its_resend_is_a_new_number():
    """send_observation through a real socket: the datagram decodes (tag under the key and the
    session nonce) to the observation, telemetry and records given, numbered from the stream's
    counter; a re-send carries the next number."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx.bind(("127.0.0.1", 0))
    try:
        w = _wire(tx.fileno(), peer=rx.getsockname())
        obs = np.array([0.5, -1.25, 3.0, 1e-3])
        tel = np.array([12.0, 11.5, 2.0])
        records = np.arange(5 * 12, dtype=np.float64).reshape(5, 12) * 0.5
        wire.send_observation(w, 40, 10, 0x105, obs, tel, records, 1, 5)
        wire.resend_observation(w)
        rx.settimeout(2.0)
        msgs = [protocol.decode(rx.recv(65536), KEY, NONCE) for _ in range(2)]
    finally:
        rx.close()
        tx.close()
    m = msgs[0]
    assert m.type == protocol.MsgType.OBSERVATION and m.session == SESSION and m.seq == 100 and m.tick == 40
    b = m.body
    assert (b.episode, b.step, b.status, b.dtype) == (EPISODE, 10, 0x105, 4)
    assert b.obs == tuple(float(np.float32(x)) for x in obs)
    assert b.telemetry == tuple(tel) + tuple(records[1:5].ravel())
    assert msgs[1].seq == 101 and msgs[1].body == b and int(w.c.sent[0]) == 2


def test_records_with_a_nan_are_left_out():
    """A step whose true records hold a NaN (not known) is sent without them: the host marks it."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        w = _wire(tx.fileno(), peer=rx.getsockname())
        records = np.zeros((4, 12))
        records[2, 3] = np.nan
        wire.send_observation(w, 4, 1, 0, np.zeros(2), np.ones(3), records, 0, 4)
        rx.settimeout(2.0)
        b = protocol.decode(rx.recv(65536), KEY, NONCE).body
    finally:
        rx.close()
        tx.close()
    assert b.telemetry == (1.0, 1.0, 1.0)


@pytest.mark.parametrize("peer", [("127.0.0.1", 5600), ("::1", 5600, 0, 0)])
def test_sockaddr_round_trip(peer):
    raw, mask = wire.sockaddr(peer)
    assert len(raw) == len(mask) and wire.address(np.frombuffer(raw, np.uint8), len(raw))[:2] == peer[:2]


def _observation(seq: int, episode: int = EPISODE, step: int = 0, n: int = 3, m: int = 4, dtype: int = 4,
                 session: int = SESSION, key: bytes = KEY, nonce: int = NONCE) -> bytes:
    obs = tuple(float(np.float32(0.25 * k - 0.5)) for k in range(n))
    tel = tuple(float(k) * 1.5 for k in range(m))
    return protocol.encode(
        protocol.Message(protocol.Observation(episode, step, 7, dtype, obs, tel), session=session, seq=seq),
        key,
        nonce,
    )


def test_the_hosts_compiled_path_gives_every_observation_the_filters_reason():
    """The host's side (impact_env.rig.host_wire.classify_observation) against the host's Python
    filter, fuzzed as the target's: each OBSERVATION from the target gets the filter's reason,
    every other datagram is queued, and an accepted one of the episode at or after the step
    awaited, newer than the one held, is copied out with its values."""
    from impact_env.rig import host_wire

    r = random.Random(26)
    w = _wire()
    f = protocol.DatagramFilter("host", session=SESSION, key=KEY)
    f.nonce, f.peer = NONCE, HOST
    seq, step, sent = 0, 0, []
    outcomes: dict[str, int] = {}
    for i in range(10_000):
        if i % 30 == 0:
            step += 1
            w.st.got[0] = 0  # a new wait
        kind = r.randrange(9)
        seq += 1
        sender = HOST
        if kind <= 2:
            data = _observation(seq, step=step + r.randint(-1, 1), n=r.randint(0, 12), m=r.randint(0, 30),
                                dtype=r.choice([4, 8]))
        elif kind == 3 and sent:
            data = r.choice(sent[-80:])
        elif kind == 4:
            data = _observation((seq - 1 - r.randint(0, 100)) & protocol.U32, step=step)
            seq -= 1
        elif kind == 5:
            b = bytearray(_observation(seq, step=step))
            for bit in r.sample(range(8 * len(b)), r.randint(1, 3)):
                b[bit // 8] ^= 1 << (bit % 8)
            data = bytes(b)
        elif kind == 6:
            base = _observation(seq, step=step)
            data = base[:r.randint(0, len(base) - 1)] if r.random() < 0.5 else base + bytes(r.randint(1, 9))
        elif kind == 7:
            data = r.choice(
                [
                    _observation(seq, session=SESSION ^ 1, step=step),
                    _observation(seq, key=b"x" * 32, step=step),
                    _observation(seq, episode=EPISODE + 1, step=step),
                    protocol.encode(
                        protocol.Message(
                            protocol.EpisodeEnd(EPISODE, 1, 0, 10, 2, 0, bytes(32)), session=SESSION, seq=seq
                        ),
                        KEY,
                        NONCE,
                    ),
                ]
            )
        else:
            data, sender = _observation(seq, step=step), STRANGER
        _put(w, data, sender)
        before = {k: int(getattr(w.c, k)[0]) for k in wire.WireCounts._fields}
        held = (int(w.st.got[0]), int(w.st.out_step[0]))
        host_wire.classify_observation(w, len(data), EPISODE, step)
        moved = [
            k for k in wire.WireCounts._fields if int(getattr(w.c, k)[0]) != before[k] and k != "authentic"
        ]
        assert len(moved) == 1, moved
        what = moved[0]
        if what == "queued":
            assert wire.queued(w) == [(data, sender)]
        else:
            msg = f.accept(data, None, None, sender)
            want = "accepted" if msg is not None else f.last_reason
            assert what == want, (i, kind, what, want, f.last_error)
            if msg is not None:
                sent.append(data)
                b = msg.body
                taken = b.episode == EPISODE and b.step >= step and not (held[0] and b.step <= held[1])
                assert (int(w.st.got[0]), int(w.st.out_step[0])) == ((1, b.step) if taken else held)
                if taken:
                    n, m = int(w.st.out_n[0]), int(w.st.out_m[0])
                    assert (n, m, int(w.st.out_status[0])) == (len(b.obs), len(b.telemetry), b.status)
                    assert tuple(w.out[:n]) == b.obs and tuple(w.out[n:n + m]) == b.telemetry
        outcomes[what] = outcomes.get(what, 0) + 1
    for reason in ("accepted", "corrupt", "unauthenticated", "wrong_session", "duplicate", "out_of_order",
                   "queued"):
        assert outcomes.get(reason, 0) > 0, outcomes
    print("host wire fuzz:", outcomes)


def test_the_hosts_command_is_protocol_command_datagram_byte_for_byte():
    """host_wire.send_command puts protocol.command_datagram's bytes on the wire."""
    from impact_env.rig import host_wire

    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        w = _wire(tx.fileno(), peer=rx.getsockname())
        host_wire.send_command(w, EPISODE, 41, -0.375, 9, 123456789)
        rx.settimeout(2.0)
        got = rx.recv(65536)
    finally:
        rx.close()
        tx.close()
    assert got == protocol.command_datagram(EPISODE, 41, -0.375, SESSION, 9, 123456789, 0, KEY, NONCE)
