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



def _ptr(context, builder, aty, arr, off=None):
    """The data pointer of array ``arr`` (type ``aty``) as i8*, ``off`` bytes in."""
    p = builder.bitcast(context.make_array(aty)(context, builder, arr).data, _I8P)
    return p if off is None else builder.gep(p, [off])


@intrinsic
def call_recvfrom(typingctx, addr, fd, buf, off, n, flags, src, srclen):
    """libc's ``ssize_t recvfrom(int fd, void *buf + off, size_t n, int flags, struct sockaddr
    *src, socklen_t *srclen)`` at ``addr``: -1 when nothing is waiting (``MSG_DONTWAIT``)."""
    def codegen(context, builder, sig, args):
        a, f, arr, o, nn, fl, s, sl = args
        fnty = ir.FunctionType(_I64, [_I32, _I8P, _I64, _I32, _I8P, _I8P])
        return builder.call(builder.inttoptr(a, fnty.as_pointer()),
                            [builder.trunc(f, _I32), _ptr(context, builder, sig.args[2], arr, o), nn,
                             builder.trunc(fl, _I32), _ptr(context, builder, sig.args[6], s),
                             _ptr(context, builder, sig.args[7], sl)])
    return types.int64(addr, fd, buf, off, n, flags, src, srclen), codegen


@intrinsic
def call_sendto(typingctx, addr, fd, buf, off, n, flags, dst, dstlen):
    """libc's ``ssize_t sendto(int fd, const void *buf + off, size_t n, int flags, const struct
    sockaddr *dst, socklen_t dstlen)`` at ``addr``."""
    def codegen(context, builder, sig, args):
        a, f, arr, o, nn, fl, d, dl = args
        fnty = ir.FunctionType(_I64, [_I32, _I8P, _I64, _I32, _I8P, _I32])
        return builder.call(builder.inttoptr(a, fnty.as_pointer()),
                            [builder.trunc(f, _I32), _ptr(context, builder, sig.args[2], arr, o), nn,
                             builder.trunc(fl, _I32), _ptr(context, builder, sig.args[6], d),
                             builder.trunc(dl, _I32)])
    return types.int64(addr, fd, buf, off, n, flags, dst, dstlen), codegen


@intrinsic
def call_hmac(typingctx, addr, md, key, key_len, buf, n, out, outlen):
    """OpenSSL's one-shot ``unsigned char *HMAC(const EVP_MD *md, const void *key, int key_len,
    const unsigned char *buf, size_t n, unsigned char *out, unsigned int *outlen)`` at ``addr``:
    the address of ``out`` (0 on failure)."""
    def codegen(context, builder, sig, args):
        a, m, k, kl, arr, nn, o, ol = args
        fnty = ir.FunctionType(_I8P, [_I8P, _I8P, _I32, _I8P, _I64, _I8P, _I8P])
        r = builder.call(builder.inttoptr(a, fnty.as_pointer()),
                         [builder.inttoptr(m, _I8P), _ptr(context, builder, sig.args[2], k),
                          builder.trunc(kl, _I32), _ptr(context, builder, sig.args[4], arr), nn,
                          _ptr(context, builder, sig.args[6], o), _ptr(context, builder, sig.args[7], ol)])
        return builder.ptrtoint(r, _I64)
    return types.int64(addr, md, key, key_len, buf, n, out, outlen), codegen


@intrinsic
def call_clock_gettime(typingctx, addr, clock, ts):
    """libc's ``int clock_gettime(clockid_t clock, struct timespec *ts)`` at ``addr`` (``ts`` an
    int64[2] array: seconds, nanoseconds)."""
    def codegen(context, builder, sig, args):
        a, c, t = args
        fnty = ir.FunctionType(_I32, [_I32, _I8P])
        return builder.call(builder.inttoptr(a, fnty.as_pointer()),
                            [builder.trunc(c, _I32), _ptr(context, builder, sig.args[2], t)])
    return types.int32(addr, clock, ts), codegen


@intrinsic
def call_poll(typingctx, addr, fds, nfds, timeout_ms):
    """libc's ``int poll(struct pollfd *fds, nfds_t nfds, int timeout_ms)`` at ``addr`` (``fds``
    an int32 array of (fd, events) pairs)."""
    def codegen(context, builder, sig, args):
        a, f, n, t = args
        fnty = ir.FunctionType(_I32, [_I8P, _I64, _I32])
        return builder.call(builder.inttoptr(a, fnty.as_pointer()),
                            [_ptr(context, builder, sig.args[1], f), n, builder.trunc(t, _I32)])
    return types.int32(addr, fds, nfds, timeout_ms), codegen


@intrinsic
def call_clock_nanosleep(typingctx, addr, clock, flags, ts):
    """libc's ``int clock_nanosleep(clockid_t clock, int flags, const struct timespec *ts, NULL)``
    at ``addr`` (``ts`` an int64[2] array: seconds, nanoseconds; flags 1: TIMER_ABSTIME)."""
    def codegen(context, builder, sig, args):
        a, c, f, t = args
        fnty = ir.FunctionType(_I32, [_I32, _I32, _I8P, _I8P])
        return builder.call(builder.inttoptr(a, fnty.as_pointer()),
                            [builder.trunc(c, _I32), builder.trunc(f, _I32), _ptr(context, builder, sig.args[3], t),
                             ir.Constant(_I8P, None)])
    return types.int32(addr, clock, flags, ts), codegen


def libcrypto_addresses() -> tuple[int, int]:
    """The addresses of OpenSSL's ``HMAC`` and of the ``EVP_MD`` that ``EVP_sha256()`` returns,
    from the libcrypto that Python's own ``hashlib`` is linked against (so the loop's tags are
    made by the library that makes the Python side's).  Raises OSError if there is none."""
    import _hashlib  # the standard library's OpenSSL binding: its dependencies hold libcrypto

    lib = ctypes.CDLL(_hashlib.__file__)
    try:
        hmac_fn, sha256 = lib.HMAC, lib.EVP_sha256
    except AttributeError as exc:
        raise OSError(f"Python's hashlib ({_hashlib.__file__}) is not linked against OpenSSL's "
                      "libcrypto, which the real-time loop's tags need") from exc
    sha256.restype = ctypes.c_void_p
    md = sha256()
    if not md:
        raise OSError("OpenSSL's EVP_sha256() returned NULL")
    return int(ctypes.cast(hmac_fn, ctypes.c_void_p).value or 0), int(md)
