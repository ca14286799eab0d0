"""Calls to C functions by address from compiled code: the target's real-time loop calls a
driver's ``read``/``apply`` (:mod:`impact_env.rig.cdriver`) and libc's ``write``/``usleep``
through their addresses, held as plain int64 in its arguments, so no Python runs in the tick.

An address is a runtime value (never a compile-time constant), so the compiled loop is cached
like any other kernel and one compilation serves every driver library.  ``fence`` is a
sequentially consistent memory fence: what the loop publishes to another thread (a ring's head)
is stored after the data it announces, and what it reads from one is loaded after its head.
"""

from __future__ import annotations

import ctypes

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

_I8P = ir.IntType(8).as_pointer()
_I32 = ir.IntType(32)
_I64 = ir.IntType(64)
_F64 = ir.DoubleType()


@intrinsic
def call_read(typingctx, addr, ctx, tick, buf):
    """``int read(void *ctx, int64_t tick, double buf[])`` at ``addr``."""
    def codegen(context, builder, sig, args):
        a, c, t, arr = args
        fnty = ir.FunctionType(_I32, [_I8P, _I64, _F64.as_pointer()])
        data = context.make_array(sig.args[3])(context, builder, arr).data
        return builder.call(builder.inttoptr(a, fnty.as_pointer()), [builder.inttoptr(c, _I8P), t, data])
    return types.int32(addr, ctx, tick, buf), codegen


@intrinsic
def call_apply(typingctx, addr, ctx, tick, command):
    """``int apply(void *ctx, int64_t tick, double command)`` at ``addr``."""
    def codegen(context, builder, sig, args):
        a, c, t, u = args
        fnty = ir.FunctionType(_I32, [_I8P, _I64, _F64])
        return builder.call(builder.inttoptr(a, fnty.as_pointer()), [builder.inttoptr(c, _I8P), t, u])
    return types.int32(addr, ctx, tick, command), codegen


@intrinsic
def call_write(typingctx, addr, fd, buf):
    """libc's ``ssize_t write(int fd, const void *buf, size_t 1)`` at ``addr`` (one byte of
    ``buf``, an array): wakes a thread blocked in select() on the other end of a pipe."""
    def codegen(context, builder, sig, args):
        a, f, arr = args
        fnty = ir.FunctionType(_I64, [_I32, _I8P, _I64])
        data = builder.bitcast(context.make_array(sig.args[2])(context, builder, arr).data, _I8P)
        return builder.call(builder.inttoptr(a, fnty.as_pointer()),
                            [builder.trunc(f, _I32), data, ir.Constant(_I64, 1)])
    return types.int64(addr, fd, buf), codegen


@intrinsic
def call_usleep(typingctx, addr, us):
    """libc's ``int usleep(useconds_t us)`` at ``addr`` (lock-step waits: yield the core)."""
    def codegen(context, builder, sig, args):
        a, u = args
        fnty = ir.FunctionType(_I32, [_I32])
        return builder.call(builder.inttoptr(a, fnty.as_pointer()), [builder.trunc(u, _I32)])
    return types.int32(addr, us), codegen


@intrinsic
def fence(typingctx):
    """A sequentially consistent fence (the compiler and the CPU keep memory order across it)."""
    def codegen(context, builder, sig, args):
        builder.fence("seq_cst")
        return context.get_dummy_value()
    return types.none(), codegen


def libc_address(name: str) -> int:
    """The address of libc's ``name`` (``write``, ``usleep``)."""
    libc = ctypes.CDLL(None, use_errno=True)
    return int(ctypes.cast(getattr(libc, name), ctypes.c_void_p).value or 0)

