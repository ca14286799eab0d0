"""The CPU's cycle counter in compiled code (LLVM's ``readcyclecounter``: rdtsc on x86-64, the
virtual counter on arm64), calibrated against ``time.perf_counter_ns``: a real-time loop paces
and times its ticks without leaving compiled code, as a controller does on its own core."""

from __future__ import annotations

import time

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from impact_env._jit import jit


@intrinsic
def _readcyclecounter(typingctx):
    def codegen(context, builder, signature, args):
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.IntType(64), []),
                                            "llvm.readcyclecounter")
        return builder.call(fn, [])
    return types.uint64(), codegen


@jit(inline="always")
def cycles():
    """The cycle counter now (uint64)."""
    return _readcyclecounter()


@jit
def cycles_now():
    """The counter now, from Python."""
    return cycles()


def ns_per_cycle(span_s: float = 0.02, repeats: int = 5) -> float:
    """Nanoseconds per counter cycle, the median of ``repeats`` spans of ``span_s`` against
    ``time.perf_counter_ns`` (the counter of a modern x86-64 runs at a constant rate)."""
    cycles_now()
    out = []
    for _ in range(repeats):
        c0, t0 = cycles_now(), time.perf_counter_ns()
        while time.perf_counter_ns() - t0 < span_s * 1e9:
            pass
        c1, t1 = cycles_now(), time.perf_counter_ns()
        out.append((t1 - t0) / float(c1 - c0))
    return float(np.median(out))


_NS_PER_CYCLE: list[float] = []


def cached_ns_per_cycle(refresh: bool = False) -> float:
    """:func:`ns_per_cycle`, measured once per process (again with ``refresh``)."""
    if refresh or not _NS_PER_CYCLE:
        _NS_PER_CYCLE[:] = [ns_per_cycle()]
    return _NS_PER_CYCLE[0]
