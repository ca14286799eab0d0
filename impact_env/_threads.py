"""Threads over blocks of envs: how the batched kernels use more than one core.

A batched kernel takes a range of envs (``kernel(i0, i1, ...)``: envs ``i0 .. i1 - 1``), touches
only their rows and releases the GIL (``nogil=True``).  :class:`BlockRunner` is the one facade: with
``threads`` = k > 1 it cuts the envs into k contiguous blocks (:func:`env_blocks`) and runs the
kernel on every block at once, the first block in the calling thread and the others in a pool of
Python threads (:func:`python_threads`); with one block it is the kernel's plain call.  A
kernel's author writes the kernel and nothing else.

Env i's arithmetic is the same compiled code on the same data whichever block holds it (no
fastmath), so the results are bitwise independent of the thread count (tested:
``tests/test_threads.py``, against the serial call); anything summed across envs is summed by
the caller after the call, in env order.

**A compiled parallel region** (numba's ``prange`` over the blocks, on numba's own threads)
runs instead where the caller gives a *shim* beside its kernel (``compare``'s compiled loop,
``impact_env/eval/rollout.py``): numba's parallel loop passes only arrays, scalars and one level
of tuple into its threads, so a shim takes each nested named tuple flattened (:func:`flatten`)
and rebuilds it inside (:func:`unflatten`, generated at compile time from the class's
annotations), and returns False where its kernel raised (numba drops an exception raised inside
a parallel loop; :class:`BlockRunner` reports the block).  For the env's step the region measured
no faster than Python threads (2 threads, N = 1024 and 16384, A/B in one process), so the env's
kernels have no shim.  The threading layer: TBB where it loads (``pip install
"impact-env[tbb]"``, :func:`_pip_tbb`), else GNU OpenMP with its idle threads sleeping
(:func:`_start_layer`); numba's thread count is set for the call and restored; the workqueue
layer's launches take a lock; in a child forked from a process that used GNU OpenMP, and with
``NUMBA_DISABLE_JIT=1``, the blocks run in Python threads instead (the same results).

``threads="auto"``: as many threads as this process may run on (``os.sched_getaffinity``), at
most one per ``min_envs`` envs (:func:`resolve_threads`).  A block has at least ``min_envs`` envs
(the caller's measured threshold): below it a block's work is less than what handing it to a
thread costs, so a small batch runs serially, in the calling thread, whatever ``threads`` says.
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys
import threading
import typing
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

import numba
import numpy as np
from numba.core import config as numba_config
from numba.extending import overload

from impact_env._jit import entry_point

AUTO = "auto"

_POOLS: dict[int, ThreadPoolExecutor] = {}
_LAUNCH_LOCK = threading.Lock()
_STATE = {"launched": False, "layer": "", "no_parallel": False}


def _after_fork_in_child() -> None:
    """A forked child has none of its parent's threads; and GNU OpenMP, once used, cannot run in
    a forked child at all (numba terminates it)."""
    _POOLS.clear()
    if _STATE["launched"] and _STATE["layer"] == "omp":
        _STATE["no_parallel"] = True


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def check_threads(threads, name: str = "threads") -> int | str:
    """``threads`` as an int >= 1 (None: 1, the serial kernel) or ``"auto"``; a ValueError
    naming ``name`` otherwise."""
    if threads is None:
        return 1
    if isinstance(threads, str) and threads.strip().lower() == AUTO:
        return AUTO
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise ValueError(f"{name} = {threads!r} must be an integer >= 1 or 'auto' (or None: 1, serial)")
    return int(threads)


def machine_threads() -> int:
    """The CPUs this process may run on (its affinity mask where the platform has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def resolve_threads(threads, n: int, min_envs: int) -> int:
    """The thread count for a batch of ``n`` envs: ``threads`` itself, or for ``"auto"`` the
    machine's CPUs (:func:`machine_threads`), at most one per ``min_envs`` envs."""
    threads = check_threads(threads)
    if threads == AUTO:
        return max(1, min(machine_threads(), int(n) // max(int(min_envs), 1)))
    return int(threads)


def env_blocks(n: int, threads: int, min_envs: int) -> list[tuple[int, int]]:
    """``threads`` contiguous blocks (i0, i1) covering envs 0 .. n - 1, as equal as can be, fewer
    where a block would have less than ``min_envs`` envs (one block: the serial call)."""
    parts = max(1, min(int(threads), n // max(int(min_envs), 1)))
    bounds = np.linspace(0, n, parts + 1).round().astype(np.int64)
    return [(int(bounds[b]), int(bounds[b + 1])) for b in range(parts)]


# -- named tuples through the parallel loop ------------------------------------------------------------
def _is_named_tuple_class(cls) -> bool:
    return isinstance(cls, type) and issubclass(cls, tuple) and hasattr(cls, "_fields")


@functools.cache
def _schema(cls) -> tuple:
    """Per field of the named tuple class ``cls``: its named tuple class, or None for a leaf (an
    array or a scalar), from the field annotations."""
    hints = typing.get_type_hints(cls)
    out = []
    for name in cls._fields:
        sub = hints.get(name)
        out.append(sub if _is_named_tuple_class(sub) else None)
    return tuple(out)


def nested(cls) -> bool:
    """Whether the named tuple class ``cls`` holds another named tuple (a shim takes it
    flattened); one of arrays and scalars only passes through numba's parallel loop as it is."""
    return any(sub is not None for sub in _schema(cls))


def _flat_into(x, cls, out: list) -> None:
    for value, sub in zip(x, _schema(cls), strict=True):
        if sub is None:
            out.append(value)
        else:
            if type(value) is not sub:
                raise TypeError(f"{cls.__name__}: a {sub.__name__} expected, got {type(value).__name__}")
            _flat_into(value, sub, out)


def flatten(x) -> tuple:
    """The leaves of the named tuple ``x`` (arrays and scalars, nested named tuples walked in
    field order): what a parallel shim takes in its place (:func:`unflatten` rebuilds it)."""
    out: list = []
    _flat_into(x, type(x), out)
    return tuple(out)


def _build(flat, cls, pos: int):
    values = []
    for sub in _schema(cls):
        if sub is None:
            values.append(flat[pos])
            pos += 1
        else:
            value, pos = _build(flat, sub, pos)
            values.append(value)
    return cls(*values), pos


def unflatten(flat, cls):
    """The named tuple of class ``cls`` whose leaves are ``flat`` (:func:`flatten`'s inverse);
    in a kernel, code generated for ``cls`` when it compiles."""
    value, _ = _build(flat, cls, 0)
    return value


def _source(cls, pos: int, names: dict) -> tuple[str, int]:
    """Python source building ``cls`` from ``flat[pos ...]``, and the next position."""
    key = f"_c{len(names)}"
    names[key] = cls
    parts = []
    for sub in _schema(cls):
        if sub is None:
            parts.append(f"flat[{pos}]")
            pos += 1
        else:
            src, pos = _source(sub, pos, names)
            parts.append(src)
    return f"{key}({', '.join(parts)})", pos


@overload(unflatten)
def _unflatten_overload(flat, cls):
    klass = getattr(cls, "instance_class", None)
    if klass is None or not _is_named_tuple_class(klass):
        return None
    names: dict = {}
    src, count = _source(klass, 0, names)
    if count != len(flat):
        return None
    exec(f"def impl(flat, cls):\n    return {src}\n", names)
    return names["impl"]


# -- running the blocks -------------------------------------------------------------------------------
def _pool(workers: int) -> ThreadPoolExecutor:
    pool = _POOLS.get(workers)
    if pool is None:
        pool = _POOLS[workers] = ThreadPoolExecutor(workers, thread_name_prefix="impact_env-block")
    return pool


def python_threads(kernel: Callable, blocks: list[tuple[int, int]], args: tuple) -> None:
    """``kernel(i0, i1, *args)`` for every block, at once, in Python threads (the kernel releases
    the GIL): the first block in the calling thread, the others in a pool's; returns when all
    are done (the first block's exception, in block order, is raised after every block has
    ended).  The fallback where a compiled parallel region cannot run (module doc)."""
    if len(blocks) == 1:
        i0, i1 = blocks[0]
        kernel(i0, i1, *args)
        return
    pool = _pool(len(blocks) - 1)
    futures: list[Future] = [pool.submit(kernel, i0, i1, *args) for i0, i1 in blocks[1:]]
    error: BaseException | None = None
    try:
        kernel(blocks[0][0], blocks[0][1], *args)
    except BaseException as exc:  # noqa: BLE001 - re-raised below, after the other blocks end
        error = exc
    for f in futures:
        failed = f.exception()
        if error is None and failed is not None:
            error = failed
    if error is not None:
        raise error


def parallel_available() -> bool:
    """Whether a compiled parallel region can run in this process (module doc)."""
    return not (_STATE["no_parallel"] or getattr(numba_config, "DISABLE_JIT", False))


def _pip_tbb() -> None:
    """Make a TBB that pip installed into this environment (``pip install "impact-env[tbb]"``)
    loadable by numba: pip puts ``libtbb.so.12`` in the environment's ``lib`` folder, which the
    dynamic loader does not search (numba/numba#6108), so numba would fall back to GNU OpenMP.
    Loaded here by its path (RTLD_GLOBAL), numba's TBB layer links to it.  TBB hands a
    parallel region to its threads for about a fifth of what OpenMP's sleeping threads cost
    (docs/env.md, "Threads").  Nothing is done where ``NUMBA_THREADING_LAYER`` names a layer
    other than TBB or the file is not there."""
    layer = str(getattr(numba_config, "THREADING_LAYER", "default"))
    if not sys.platform.startswith("linux") or layer not in ("default", "tbb", "safe", "threadsafe", "forksafe"):
        return
    path = os.path.join(sys.prefix, "lib", "libtbb.so.12")
    if os.path.isfile(path):
        try:
            ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
        except OSError:
            pass  # (numba then takes the next layer, as without it)


def _start_layer() -> None:
    """Start numba's threading layer (its first parallel launch in this process would), with
    GNU OpenMP's idle threads told to sleep rather than spin (``OMP_WAIT_POLICY=PASSIVE``, unless
    the variable is set): spinning threads that wait at the end of a region for a thread that
    another process took the core from made a step 4 to 6 times slower on a shared machine
    (scripts/bench_env.py, docs/env.md "Threads").  The runtime reads the variable once, as it
    loads; it is unset again after, so other OpenMP runtimes loaded later (torch's) and child
    processes see the environment as it was."""
    _pip_tbb()
    unset = "OMP_WAIT_POLICY" not in os.environ
    if unset:
        os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    try:
        numba.get_num_threads()  # (loads and starts the threading layer)
    finally:
        if unset:
            os.environ.pop("OMP_WAIT_POLICY", None)


def _launch(call: Callable, threads: int, args: tuple):
    """``call(*args)`` (a parallel shim) on ``threads`` of numba's threads; numba's thread count
    of the calling thread restored after it."""
    threads = max(1, min(int(threads), int(getattr(numba_config, "NUMBA_NUM_THREADS", 1))))
    locked = _STATE["layer"] not in ("omp", "tbb")  # workqueue, or not known before the first launch
    if locked:
        _LAUNCH_LOCK.acquire()
    try:
        if not _STATE["launched"]:
            _start_layer()
        before = numba.get_num_threads()
        numba.set_num_threads(threads)
        try:
            return call(*args)
        finally:
            numba.set_num_threads(before)
            if not _STATE["launched"]:
                _STATE["launched"] = True
                _STATE["layer"] = numba.threading_layer()
    finally:
        if locked:
            _LAUNCH_LOCK.release()


class BlockRunner:
    """The one facade over blocks of envs: ``runner(blocks, args)`` runs ``kernel(i0, i1, *args)``
    for every block (i0, i1) of ``blocks`` (:func:`env_blocks`).  One block is the kernel's
    plain call in the calling thread (the reference every other way is tested against, bitwise);
    several run at once in :func:`python_threads`, or, given a parallel ``shim(bounds, ok,
    *args)`` (module doc), in one compiled parallel region where that can run.

    After the first call the kernel is called through its compiled entry point for the first
    call's argument types (:func:`impact_env._jit.entry_point`): numba's dispatcher would type
    the ~50 arrays of the env's nested named tuples again at every call, about 100 us of a
    single env's step on a loaded 2-core machine against 15 us through the entry point.  The
    caller therefore keeps its arguments' types fixed (dtypes, dimensions, C-contiguous and
    writeable arrays: :meth:`impact_env.sim.simulator.Simulator.step_args` converts)."""

    def __init__(self, kernel, shim=None):
        self.kernel = kernel
        self.shim = shim
        self._entry = None  # the kernel's compiled entry point, from the first call's types
        self._flat: dict[int, tuple] = {}  # argument position -> (the named tuple, its leaves)
        self._bounds: tuple | None = None  # (blocks, bounds, ok) of the last parallel call

    def _flat_args(self, args: tuple) -> tuple:
        out = []
        for k, a in enumerate(args):
            if isinstance(a, tuple) and hasattr(a, "_fields") and nested(type(a)):
                seen = self._flat.get(k)
                if seen is None or seen[0] is not a:
                    seen = self._flat[k] = (a, flatten(a))
                out.append(seen[1])
            else:
                out.append(a)
        return tuple(out)

    def _call(self, i0: int, i1: int, *args) -> None:
        if self._entry is not None:
            self._entry(i0, i1, *args)
        else:  # the first call: numba types the arguments (and compiles or loads the kernel)
            self.kernel(i0, i1, *args)
            self._entry = entry_point(self.kernel, (i0, i1) + args)

    def __call__(self, blocks: list[tuple[int, int]], args: tuple) -> None:
        if len(blocks) == 1:
            self._call(blocks[0][0], blocks[0][1], *args)
            return
        if self.shim is None or not parallel_available():
            python_threads(self._entry or self.kernel, blocks, args)
            return
        if self._bounds is None or self._bounds[0] is not blocks:
            edges = np.array([b[0] for b in blocks] + [blocks[-1][1]], dtype=np.int64)
            self._bounds = (blocks, edges, np.zeros(len(blocks), dtype=np.bool_))
        _, edges, ok = self._bounds
        _launch(self.shim, len(blocks), (edges, ok) + self._flat_args(args))
        if not ok.all():
            b = int(np.argmin(ok))
            raise RuntimeError(f"envs {blocks[b][0]} .. {blocks[b][1] - 1}: the compiled kernel "
                               f"{getattr(self.kernel, '__name__', self.kernel)} raised in a parallel "
                               "block (run with threads=1 for its message)")
