"""Threads over blocks of envs: how the batched kernels use more than one core.

A batched kernel that takes a range of envs (``kernel(i0, i1, ...)``: envs ``i0 .. i1 - 1``) and
is compiled with ``nogil=True`` runs, with ``threads`` = k > 1, as k calls on contiguous blocks
of envs at once: the calling thread runs the first block, a shared pool of k - 1 Python threads
the others.  Env i's arithmetic is the same code on the same data whichever block holds it and
every env touches only its own rows, so the results are bitwise independent of the thread
count (tested: ``tests/test_threads.py``); anything summed across envs is summed by the caller
after the call, in env order.

Why Python threads rather than ``numba.prange``: numba's parallel loop does not take named
tuples (the kernels' arguments, docs/architecture.md), so every kernel would have to pass each
leaf and rebuild its tuples (:func:`impact_env.hardware.replay.replay_kernel` does, for a
kernel of few leaves), and a field added to a state type would need an edit there; a block
range is two integers.  The thread count is an argument, not numba's process-wide setting.

A block has at least ``min_envs`` envs (the caller's measured threshold): below it the fixed
cost of waking a thread (tens of us) is more than the work it takes over, so a small batch runs
serially, in the calling thread, whatever ``threads`` says.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

_POOLS: dict[int, ThreadPoolExecutor] = {}


def _forget_pools() -> None:  # a forked child has none of its parent's threads
    _POOLS.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pools)


def check_threads(threads, name: str = "threads") -> int:
    """``threads`` as an int >= 1 (None: 1, the serial kernel); a ValueError naming ``name``
    otherwise."""
    if threads is None:
        return 1
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise ValueError(f"{name} = {threads!r} must be an integer >= 1 (or None: 1, serial)")
    return int(threads)


def env_blocks(n: int, threads: int, min_envs: int) -> list[tuple[int, int]]:
    """``threads`` contiguous blocks (i0, i1) covering envs 0 .. n - 1, as equal as can be, fewer
    where a block would have less than ``min_envs`` envs (one block: the serial call)."""
    parts = max(1, min(int(threads), n // max(int(min_envs), 1)))
    bounds = np.linspace(0, n, parts + 1).round().astype(np.int64)
    return [(int(bounds[b]), int(bounds[b + 1])) for b in range(parts)]


def _pool(workers: int) -> ThreadPoolExecutor:
    pool = _POOLS.get(workers)
    if pool is None:
        pool = _POOLS[workers] = ThreadPoolExecutor(workers, thread_name_prefix="impact_env-block")
    return pool


def run_blocks(kernel: Callable, blocks: list[tuple[int, int]], args: tuple) -> None:
    """``kernel(i0, i1, *args)`` for every block, at once: the first block in the calling thread,
    the others in the pool's threads; returns when all are done (the first block's exception,
    in block order, is raised after every block has ended)."""
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
