"""The target's socket reader drains every waiting datagram at each wake-up and counts what the
kernel dropped (impact_env.rig.transport: Endpoint.recv_many, kernel_drops; Link.recv_all)."""

from __future__ import annotations

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
