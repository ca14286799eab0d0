"""The project's one numba jit helper.

Every kernel in ``impact_env`` is decorated with :func:`jit`, so caching
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
    under ``NUMBA_CACHE_DIR/impact_env-<sources hash>/`` if that is set, where a repository's
    checkout and an installed wheel of the same sources share their kernels); ``0`` turns the
    cache off.
``NUMBA_DISABLE_JIT``
    numba's own switch; ``1`` runs every kernel as plain Python (slow, but coverage and
    debuggers see the code).

While project kernels compile (the cache for the current source stamp is cold, or caching is
off), a progress line on stderr says how many kernels so far, which one now, and how long
(:class:`_CompileProgress`: "compiling numba kernels (first run of this code; cached
afterwards): 7 so far, now plant.integrators._advance_split, 41 s"), and a last line how many
and how long; a warm cache prints nothing, and nothing is printed at import.

Fewer specialisations: a kernel called from another kernel with a constant argument (``_trial(DOPRI5,
...)``) would be compiled once per constant value (numba types the constant as a literal); the
helper types such calls with the plain type (``int64``), so one machine-code version serves every
call, as it does for calls from Python (:func:`_plain_call_template`; numbers unchanged: the same
operations, no fastmath).
"""

from __future__ import annotations

import atexit
import hashlib
import os
import sys
import threading
import time
from pathlib import Path

import numba
from numba.core import caching, config, errors, event, types

CACHE = os.environ.get("IMPACT_ENV_NUMBA_CACHE", "1").strip().lower() not in ("0", "false", "no", "off")

_ROOT = Path(__file__).resolve().parent.parent
_PACKAGES = (str(_ROOT / "impact_env") + os.sep,)


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
            # under the sources' hash and the file's folder relative to the package, not numba's
            # hash of its absolute path: a checkout and an installed wheel of the same sources
            # share one cache, and different sources never overwrite each other's index
            folder = os.path.relpath(os.path.dirname(os.path.abspath(py_file)), _ROOT)
            self._cache_path = os.path.join(config.CACHE_DIR, f"impact_env-{_STAMP}", folder)

    def get_source_stamp(self):
        return _STAMP

    @classmethod
    def from_function(cls, py_func, py_file):
        if not os.path.abspath(py_file).startswith(_PACKAGES):
            return None
        return super().from_function(py_func, py_file)


if _ProjectCacheLocator not in caching.CacheImpl._locator_classes:
    caching.CacheImpl._locator_classes.insert(0, _ProjectCacheLocator)


PROGRESS_HEAD = "impact_env: compiling numba kernels (first run of this code; cached afterwards)"
#: one line at most this often when stderr is not a terminal (a log file, CI): a cold run's log
#: gets a few dozen lines under load, not one per kernel and second
LOG_EVERY_S = 20.0

_KERNELS: dict[int, object] = {}  # id(py_func) -> its dispatcher, for every kernel made by jit()


def _kernel_name(func) -> str:
    mod = getattr(func, "__module__", "") or ""
    mod = mod[len("impact_env."):] if mod.startswith("impact_env.") else mod
    return f"{mod}.{func.__qualname__}" if mod else func.__qualname__


class _CompileProgress(event.Listener):
    """The compile progress line on stderr (module doc).

    numba broadcasts ``numba:compile`` only on a cache miss (a kernel loaded from the on-disk
    cache is not compiled), so the line appears exactly when kernels are compiled, never at
    import.  Each kernel is counted once, when its first compile starts (a second signature of it
    is not counted again), so the count only climbs, by one.  There is no "of N": numba compiles
    a kernel when Python first calls it, so what a run will compile is known only at its end (an
    earlier total, counted from the kernels each call reaches, jumped from 1/1 to 8/19 to 20/20
    on the first run of compare); the last line gives the total.  One kernel can take minutes
    (typing a large one on a loaded machine), so while kernels compile a daemon thread renews the
    line's seconds (every second on a terminal, every :data:`LOG_EVERY_S` s in a log); numba's
    typing and LLVM let it run."""

    def __init__(self, stream=None):
        self.stream = stream
        self.depth = 0  # project kernels compiling now (nested: a caller types its callees)
        self.numbered: dict[int, int] = {}  # id(py_func) -> its number, in the order compiles started
        self.done = 0
        self.t0: float | None = None
        self.last = -1e300
        self.width = 0
        self.busy = 0.0  # s spent compiling (outermost compiles' wall time, summed)
        self.entered = 0.0  # when the outermost compile now running started
        self.names: list[str] = []  # the kernels compiling now, callers first
        self.beat: tuple[int, threading.Thread] | None = None  # (pid, thread): a fork has none

    def _out(self):
        return self.stream if self.stream is not None else sys.stderr

    def _show(self, force: bool) -> None:
        if self.t0 is None or not self.names:
            return
        now = time.perf_counter()
        where = "" if CACHE else "; caching is off: IMPACT_ENV_NUMBA_CACHE=0"
        busy = self.busy + now - self.entered  # s of compiling so far
        line = f"{PROGRESS_HEAD}{where}: {len(self.numbered)} so far, now {self.names[-1]}, {busy:.0f} s"
        out = self._out()
        if out.isatty():
            print("\r" + line.ljust(self.width), end="", file=out, flush=True)
            self.width = len(line)
        elif force or now - self.last >= LOG_EVERY_S:
            print(line, file=out, flush=True)
            self.last = now

    def _heartbeat(self) -> None:
        while True:
            time.sleep(1.0 if self._out().isatty() else LOG_EVERY_S)
            if self.depth > 0:
                self._show(force=False)

    def on_start(self, ev):
        d = ev.data.get("dispatcher")
        func = getattr(d, "py_func", None)
        if func is None or id(func) not in _KERNELS:
            return
        if self.t0 is None:
            self.t0 = time.perf_counter()
            atexit.register(self.summary)
        if self.beat is None or self.beat[0] != os.getpid():
            thread = threading.Thread(target=self._heartbeat, name="impact_env-compile-progress", daemon=True)
            thread.start()
            self.beat = (os.getpid(), thread)
        if self.depth == 0:
            self.entered = time.perf_counter()
        self.depth += 1
        first = not self.numbered
        self.numbered.setdefault(id(func), len(self.numbered) + 1)
        self.names.append(_kernel_name(func))
        self._show(force=first)

    def on_end(self, ev):
        func = getattr(ev.data.get("dispatcher"), "py_func", None)
        if func is None or id(func) not in _KERNELS:
            return
        self.depth -= 1
        self.done += 1
        if self.names:  # back in the caller (numba lowers it after typing its callees)
            self.names.pop()
        if self.depth == 0:
            self.busy += time.perf_counter() - self.entered
        out = self._out()
        if self.depth == 0 and self.width and out.isatty():  # the line goes before anything else prints
            print("\r" + " " * self.width + "\r", end="", file=out, flush=True)
            self.width = 0

    def summary(self):
        if self.t0 is None or self.done == 0:
            return
        print(f"impact_env: compiled {len(self.numbered)} numba kernels in {self.busy:.0f} s"
              + ("; later runs load them from the cache" if CACHE else " (caching is off)"),
              file=self._out(), flush=True)
        self.t0 = None


_PROGRESS = _CompileProgress()
event.register("numba:compile", _PROGRESS)


def _plain_call_template(dispatcher):
    """``dispatcher.get_call_template`` typing a kernel-to-kernel call's literal arguments
    (``Literal[int](3)``) as their plain types, so that one compiled version serves calls with
    any constant; where a kernel needs the literal (it indexes a heterogeneous tuple with it),
    numba's own typing."""
    own = dispatcher.get_call_template

    def get_call_template(args, kws):
        plain = tuple(types.unliteral(a) for a in args)
        plain_kws = {k: types.unliteral(v) for k, v in kws.items()}
        if plain != tuple(args) or plain_kws != kws:
            try:
                return own(plain, plain_kws)
            except errors.TypingError:
                pass
        return own(args, kws)

    return get_call_template


def jit(func=None, **options):
    """``numba.njit`` with the project's defaults (``cache`` from the environment, no fastmath).

    fastmath stays off: the kernels are compared bitwise between runs and against references,
    and reassociation would make results depend on the compiler's choices.

    ``inline="always"`` (numba inlines the callee's typed IR into each caller) is for the small
    kernels of the per-env step (the plant, the effects, the stage, the task): measured against
    plain calls, it makes the vector env's step faster (LLVM leaves many of those calls out of
    line) and ``compare``'s rollout slower (docs/architecture.md, "Compiled kernels").  Never for
    a large kernel that many callers reach, as the
    model-predictive laws' solver and estimator: every caller would type and compile its own
    copy (docs/architecture.md, "Compiled kernels").
    """
    options.setdefault("cache", CACHE)
    options.setdefault("fastmath", False)
    options.setdefault("error_model", "numpy")
    if func is None:
        return lambda f: jit(f, **options)
    dispatcher = numba.njit(**options)(func)
    dispatcher.get_call_template = _plain_call_template(dispatcher)
    _KERNELS[id(func)] = dispatcher
    return dispatcher


def bound_call(dispatcher, args: tuple):
    """A caller for ``dispatcher(*args)`` and later calls with arguments of exactly these types,
    which skips numba's per-call typing of the arguments (3 us of a single env's step, whose
    kernel takes 52 arrays in nested tuples).  Calls the dispatcher once (compiling or loading
    the kernel), then returns the compiled entry point for these types, or the dispatcher itself
    where numba did not record it.  Only for arguments whose types never change (the caller keeps
    its arrays, dtypes and layouts fixed); arrays must be C-contiguous where they were."""
    dispatcher(*args)
    return entry_point(dispatcher, args)


def entry_point(dispatcher, args: tuple):
    """The compiled entry point of ``dispatcher`` for the types of ``args``, once a call with them
    has compiled or loaded it (else the dispatcher): :func:`bound_call` for a caller that needs
    its first call's result."""
    sig = tuple(numba.typeof(a) for a in args)
    cres = dispatcher.overloads.get(sig)
    return dispatcher if cres is None else cres.entry_point
