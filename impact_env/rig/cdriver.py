"""Drivers called by address from the compiled loop.  A driver written in C
(``impact_env/deploy/rt/impact_driver.h``), loaded from a shared library:
what a lab writes around its DAQ library (NI-DAQmx, comedi, a board's SDK) so that the target's
compiled loop (:mod:`impact_env.rig.rtloop`) calls ``read`` and ``apply`` every tick with no
Python in between.  ``impact-env rig serve --driver LIB.so --driver-config STRING``.

The library exports ``int impact_driver_open(impact_driver *drv, const char *config)``, which
fills the struct's function pointers and context.  The lifecycle calls outside the tick (arm,
release, idle, close) go through ctypes from Python; the tick's read and apply through their
addresses (:mod:`impact_env.rig.cfunc`) from compiled code.  A Python
:class:`~impact_env.rig.driver.RigDriver` is called the same way, through
:class:`PythonCallbacks` (lock-step only).
"""

from __future__ import annotations

import ctypes
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np

from impact_env.rig.driver import RigDriver
from impact_env.rig.errors import RigError
from impact_env.scene import Scene, load_scene

ABI = 2  # IMPACT_DRIVER_ABI
RT_DIR = Path(__file__).resolve().parent.parent / "deploy" / "rt"

_READ = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_int64, ctypes.POINTER(ctypes.c_double))
_APPLY = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_int64, ctypes.c_double)
_VOID = ctypes.CFUNCTYPE(None, ctypes.c_void_p)
_ARM = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_uint64)
_RELEASE = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p)


class _Struct(ctypes.Structure):
    _fields_ = [("ctx", ctypes.c_void_p), ("read", ctypes.c_void_p), ("apply", ctypes.c_void_p),
                ("idle", ctypes.c_void_p), ("arm", ctypes.c_void_p), ("release", ctypes.c_void_p),
                ("close", ctypes.c_void_p), ("abi", ctypes.c_uint32), ("real_size", ctypes.c_uint32)]


class CDriver(RigDriver):
    """The driver in the shared library ``path`` (opened with ``config``) for the rig ``scene``
    describes (control rate, command scale, sensor calibration).  ``virtual`` is False: the
    target sees what a physical rig gives it, its readings and its applied commands."""

    virtual = False

    def __init__(self, path: str | os.PathLike, scene: Scene | str = "rig", config: str = ""):
        self.scene = load_scene(scene)
        self.path = Path(path)
        if not self.path.is_file():
            raise RigError(f"--driver {str(path)!r}: no such shared library")
        try:
            self._lib = ctypes.CDLL(str(self.path.resolve()))
        except OSError as exc:
            raise RigError(f"--driver {str(path)!r}: cannot load it ({exc})") from None
        try:
            open_fn = self._lib.impact_driver_open
        except AttributeError:
            raise RigError(f"--driver {str(path)!r} exports no impact_driver_open(impact_driver *, "
                           "const char *) (impact_env/deploy/rt/impact_driver.h)") from None
        open_fn.argtypes = [ctypes.POINTER(_Struct), ctypes.c_char_p]
        open_fn.restype = ctypes.c_int
        self._s = _Struct()
        self.config = config
        rc = open_fn(ctypes.byref(self._s), config.encode())
        if rc != 0:
            raise RigError(f"--driver {str(path)!r}: impact_driver_open(config={config!r}) returned {rc}")
        s = self._s
        if s.abi != ABI or s.real_size != 8:
            raise RigError(f"--driver {str(path)!r}: ABI {s.abi} with {s.real_size}-byte impact_real; the "
                           f"target needs ABI {ABI} and double (build with -DIMPACT_DRIVER_STANDALONE, "
                           "no IMPACT_FLOAT32)")
        missing = [f[0] for f in _Struct._fields_[1:7] if not getattr(s, f[0])]
        if missing:
            raise RigError(f"--driver {str(path)!r}: impact_driver_open left {', '.join(missing)} NULL")
        self._read = _READ(s.read)
        self._apply = _APPLY(s.apply)
        self._idle = _VOID(s.idle)
        self._arm = _ARM(s.arm)
        self._release = _RELEASE(s.release)
        self._close = _VOID(s.close)
        self._buf = np.zeros(4)
        self._tick = 0
        self._open = True

    @property
    def addresses(self) -> tuple[int, int, int]:
        """(read, apply, ctx) as ints, for the compiled loop."""
        return int(self._s.read), int(self._s.apply), int(self._s.ctx or 0)

    def initialise(self) -> None:
        self.idle()

    def arm(self, seed: int) -> None:
        rc = self._arm(self._s.ctx, int(seed) & 0xFFFFFFFFFFFFFFFF)
        if rc != 0:
            raise RigError(f"the C driver's arm() returned {rc}")
        self._tick = 0

    def release(self) -> None:
        rc = self._release(self._s.ctx)
        if rc != 0:
            raise RigError(f"the C driver's release() returned {rc}")

    def read(self) -> np.ndarray:
        """The readings of the current tick (tick 0 after ``arm``; lock-step tests only)."""
        rc = self._read(self._s.ctx, self._tick, self._buf.ctypes.data_as(ctypes.POINTER(ctypes.c_double)))
        if rc != 0:
            raise RigError(f"the C driver's read(tick {self._tick}) returned {rc}")
        return self._buf

    def read_tick(self, tick: int) -> np.ndarray:
        """The readings of ``tick`` (a copy)."""
        self._tick = int(tick)
        return self.read().copy()

    def apply(self, command: float, ticks: int = 1) -> float:
        self._apply(self._s.ctx, self._tick, float(command))
        self._tick += int(ticks)
        return float(command) * float(self.scene.effects.command_scale)

    def idle(self) -> None:
        if self._open:
            self._idle(self._s.ctx)

    def shutdown(self) -> None:
        if self._open:
            self._open = False
            self._idle(self._s.ctx)
            self._close(self._s.ctx)


class PythonCallbacks:
    """A Python :class:`~impact_env.rig.driver.RigDriver`'s ``read`` and ``apply`` as C functions
    of the driver ABI's signatures (ctypes callbacks), so that the compiled loop
    (:mod:`impact_env.rig.rtloop`) calls them by address as it calls a C driver's: one loop for
    every driver.  Each call takes the GIL: lock-step only (the target refuses real time).

    ``apply`` writes the force the driver returns into :attr:`applied` (the log's
    ``force_applied_N``).  An exception in the driver, or a fault its ``error()`` reports, returns
    a non-zero code: the loop drives 0 N and ends the episode FAULT; :meth:`take_fault` says what
    it was."""

    def __init__(self, driver: RigDriver):
        self.driver = driver
        self.applied = np.zeros(1)  # N
        self.fault = ""
        # kept referenced for the target's lifetime: the loop holds only their addresses
        self._read = _READ(self._on_read)
        self._apply = _APPLY(self._on_apply)

    @property
    def addresses(self) -> tuple[int, int, int]:
        """(read, apply, ctx) as ints, for the compiled loop (no context: the callbacks are bound)."""
        return (int(ctypes.cast(self._read, ctypes.c_void_p).value or 0),
                int(ctypes.cast(self._apply, ctypes.c_void_p).value or 0), 0)

    def take_fault(self) -> str:
        fault, self.fault = self.fault, ""
        return fault

    def _on_read(self, _ctx, tick: int, buf) -> int:
        try:
            raw = self.driver.read()
            for i in range(4):
                buf[i] = float(raw[i])
        except Exception as exc:  # noqa: BLE001 (any driver error ends the episode FAULT, named)
            self.fault = f"read() at tick {tick} raised {type(exc).__name__}: {exc}"
            return -1
        return 0

    def _on_apply(self, _ctx, tick: int, command: float) -> int:
        try:
            self.applied[0] = self.driver.apply(command)
            fault = self.driver.error()
        except Exception as exc:  # noqa: BLE001
            self.fault = f"apply() at tick {tick} raised {type(exc).__name__}: {exc}"
            return -1
        if fault:
            self.fault = f"at tick {tick}: {fault}"
            return -2
        return 0


def build_replay_driver(out_dir: str | os.PathLike, cc: str | None = None) -> Path:
    """Compile ``deploy/rt/replay_driver.c`` into ``out_dir/replay_driver.so`` (gcc; the flags of
    the C export's checks) and return its path."""
    cc = cc or shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        raise RigError("no C compiler (gcc or cc) on PATH to build the replay driver")
    out = Path(out_dir) / "replay_driver.so"
    cmd = [cc, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-ffp-contract=off", "-shared", "-fPIC",
           "-DIMPACT_DRIVER_STANDALONE", f"-I{RT_DIR}", "-o", str(out), str(RT_DIR / "replay_driver.c"),
           "-lm"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RigError(f"building the replay driver failed: {' '.join(cmd)}\n{r.stderr}")
    return out
