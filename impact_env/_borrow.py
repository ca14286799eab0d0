"""Borrowed arrays: a kernel's view of its argument arrays without reference counting.

numba keeps a reference count on every array (its NRT meminfo) and raises and drops it, with
an atomic instruction, each time a view or a named tuple's field is taken: ``p.hw.plant.y[i]``,
a row of the effects' parameters, a slice of a state row.  The batched tick takes dozens of such
views per env, and ``perf`` put the two atomic instructions of ``NRT_incref``/``NRT_decref`` at
a quarter of all samples of ``compare``'s compiled loop (``scripts/bench_env.py``, "the batched
control period").  Every array a kernel is given is owned by the caller's Python objects for the
whole call, so counting references to it inside the call protects nothing.

:func:`borrow` returns the same value with every array in it (recursively through named tuples
and tuples) rebuilt without a meminfo: same data, shape, strides and type, so the kernel's code
and results are unchanged (bitwise: ``tests/test_golden.py``, ``tests/test_threads.py``), and
``NRT_incref`` returns at its null check.  Use it only at the top of a kernel called from Python,
on its arguments, and never let a borrowed array (or a view of one) escape the call: returned
to Python, it would not keep its memory alive.  With ``NUMBA_DISABLE_JIT=1`` it is the identity.
"""

from __future__ import annotations

from numba import types
from numba.extending import intrinsic, overload


def borrow(x):
    """``x`` with every array in it borrowed (inside a kernel); the identity in Python."""
    return x


@intrinsic
def _borrow_array(typingctx, arr):
    if not isinstance(arr, types.Array):
        return None

    def codegen(context, builder, sig, args):
        src = context.make_array(sig.args[0])(context, builder, args[0])
        dst = context.make_array(sig.return_type)(context, builder)
        context.populate_array(dst, data=src.data, shape=src.shape, strides=src.strides,
                               itemsize=src.itemsize, meminfo=None)
        return dst._getvalue()

    return arr(arr), codegen


@overload(borrow)
def _borrow_overload(x):
    if isinstance(x, types.Array):
        return lambda x: _borrow_array(x)
    if isinstance(x, types.BaseNamedTuple):
        fields = ", ".join(f"borrow(x[{k}])" for k in range(len(x)))
        ns = {"cls": x.instance_class, "borrow": borrow}
        exec(f"def impl(x):\n    return cls({fields})\n", ns)
        return ns["impl"]
    if isinstance(x, types.BaseTuple):
        fields = "".join(f"borrow(x[{k}]), " for k in range(len(x)))
        ns = {"borrow": borrow}
        exec(f"def impl(x):\n    return ({fields})\n", ns)
        return ns["impl"]
    return lambda x: x
