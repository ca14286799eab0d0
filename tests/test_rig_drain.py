"""The target's socket reader drains every waiting datagram at each wake-up and counts what the
kernel dropped (impact_env.rig.transport: Endpoint.recv_many, kernel_drops; Link.recv_all)."""

from __future__ import annotations

import os
import socket
import sys

import pytest

from impact_env.rig import protocol as P
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
            host.send(P.Heartbeat(0, 0, k, 0))
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
@pytest.mark.parametrize("lanes", [True, False], ids=["lane", "no-lane"])
def test_a_flood_from_others_leaves_the_lanes_peer_its_datagrams(lanes):
    """A stranger's 2000 datagrams fill the target's 4 KiB buffer (the kernel drops most of
    them), then the host sends 20, each read by the lane's owner (as the real-time loop reads it:
    the lane's file descriptor).  With a lane for the host (Endpoint.open_lane) every one of the
    host's arrives, in order, and every drop is the stranger's; without one (the fault a lane
    removes) the host's land behind the flood, and the kernel drops them."""
    e = Endpoint(rcvbuf=4096, lanes=lanes)
    host, stranger = _udp(), _udp()
    try:
        fd = e.open_lane(host.getsockname())
        assert (fd >= 0) == lanes
        e.lane_busy = lanes  # the loop owns the lane: the socket's reader leaves it alone
        for _ in range(2000):
            stranger.sendto(b"x" * 100, e.local)
        mine = []
        for k in range(20):
            host.sendto(b"h%02d" % k, e.local)
            if lanes:
                mine.append(os.read(fd, 100))
        got = e.recv_many()
        mine += [d for d, a in got if a == host.getsockname()]
        theirs = [d for d, a in got if a == stranger.getsockname()]
        assert len(mine) + len(theirs) == len(got) + (20 if lanes else 0)
        assert len(mine) + len(theirs) + e.kernel_drops() == 2020  # every datagram read or counted
        if lanes:
            assert mine == [b"h%02d" % k for k in range(20)] and 0 < len(theirs) < 2000
        else:
            assert len(mine) < 20 and e.kernel_drops() > 2000 - len(theirs)
    finally:
        host.close()
        stranger.close()
        e.close()


@linux
def test_a_lane_replaced_or_closed_loses_nothing_and_the_address_stays_taken():
    """A lane for another peer replaces the first: what the first held is read first.  A second
    endpoint cannot bind the address (a second target is refused, lanes or not)."""
    e = Endpoint(lanes=True)
    a, b = _udp(), _udp()
    try:
        e.open_lane(a.getsockname())
        assert e.open_lane(a.getsockname()) == e.open_lane(a.getsockname())  # the same lane
        e.lane_busy = True
        for k in range(3):
            a.sendto(b"a%d" % k, e.local)
        assert e.recv_many() == []  # in the lane, which its owner reads
        e.lane_busy = False
        e.open_lane(b.getsockname())
        b.sendto(b"b0", e.local)
        assert [d for d, _ in e.recv_many()] == [b"a0", b"a1", b"a2", b"b0"]
        with pytest.raises(OSError, match="cannot bind"):
            Endpoint(e.address, lanes=True)
    finally:
        a.close()
        b.close()
        e.close()
