"""The project's one numba jit helper.

Every kernel in ``impact_env`` (and in ``baselines``) is decorated with :func:`jit`, so caching
and compilation flags are set in one place.  Nothing is compiled at import time: numba compiles
a kernel lazily on its first call, and with caching on the machine code is reused across
processes.

Why a custom cache key: numba's own on-disk cache is keyed on the stamp (mtime, size) of the
file that holds the decorated function only.  A kernel that inlines or calls kernels from other
files (``run_periods`` calls ``advance``, which calls ``deriv``) would keep running stale
machine code after those files change.  :class:`_ProjectCacheLocator` keys every project kernel
on a hash of *all* project sources instead, so any edit invalidates every cached kernel.

Environment variables
---------------------
``IMPACT_ENV_NUMBA_CACHE``
    ``1`` (default) caches compiled kernels on disk (``__pycache__`` next to the source, or
    under ``NUMBA_CACHE_DIR`` if set); ``0`` turns the cache off.
``NUMBA_DISABLE_JIT``
    numba's own switch; ``1`` runs every kernel as plain Python (slow, but coverage and
    debuggers see the code).

Before the first compile of a project kernel in a process (that is, when the cache for the
current source stamp is cold), one line on stderr says so and how long it takes
(:data:`COLD_COMPILE_NOTICE`); a warm cache prints nothing.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

import numba
from numba.core import caching, config, event

CACHE = os.environ.get("IMPACT_ENV_NUMBA_CACHE", "1").strip().lower() not in ("0", "false", "no", "off")

_ROOT = Path(__file__).resolve().parent.parent
_PACKAGES = tuple(str(_ROOT / name) + os.sep for name in ("impact_env", "baselines"))


def _sources_hash() -> str:
    h = hashlib.sha256()
    for pkg in _PACKAGES:
        for path in sorted(Path(pkg).rglob("*.py")):
            h.update(str(path.relative_to(_ROOT)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


_STAMP = _sources_hash() if CACHE else ""


class _ProjectCacheLocator(caching.InTreeCacheLocator):
    """Numba cache locator for project kernels: the source stamp is the hash of every project
    source file, so a change anywhere in the project recompiles every cached kernel."""

    def __init__(self, py_func, py_file):
        super().__init__(py_func, py_file)
        if config.CACHE_DIR:
            self._cache_path = os.path.join(config.CACHE_DIR, self.get_suitable_cache_subpath(py_file))

    def get_source_stamp(self):
        return _STAMP

    @classmethod
    def from_function(cls, py_func, py_file):
        if not os.path.abspath(py_file).startswith(_PACKAGES):
            return None
        return super().from_function(py_func, py_file)


if _ProjectCacheLocator not in caching.CacheImpl._locator_classes:
    caching.CacheImpl._locator_classes.insert(0, _ProjectCacheLocator)


COLD_COMPILE_NOTICE = (
    "impact_env: compiling the numba kernels for this version of the code (no cached machine code "
    "for it yet{where}): about 20-60 s on a 2-core machine, once; later runs load them from the cache.")


class _ColdCompileNotice(event.Listener):
    """Says on stderr, once per process, that project kernels are being compiled.

    numba broadcasts ``numba:compile`` only on a cache miss (a kernel loaded from the on-disk
    cache is not compiled), so the line appears exactly when the cache for the current source
    stamp is cold (or caching is off), before the first compile, never at import."""

    def __init__(self):
        self.said = False

    def on_start(self, ev):
        if self.said:
            return
        func = getattr(ev.data.get("dispatcher"), "py_func", None)
        code = getattr(func, "__code__", None)
        if code is None or not os.path.abspath(code.co_filename).startswith(_PACKAGES):
            return
        self.said = True
        where = "" if CACHE else "; caching is off: IMPACT_ENV_NUMBA_CACHE=0"
        print(COLD_COMPILE_NOTICE.format(where=where), file=sys.stderr, flush=True)

    def on_end(self, ev):
        pass


_NOTICE = _ColdCompileNotice()
event.register("numba:compile", _NOTICE)


def jit(func=None, **options):
    """``numba.njit`` with the project's defaults (``cache`` from the environment, no fastmath).

    fastmath stays off: the kernels are compared bitwise between runs and against references,
    and reassociation would make results depend on the compiler's choices.
    """
    options.setdefault("cache", CACHE)
    options.setdefault("fastmath", False)
    options.setdefault("error_model", "numpy")
    if func is None:
        return lambda f: numba.njit(**options)(f)
    return numba.njit(**options)(func)


def bound_call(dispatcher, args: tuple):
    """A caller for ``dispatcher(*args)`` and later calls with arguments of exactly these types,
    which skips numba's per-call typing of the arguments (3 us of a single env's step, whose
    kernel takes 52 arrays in nested tuples).  Calls the dispatcher once (compiling or loading
    the kernel), then returns the compiled entry point for these types, or the dispatcher itself
    where numba did not record it.  Only for arguments whose types never change (the caller keeps
    its arrays, dtypes and layouts fixed); arrays must be C-contiguous where they were."""
    dispatcher(*args)
    sig = tuple(numba.typeof(a) for a in args)
    cres = dispatcher.overloads.get(sig)
    return dispatcher if cres is None else cres.entry_point
