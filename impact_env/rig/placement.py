"""Where the target's threads run: the real-time loop on a core of its own, Python elsewhere.

The compiled loop spins on its core between ticks (:mod:`impact_env.rig.rtloop`); the target's
Python threads (the network's, the log writer's) and whatever else the machine runs must not
take that core from it, or the loop is preempted for a scheduler's time slice (milliseconds) and
ticks are skipped.  So, on a machine with two CPUs or more allowed to the process, the loop's
thread is pinned to one CPU (the last allowed one, where ``isolcpus=`` usually leaves a core for
such work; ``rig serve --loop-cpu N`` chooses another) and the target's other threads to the
rest, for the length of the episode; the log writer also yields to the host's process
(``nice`` +10: it writes every 50 ms and can wait).

Pinning keeps the target's own threads off the loop's core, not the rest of the machine: a
process of normal priority that the scheduler puts there still takes time slices from a loop of
normal priority (nice values do not order processes of different sessions on a desktop Linux
with autogroup, either).  So, where the process may (root, or CAP_SYS_NICE):
``--loop-fifo PRIO`` gives the loop's thread the real-time policy ``SCHED_FIFO``, which no
normal thread preempts.  Such a thread must not spin without end while the kernel's real-time
throttling is on (``/proc/sys/kernel/sched_rt_runtime_us`` not -1: it would stop the thread for
50 ms of every second), so the loop then sleeps (``clock_nanosleep``) until 50 us before each
deadline and spins only the rest, which needs a kernel whose timer wakes a thread well within
50 us (a PREEMPT_RT kernel on bare metal; not this project's 2-vCPU VM, where it wakes 10-60 us
late).  Where the throttling is off (``-1``, as real-time guides set it for a busy-polling
thread on an isolated core), the SCHED_FIFO loop spins.
``--loop-nice N`` is the milder option (a nice value for the loop's thread).  With one CPU, or
``--loop-cpu -1``, nothing is pinned.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from dataclasses import dataclass

# a SCHED_FIFO loop sleeps until this long before each tick's deadline, then spins: a real-time
# thread that spun all the time would be throttled by the kernel (sched_rt_runtime_us: 50 ms of
# each second) and would starve its core; 50 us covers a virtual machine's timer wake-up
SLEEP_MARGIN_S = 50e-6


def _allowed() -> list[int]:
    try:
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return []


def rt_throttled() -> bool:
    """Whether the kernel throttles real-time threads (sched_rt_runtime_us is not -1)."""
    try:
        return int(open("/proc/sys/kernel/sched_rt_runtime_us").read()) != -1
    except (OSError, ValueError):
        return True


@dataclass
class Placement:
    """The target's thread placement (see the module doc).  ``loop_cpu``: the loop's CPU (None:
    the last allowed one when there are two or more; -1: no pinning); ``loop_nice``: the loop
    thread's nice value (0: unchanged)."""

    loop_cpu: int | None = None
    loop_nice: int = 0
    loop_fifo: int = 0  # SCHED_FIFO priority of the loop's thread, 1-99 (0: the normal policy)

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
        if not 0 <= int(self.loop_fifo) <= 99:
            raise ValueError(f"loop_fifo = {self.loop_fifo} must be a SCHED_FIFO priority in [1, 99] (0: none)")
        if self.loop_fifo:  # may this process use a real-time policy? (asked now, not mid-episode)
            tid = threading.get_native_id()
            try:
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(int(self.loop_fifo)))
                os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
            except OSError as exc:
                raise ValueError(f"loop_fifo = {self.loop_fifo} needs root or CAP_SYS_NICE ({exc.strerror}); "
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

    @property
    def pinned(self) -> bool:
        return self.loop_cpu != -1 and bool(self.others)

    def describe(self) -> str:
        """One line for ``rig serve``'s start."""
        if not self.pinned:
            return "the real-time loop is not pinned (one CPU, or --loop-cpu -1)"
        nice = f", nice {self.loop_nice}" if self.loop_nice else ""
        if self.loop_fifo:
            nice += (f", SCHED_FIFO {self.loop_fifo} (" + (f"sleeping to {SLEEP_MARGIN_S * 1e6:g} us before each "
                     "tick: the kernel throttles real-time threads)" if rt_throttled() else "spinning: the "
                     "kernel's real-time throttling is off)"))
        return (f"the real-time loop runs on CPU {self.loop_cpu}{nice}, the target's Python threads on "
                f"{sorted(self.others)}")

    def loop_thread(self) -> None:
        """Called by the loop's thread before the episode."""
        if not self.pinned:
            if self.loop_fifo:
                os.sched_setscheduler(threading.get_native_id(), os.SCHED_FIFO, os.sched_param(int(self.loop_fifo)))
            return
        os.sched_setaffinity(0, {int(self.loop_cpu or 0)})  # 0: the calling thread (Linux)
        if self.loop_nice:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), int(self.loop_nice))
        if self.loop_fifo:
            os.sched_setscheduler(threading.get_native_id(), os.SCHED_FIFO, os.sched_param(int(self.loop_fifo)))

    @property
    def sleep_margin_s(self) -> float:
        """How long before each deadline the loop stops sleeping and spins (0: it never sleeps):
        a SCHED_FIFO loop sleeps while the kernel's real-time throttling is on."""
        return SLEEP_MARGIN_S if self.loop_fifo and rt_throttled() else 0.0

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
