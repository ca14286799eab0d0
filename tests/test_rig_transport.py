"""UDP transport of the rig (impact_env.rig.transport), on loopback only, every wait bounded."""

from __future__ import annotations

import hashlib
import random
import threading
import time

import pytest

from impact_env.rig import protocol, transport

LOOP = "udp://127.0.0.1:0"
# these calls return within their own timeouts (0.02-0.2 s); what the tests guard against is a
# hang, so the bound is far above any scheduling delay of a loaded machine, not a speed figure
HANG_S = 10.0


@pytest.mark.parametrize("text,addr", [
    ("udp://127.0.0.1:5600", ("127.0.0.1", 5600)),
    ("UDP://rig.local:1", ("rig.local", 1)),
    ("udp://[::1]:65535", ("::1", 65535)),
    (" udp://10.0.0.2:80 ", ("10.0.0.2", 80)),
])
def test_parse_address(text, addr):
    assert transport.parse_address(text) == addr
    assert transport.parse_address(transport.format_address(addr)) == addr


@pytest.mark.parametrize("text,match", [
    ("tcp://127.0.0.1:5600", "must start with udp://"),
    ("127.0.0.1:5600", "must start with udp://"),
    ("udp://127.0.0.1", "has no :PORT"),
    ("udp://127.0.0.1:http", "is not a number"),
    ("udp://127.0.0.1:0", r"out of range \[1, 65535\]"),
    ("udp://127.0.0.1:70000", "out of range"),
    ("udp://:5600", "no valid host"),
    ("udp://::1:5600", "in brackets"),
    ("udp://[::1]5600", "closing ]"),
    ("udp://[not-v6]:5600", "not an IPv6 address"),
    (5600, "not a string"),
])
def test_parse_address_errors(text, match):
    with pytest.raises(ValueError, match=match):
        transport.parse_address(text)
    assert transport.parse_address("udp://127.0.0.1:0", allow_port_zero=True) == ("127.0.0.1", 0)


def test_endpoint_send_recv_timeout_and_close():
    with transport.Endpoint(LOOP) as a, transport.Endpoint(LOOP, peer=LOOP.replace(":0", ":1")) as b:
        assert a.local[0] == "127.0.0.1" and a.local[1] > 0
        assert b.send(b"hello", a.local)
        got = a.recv(1.0)
        assert got is not None and got[0] == b"hello" and got[1] == b.local
        t0 = time.perf_counter()
        assert a.recv(0.02) is None  # nothing more: returns after its timeout
        assert time.perf_counter() - t0 < HANG_S
        assert a.recv(0.0) is None
    t0 = time.perf_counter()
    a.close()  # idempotent
    assert time.perf_counter() - t0 < HANG_S
    with pytest.raises(transport.EndpointClosed, match="closed"):
        a.recv(0.1)
    with pytest.raises(transport.EndpointClosed):
        a.send(b"x", b.local)
    with pytest.raises(OSError, match="cannot bind"), transport.Endpoint("udp://127.0.0.1:0") as c:
        transport.Endpoint(c.address)


def test_endpoint_refuses_oversize_and_missing_peer():
    with transport.Endpoint(LOOP) as a:
        with pytest.raises(ValueError, match="no peer"):
            a.send(b"x")
        with pytest.raises(ValueError, match="exceeds"):
            a.send(bytes(protocol.MAX_DATAGRAM + 1), a.local)


class Responder:
    """A minimal target on a thread: answers HELLO with INFO, POLICY_CHUNK with ACK, FETCH with
    CHUNK (from ``resource``); drops each incoming and outgoing datagram with probability
    ``loss``, sends some replies twice (duplicates) and holds some back one round (reordering)."""

    def __init__(self, loss=0.0, resource=b"", refuse_arm=False, seed=1):
        self.ep = transport.Endpoint(LOOP)
        self.link = transport.Link(self.ep, "target")
        self.loss, self.resource, self.refuse_arm = loss, resource, refuse_arm
        self.rng = random.Random(seed)
        self.upload = transport.UploadAssembler()
        self.stop = threading.Event()
        self.requests = 0
        self.retries_seen = 0
        self._held = None
        self.error = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _send(self, body, msg):
        """Send the reply as a network would deliver it: maybe lost, maybe twice (the same
        bytes), maybe after the next reply (reordered)."""
        data = protocol.encode(self.link.stamp(body, reply_to=msg))
        to = self.link.last_sender
        if self.rng.random() < self.loss:
            return
        if self._held is not None:
            self.ep.send(data, to)
            self.ep.send(self._held, to)
            self._held = None
            return
        if self.rng.random() < 0.1:
            self._held = data
            return
        self.ep.send(data, to)
        if self.rng.random() < 0.1:
            self.ep.send(data, to)

    def _run(self):
        try:
            self._serve()
        except BaseException as exc:  # reported by close()
            self.error = exc

    def _serve(self):
        while not self.stop.is_set():
            got = self.ep.recv(0.01)
            if got is None or self.rng.random() < self.loss:
                continue
            msg = self.link.filter.accept(got[0])
            if msg is None:
                continue
            self.link.last_sender = got[1]
            self.requests += 1
            self.retries_seen += bool(msg.flags & protocol.FLAG_RETRY)
            b = msg.body
            if msg.type == protocol.MsgType.HELLO:
                self.link.session = msg.session
                self._send(protocol.Info(b.nonce, 1e4, 0, 0, True, len(self.resource),
                                         hashlib.sha256(self.resource).digest()), msg)
            elif msg.type == protocol.MsgType.POLICY_CHUNK:
                self._send(self.upload.add(b, msg.seq), msg)
            elif msg.type == protocol.MsgType.FETCH:
                self._send(transport.chunk_reply(self.resource, b, msg.seq), msg)
            elif msg.type == protocol.MsgType.ARM and self.refuse_arm:
                self._send(protocol.Error(protocol.ErrorCode.BAD_REQUEST, msg.seq, "history too long"), msg)

    def close(self):
        self.stop.set()
        self.thread.join(5.0)
        assert not self.thread.is_alive()
        self.ep.close()
        assert self.error is None, self.error


@pytest.fixture
def responder(request):
    r = Responder(**getattr(request, "param", {}))
    yield r
    r.close()


def _host(target: Responder, session=0xC0FFEE):
    return transport.Link(transport.Endpoint(LOOP, peer=target.ep.address), "host", session=session)


def _hello(link, nonce=b"\x07" * protocol.NONCE_SIZE, **kw):
    return link.request(
        protocol.Hello(nonce),
        lambda m: m.type == protocol.MsgType.INFO and m.body.nonce == nonce,
        "INFO",
        **kw,
    )


def test_request_reply_and_timestamps(responder):
    host = _host(responder)
    try:
        t0 = time.perf_counter_ns()
        info = _hello(host, timeout_s=0.5)
        assert info.session == 0xC0FFEE and info.body.lockstep
        assert t0 <= info.host_ns <= time.perf_counter_ns()  # our send time, echoed back
        assert info.target_ns > 0
    finally:
        host.endpoint.close()


@pytest.mark.parametrize("responder", [{"loss": 0.3, "seed": 3}], indirect=True)
def test_upload_and_fetch_through_loss_duplicates_and_reordering(responder):
    blob = random.Random(5).randbytes(100_000)  # a ~100 kB policy file
    responder.resource = random.Random(6).randbytes(20_000)
    host = _host(responder)
    try:
        _hello(host, timeout_s=0.02, retries=50)
        n = transport.upload(host, blob, timeout_s=0.02, retries=50)
        assert n == -(-len(blob) // protocol.CHUNK_DATA)
        assert responder.upload.complete and responder.upload.data == blob
        got = transport.fetch(
            host,
            protocol.Resource.SCENE,
            0,
            hashlib.sha256(responder.resource).digest(),
            timeout_s=0.02,
            retries=50,
        )
        assert got == responder.resource
        assert responder.retries_seen > 0  # loss forced retries
        dropped = host.filter.counts()
        assert dropped["duplicate"] + dropped["out_of_order"] > 0  # duplicated/reordered replies were dropped
        assert sum(dropped.values()) == host.filter.total
    finally:
        host.endpoint.close()


def test_empty_upload_and_fetch(responder):
    host = _host(responder)
    try:
        _hello(host, timeout_s=0.5)
        assert transport.upload(host, b"", timeout_s=0.5) == 1 and responder.upload.data == b""
        assert transport.fetch(host, protocol.Resource.SCENE, 0, timeout_s=0.5) == b""
    finally:
        host.endpoint.close()


@pytest.mark.parametrize("responder", [{"refuse_arm": True}], indirect=True)
def test_error_reply_raises_rig_error(responder):
    host = _host(responder)
    try:
        _hello(host, timeout_s=0.5)
        with pytest.raises(transport.RigError, match="refused ARMED: BAD_REQUEST: history too long"):
            host.request(
                protocol.Arm(), lambda m: m.type == protocol.MsgType.ARMED, "ARMED", timeout_s=0.5, retries=0
            )
    finally:
        host.endpoint.close()


@pytest.mark.parametrize("silent", ["bound", "closed port"])
def test_rig_timeout_is_raised_within_its_bound(silent):
    """A target that never answers (a bound socket that reads nothing, or no socket at all, which
    on loopback answers with ICMP port-unreachable) makes ``request`` raise RigTimeout after
    (retries + 1) timeouts, naming what it waited for and where."""
    quiet = transport.Endpoint(LOOP)
    addr = quiet.address
    if silent == "closed port":
        quiet.close()
    host = transport.Link(transport.Endpoint(LOOP, peer=addr), "host", session=1)
    t0 = time.perf_counter()
    try:
        with pytest.raises(transport.RigTimeout) as info:
            _hello(host, timeout_s=0.05, retries=3)
    finally:
        elapsed = time.perf_counter() - t0
        t1 = time.perf_counter()
        host.endpoint.close()
        quiet.close()
        assert time.perf_counter() - t1 < HANG_S  # close() does not hang
    e = info.value
    assert e.tries == 4 and 0.2 <= e.waited_s and elapsed < 0.2 + HANG_S
    assert addr in str(e) and "no INFO" in str(e) and "4 tries" in str(e)


def test_request_argument_checks():
    with transport.Endpoint(LOOP) as ep:
        link = transport.Link(ep, "host", session=1)
        with pytest.raises(ValueError, match="timeout_s"):
            link.request(protocol.Hello(), lambda m: True, "x", timeout_s=0.0)


def test_upload_assembler_contiguous_prefix_and_restart():
    data = bytes(range(256)) * 20
    up = transport.UploadAssembler()
    uid = transport.upload_id(data)
    c = lambda off, n=1024: protocol.PolicyChunk(uid, len(data), off, data[off:off + n])
    assert up.add(c(0)).value == 1024
    assert up.add(c(0)).value == 1024  # a repeat is harmless
    ack = up.add(c(3072))
    assert ack.code == protocol.ErrorCode.OUT_OF_RANGE and ack.value == 1024  # past the prefix
    for off in range(1024, len(data), 1024):
        assert up.add(c(off)).code == protocol.ErrorCode.OK
    assert up.complete and up.data == data
    other = b"new file"
    up.add(protocol.PolicyChunk(transport.upload_id(other), len(other), 0, other))
    assert up.data == other
    bad = protocol.PolicyChunk(12345, 3, 0, b"abc")  # id does not match the bytes
    up.add(bad)
    assert not up.complete
    with pytest.raises(ValueError, match="incomplete"):
        _ = up.data
    assert (
        transport.UploadAssembler(max_bytes=10).add(protocol.PolicyChunk(1, 11, 0, b"")).code
        == protocol.ErrorCode.OUT_OF_RANGE
    )


def test_chunk_reply():
    data = bytes(3000)
    r = transport.chunk_reply(data, protocol.Fetch(protocol.Resource.EPISODE, 4, 2048, 4096), seq=9)
    assert (r.total, r.offset, len(r.data), r.item) == (3000, 2048, 952, 4)
    assert transport.chunk_reply(data, protocol.Fetch(protocol.Resource.EPISODE, 4, 3000, 100)).data == b""
    err = transport.chunk_reply(data, protocol.Fetch(protocol.Resource.EPISODE, 4, 3001, 100), seq=9)
    assert (
        isinstance(err, protocol.Error) and err.code == protocol.ErrorCode.OUT_OF_RANGE and err.ref_seq == 9
    )
