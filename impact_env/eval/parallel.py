"""Run independent tasks over the machine's cores, or over a cluster, with one progress bar.

Locally (the default), workers are forked where the platform allows it (Linux), after the caller
has compiled the kernels once (:func:`prepare`), so that no worker compiles or loads them again;
elsewhere they are spawned.  Each worker reports progress as counts through a queue; the parent
draws a ``tqdm`` bar if tqdm is installed, else a one-line counter on stderr.

On a cluster (``--cluster tcp://SCHEDULER:PORT``: a Dask distributed scheduler, :class:`Cluster`),
the same tasks go to the cluster's workers as they are, one Dask task each, and the bar moves as
tasks finish.  Dask is an optional extra (``pip install 'impact-env[cluster]'``), imported only
when a cluster is asked for.

Either way :func:`run_tasks` returns ``[fn(task) for task in tasks]`` in task order: the tasks,
their seeds and the merge are the caller's and the same whatever runs them, so the outcome never
depends on the number of workers, on scheduling, or on where the tasks ran (docs/cluster.md).
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import queue as _queue
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any
from urllib.parse import urlsplit

from impact_env.config import ConfigError

_QUEUE = None
CLUSTER_HINT = "pip install 'impact-env[cluster]'"
CONNECT_TIMEOUT_S = 10.0


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
              progress: bool = True, cluster: Cluster | None = None) -> list[Any]:
    """``[fn(task) for task in tasks]``, over ``workers`` processes (or on ``cluster``'s workers),
    with a progress bar of ``total`` units that the tasks advance with :func:`report` (on a
    cluster: as whole tasks finish).  Exceptions in a task propagate."""
    global _LOCAL
    bar = Progress(total, desc, progress)
    try:
        if cluster is not None:
            return cluster.map(fn, tasks, bar, total)
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


def prepare(fn: Callable[..., Any], *args: Any, workers: int, cluster: Cluster | None = None) -> None:
    """Compile (or load) the kernels before the tasks run: ``fn(*args)`` in this process when a
    local pool of ``workers`` > 1 will be forked from it, once on every worker of ``cluster``."""
    if cluster is not None:
        cluster.on_every_worker(fn, *args)
    elif workers > 1:
        fn(*args)


# -- a cluster: Dask distributed --------------------------------------------------------------------
def parse_cluster(address: str, option: str = "--cluster") -> str:
    """Check a scheduler address, ``tcp://HOST:PORT``; ConfigError naming ``option`` otherwise
    (before anything is imported, connected or run)."""
    text = str(address).strip()
    usage = ("expected tcp://HOST:PORT, the address of a Dask scheduler (`dask scheduler` prints it; "
             "docs/cluster.md)")
    scheme, sep, _rest = text.partition("://")
    if not sep:
        raise ConfigError(f"{option} {address!r}: {usage}")
    if scheme.lower() == "ray":
        raise ConfigError(f"{option} {address!r}: Ray is not the engine here: impact-env runs its tasks on "
                          f"Dask distributed; {usage}")
    if scheme.lower() != "tcp":
        raise ConfigError(f"{option} {address!r}: scheme {scheme + '://'!r} is not supported; {usage}")
    try:
        parts = urlsplit(text)
        port = parts.port
    except ValueError:
        raise ConfigError(f"{option} {address!r}: the port is not a number in 1..65535; {usage}") from None
    if not parts.hostname or port is None or not 1 <= port <= 65535:
        raise ConfigError(f"{option} {address!r}: {usage}")
    if parts.path not in ("", "/") or parts.query or parts.fragment or parts.username:
        raise ConfigError(f"{option} {address!r}: {usage}")
    return f"tcp://{parts.netloc}"


class Cluster:
    """A connection to a Dask distributed scheduler with at least one worker.

    ``Cluster("tcp://10.0.0.5:8786")`` connects (or raises ConfigError naming ``option``: a bad
    address, Dask not installed, no scheduler answering within ``timeout`` s, no worker joining
    within ``timeout`` s).  Use it as a context manager, or :meth:`close` it."""

    def __init__(self, address: str, option: str = "--cluster", timeout: float | None = None):
        self.address = parse_cluster(address, option)
        timeout = CONNECT_TIMEOUT_S if timeout is None else float(timeout)
        try:
            import distributed
        except ImportError:
            raise ConfigError(f"{option} needs Dask distributed, which is not installed: "
                              f"{CLUSTER_HINT}") from None
        try:
            self.client = distributed.Client(self.address, timeout=timeout, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise ConfigError(f"{option} {self.address}: no Dask scheduler answered ({exc})") from None
        try:
            self.client.wait_for_workers(1, timeout=timeout)
        except (OSError, TimeoutError):
            self.client.close()
            raise ConfigError(f"{option} {self.address}: the scheduler answered but has no worker after "
                              f"{timeout:g} s (start some: dask worker {self.address})") from None

    @property
    def workers(self) -> int:
        """Worker threads over the cluster: how many tasks can run at once."""
        return max(1, sum(self.client.nthreads().values()))

    def on_every_worker(self, fn: Callable[..., Any], *args: Any) -> None:
        """``fn(*args)`` once in every worker process (a task asked of each), e.g. to load the
        compiled kernels before the timed tasks.  ``allow_other_workers``: a worker that leaves
        meanwhile does not leave its call waiting forever (it runs elsewhere, harmlessly)."""
        futures = [self.client.submit(_unbox, _Box(fn, args), workers=[w], allow_other_workers=True,
                                      pure=False) for w in self.client.nthreads()]
        self.client.gather(futures)

    def map(self, fn: Callable[[Any], Any], tasks: Sequence[Any], bar: Progress, total: int) -> list[Any]:
        """``[fn(t) for t in tasks]`` on the workers, in task order; the bar advances by a task's
        share of ``total`` as each task finishes.  A task's exception propagates (the rest are
        cancelled)."""
        from distributed import as_completed

        # pure=False: one Dask task per task, never merged with an equal one
        futures = self.client.map(_unbox, [_Box(fn, (t,)) for t in tasks], pure=False)
        try:
            n, done = len(futures), 0
            for k, fut in enumerate(as_completed(futures, loop=self.client.loop), start=1):
                if fut.status != "finished":  # an error (or lost): gather raises it
                    break
                units = total * k // n - done
                done += units
                bar.update(units)
            return self.client.gather(futures)  # in task order; raises a failed task's error
        finally:
            self.client.cancel(futures)

    def close(self) -> None:
        self.client.close()

    def __enter__(self) -> Cluster:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Box:
    """A call ``fn(*args)`` as one opaque argument: Dask looks inside the lists, dicts and
    dataclasses of a task's arguments (for futures to resolve) and rebuilds them on the worker; a
    box it pickles and passes as it is, so ``fn`` gets the very objects the local pool would."""

    __slots__ = ("fn", "args")

    def __init__(self, fn: Callable[..., Any], args: tuple):
        self.fn, self.args = fn, args

    def __getstate__(self) -> tuple:
        return self.fn, self.args

    def __setstate__(self, state: tuple) -> None:
        self.fn, self.args = state


def _unbox(box: _Box) -> Any:
    return box.fn(*box.args)


def connect(cluster: str | Cluster | None, option: str = "--cluster") -> tuple[Cluster | None, bool]:
    """``(Cluster, owned)`` for an address (a new connection, ``owned``: the caller closes it), a
    Cluster (as it is) or None (no cluster: the local pool)."""
    if cluster is None or isinstance(cluster, Cluster):
        return cluster, False
    return Cluster(cluster, option), True


@contextlib.contextmanager
def session(cluster: str | Cluster | None, workers: int | None) -> Iterator[tuple[Cluster | None, int]]:
    """``(Cluster or None, workers)`` for a run: the cluster connected (checked: address,
    scheduler, workers, before anything runs) and closed at the end if this opened it; ``workers``
    defaults to the cluster's worker threads, or the local pool's size."""
    cl, owned = connect(cluster)
    try:
        if workers is None:
            workers = cl.workers if cl is not None else default_workers()
        yield cl, max(1, int(workers))
    finally:
        if owned and cl is not None:
            cl.close()
