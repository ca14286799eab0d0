"""A driver written in C (``impact_env/deploy/rt/impact_driver.h``), loaded from a shared library:
what a lab writes around its DAQ library (NI-DAQmx, comedi, a board's SDK) so that the target's
compiled loop (:mod:`impact_env.rig.rtloop`) calls ``read`` and ``apply`` every tick with no
Python in between.  ``impact-env rig serve --driver LIB.so --driver-config STRING``.

The library exports ``int impact_driver_open(impact_driver *drv, const char *config)``, which
fills the struct's function pointers and context.  The lifecycle calls outside the tick (arm,
release, idle, close) go through ctypes from Python; the tick's read and apply through their
addresses (:mod:`impact_env.rig.cfunc`) from compiled code.
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
