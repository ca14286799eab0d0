"""The target's socket reader drains every waiting datagram at each wake-up and counts what the
kernel dropped (impact_env.rig.transport: Endpoint.recv_many, kernel_drops; Link.recv_all)."""

from __future__ import annotations

import os
import socket
import sys

import pytest

from impact_env.rig import protocol
from impact_env.rig.transport import Endpoint, Link

linux = pytest.mark.skipif(not sys.platform.startswith("linux"),
                           reason="SO_RXQ_OVFL and /proc/net/udp are Linux's")


@linux
def test_every_datagram_is_read_or_counted_dropped_by_the_kernel():
    """2000 datagrams into a 4 KiB receive buffer, none read while they come: the kernel keeps a
    few and drops the rest; one drain reads every kept one, and kept + dropped = sent, exactly."""
    e = Endpoint(rcvbuf=4096)
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for _ in range(2000):
            s.sendto(b"x" * 100, e.local)
        got = e.recv_many()
        assert 0 < len(got) < 2000 and e.recv_many() == []  # the first drain took all there was
        assert len(got) + e.kernel_drops() == 2000
        s.sendto(b"y", e.local)  # the next datagram carries the count (SO_RXQ_OVFL) as well
        assert len(e.recv_many()) == 1 and e.kernel_dropped == 2000 - len(got)
    finally:
        s.close()
        e.close()
    assert e.kernel_drops() == 2000 - len(got)  # still readable once closed


def test_recv_all_counts_junk_by_reason_and_returns_the_good_ones_in_order():
    target = Link(Endpoint(), "target", session=7)
    host = Link(Endpoint(peer=target.endpoint.address), "host", session=7)
    junk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for k in range(5):
            junk.sendto(b"junk" * 10, target.endpoint.local)
            host.send(protocol.Heartbeat(0, 0, k, 0))
        got = target.recv_all()
        assert [m.body.step for m in got] == list(range(5))
        assert target.filter.counts()["corrupt"] == 5 and target.endpoint.received == 10
    finally:
        junk.close()
        target.endpoint.close()
        host.endpoint.close()


def _udp():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    return s


@linux
@pytest.mark.parametrize("session", [True, False], ids=["session-socket", "shared-socket"])
def test_a_flood_from_others_leaves_the_sessions_host_its_datagrams(session):
    """A stranger's 2000 datagrams fill the target's 4 KiB buffer (the kernel drops most of
    them), then the host sends 20, each read by the session socket's owner (as the real-time loop
    reads it: its file descriptor).  With a socket of the session's own (Endpoint.open_session),
    which the host sends to, every one of the host's arrives, in order, and every drop is the
    stranger's; without one (the host sending to the target's socket) the host's land behind the
    flood, and the kernel drops them."""
    e = Endpoint(rcvbuf=4096)
    host, stranger = _udp(), _udp()
    try:
        to = e.local
        if session:
            port = e.open_session(host.getsockname())
            assert port not in (0, e.local[1]) and e.session_fd >= 0
            to = (e.local[0], port)
            e.session_busy = True  # the loop owns the session's socket: the target's reader leaves it alone
        for _ in range(2000):
            stranger.sendto(b"x" * 100, e.local)
        mine = []
        for k in range(20):
            host.sendto(b"h%02d" % k, to)
            if session:
                mine.append(os.read(e.session_fd, 100))
        got = e.recv_many()
        mine += [d for d, a in got if a == host.getsockname()]
        theirs = [d for d, a in got if a == stranger.getsockname()]
        assert len(mine) + len(theirs) == len(got) + (20 if session else 0)
        assert len(mine) + len(theirs) + e.kernel_drops() == 2020  # every datagram read or counted
        if session:
            assert mine == [b"h%02d" % k for k in range(20)] and 0 < len(theirs) < 2000
        else:
            assert len(mine) < 20 and e.kernel_drops() > 2000 - len(theirs)
    finally:
        host.close()
        stranger.close()
        e.close()


@linux
def test_a_session_socket_replaced_or_closed_loses_nothing_and_takes_its_peer_only():
    """A session socket for another peer replaces the first: what the first held is read first.
    The session's socket takes its host's datagrams only (connected: another sender's are not
    delivered to it), and sends to its host go out of it.  A second endpoint cannot bind the
    target's address, nor anyone the session's port."""
    e = Endpoint()
    a, b = _udp(), _udp()
    try:
        port_a = e.open_session(a.getsockname())
        assert e.open_session(a.getsockname()) == port_a  # the same socket
        e.session_busy = True
        for k in range(3):
            a.sendto(b"a%d" % k, (e.local[0], port_a))
        b.sendto(b"not a's", (e.local[0], port_a))  # not the session's host: never delivered
        assert e.recv_many() == []  # in the session's socket, which its owner reads
        e.send(b"to a", a.getsockname())
        assert a.recvfrom(100) == (b"to a", (e.local[0], port_a))
        e.send(b"to a, main", a.getsockname(), main=True)
        assert a.recvfrom(100) == (b"to a, main", e.local)
        e.session_busy = False
        port_b = e.open_session(b.getsockname())
        b.sendto(b"b0", (e.local[0], port_b))
        assert [d for d, _ in e.recv_many()] == [b"a0", b"a1", b"a2", b"b0"]
        with pytest.raises(OSError, match="cannot bind"):
            Endpoint(e.address)
        for port in (e.local[1], port_b):
            thief = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            thief.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            thief.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            with pytest.raises(OSError):
                thief.bind(("127.0.0.1", port))
            thief.close()
        e.close_session()
        assert e.session_fd == -1 and e.session_port == 0
    finally:
        a.close()
        b.close()
        e.close()
