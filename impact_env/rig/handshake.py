"""The target's side of opening a session: challenges that are answered once, and a per-source
rate limit on the replies it sends before a session exists (:class:`impact_env.rig.protocol.DatagramFilter`
holds one of each).

A HELLO opens nothing.  It is answered with a CHALLENGE carrying a fresh target nonce
(``secrets.token_bytes``); the session opens on the host's RESPONSE, tagged over both nonces,
from the address the challenge went to, within ``ttl_s``, once.  A recorded HELLO replayed
(from anywhere) only draws a challenge that its sender cannot answer without the key, and a
recorded RESPONSE names a challenge already spent: neither opens, holds nor evicts a session.

Both tables are bounded (``max_pending`` challenges, ``max_sources`` buckets; the least recently
used entry goes first), so a flood costs the target a fixed amount of memory.
"""

from __future__ import annotations

import hmac
import secrets
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable

NONCE_SIZE = 16  # bytes of a host's or a target's nonce (128 bits)


class RateLimiter:
    """Token buckets, one per source: ``allow(source)`` takes a token if the source has one.

    A bucket holds at most ``burst`` tokens and gains ``rate_hz`` per second of ``clock`` (s).
    At most ``max_sources`` buckets are kept; a source that was evicted comes back with a full
    bucket, so a flood from more sources than that gets ``burst`` replies each, no more.
    ``allowed`` and ``refused`` count the calls."""

    def __init__(self, rate_hz: float = 50.0, burst: int = 32, max_sources: int = 1024,
                 clock: Callable[[], float] = time.monotonic):
        if not (rate_hz > 0 and burst >= 1 and max_sources >= 1):
            raise ValueError(f"rate_hz = {rate_hz!r} 1/s must be > 0, burst = {burst!r} and "
                             f"max_sources = {max_sources!r} >= 1")
        self.rate_hz, self.burst, self.max_sources = float(rate_hz), float(burst), int(max_sources)
        self.clock = clock
        self._buckets: OrderedDict[Hashable, list[float]] = OrderedDict()
        self.allowed = self.refused = 0

    def __len__(self) -> int:
        return len(self._buckets)

    def allow(self, source: Hashable) -> bool:
        now = self.clock()
        b = self._buckets.get(source)
        if b is None:
            if len(self._buckets) >= self.max_sources:
                self._buckets.popitem(last=False)
            b = self._buckets[source] = [self.burst, now]
        else:
            self._buckets.move_to_end(source)
            b[0] = min(self.burst, b[0] + (now - b[1]) * self.rate_hz)
            b[1] = now
        if b[0] >= 1.0:
            b[0] -= 1.0
            self.allowed += 1
            return True
        self.refused += 1
        return False


class Challenges:
    """The challenges a target has sent and not yet seen answered: ``issue`` one for a HELLO
    (the same one again for a retried HELLO: same source, session and host nonce), ``redeem``
    it with the RESPONSE's nonces (true once; compared with :func:`hmac.compare_digest`)."""

    def __init__(self, ttl_s: float = 5.0, max_pending: int = 64,
                 clock: Callable[[], float] = time.monotonic):
        if not (ttl_s > 0 and max_pending >= 1):
            raise ValueError(f"ttl_s = {ttl_s!r} s must be > 0 s and max_pending = {max_pending!r} >= 1")
        self.ttl_s, self.max_pending, self.clock = float(ttl_s), int(max_pending), clock
        self._pending: OrderedDict[tuple, tuple[bytes, float]] = OrderedDict()

    def __len__(self) -> int:
        return len(self._pending)

    def issue(self, source: Hashable, session: int, host_nonce: bytes) -> bytes:
        """The target nonce answering a HELLO of ``session`` with ``host_nonce`` from ``source``."""
        now = self.clock()
        key = (source, session, bytes(host_nonce))
        got = self._pending.get(key)
        if got is not None and got[1] > now:
            return got[0]
        self._pending.pop(key, None)
        while len(self._pending) >= self.max_pending:
            self._pending.popitem(last=False)
        nonce = secrets.token_bytes(NONCE_SIZE)
        self._pending[key] = (nonce, now + self.ttl_s)
        return nonce

    def redeem(self, source: Hashable, session: int, host_nonce: bytes, target_nonce: bytes) -> bool:
        """Whether (``host_nonce``, ``target_nonce``) answer a live challenge sent to ``source``
        for ``session``; a challenge is spent by the first answer."""
        key = (source, session, bytes(host_nonce))
        got = self._pending.get(key)
        if got is None:
            return False
        if got[1] <= self.clock():
            del self._pending[key]
            return False
        if not hmac.compare_digest(got[0], bytes(target_nonce)):
            return False
        del self._pending[key]
        return True
