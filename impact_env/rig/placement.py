"""Where the target's threads run: the real-time loop on a core of its own, Python elsewhere.

The compiled loop spins on its core between ticks (:mod:`impact_env.rig.rtloop`); the target's
Python threads (the network's, the log writer's) and whatever else the machine runs must not
take that core from it, or the loop is preempted for a scheduler's time slice (milliseconds) and
ticks are skipped.  So, on a machine with two CPUs or more allowed to the process, the loop's
thread is pinned to one CPU (the last allowed one, where ``isolcpus=`` usually leaves a core for
such work; ``rig serve --loop-cpu N`` chooses another) and the target's other threads to the
rest, for the length of the episode; the log writer also yields to the host's process
(``nice`` +10: it writes every 50 ms and can wait).  ``loop_nice`` (``--loop-nice``, e.g. -10)
raises the loop's priority where the process may (root, or CAP_SYS_NICE); a real-time policy
(``SCHED_FIFO``) is not used for a thread that spins: the kernel's real-time throttling would
stop it for 50 ms every second.  With one CPU, or ``--loop-cpu -1``, nothing is pinned.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from dataclasses import dataclass, field


def _allowed() -> list[int]:
    try:
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return []


@dataclass
class Placement:
    """The target's thread placement (see the module doc).  ``loop_cpu``: the loop's CPU (None:
    the last allowed one when there are two or more; -1: no pinning); ``loop_nice``: the loop
    thread's nice value (0: unchanged)."""

    loop_cpu: int | None = None
    loop_nice: int = 0
    notes: list[str] = field(default_factory=list)

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
        return (f"the real-time loop runs on CPU {self.loop_cpu}{nice}, the target's Python threads on "
                f"{sorted(self.others)}")

    def loop_thread(self) -> None:
        """Called by the loop's thread before the episode."""
        if not self.pinned:
            return
        os.sched_setaffinity(0, {int(self.loop_cpu or 0)})  # 0: the calling thread (Linux)
        if self.loop_nice:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), int(self.loop_nice))

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
