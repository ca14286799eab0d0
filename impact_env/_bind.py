"""Kernel calls whose named tuples are bound once: the single env's step without unboxing them.

A compiled kernel's entry point unboxes every array of its arguments on every call (about 45 ns
each: ``python scripts/bench_call.py``); the env's step hands its kernel ~50 arrays in nested
named tuples, 2.6 us of a 7.7 us step (docs/env.md).  Those named tuples are the same objects
from call to call, so their arrays' addresses, shapes and scalars can be written once into three
small arrays; a *shim* generated for the kernel's argument types takes those three arrays (and
the call's own arrays, which may change), rebuilds every array with ``numba.carray`` and every
named tuple with its constructor, and calls the kernel with them: the kernel's own compiled code
for the same types, so the results are bitwise those of the direct call (``tests/test_bind.py``).

The shim's source is written to a file (``NUMBA_CACHE_DIR/impact_env_bind``, else the user's
cache folder's, else a 0700 folder of the user's in the temporary one; a folder that others may
write to is not used: the shim is imported from it) named by a hash of its text and of the
project's sources
(:data:`impact_env._jit._STAMP`), so numba caches it like any kernel and a change to the project
gives a new shim.  :class:`Bound` keeps the named tuples it was made from (their arrays stay
alive) and is used only while the caller passes the very same objects (:meth:`Bound.fits`).
Anything the shim cannot rebuild (a non-contiguous or read-only array, a scalar type other than
int64, float64 and bool) leaves the call as it was: :func:`bind` returns None.

``IMPACT_ENV_BIND=0`` turns binding off; so does ``NUMBA_DISABLE_JIT=1``.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import operator
import os
import sys
import tempfile
from pathlib import Path

import numba
import numpy as np
from numba.core import config as numba_config
from numba.core import types as nt
from numba.extending import intrinsic

from impact_env import _jit

ENABLED = os.environ.get("IMPACT_ENV_BIND", "1").strip().lower() not in ("0", "false", "no", "off")


def _pointer(nbtype):
    @intrinsic
    def as_pointer(typingctx, addr):
        sig = nt.CPointer(nbtype)(addr)

        def codegen(context, builder, signature, args):
            return builder.inttoptr(args[0], context.get_value_type(nt.CPointer(nbtype)))

        return sig, codegen

    return as_pointer


# the dtypes a bound array may have: an int64 address as a pointer to its first element
P_float64 = _pointer(nt.float64)
P_int64 = _pointer(nt.int64)
P_bool = _pointer(nt.boolean)
P_float32 = _pointer(nt.float32)
_POINTERS = {np.dtype(np.float64): "P_float64", np.dtype(np.int64): "P_int64", np.dtype(np.bool_): "P_bool",
             np.dtype(np.float32): "P_float32"}
_SCALARS = {nt.int64: "np.int64({})", nt.float64: "{}", nt.boolean: "({} != 0.0)"}


class _Unsupported(Exception):
    pass


class _Writer:
    """Walks the bound arguments: the source that rebuilds each, and the values to bind."""

    def __init__(self):
        self.imports: dict[str, str] = {}  # "module:qualname" -> its alias in the shim
        self.ptrs: list[int] = []
        self.shapes: list[int] = []
        self.scal: list[float] = []

    def _class(self, cls) -> str:
        if "<locals>" in cls.__qualname__ or "." in cls.__qualname__:
            raise _Unsupported(f"{cls.__qualname__}: not importable by name")
        return self.imports.setdefault(f"{cls.__module__}:{cls.__qualname__}", f"C{len(self.imports)}")

    def expr(self, x) -> str:
        if isinstance(x, tuple) and hasattr(x, "_fields"):
            return f"{self._class(type(x))}({', '.join(self.expr(v) for v in x)})"
        if isinstance(x, np.ndarray):
            if x.dtype not in _POINTERS or not x.flags.c_contiguous or not x.flags.writeable or x.ndim == 0:
                raise _Unsupported(f"array {x.dtype} {x.shape}")
            k, s0 = len(self.ptrs), len(self.shapes)
            self.ptrs.append(int(x.__array_interface__["data"][0]))
            self.shapes.extend(int(n) for n in x.shape)
            shape = ", ".join(f"shapes[{s0 + j}]" for j in range(x.ndim))
            return f"carray({_POINTERS[x.dtype]}(ptrs[{k}]), ({shape},))"
        t = numba.typeof(x)
        if t not in _SCALARS:
            raise _Unsupported(f"scalar {t}")
        k = len(self.scal)
        self.scal.append(float(x))
        if float(self.scal[k]) != x:
            raise _Unsupported(f"scalar {x!r} not exact in float64")
        return _SCALARS[t].format(f"scal[{k}]")


def _private(d: Path) -> bool:
    """``d`` exists, is a folder of this user's and nobody else may write in it (the shim is
    imported from it: a folder others can write to would let them choose the code)."""
    getuid = getattr(os, "getuid", None)  # (POSIX; elsewhere no folder is trusted: no binding)
    st = d.stat()
    return (getuid is not None and d.is_dir() and not d.is_symlink() and st.st_uid == getuid()
            and not st.st_mode & 0o022)


def _folder() -> Path:
    """Where the shims are written: ``NUMBA_CACHE_DIR/impact_env_bind``, else the user's cache
    folder's, else a folder of this user's own in the temporary folder (mode 0700)."""
    home = os.path.expanduser("~")
    user = os.environ.get("XDG_CACHE_HOME") or (os.path.join(home, ".cache") if home != "~" else None)
    tmp = os.path.join(tempfile.gettempdir(), f"impact_env_bind-{getattr(os, 'getuid', lambda: 'x')()}")
    for base, name in ((os.environ.get("NUMBA_CACHE_DIR"), "impact_env_bind"), (user, "impact_env_bind"),
                       (tmp, "")):
        if not base:
            continue
        d = Path(base) / name if name else Path(base)
        try:
            d.mkdir(mode=0o700, parents=True, exist_ok=True)
            if not _private(d):
                continue
            probe = d / f".probe{os.getpid()}"
            probe.write_text("")
            probe.unlink()
            return d
        except OSError:
            continue
    raise _Unsupported("no private writable folder for the shim")


def _module(source: str):
    """The module of ``source``, written once under its hash (atomically: several processes)."""
    name = "impact_env_bind_" + hashlib.sha256((_jit._STAMP + source).encode()).hexdigest()[:20]
    mod = sys.modules.get(name)
    if mod is not None:
        return mod
    path = _folder() / f"{name}.py"
    if not path.is_file() or path.read_text() != source:
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(source)
        os.replace(tmp, path)
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise _Unsupported(f"{path}: not importable")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def _nothing():
    return None


class NotCopied:
    """What holds addresses of its owner's arrays (a :class:`Bound`, a prepared call): a copy of
    the owner (``copy.deepcopy`` of an env, a pickle) has arrays of its own, and a copied holder
    would still point at these, so it copies as None: the copy binds its own on its next call."""

    __slots__ = ()

    def __deepcopy__(self, memo):
        return None

    def __reduce__(self):
        return (_nothing, ())


class Bound(NotCopied):
    """``kernel(*args)`` with the named tuples and scalars of ``args`` bound: called with the
    whole ``args`` again, it passes on only the arrays at :attr:`live`."""

    def __init__(self, shim, live: tuple[int, ...], fixed: dict[int, object], ptrs, shapes, scal):
        self.live = live
        self._entry = shim
        self._bound = (ptrs, shapes, scal)
        # fits(args): one generated expression (chained ``is`` and ``==`` on locals), the fastest
        # check Python has for it: it runs before every bound call
        terms, defaults = [], {}
        for j, (k, v) in enumerate(fixed.items()):
            defaults[f"o{j}"] = v
            if isinstance(v, tuple):
                terms.append(f"a[{k}] is o{j}")  # the same named tuple object
            else:  # an equal scalar of the same type (1 and 1.0 would be typed differently)
                defaults[f"t{j}"] = type(v)
                terms.append(f"type(a[{k}]) is t{j} and a[{k}] == o{j}")
        ns: dict = {}
        exec(f"def fits(a, {', '.join(f'{n}={n}' for n in defaults)}):\n"
             f"    return {' and '.join(terms) or 'True'}\n", dict(defaults), ns)
        self.fits = ns["fits"]
        self._get_live = operator.itemgetter(*live) if len(live) > 1 else (lambda a, k=(live or (0,))[0]: (a[k],))
        self._keep = fixed  # the named tuples keep the bound arrays alive

    def __call__(self, args: tuple):
        return self._entry(*self._bound, *self._get_live(args))

    def prepared(self, args: tuple) -> functools.partial:
        """The bound call of ``args`` (which fit) as a call of no arguments, its live arrays
        bound too: for a caller that passes these very arrays (changed in place) at every call.
        The caller keeps this Bound (the named tuples' arrays) alive while it uses the call."""
        return functools.partial(self._entry, *self._bound, *self._get_live(args))


def bind(kernel, args: tuple) -> Bound | None:
    """A :class:`Bound` for ``kernel(*args)`` (a project kernel that has been called with such
    arguments), or None where binding is off or the arguments cannot be bound."""
    if not ENABLED or getattr(numba_config, "DISABLE_JIT", False):
        return None
    w = _Writer()
    live, fixed, exprs = [], {}, []
    try:
        for k, a in enumerate(args):
            if isinstance(a, np.ndarray):
                live.append(k)
                exprs.append(f"live{len(live) - 1}")
            else:
                fixed[k] = a
                exprs.append(w.expr(a))
        kmod, kname = kernel.py_func.__module__, kernel.py_func.__qualname__
        if "." in kname:
            raise _Unsupported("kernel not importable by name")
        lines = ['"""Generated by impact_env._bind: a bound call of ' f'{kmod}.{kname}."""',
                 "import numpy as np", "from numba import carray",
                 "from impact_env._jit import jit", "from impact_env._bind import P_bool, P_float32, P_float64, P_int64",
                 f"from {kmod} import {kname} as KERNEL"]
        lines += [f"from {key.split(':')[0]} import {key.split(':')[1]} as {alias}" for key, alias in w.imports.items()]
        params = ", ".join(["ptrs", "shapes", "scal"] + [f"live{j}" for j in range(len(live))])
        lines += ["", "", "@jit(nogil=True)", f"def bound({params}):",
                  f"    return KERNEL({', '.join(exprs)})", ""]
        mod = _module("\n".join(lines))
    except (_Unsupported, OSError, ImportError):
        return None
    ptrs = np.array(w.ptrs or [0], dtype=np.int64)
    shapes = np.array(w.shapes or [0], dtype=np.int64)
    scal = np.array(w.scal or [0.0], dtype=np.float64)
    call = (ptrs, shapes, scal) + tuple(args[k] for k in live)
    mod.bound.compile(tuple(numba.typeof(a) for a in call))  # (or loads it; runs nothing: the caller's call ran)
    return Bound(_jit.entry_point(mod.bound, call), tuple(live), fixed, ptrs, shapes, scal)
