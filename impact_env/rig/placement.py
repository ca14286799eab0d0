"""Where and how the target's threads run: the real-time loop on a core of its own, under
``SCHED_FIFO`` where the process may, Python elsewhere, and a host on the same machine off the
loop's core.

The compiled loop spins on its core between ticks (:mod:`impact_env.rig.rtloop`).  Whatever
else runs on that core takes it from the loop for a scheduler's time slice (milliseconds), and
the loop skips ticks; a stretch of more than the target's ``max_gap`` (1 ms) ends the episode
OVERRUN.  So, with no setting made by hand, the target applies what it is permitted to:

* **pinning**: on a machine with two CPUs or more allowed to the process, the loop's thread runs
  on one CPU (the last allowed one, where ``isolcpus=`` usually leaves a core for such work;
  ``rig serve --loop-cpu N`` chooses another, ``-1`` none) and the target's other threads on the
  rest, the log writer at nice +10;
* **SCHED_FIFO** (priority :data:`AUTO_FIFO`) where the process may (root, ``CAP_SYS_NICE``, or
  an ``rtprio`` limit): no ordinary thread preempts the loop; ``--loop-fifo PRIO`` picks the
  priority, ``--loop-fifo 0`` keeps the normal policy;
* **mlockall** where the memory-lock limit allows it: no page fault in a tick;
* **a host on the same machine keeps off the loop's CPU**: the target names its loop's CPU in a
  file of this user's (:func:`publish_loop_cpu`) and a host whose target is on this machine moves
  itself to the other CPUs while it runs (:func:`keep_off_loop_cpu`, called by the host's client).

Real-time throttling.  While ``kernel.sched_rt_runtime_us`` is not -1 (the default: 950 ms of
each second of ``sched_rt_period_us``), the kernel takes the CPU from a real-time thread that
used more than that share of the period, for the rest of it: a loop that spins through
back-to-back episodes stops for about 50 ms.  The loop spins all the same (sleeping between ticks
on a virtual machine wakes it late by up to milliseconds: the vCPU halts), and keeps within the
share instead: before an episode it rests long enough that its share of time spinning stays at
:data:`RT_SHARE` of what the kernel allows (about 0.07 s after a 0.4 s episode); an episode
longer than :data:`RT_SPIN_LIMIT` of the allowance sleeps until :data:`SLEEP_MARGIN_S` before
each tick and spins the rest.  ``impact-env rig check`` measures what each costs here.
"""

from __future__ import annotations

import contextlib
import ctypes
import ipaddress
import json
import os
import resource
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

# a real-time loop that must sleep (an episode longer than the kernel lets a real-time thread
# spin) sleeps until this long before each tick's deadline, then spins
SLEEP_MARGIN_S = 50e-6
AUTO_FIFO = 50  # the SCHED_FIFO priority applied where permitted (PREEMPT_RT's IRQ threads run at 50)
RT_SHARE = 0.85  # of the kernel's real-time allowance, the share of time the loop spins at most
RT_SPIN_LIMIT = 0.8  # an episode longer than this share of the allowance (s) sleeps between ticks


def _allowed() -> list[int]:
    try:
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return []


def _read_int(path: str) -> int | None:
    try:
        return int(Path(path).read_text())
    except (OSError, ValueError):
        return None


def rt_allowance() -> tuple[float, float] | None:
    """(runtime, period) in s of the kernel's real-time throttling, or None where it is off
    (``kernel.sched_rt_runtime_us`` -1)."""
    runtime = _read_int("/proc/sys/kernel/sched_rt_runtime_us")
    period = _read_int("/proc/sys/kernel/sched_rt_period_us") or 1_000_000
    if runtime == -1:
        return None
    return (0.95 if runtime is None else runtime / 1e6), period / 1e6


def rt_throttled() -> bool:
    """Whether the kernel throttles real-time threads (sched_rt_runtime_us is not -1)."""
    return rt_allowance() is not None


def _may_fifo(prio: int) -> str | None:
    """None if this thread may take SCHED_FIFO at ``prio`` (tried and set back), else why not."""
    tid = threading.get_native_id()
    try:
        was, param = os.sched_getscheduler(tid), os.sched_getparam(tid)
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(int(prio)))
        os.sched_setscheduler(tid, was, param)
        return None
    except (OSError, AttributeError) as exc:
        return getattr(exc, "strerror", None) or str(exc)


MCL_CURRENT, MCL_FUTURE = 1, 2
CAP_IPC_LOCK = 14  # linux/capability.h: lock memory beyond RLIMIT_MEMLOCK


def _has_capability(bit: int) -> bool:
    """Whether this process's effective capabilities hold capability ``bit`` (/proc/self/status)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("CapEff:"):
                return bool(int(line.split()[1], 16) >> bit & 1)
    except (OSError, ValueError, IndexError):
        pass
    return False


def lock_memory() -> str | None:
    """``mlockall(MCL_CURRENT | MCL_FUTURE)`` where the memory-lock limit is unlimited or the
    process holds CAP_IPC_LOCK (under a lower limit later allocations would fail); None on success,
    else why not."""
    soft, _hard = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    if soft != resource.RLIM_INFINITY and not _has_capability(CAP_IPC_LOCK):
        return f"the memory-lock limit is {soft // 1024} KiB (ulimit -l), not unlimited"
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
        return os.strerror(ctypes.get_errno())
    return None


@dataclass
class Placement:
    """The target's thread placement and scheduling (see the module doc).  ``loop_cpu``: the
    loop's CPU (None: the last allowed one when there are two or more; -1: no pinning);
    ``loop_nice``: the loop thread's nice value (0: unchanged); ``loop_fifo``: its SCHED_FIFO
    priority (None: :data:`AUTO_FIFO` where permitted, else the normal policy; 0: the normal
    policy; 1-99: that priority, an error where not permitted)."""

    loop_cpu: int | None = None
    loop_nice: int = 0
    loop_fifo: int | None = 0
    #: what was applied, and what could not be with what that costs (rig serve prints both)
    applied: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)

    def __post_init__(self):
        allowed = _allowed()
        if self.loop_cpu is None:
            self.loop_cpu = allowed[-1] if len(allowed) >= 2 else -1
        elif self.loop_cpu != -1 and self.loop_cpu not in allowed:
            raise ValueError(f"loop_cpu = {self.loop_cpu} is not a CPU this process may run on "
                             f"({allowed}; -1: no pinning)")
        if not -20 <= int(self.loop_nice) <= 19:
            raise ValueError(f"loop_nice = {self.loop_nice} must be in [-20, 19]")
        self.others = {c for c in allowed if c != self.loop_cpu} if self.loop_cpu != -1 else set()
        auto = self.loop_fifo is None
        if not auto and not 0 <= int(self.loop_fifo or 0) <= 99:
            raise ValueError(f"loop_fifo = {self.loop_fifo} must be a SCHED_FIFO priority in [1, 99] "
                             "(0: none)")
        if auto:  # what this process may: applied, or said with its cost
            why = _may_fifo(AUTO_FIFO)
            self.loop_fifo = AUTO_FIFO if why is None else 0
            if why is not None:
                self.missing.append(
                    f"SCHED_FIFO ({why}: needs root, CAP_SYS_NICE or an rtprio limit): the loop runs as an "
                    "ordinary thread, and any process the scheduler puts on its CPU takes slices of "
                    "milliseconds from it (ticks skipped, episodes ending OVERRUN)")
        elif self.loop_fifo:  # asked for by name: refused now, not mid-episode
            why = _may_fifo(int(self.loop_fifo))
            if why is not None:
                raise ValueError(f"loop_fifo = {self.loop_fifo} needs root or CAP_SYS_NICE ({why}); "
                                 "leave it at 0") from None
        if self.loop_nice < 0:  # may this process raise a thread's priority? (asked now, not mid-episode)
            tid = threading.get_native_id()
            was = os.getpriority(os.PRIO_PROCESS, tid)
            try:
                os.setpriority(os.PRIO_PROCESS, tid, int(self.loop_nice))
                os.setpriority(os.PRIO_PROCESS, tid, was)
            except OSError as exc:
                raise ValueError(f"loop_nice = {self.loop_nice} needs root or CAP_SYS_NICE ({exc.strerror}); "
                                 "leave it at 0") from None
        self.auto = auto
        self._spun_s = 0.0  # the last episode's spin (s), and when it ended (perf_counter)
        self._spun_end = -1e9
        if self.pinned:
            self.applied.append(f"the loop pinned to CPU {self.loop_cpu}, the target's Python threads to "
                                f"{sorted(self.others)}")
            if len(allowed) < 3:
                rest = ", ".join(map(str, sorted(self.others)))
                self.missing.append(
                    f"a CPU for a host on this machine (only {len(allowed)} CPUs, the loop's being the "
                    f"loop's): a host here shares CPU {rest} with the target's Python threads and every "
                    "other process, and its COMMANDs come late whenever they are busy (the host on another "
                    "machine, or a third CPU, gives it one of its own)")
        elif self.loop_cpu == -1 and len(allowed) >= 2:
            self.missing.append("pinning (--loop-cpu -1): the target's own threads share the loop's CPU")
        else:
            self.missing.append("pinning (one CPU): the target's own threads and every other process share "
                                "the loop's CPU")
        if self.loop_fifo:
            allowance = rt_allowance()
            self.applied.append(f"SCHED_FIFO {self.loop_fifo} for the loop" + (
                "" if allowance is None else
                f" (the kernel lets real-time threads run {allowance[0] / allowance[1]:.0%} of each "
                f"{allowance[1]:g} s: the loop rests between episodes to stay within {RT_SHARE:.0%} of that, "
                f"and an episode longer than {RT_SPIN_LIMIT * allowance[0]:.2f} s sleeps to "
                f"{SLEEP_MARGIN_S * 1e6:g} us before each tick)"))
        if self.loop_nice:
            self.applied.append(f"nice {self.loop_nice} for the loop")

    def lock_memory(self) -> None:
        """mlockall where permitted (``rig serve``; a test process keeps its memory as it is)."""
        why = lock_memory()
        if why is None:
            self.applied.append("mlockall: the process's memory locked (no page fault in a tick)")
        else:
            self.missing.append(f"mlockall ({why}): a page fault in a tick can make it late (ulimit -l "
                                "unlimited, or CAP_IPC_LOCK)")

    @property
    def pinned(self) -> bool:
        return self.loop_cpu != -1 and bool(self.others)

    def describe(self) -> str:
        """One line for ``rig serve``'s start."""
        if not self.pinned:
            return "the real-time loop is not pinned (one CPU, or --loop-cpu -1)"
        nice = f", nice {self.loop_nice}" if self.loop_nice else ""
        if self.loop_fifo:
            nice += f", SCHED_FIFO {self.loop_fifo}"
        return (f"the real-time loop runs on CPU {self.loop_cpu}{nice}, the target's Python threads on "
                f"{sorted(self.others)}")

    def loop_thread(self) -> None:
        """Called by the loop's thread before the episode: its CPU, its nice value and policy,
        after the rest the kernel's real-time allowance asks for (module doc)."""
        allowance = rt_allowance() if self.loop_fifo else None
        if allowance is not None and self._spun_s > 0.0:
            runtime, period = allowance
            rest = self._spun_s * (period / (RT_SHARE * runtime) - 1.0)
            wait = self._spun_end + rest - time.perf_counter()
            if wait > 0.0:
                time.sleep(min(wait, period))
        self._started = time.perf_counter()
        tid = threading.get_native_id()
        if self.pinned:
            os.sched_setaffinity(0, {int(self.loop_cpu or 0)})  # 0: the calling thread (Linux)
            if self.loop_nice:
                os.setpriority(os.PRIO_PROCESS, tid, int(self.loop_nice))
        if self.loop_fifo:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(int(self.loop_fifo)))

    def loop_done(self) -> None:
        """Called by the loop's thread when the episode's loop returns."""
        now = time.perf_counter()
        self._spun_s = now - getattr(self, "_started", now)
        self._spun_end = now

    def sleep_margin_for(self, episode_s: float) -> float:
        """How long before each deadline the loop stops sleeping and spins, for an episode of
        ``episode_s`` (0: it spins throughout): a SCHED_FIFO loop sleeps where the kernel throttles
        real-time threads and the episode is longer than it lets one spin (module doc)."""
        allowance = rt_allowance() if self.loop_fifo else None
        if allowance is None or episode_s <= RT_SPIN_LIMIT * allowance[0]:
            return 0.0
        return SLEEP_MARGIN_S

    @property
    def sleep_margin_s(self) -> float:
        """:meth:`sleep_margin_for` an episode that spins as long as the kernel allows."""
        return self.sleep_margin_for(0.0)

    def python_thread(self) -> Callable[[], None]:
        """Called by a Python thread of the target for the episode; returns what restores it."""
        if not self.pinned:
            return lambda: None
        before = os.sched_getaffinity(0)
        os.sched_setaffinity(0, self.others)
        return lambda: os.sched_setaffinity(0, before)

    def background_thread(self) -> None:
        """Called by a thread that can wait (the log writer): off the loop's CPU, low priority."""
        if not self.pinned:
            return
        os.sched_setaffinity(0, self.others)
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 10)
        except OSError:
            pass


# -- a host on the target's machine keeps off the loop's CPU ---------------------------------------------
def _hint_dir() -> Path:
    base = os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()
    return Path(base) / f"impact-env-rig-{os.getuid()}"


def _hint_file(port: int) -> Path:
    return _hint_dir() / f"{int(port)}.json"


def publish_loop_cpu(port: int, cpu: int) -> Callable[[], None]:
    """The target on UDP ``port`` says which CPU its loop spins on, for a host of this user on
    this machine (:func:`keep_off_loop_cpu`); returns what removes the note."""
    path = _hint_file(port)
    try:
        path.parent.mkdir(mode=0o700, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps({"pid": os.getpid(), "loop_cpu": int(cpu)}))
        os.replace(tmp, path)
    except OSError:
        return lambda: None

    def remove() -> None:
        with contextlib.suppress(OSError):
            if json.loads(path.read_text()).get("pid") == os.getpid():
                path.unlink()
    return remove


def _is_local(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback or host in _local_addresses()
    except ValueError:
        return host == "localhost"


def _local_addresses() -> set[str]:
    import socket

    try:
        return {str(a[4][0]) for a in socket.getaddrinfo(socket.gethostname(), None)}
    except OSError:
        return set()


def loop_cpu_of(host: str, port: int) -> int | None:
    """The CPU the loop of the target at ``host:port`` spins on, if that target runs on this
    machine as this user and said so (:func:`publish_loop_cpu`), else None."""
    if not _is_local(host):
        return None
    try:
        note = json.loads(_hint_file(port).read_text())
        os.kill(int(note["pid"]), 0)  # the target that wrote it is alive
        return int(note["loop_cpu"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def keep_off_loop_cpu(host: str, port: int) -> Callable[[], None]:
    """A host whose target runs on this machine moves this process off the target's loop CPU
    (where another CPU is left to it); returns what restores its CPUs."""
    cpu = loop_cpu_of(host, port)
    allowed = set(_allowed())
    if cpu is None or cpu not in allowed or len(allowed) < 2:
        return lambda: None
    try:
        os.sched_setaffinity(0, allowed - {cpu})
    except OSError:
        return lambda: None

    def restore() -> None:
        with contextlib.suppress(OSError):
            os.sched_setaffinity(0, allowed)
    return restore
