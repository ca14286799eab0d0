"""Helpers of the rig tests: a target process on loopback, and a lossy UDP proxy between a host
and a target (loss, bursts, duplicates, reordering; seeded, bounded in time)."""

from __future__ import annotations

import os
import random
import re
import select
import socket
import subprocess
import threading
import time
from pathlib import Path

from impact_env.rig.loopback import FLOOD, serve, stop  # noqa: F401  (the tests import them from here)

ROOT = Path(__file__).resolve().parent.parent


def slow_rate_args(rate_hz: float) -> tuple[str, ...]:
    """``rig serve`` options for the rig scene at a control rate far below its 10 kHz (a target a
    delayed host can answer with margins of milliseconds): the rate, and the sensors' filters off
    (their 20-1000 Hz bands need a Nyquist frequency above 1 kHz)."""
    filters = ("accelerometer", "force", "potentiometer", "body1_displacement")
    return ("--set", f"control.rate={rate_hz:g}",
            *(a for f in filters for a in ("--set", f'effects.filters.{f}.kind="none"')))


def start_target(*args: str, timeout_s: float = 300.0,
                 driver: str | None = None) -> tuple[subprocess.Popen, str]:
    """:func:`impact_env.rig.loopback.serve` with the tests' defaults: the repository on
    PYTHONPATH (so that ``tests.rig_drivers`` imports for ``driver``); ``--max-gap 1000`` (ms)
    unless ARGS give one (the 1 ms default would end episodes OVERRUN whenever this shared
    machine preempts the loop, which is not what most tests test); ``--loop-fifo 0`` unless ARGS
    give one."""
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
    if "--max-gap" not in args:  # a shared, loaded machine preempts the loop for ms: only the tests
        args = (*args, "--max-gap", "1000")  # of the gap limit itself (a driver's injected stall) keep 1 ms
    if "--loop-fifo" not in args:  # a real-time target's default is a SCHED_FIFO spinner where
        # permitted (root): tests run beside each other (pytest -n auto), and two FIFO spinners on
        # one CPU would starve each other and the tests' own processes; the tests inject lateness
        # instead, and tests/test_rig_check.py tests the placement with fakes
        args = (*args, "--loop-fifo", "0")
    return serve(*args, timeout_s=timeout_s, driver=driver, cwd=ROOT, env=dict(os.environ, PYTHONPATH=path))


def streamed_ticks(folder: Path) -> int:
    """The most rows a target's streamed log (``*.partial``) in ``folder`` has on disk now (0:
    none readable yet): read without HDF5's file lock, which the target holds while it writes,
    and retried by the caller if a read meets a half-written file."""
    import h5py

    most = 0
    for path in Path(folder).glob("*.partial"):
        try:
            with h5py.File(path, "r", locking=False) as f:
                most = max(most, int(f.attrs["n_ticks"]))
        except (OSError, KeyError, ValueError):
            continue
    return most


class LossyProxy:
    """A UDP relay between a host and a target: datagrams from the host go to the target and back,
    each dropped with probability ``loss`` (in bursts of ``burst`` datagrams), duplicated with
    ``dup``, and held back to be sent after the next one with ``reorder``; with ``cut`` set, every
    datagram from the host is dropped (counted ``cut``); ``drop_first``: message type -> how many
    of the target's first datagrams of that type to drop (counted ``dropped_by_type``).  The host sees the proxy at 127.0.0.2
    (``address``), the target on 127.0.0.1: once the target's INFO names its session's port, the
    proxy listens on 127.0.0.2 at that port too and relays it to the target's session socket (as
    a router that forwards the session's port).  Runs in a thread until ``close`` (or ``max_s``)."""

    def __init__(self, target: str, loss: float = 0.0, dup: float = 0.0, reorder: float = 0.0, burst: int = 1,
                 seed: int = 0, max_s: float = 120.0, drop_first: dict[int, int] | None = None):
        host, port = re.match(r"udp://([^:]+):(\d+)", target).groups()
        self.target = (host, int(port))
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.2", 0))
        self.address = f"udp://127.0.0.2:{self.sock.getsockname()[1]}"
        self.up = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.up.bind(("127.0.0.1", 0))
        self.loss, self.dup, self.reorder, self.burst = loss, dup, reorder, max(1, int(burst))
        self.cut = False
        self.rng = random.Random(seed)
        self.client = None
        self.counts = {"forwarded": 0, "dropped": 0, "duplicated": 0, "reordered": 0, "cut": 0}
        self.drop_first = dict(drop_first or {})
        self.dropped_by_type: dict[int, int] = {}
        self._dropping = 0
        self._held = {}
        # the target's session ports: the proxy's listener for each, and back
        self._listeners: dict[int, socket.socket] = {}
        self._stop = threading.Event()
        self._deadline = time.monotonic() + max_s
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _pass(self, sock, data, dest) -> None:
        if self._dropping == 0 and self.rng.random() < self.loss:
            self._dropping = self.burst
        if self._dropping:
            self._dropping -= 1
            self.counts["dropped"] += 1
            return
        held = self._held.pop(id(sock), None)
        if self.rng.random() < self.reorder and held is None:
            self._held[id(sock)] = (data, dest)
            self.counts["reordered"] += 1
            return
        copies = 2 if self.rng.random() < self.dup else 1
        self.counts["duplicated"] += copies - 1
        for _ in range(copies):
            sock.sendto(data, dest)
            self.counts["forwarded"] += 1
        if held is not None:
            sock.sendto(*held)
            self.counts["forwarded"] += 1

    def _listen(self, data: bytes) -> None:
        """An INFO (type 2) names the session's port (payload bytes 72..73): listen there."""
        if len(data) >= 42 + 74 and data[:4] == b"IMPR" and data[6] == 2:
            port = int.from_bytes(data[42 + 72:42 + 74], "little")
            if port and port not in self._listeners:
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                s.bind(("127.0.0.2", port))
                self._listeners[port] = s

    def _run(self) -> None:
        while not self._stop.is_set() and time.monotonic() < self._deadline:
            socks = [self.sock, self.up, *self._listeners.values()]
            ready, _, _ = select.select(socks, [], [], 0.05)
            for s in ready:
                try:
                    data, addr = s.recvfrom(70000)
                except OSError:
                    return
                if s is self.up:  # from the target: back to the host, from the matching address
                    self._listen(data)
                    kind = data[6] if len(data) > 6 and data[:4] == b"IMPR" else -1
                    if self.drop_first.get(kind, 0) > 0:
                        self.drop_first[kind] -= 1
                        self.dropped_by_type[kind] = self.dropped_by_type.get(kind, 0) + 1
                        continue
                    back = self._listeners.get(addr[1], self.sock)
                    if self.client is not None:
                        self._pass(back, data, self.client)
                    continue
                self.client = addr
                if self.cut:
                    self.counts["cut"] += 1
                    continue
                port = s.getsockname()[1] if s is not self.sock else self.target[1]
                self._pass(self.up, data, (self.target[0], port))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.sock.close()
        self.up.close()
        for s in self._listeners.values():
            s.close()



def udp_receive_queue(port: int) -> int | None:
    """Bytes waiting in the receive queue of the UDP socket bound to local ``port``, from Linux's
    ``/proc/net/udp``; None where there is no such file or socket."""
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if int(fields[1].rsplit(":", 1)[1], 16) == port:
                return int(fields[4].split(":")[1], 16)
    return None


def wait_read(port: int, timeout_s: float = 10.0) -> None:
    """Wait until the target has read every datagram waiting for it on ``port`` (its socket's
    receive queue is empty), so that a count it prints when stopped holds them all."""
    deadline = time.monotonic() + timeout_s
    while (udp_receive_queue(port) or 0) > 0 and time.monotonic() < deadline:
        time.sleep(0.01)
