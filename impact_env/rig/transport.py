"""UDP transport for the rig: addresses, a non-blocking endpoint, and a session link with
reliable requests and chunked transfers over an unreliable network.

Layers, bottom up:

* :func:`parse_address` / :func:`format_address`: ``udp://HOST:PORT`` (IPv6 as ``udp://[::1]:PORT``).
* :class:`Endpoint`: one non-blocking UDP socket.  ``send`` never blocks (a full send buffer
  drops the datagram and counts it, as the network would); ``recv(timeout)`` waits at most
  ``timeout`` seconds (``select`` with microsecond resolution) and returns None when nothing
  came; ``close()`` is idempotent and returns at once.
* :class:`Link`: one side of a session.  It stamps every outgoing message (session id, its own
  sequence counter, this side's ``perf_counter_ns``, the other side's timestamp echoed from the
  message it answers), and passes every incoming datagram through a
  :class:`~impact_env.rig.protocol.DatagramFilter` (``link.filter.counts()`` are the drops).
  :meth:`Link.request` sends a request and waits for the reply that ``match`` accepts, sending
  it again (new sequence number, ``FLAG_RETRY``) after each ``timeout_s`` without a reply, at
  most ``retries`` times; then it raises :class:`RigTimeout`.  The whole call therefore returns
  or raises within ``(retries + 1) * timeout_s`` (plus the time the callbacks take).  An ERROR
  that answers one of the attempts raises :class:`RigError` at once.
* :func:`upload` and :func:`fetch`: a file of any size (a ~100 kB policy, an episode's HDF5
  log) as a sequence of ``CHUNK_DATA``-byte requests, each acknowledged (stop-and-wait: simple,
  and a lost datagram costs one ``timeout_s``), checked against a sha256 at the end.
"""

from __future__ import annotations

import hashlib
import ipaddress
import os
import select
import socket
import time
from collections.abc import Callable

from impact_env.rig import protocol
from impact_env.rig.errors import RigError

Address = tuple[str, int]


class RigTimeout(TimeoutError):
    """Nothing acceptable came back in time.  ``what`` was awaited for ``waited_s`` seconds
    from ``address`` over ``tries`` attempts."""

    def __init__(self, what: str, waited_s: float, address: str, tries: int = 1):
        tries_s = f" over {tries} tries" if tries > 1 else ""
        super().__init__(f"no {what} from {address} within {waited_s:.3g} s{tries_s}: is the target "
                         "running and reachable (impact-env rig serve), and the address right?")
        self.what, self.waited_s, self.address, self.tries = what, waited_s, address, tries


class EndpointClosed(OSError):
    """The endpoint was closed."""


# -- addresses -----------------------------------------------------------------------------------------
def parse_address(text: str, allow_port_zero: bool = False) -> Address:
    """``"udp://HOST:PORT"`` -> ``(HOST, PORT)``.  HOST is a name, an IPv4 address or a
    bracketed IPv6 address; PORT 1..65535 (0, "any free port", only with ``allow_port_zero``).
    Raises ValueError saying what is wrong and what is expected."""
    example = "expected udp://HOST:PORT, e.g. udp://127.0.0.1:5600 or udp://[::1]:5600"
    if not isinstance(text, str):
        raise ValueError(f"address {text!r} is not a string; {example}")
    scheme, sep, rest = text.strip().partition("://")
    if not sep or scheme.lower() != "udp":
        raise ValueError(f"address {text!r} must start with udp://; {example}")
    if rest.startswith("["):
        host, close, tail = rest[1:].partition("]")
        if not close or not tail.startswith(":"):
            raise ValueError(f"address {text!r}: an IPv6 host needs its closing ] and a :PORT; {example}")
        port_s = tail[1:]
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            raise ValueError(f"address {text!r}: {host!r} is not an IPv6 address; {example}") from None
    else:
        host, colon, port_s = rest.rpartition(":")
        if not colon:
            raise ValueError(f"address {text!r} has no :PORT; {example}")
        if ":" in host:
            raise ValueError(f"address {text!r}: write an IPv6 host in brackets; {example}")
    if not host or any(c.isspace() or c in "/?#@" for c in host):
        raise ValueError(f"address {text!r} has no valid host; {example}")
    if not port_s.isdigit():
        raise ValueError(f"address {text!r}: port {port_s!r} is not a number; {example}")
    port = int(port_s)
    if not (0 if allow_port_zero else 1) <= port <= 65535:
        lo = 0 if allow_port_zero else 1
        raise ValueError(f"address {text!r}: port {port} is out of range [{lo}, 65535]")
    return host, port


def format_address(addr: Address) -> str:
    host, port = addr[0], addr[1]
    return f"udp://[{host}]:{port}" if ":" in host else f"udp://{host}:{port}"


def _as_address(addr: str | Address, allow_port_zero: bool = False) -> Address:
    if isinstance(addr, str):
        return parse_address(addr, allow_port_zero)
    host, port = addr[0], addr[1]
    return parse_address(format_address((str(host), int(port))), allow_port_zero)


def _resolve(addr: Address) -> tuple[int, tuple]:
    try:
        infos = socket.getaddrinfo(addr[0], addr[1], type=socket.SOCK_DGRAM)
    except socket.gaierror as exc:
        raise ValueError(f"cannot resolve host {addr[0]!r} of {format_address(addr)}: {exc}") from None
    family, _, _, _, sockaddr = infos[0]
    return family, sockaddr


# -- endpoint ------------------------------------------------------------------------------------------
def _same_peer(a: tuple | None, b: tuple | None) -> bool:
    return a is not None and b is not None and tuple(a[:2]) == tuple(b[:2])


def _proc_drops(sock: socket.socket) -> int:
    """The kernel's drop count of ``sock`` (Linux's /proc/net/udp{,6}, found by the socket's
    inode); -1 where there is none."""
    try:
        ino = str(os.fstat(sock.fileno()).st_ino)
    except OSError:
        return -1
    for name in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(name) as fh:
                for line in fh.read().splitlines()[1:]:
                    f = line.split()
                    if len(f) >= 13 and f[9] == ino:
                        return int(f[12])
        except (OSError, ValueError):
            continue
    return -1


SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)  # Linux: the kernel's drop count with each datagram


class Endpoint:
    """A non-blocking UDP socket bound to ``bind`` (default: loopback, a free port), never with
    ``SO_REUSEPORT`` or ``SO_REUSEADDR``: another process, whatever its user, cannot bind the same
    address beside it and take a share of its datagrams (the kernel refuses the second bind).

    ``peer`` is the default destination of :meth:`send`.  Attributes: ``address`` (the bound
    ``udp://`` address), ``sent``, ``received``, ``send_dropped`` (datagrams a full buffer or
    an unreachable peer refused; UDP gives no other delivery report).

    A target gives its session's host a socket of the session's own (:meth:`open_session`).
    """

    def __init__(self, bind: str | Address = "udp://127.0.0.1:0", peer: str | Address | None = None,
                 rcvbuf: int = 1 << 20):
        b = _as_address(bind, allow_port_zero=True)
        family, sockaddr = _resolve(b)
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, int(rcvbuf))
            self._sock.bind(sockaddr)
            self._sock.setblocking(False)
        except OSError as exc:
            self._sock.close()
            raise OSError(f"cannot bind {format_address(b)}: {exc}") from exc
        self._family = family
        self._rcvbuf = int(rcvbuf)
        self._session: socket.socket | None = None
        self._session_peer: tuple | None = None
        #: True while another reader (the target's real-time loop) owns the session's socket: recv
        #: and recv_many then read the endpoint's own socket only
        self.session_busy = False
        self._pending: list[tuple[bytes, tuple]] = []  # what a closed session socket still held
        self._session_drops_before = 0  # kernel drops of session sockets already closed
        local = self._sock.getsockname()
        self.local: Address = (local[0], local[1])
        self.peer: tuple | None = None
        if peer is not None:
            self.peer = _resolve(_as_address(peer))[1]
        self.sent = self.received = self.send_dropped = 0
        # datagrams the kernel dropped because the receive buffer was full (Linux SO_RXQ_OVFL:
        # the count arrives with each datagram; None where the platform has no such counter)
        self.kernel_dropped: int | None = None
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
            self.kernel_dropped = 0
        except OSError:
            pass
        self._closed = False

    @property
    def address(self) -> str:
        return format_address(self.local)

    @property
    def closed(self) -> bool:
        return self._closed

    def _check(self):
        if self._closed:
            raise EndpointClosed(f"endpoint {self.address} is closed")

    def send(self, data: bytes, addr: tuple | None = None, main: bool = False) -> bool:
        """Send one datagram to ``addr`` (default: the peer); False if the OS refused it.  To the
        session's peer it goes out of the session's socket, unless ``main`` (a handshake's reply,
        from the address the peer knows before it learns the session's port)."""
        self._check()
        dest = addr if addr is not None else self.peer
        if dest is None:
            raise ValueError(f"endpoint {self.address} has no peer: give addr")
        if len(data) > protocol.MAX_DATAGRAM:
            raise ValueError(f"datagram of {len(data)} B exceeds {protocol.MAX_DATAGRAM} B")
        session = self._session is not None and not main and _same_peer(dest, self._session_peer)
        sock = self._session if session and self._session is not None else self._sock
        try:
            sock.sendto(data, dest)
        except (BlockingIOError, ConnectionRefusedError, InterruptedError):
            self.send_dropped += 1
            return False
        self.sent += 1
        return True

    def _readers(self) -> list[socket.socket]:
        """The sockets this endpoint reads now: the session's (unless the loop owns it), then its own."""
        if self._session is not None and not self.session_busy:
            return [self._session, self._sock]
        return [self._sock]

    def recv(self, timeout: float = 0.0, spin_s: float = 0.0) -> tuple[bytes, tuple] | None:
        """The next datagram and its sender, waiting at most ``timeout`` s (0: just poll);
        None if none came.  ``spin_s``: the first part of the wait, up to that long, polls the
        socket without sleeping (a real-time host: a thread asleep in select() takes tens of
        microseconds to wake on a virtual machine's idle CPU; spinning, none)."""
        self._check()
        now = time.perf_counter()
        deadline = now + max(float(timeout), 0.0)
        spin_until = now + min(max(float(spin_s), 0.0), max(float(timeout), 0.0))
        while True:
            if self._pending:
                self.received += 1
                return self._pending.pop(0)
            socks = self._readers()
            for sock in socks:
                try:
                    data, addr = sock.recvfrom(protocol.MAX_DATAGRAM + 1)
                    self.received += 1
                    return data, addr
                except (BlockingIOError, InterruptedError):
                    pass
                except ConnectionRefusedError:  # an ICMP error from an earlier send: not a datagram
                    break
                except OSError:
                    if self._closed:
                        raise EndpointClosed(f"endpoint {self.address} was closed while waiting") from None
                    raise
            else:
                now = time.perf_counter()
                remaining = deadline - now
                if remaining <= 0:
                    return None
                if now < spin_until:
                    continue
                try:
                    select.select(socks, [], [], remaining)
                except (OSError, ValueError):
                    if self._closed:
                        raise EndpointClosed(f"endpoint {self.address} was closed while waiting") from None
                    raise

    def recv_many(self, limit: int = 4096) -> list[tuple[bytes, tuple]]:
        """Every datagram waiting now (at most ``limit``), the session's first, without waiting: a
        reader that drains the queue at each wake-up, so that junk never queues ahead of the host.
        Reads the kernel's drop counter (``kernel_dropped``) from each datagram's ancillary data."""
        self._check()
        out = self._pending[:limit]
        del self._pending[:limit]
        self.received += len(out)
        anc = socket.CMSG_SPACE(4) if self.kernel_dropped is not None else 0
        for sock in self._readers():
            while len(out) < limit:
                try:
                    data, ancdata, _flags, addr = sock.recvmsg(protocol.MAX_DATAGRAM + 1, anc)
                except (BlockingIOError, InterruptedError):
                    break
                except ConnectionRefusedError:
                    continue
                except OSError:
                    if self._closed:
                        raise EndpointClosed(f"endpoint {self.address} was closed while reading") from None
                    raise
                self.received += 1
                for level, kind, value in ancdata:
                    if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(value) >= 4 \
                            and sock is self._sock:
                        # the socket's drops since it opened (a session socket's are read from /proc)
                        self.kernel_dropped = int.from_bytes(value[:4], "little")
                out.append((data, addr))
        return out

    def open_session(self, peer: tuple) -> int:
        """A socket of ``peer``'s session's own: bound to this endpoint's host address on a port the
        kernel picks (no ``SO_REUSEPORT``: no other process can bind it beside this one) and
        connected to ``peer``, so that the kernel puts in its buffer ``peer``'s datagrams and no
        one else's (a connected UDP socket matches its peer only).  A flood from any other sender
        then fills the endpoint's own buffer, never the session's.  The target names the port in
        its INFO (authenticated), and its host sends the session's datagrams there
        (:mod:`impact_env.rig.wire`: the real-time loop reads it).  Returns the port.  The socket
        stays open for ``peer``; one for another peer replaces it, what the old one held read
        first.  :meth:`recv` and :meth:`recv_many` read it too (not while ``session_busy``);
        :meth:`send` to ``peer`` goes out of it."""
        self._check()
        if self._session is not None and _same_peer(self._session_peer, peer):
            return self.session_port
        self.close_session()
        sock = socket.socket(self._family, socket.SOCK_DGRAM)
        local = self._sock.getsockname()
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self._rcvbuf)
            sock.bind((local[0], 0, *local[2:]))
            sock.connect(peer)
            sock.setblocking(False)
        except OSError as exc:
            sock.close()
            raise OSError(f"cannot open a session socket on {format_address(self.local)} for "
                          f"{format_address((peer[0], peer[1]))}: {exc}") from exc
        self._session, self._session_peer = sock, peer
        return self.session_port

    @property
    def session_fd(self) -> int:
        """The session socket's file descriptor (-1: none open)."""
        return self._session.fileno() if self._session is not None else -1

    @property
    def session_port(self) -> int:
        """The session socket's port (0: none open)."""
        return self._session.getsockname()[1] if self._session is not None else 0

    def close_session(self) -> None:
        """Close the session's socket (if open): what it holds is read first (the kernel would
        discard it), for :meth:`recv` and :meth:`recv_many`."""
        sock, self._session = self._session, None
        self._session_peer = None
        if sock is None:
            return
        while True:
            try:
                self._pending.append(sock.recvfrom(protocol.MAX_DATAGRAM + 1))
            except OSError:  # nothing left (BlockingIOError), or an ICMP error reported: done
                break
        self._session_drops_before += max(_proc_drops(sock), 0)
        sock.close()

    def kernel_drops(self) -> int:
        """Datagrams the kernel dropped for this endpoint's sockets (its own and its sessions')
        since it opened (a receive buffer full): Linux's per-socket counter in /proc/net/udp (read
        now, so drops after the last datagram count too), else the last SO_RXQ_OVFL value seen,
        else 0."""
        if self._closed:  # the last count read (a closed socket has left /proc)
            return self.kernel_dropped or 0
        own = _proc_drops(self._sock)
        if own < 0:
            return self.kernel_dropped or 0
        session = _proc_drops(self._session) if self._session is not None else 0
        self.kernel_dropped = own + max(session, 0) + self._session_drops_before
        return self.kernel_dropped

    def wait_readable(self, timeout: float, *others) -> list:
        """select() on the sockets read now (:meth:`recv`) and ``others`` (file descriptors) for
        at most ``timeout`` s."""
        self._check()
        if self._pending:
            return [self._sock]
        try:
            return select.select([*self._readers(), *others], [], [], max(float(timeout), 0.0))[0]
        except (OSError, ValueError):
            if self._closed:
                raise EndpointClosed(f"endpoint {self.address} was closed while waiting") from None
            raise

    def fileno(self) -> int:
        return self._sock.fileno()

    def close(self) -> None:
        """Close the socket (idempotent, never blocks)."""
        if not self._closed:
            self.kernel_drops()
            self._closed = True
            self.close_session()
            self._sock.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self):
        return f"Endpoint({self.address}{', closed' if self._closed else ''})"


# -- link ------------------------------------------------------------------------------------------------
class Link:
    """One side (``role`` "host" or "target") of a session over an :class:`Endpoint`.

    ``session``: the session id (the host picks it, nonzero; the target sets it when a HELLO
    opens one).  ``clock``: ns timestamps for the header (default ``time.perf_counter_ns``).
    ``last_sender``: the address the last accepted message came from (the target answers it).
    """

    def __init__(self, endpoint: Endpoint, role: str, session: int | None = None,
                 clock: Callable[[], int] = time.perf_counter_ns, key: bytes = b"",
                 on_stranger: Callable[[protocol.Message, tuple], None] | None = None):
        self.endpoint = endpoint
        self.role = role
        self.filter = protocol.DatagramFilter(role, session=session, key=bytes(key))
        self.clock = clock
        self.seq = 0
        self.last_sender: tuple | None = None
        self.on_stranger = on_stranger
        self.on_unauthenticated: Callable[[bytes, tuple], None] | None = None
        # sees every accepted message, whoever waits for it (a request's wait drops the others)
        self.on_accept: Callable[[protocol.Message], None] | None = None
        # the target's handshake: takes the HELLOs and RESPONSEs (with their sender) that the
        # filter accepted, idle or mid-episode; they are not returned by recv
        self.on_handshake: Callable[[protocol.Message, tuple], None] | None = None
        # a request the filter refused for a field out of range: (code, seq, text, size), sender
        self.on_refused: Callable[[tuple, tuple], None] | None = None

    @property
    def session(self) -> int | None:
        return self.filter.session

    @session.setter
    def session(self, value: int | None) -> None:
        self.filter.session = value

    @property
    def peer_name(self) -> str:
        p = self.endpoint.peer or self.last_sender
        return format_address((p[0], p[1])) if p else "the peer"

    def send(
        self,
        body: protocol.Body,
        tick: int = 0,
        reply_to: protocol.Message | None = None,
        flags: int = 0,
        addr: tuple | None = None,
    ) -> protocol.Message:
        """Stamp, number and send ``body``; returns the message sent."""
        msg = self.stamp(body, tick, reply_to, flags)
        self.endpoint.send(protocol.encode(msg, self.filter.key, self.filter.nonce), addr)
        return msg

    def stamp(self, body: protocol.Body, tick: int = 0, reply_to: protocol.Message | None = None,
              flags: int = 0) -> protocol.Message:
        """The message ``body`` becomes when sent now: this session, the next sequence number
        (taken), this side's clock, the other side's timestamp echoed from ``reply_to``."""
        now = self.clock() & protocol.U64
        if self.role == "host":
            hns, tns = now, (reply_to.target_ns if reply_to is not None else 0)
        else:
            hns, tns = (reply_to.host_ns if reply_to is not None else 0), now
        msg = protocol.Message(
            body, session=self.session or 0, seq=self.seq, tick=tick, host_ns=hns, target_ns=tns, flags=flags
        )
        self.seq = (self.seq + 1) & protocol.U32
        return msg

    def recv(self, timeout: float = 0.0, episode: int | None = None,
             step: int | None = None, spin_s: float = 0.0) -> protocol.Message | None:
        """The next accepted message within ``timeout`` s (dropped datagrams are counted by
        ``self.filter`` and waiting goes on); None if none came in time.  ``spin_s``: see
        :meth:`Endpoint.recv`."""
        deadline = time.perf_counter() + max(float(timeout), 0.0)
        while True:
            got = self.endpoint.recv(max(deadline - time.perf_counter(), 0.0), spin_s)
            if got is None:
                return None
            msg = self.take(got[0], got[1], episode, step)
            if msg is not None:
                return msg
            if time.perf_counter() >= deadline:
                return None

    def recv_all(self, episode: int | None = None, step: int | None = None,
                 limit: int = 4096) -> list[protocol.Message]:
        """Every datagram waiting now through the filter (each one accepted or counted under its
        reason by ``self.filter``); returns the accepted messages, in order."""
        out = []
        for data, addr in self.endpoint.recv_many(limit):
            msg = self.take(data, addr, episode, step)
            if msg is not None:
                out.append(msg)
        return out

    def take(self, data: bytes, addr: tuple, episode: int | None = None,
             step: int | None = None) -> protocol.Message | None:
        """One datagram through the filter: an accepted message for the caller; a handshake
        (HELLO, RESPONSE) to ``on_handshake``; a rejected one counted and reported to
        ``on_unauthenticated`` / ``on_stranger``.  The one path of :meth:`recv`, :meth:`recv_all`
        and the datagrams the target's real-time loop read (:mod:`impact_env.rig.wire`), so that
        all treat every datagram alike."""
        msg = self.filter.accept(data, episode, step, addr)
        if msg is not None and self.on_handshake is not None and msg.type in protocol.HANDSHAKE_TYPES:
            self.on_handshake(msg, addr)
            return None
        if msg is not None:
            self.last_sender = addr
            if self.on_accept is not None:
                self.on_accept(msg)
            return msg
        refusal, self.filter.refusal = self.filter.refusal, None
        if refusal is not None and self.on_refused is not None:
            self.on_refused(refusal, addr)
        if self.filter.last_unauth and self.on_unauthenticated is not None:
            self.on_unauthenticated(data, addr)
        self.filter.last_unauth = False
        if self.filter.last_stranger is not None:
            stranger, self.filter.last_stranger = self.filter.last_stranger, None
            if self.on_stranger is not None:
                self.on_stranger(stranger, addr)
        return None

    def request(
        self,
        body: protocol.Body,
        match: Callable[[protocol.Message], bool],
        what: str,
        timeout_s: float = 0.05,
        retries: int = 5,
        on_other: Callable[[protocol.Message], None] | None = None,
        addr: tuple | None = None,
    ) -> protocol.Message:
        """Send ``body`` and return the first accepted message for which ``match`` is true,
        re-sending after every ``timeout_s`` s without one, ``retries`` times at most.

        Other messages that arrive meanwhile go to ``on_other`` (or are dropped).  Raises
        :class:`RigTimeout` after ``(retries + 1) * timeout_s`` s without a match, and
        :class:`RigError` when an ERROR answers one of the attempts.
        """
        if not timeout_s > 0 or int(retries) < 0:
            raise ValueError(f"timeout_s = {timeout_s!r} s must be > 0 and retries = {retries!r} >= 0")
        seqs = set()
        t0 = time.perf_counter()
        for attempt in range(int(retries) + 1):
            sent = self.send(body, flags=protocol.FLAG_RETRY if attempt else 0, addr=addr)
            seqs.add(sent.seq)
            deadline = time.perf_counter() + timeout_s
            while (remaining := deadline - time.perf_counter()) > 0:
                msg = self.recv(remaining)
                if msg is None:
                    break
                if msg.type == protocol.MsgType.ERROR and msg.payload(protocol.Error).ref_seq in seqs:
                    err = msg.payload(protocol.Error)
                    raise RigError(what, err.code, err.text)
                if match(msg):
                    return msg
                if on_other is not None:
                    on_other(msg)
        raise RigTimeout(what, time.perf_counter() - t0, self.peer_name, int(retries) + 1)


# -- chunked transfers -----------------------------------------------------------------------------------
def upload_id(data: bytes) -> int:
    """The upload id of a file: the first 8 bytes of its sha256, as a little-endian u64."""
    return int.from_bytes(hashlib.sha256(data).digest()[:8], "little")


def upload(link: Link, data: bytes, timeout_s: float = 0.05, retries: int = 5,
           on_other: Callable[[protocol.Message], None] | None = None) -> int:
    """Send ``data`` (a policy file) as POLICY_CHUNKs, each acknowledged by an ACK whose value
    is the length the target holds, at least the chunk's end offset (more when it holds the file
    already: the same file uploaded again).  Returns the number of chunks; raises RigTimeout/RigError."""
    if len(data) > protocol.MAX_TRANSFER:
        raise ValueError(f"file of {len(data)} B exceeds {protocol.MAX_TRANSFER} B")
    uid = upload_id(data)
    offsets = range(0, max(len(data), 1), protocol.CHUNK_DATA)
    for off in offsets:
        piece = data[off:off + protocol.CHUNK_DATA]
        end = off + len(piece)

        def acked(m, end=end):
            b = m.body
            return (
                m.type == protocol.MsgType.ACK
                and b.acked_type == protocol.MsgType.POLICY_CHUNK
                and b.value >= end
            )

        reply = link.request(protocol.PolicyChunk(uid, len(data), off, piece), acked,
                             f"ACK of policy bytes {off}..{end} of {len(data)}", timeout_s, retries, on_other)
        ack = reply.payload(protocol.Ack)
        if ack.code != protocol.ErrorCode.OK:
            raise RigError(f"policy bytes {off}..{end}", ack.code, "chunk not accepted")
    return len(offsets)


def fetch(link: Link, resource: int, item: int = 0, sha256: bytes | None = None, timeout_s: float = 0.05,
          retries: int = 5, on_other: Callable[[protocol.Message], None] | None = None,
          max_total: int = protocol.MAX_TRANSFER) -> bytes:
    """Fetch a resource (``protocol.Resource``: the scene TOML, an episode's log) chunk by chunk;
    checks the total stays the same across chunks and, if given, the sha256 of the result."""
    parts: list[bytes] = []
    off, total = 0, None
    try:
        name = f"{protocol.Resource(resource).name} {item}"
    except ValueError:
        name = f"resource {resource} item {item}"
    while total is None or off < total:
        def answers(m, off=off):
            b = m.body
            return (
                m.type == protocol.MsgType.CHUNK
                and b.resource == resource
                and b.item == item
                and b.offset == off
            )

        reply = link.request(protocol.Fetch(resource, item, off, protocol.CHUNK_DATA), answers,
                             f"CHUNK of {name} at byte {off}", timeout_s, retries,
                             on_other).payload(protocol.Chunk)
        if total is None:
            total = reply.total
            if total > max_total:
                raise ValueError(f"{name} is {total} B, more than max_total = {max_total} B")
        elif reply.total != total:
            raise RigError(f"{name}", protocol.ErrorCode.BAD_REQUEST,
                           f"its size changed during the transfer ({total} -> {reply.total} B)")
        if not reply.data and off < total:
            raise RigError(f"{name}", protocol.ErrorCode.BAD_REQUEST, f"empty chunk at byte {off} of {total}")
        parts.append(reply.data)
        off += len(reply.data)
    out = b"".join(parts)
    if sha256 is not None and hashlib.sha256(out).digest() != sha256:
        raise RigError(
            f"{name}", protocol.ErrorCode.BAD_REQUEST, "sha256 of the fetched bytes does not match"
        )
    return out


# -- the target's side of the transfers -------------------------------------------------------------------
class UploadAssembler:
    """Collects an uploaded file from POLICY_CHUNKs (the target's side of :func:`upload`).

    Chunks extend a contiguous prefix: ``add`` takes a chunk that starts inside or at the end of
    what has arrived (a repeat is harmless) and returns the ACK to send, whose value is the
    length received so far; a chunk past that end is answered with code OUT_OF_RANGE.  A chunk of
    another upload id (a new file) starts over.  ``complete`` once ``total`` bytes are in and
    their sha256 starts with the upload id.
    """

    def __init__(self, max_bytes: int = 64 << 20):
        self.max_bytes = int(max_bytes)
        self.upload_id: int | None = None
        self.total = 0
        self._buf = bytearray()

    @property
    def received(self) -> int:
        return len(self._buf)

    @property
    def complete(self) -> bool:
        return (self.upload_id is not None and len(self._buf) == self.total
                and upload_id(bytes(self._buf)) == self.upload_id)

    @property
    def data(self) -> bytes:
        if not self.complete:
            raise ValueError(f"upload incomplete: {len(self._buf)} of {self.total} B "
                             f"(or its sha256 does not match the upload id)")
        return bytes(self._buf)

    def add(self, chunk: protocol.PolicyChunk, seq: int = 0) -> protocol.Ack:
        if chunk.upload_id != self.upload_id or chunk.total != self.total:
            if chunk.total > self.max_bytes:
                return protocol.Ack(protocol.MsgType.POLICY_CHUNK, protocol.ErrorCode.OUT_OF_RANGE, seq, 0)
            self.upload_id, self.total, self._buf = chunk.upload_id, chunk.total, bytearray()
        end = chunk.offset + len(chunk.data)
        if chunk.offset > len(self._buf):
            return protocol.Ack(
                protocol.MsgType.POLICY_CHUNK, protocol.ErrorCode.OUT_OF_RANGE, seq, len(self._buf)
            )
        if end > len(self._buf):
            self._buf[chunk.offset:] = chunk.data
        return protocol.Ack(protocol.MsgType.POLICY_CHUNK, protocol.ErrorCode.OK, seq, len(self._buf))


def chunk_reply(data: bytes, request: protocol.Fetch, seq: int = 0) -> protocol.Chunk | protocol.Error:
    """The CHUNK answering ``request`` (of sequence number ``seq``) for the resource bytes
    ``data`` (the target's side of :func:`fetch`), or an ERROR (OUT_OF_RANGE) for an offset past
    the end."""
    if request.offset > len(data):
        return protocol.Error(
            protocol.ErrorCode.OUT_OF_RANGE, seq, f"offset {request.offset} B is past the end ({len(data)} B)"
        )
    n = min(request.max_len, protocol.CHUNK_DATA)
    return protocol.Chunk(request.resource, request.item, len(data), request.offset,
                   bytes(data[request.offset:request.offset + n]))
