"""Run independent tasks over the machine's cores, with one progress bar fed by every worker.

Workers are forked where the platform allows it (Linux), after the caller has compiled the
kernels once (``warm_up``), so that no worker compiles or loads them again; elsewhere they are
spawned.  Each worker reports progress as counts through a queue; the parent draws a ``tqdm``
bar if tqdm is installed, else a one-line counter on stderr.  Results come back in task order,
so the outcome never depends on the number of workers or on scheduling.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue as _queue
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

_QUEUE = None


def report(count: int) -> None:
    """Called inside a task: ``count`` more units of work are done."""
    if _QUEUE is not None:
        _QUEUE.put(count)
    elif _LOCAL is not None:
        _LOCAL.update(count)


_LOCAL = None


def _init(q) -> None:
    global _QUEUE
    _QUEUE = q


class Progress:
    """A progress bar: tqdm if installed, else ``desc: 45% (1234/2730)`` rewritten on stderr (one
    line per tenth when stderr is not a terminal).  Silent when ``enabled`` is false."""

    def __init__(self, total: int, desc: str, enabled: bool = True):
        self.total, self.desc, self.done, self.enabled = max(int(total), 1), desc, 0, enabled
        self._bar = None
        self._last = 0.0
        self._tty = sys.stderr.isatty()
        if enabled:
            try:
                from tqdm import tqdm

                self._bar = tqdm(total=self.total, desc=desc, unit="step", file=sys.stderr, leave=False)
            except ImportError:
                self._bar = None

    def update(self, n: int) -> None:
        self.done += n
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(n)
            return
        pct = 100.0 * self.done / self.total
        if not self._tty:  # a log file: one line per tenth, no carriage returns
            if int(pct // 10) > self._last or self.done >= self.total:
                self._last = int(pct // 10)
                print(f"{self.desc}: {pct:5.1f}% ({self.done}/{self.total})", file=sys.stderr, flush=True)
            return
        now = time.monotonic()
        if now - self._last > 0.5 or self.done >= self.total:
            self._last = now
            print(f"\r{self.desc}: {pct:5.1f}% ({self.done}/{self.total})", end="", file=sys.stderr,
                  flush=True)

    def close(self) -> None:
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.close()
        elif self._tty:
            print("\r" + " " * (len(self.desc) + 40) + "\r", end="", file=sys.stderr, flush=True)


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def run_tasks(fn: Callable[[Any], Any], tasks: Sequence[Any], workers: int, total: int, desc: str,
              progress: bool = True) -> list[Any]:
    """``[fn(task) for task in tasks]``, over ``workers`` processes, with a progress bar of
    ``total`` units that the tasks advance with :func:`report`.  Exceptions in a task propagate."""
    global _LOCAL
    bar = Progress(total, desc, progress)
    try:
        if workers <= 1 or len(tasks) <= 1:
            _LOCAL = bar
            try:
                return [fn(t) for t in tasks]
            finally:
                _LOCAL = None
        method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
        ctx = mp.get_context(method)
        q = ctx.Queue()
        with ctx.Pool(min(workers, len(tasks)), initializer=_init, initargs=(q,)) as pool:
            pending = [pool.apply_async(fn, (t,)) for t in tasks]
            while not all(p.ready() for p in pending):
                _drain(q, bar, timeout=0.1)
            _drain(q, bar, timeout=0.0)
            return [p.get() for p in pending]
    finally:
        bar.close()


def _drain(q, bar: Progress, timeout: float) -> None:
    try:
        bar.update(q.get(timeout=timeout) if timeout else q.get_nowait())
        while True:
            bar.update(q.get_nowait())
    except _queue.Empty:
        pass
