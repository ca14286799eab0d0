"""What calling a compiled kernel with many arrays costs, and what binding them once would save
(issue 28, part 2: the single env's step hands its compiled step ~50 arrays and ~25 scalars each
call, 2.6 us of its 7.7; docs/env.md).

Times, in one process, a trivial numba kernel of ``--arrays`` float64 arrays called

1. through numba's dispatcher with the arrays as arguments (what the env's step does today),
2. with the same arrays in one named tuple, and in one plain tuple,
3. through a ``numba.cfunc`` shim called by ``ctypes`` with two pointers (the arrays' addresses
   and lengths, written once): the shim rebuilds the arrays with ``numba.carray`` and calls the
   same kernel, so nothing is unboxed per call ("bind once"),

and one array through the dispatcher as the reference.  Prints microseconds per call (best of
5 rounds) and each as a ratio to the reference.

    python scripts/bench_call.py [--arrays 50] [--calls 20000]
"""

from __future__ import annotations

import argparse
import collections
import ctypes
import time

import numpy as np
from numba import carray, cfunc, njit
from numba.core import types as numba_types
from numba.extending import intrinsic


@intrinsic
def _as_f64_pointer(typingctx, addr):
    """An int64 address as a float64 pointer (for ``carray``)."""
    sig = numba_types.CPointer(numba_types.float64)(addr)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(numba_types.CPointer(numba_types.float64)))

    return sig, codegen


def _kernels(n: int):
    names = [f"a{i}" for i in range(n)]
    ns: dict = {"carray": carray, "_p": _as_f64_pointer}
    exec(f"def flat({', '.join(names)}):\n    a0[0] += 1.0\n    return a0[0] + a{n - 1}[0]\n", ns)
    flat = njit(ns["flat"])
    ns["flat"] = flat
    body = [f"def shim(ptrs, lens):\n    p = carray(ptrs, ({n},))\n    s = carray(lens, ({n},))"]
    body += [f"    a{i} = carray(_p(p[{i}]), (s[{i}],))" for i in range(n)]
    body += [f"    return flat({', '.join(names)})"]
    exec("\n".join(body) + "\n", ns)
    int_pointer = numba_types.CPointer(numba_types.int64)
    shim = cfunc(numba_types.float64(int_pointer, int_pointer))(ns["shim"])
    return flat, shim, names


@njit
def _via_named(t):
    return t[0][0] + t[-1][0]


@njit
def _one(a):
    return a[0]


def _time(fn, args, calls: int) -> float:
    fn(*args)
    best = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn(*args)
        best = min(best, (time.perf_counter() - t0) / calls)
    return best * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--arrays", type=int, default=50)
    ap.add_argument("--calls", type=int, default=20000)
    args = ap.parse_args()
    n = args.arrays
    arrs = [np.zeros(4) for _ in range(n)]
    flat, shim, names = _kernels(n)
    named = collections.namedtuple("Bundle", names)(*arrs)
    ptrs = np.array([a.ctypes.data for a in arrs], dtype=np.int64)
    lens = np.array([a.shape[0] for a in arrs], dtype=np.int64)
    call = ctypes.CFUNCTYPE(ctypes.c_double, ctypes.c_void_p, ctypes.c_void_p)(shim.address)
    ref = _time(_one, (arrs[0],), args.calls)
    rows = [("one array, dispatcher (reference)", ref),
            (f"{n} arrays as arguments, dispatcher", _time(flat, arrs, args.calls)),
            (f"{n} arrays in one named tuple, dispatcher", _time(_via_named, (named,), args.calls)),
            (f"{n} arrays in one plain tuple, dispatcher", _time(_via_named, (tuple(arrs),), args.calls)),
            (f"{n} arrays bound once: cfunc shim through ctypes", _time(call, (ptrs.ctypes.data, lens.ctypes.data),
                                                                       args.calls))]
    print(f"| call | us | / reference |\n|---|---|---|")
    for name, us in rows:
        print(f"| {name} | {us:.2f} | {us / ref:.1f} |")


if __name__ == "__main__":
    main()
