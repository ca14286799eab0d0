"""Threads over blocks of envs: how the batched kernels use more than one core.

A batched kernel takes a range of envs (``kernel(i0, i1, ...)``: envs ``i0 .. i1 - 1``).  With
``threads`` = k > 1 its envs are cut into k contiguous blocks (:func:`env_blocks`) and the
blocks run in **one compiled parallel region**: the kernel's *parallel shim*, a numba
``prange`` over the blocks, compiled once (and cached) per kernel, on numba's own pool of native
threads (its threading layer: tbb, omp or workqueue).  The arguments are unboxed once, in the
calling thread, which runs a block itself; no Python and no GIL are involved while the blocks
run, so the cost of a hand-off is the threading layer's wake-up (a few us), not a Python
thread's (tens of us, and the arguments' unboxing under the GIL in every thread, which is what
kept the former pool of Python threads from scaling past two cores).

Env i's arithmetic is the same compiled code on the same data whichever block holds it (no
fastmath: the compiler may not reorder floating-point operations), and every env touches only
its own rows, so the results are bitwise independent of the thread count (tested:
``tests/test_threads.py``, against the serial call); anything summed across envs is summed by
the caller after the call, in env order.

**The shim.**  numba's parallel loop passes only arrays, scalars and *one* level of tuple into
its threads, while the kernels take nested named tuples (docs/architecture.md).  A shim
therefore takes each nested named-tuple argument as one flat tuple of its leaves
(:func:`flatten`; one of arrays and scalars only goes in as it is) and rebuilds it inside the
loop (:func:`unflatten`, generated at compile time from the named tuple class's field
annotations, so a field added to a state type needs no edit here).  A shim is a
few lines next to its kernel::

    @jit(nogil=True)
    def _sim_block(i0, i1, actions, active, fp, fs):  # the guard: False if the kernel raised
        try:
            sim_step(i0, i1, actions, active, unflatten(fp, SimParams), unflatten(fs, SimState))
        except Exception:
            return False
        return True

    @jit(nogil=True, parallel=True)
    def sim_blocks(bounds, ok, actions, active, fp, fs):
        for b in prange(bounds.shape[0] - 1):
            ok[b] = _sim_block(bounds[b], bounds[b + 1], actions, active, fp, fs)

and :class:`BlockRunner` calls the kernel serially (one block) or the shim (several).  numba
drops an exception raised inside a parallel loop silently, hence the guard: a block whose kernel
raised is reported by :class:`BlockRunner` as a RuntimeError naming its envs (the serial call,
``threads=1``, gives the kernel's own message).

**The threading layer**: numba takes TBB where it loads (``pip install "impact-env[tbb]"``:
:func:`_pip_tbb` makes pip's copy loadable), else GNU OpenMP; TBB hands a region to its threads
several times faster.  **Its limits**, handled here: GNU OpenMP's idle threads sleep instead of
spinning (:func:`_start_layer`: on a shared machine spinning made threads several times slower
than one thread); numba's thread count (``numba.set_num_threads``,
thread-local) is set for the call and restored after it, and capped at numba's pool size
(``NUMBA_NUM_THREADS``, the CPU count by default: more blocks than threads is fine, a thread then
runs several); the workqueue layer (numba's fallback where neither tbb nor OpenMP is installed)
aborts the process if two threads launch parallel regions at once, so launches take a lock
there; GNU OpenMP cannot run in a process forked from one that used it (numba terminates the
child), so in such a child (``compare``'s forked workers, when their parent ran a threaded
step) the blocks run in a pool of Python threads instead (the former way: the same results,
slower); and with ``NUMBA_DISABLE_JIT=1`` too.

``threads="auto"``: as many threads as this process may run on (``os.sched_getaffinity``), at
most one per ``min_envs`` envs (:func:`resolve_threads`).

A block has at least ``min_envs`` envs (the caller's measured threshold): below it a block's
work is less than what waking a thread and sharing the cache lines at the block's edges cost,
so a small batch runs serially, in the calling thread, whatever ``threads`` says.
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
    """Runs ``kernel(i0, i1, *args)`` over blocks of envs: one block, the kernel itself; several,
    its parallel ``shim(bounds, ok, *args)`` (each nested named tuple of ``args`` flattened) in one
    compiled parallel region, or, where that cannot run, :func:`python_threads`.

    ``entry``: :func:`impact_env._jit.entry_point`, for a caller that keeps the arguments' types
    fixed from call to call (as :func:`~impact_env._jit.bound_call` requires): after its first
    call each compiled function is called through its entry point, without numba's typing of
    the arguments.  ``bind`` (with ``entry``): :func:`impact_env._bind.bind`: a serial call whose
    named tuples are the objects of the call before runs bound, without unboxing them.  The
    flattening of a named tuple is reused while the caller passes the same object."""

    def __init__(self, kernel, shim, entry: Callable | None = None, bind: Callable | None = None):
        self.kernel = kernel
        self.shim = shim
        self.entry = entry
        self.bind = bind
        self._serial = None
        self._par = None
        self._flat: dict[int, tuple] = {}  # argument position -> (the named tuple, its leaves)
        self._bounds: tuple | None = None  # (blocks, bounds, ok) of the last parallel call
        self._bound: typing.Any = None  # the serial call bound by ``bind`` (None: not yet; False: cannot be)

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

    def prepared(self, blocks: list[tuple[int, int]], args: tuple) -> Callable[[], None] | None:
        """The serial call of ``args`` as a call of no arguments (:meth:`Bound.prepared
        <impact_env._bind.Bound.prepared>`), once a call with these very objects has bound it;
        None otherwise (several blocks, binding off, or no bound call yet)."""
        if len(blocks) != 1:
            return None
        full = tuple(blocks[0]) + args
        bound = self._bound
        return bound.prepared(full) if bound and bound.fits(full) else None

    def __call__(self, blocks: list[tuple[int, int]], args: tuple) -> None:
        if len(blocks) == 1:
            i0, i1 = blocks[0]
            full = (i0, i1) + args
            bound = self._bound
            if bound and bound.fits(full):
                bound(full)
                return
            if self._serial is not None:
                self._serial(*full)
            else:
                self.kernel(*full)
                if self.entry is None:
                    return
                self._serial = self.entry(self.kernel, full)
            # bound for the next calls with these named tuples (False: they cannot be; not tried again)
            if bound is not False and self.bind is not None:
                self._bound = self.bind(self.kernel, full) or False
            return
        if not parallel_available():
            python_threads(self._serial or self.kernel, blocks, args)
            return
        if self._bounds is None or self._bounds[0] is not blocks:
            edges = np.array([b[0] for b in blocks] + [blocks[-1][1]], dtype=np.int64)
            self._bounds = (blocks, edges, np.zeros(len(blocks), dtype=np.bool_))
        _, edges, ok = self._bounds
        pargs = (edges, ok) + self._flat_args(args)
        if self._par is not None:
            _launch(self._par, len(blocks), pargs)
        else:
            _launch(self.shim, len(blocks), pargs)
            if self.entry is not None:
                self._par = self.entry(self.shim, pargs)
        if not ok.all():
            b = int(np.argmin(ok))
            raise RuntimeError(f"envs {blocks[b][0]} .. {blocks[b][1] - 1}: the compiled kernel "
                               f"{getattr(self.kernel, '__name__', self.kernel)} raised in a parallel "
                               "block (run with threads=1 for its message)")
