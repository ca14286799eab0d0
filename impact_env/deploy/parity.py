"""Proof that a generated C file acts as the simulator's kernels do: build it with gcc, load it
with :mod:`ctypes`, and drive it tick by tick beside the numba target (the rig target's
:class:`~impact_env.rig.controller.Controller`, onboard mode) on readings recorded from the
virtual rig (:class:`~impact_env.rig.driver.VirtualRig`), or in closed loop with the virtual
rig as the plant.

``impact-env export SPEC --scene S --c DIR --check`` runs :func:`check` after writing; the
tests (``tests/test_c_export.py``) run it over scenes, seeds, laws and networks.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from impact_env.config import ConfigError
from impact_env.control.observation import make_layout
from impact_env.control.policy import CompiledPolicy
from impact_env.deploy.c_export import HEADER_NAME, SOURCE_NAME, float32_refusal
from impact_env.hardware import stage as hardware_stage
from impact_env.hardware.batch import Hardware
from impact_env.rig.controller import Controller
from impact_env.rig.driver import VirtualRig
from impact_env.sim import records as sim_records
from impact_env.sim.metrics import EpisodeMetrics

CFLAGS = ("-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-ffp-contract=off")
F32_EPS = float(np.finfo(np.float32).eps)
# What docs/rig/c-export.md promises of a build ("Deploying to real-time hardware", "How it is checked"):
# the double build bitwise the numba target's (every command, force and status word); the float32
# build within F32_BOUND of full scale on the ticks where both builds take the same discrete
# decisions (the same status bits and the same contact-detector bit, at the tick and at its policy
# step's first tick, where the policy read it), and at most F32_FLIP_FRACTION of the ticks deciding
# differently (on those the command may differ by anything up to full scale: a law's force gated
# on a detector a tick apart is 0 N in one build and 20 N in the other).
F32_BOUND = 1e-4
F32_FLIP_FRACTION = 0.05


def find_cc() -> str:
    """The C compiler: ``$CC`` or gcc."""
    cc = os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")
    if not cc:
        raise ConfigError("no C compiler found (install gcc, or set CC)")
    return cc


def build_shared(c_dir, out: Path | None = None, float32: bool = False, extra: tuple[str, ...] = ()) -> Path:
    """Compile ``c_dir``'s impact_policy.c as a shared library with :data:`CFLAGS` (and
    ``-DIMPACT_FLOAT32``); returns its path.  A warning is an error."""
    c_dir = Path(c_dir)
    out = Path(out) if out is not None else c_dir / ("libimpact_f32.so" if float32 else "libimpact.so")
    cmd = [find_cc(), *CFLAGS, "-fPIC", "-shared", *(("-DIMPACT_FLOAT32",) if float32 else ()), *extra,
           "-o", str(out), str(c_dir / SOURCE_NAME),
           "-lm"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    if r.returncode != 0:
        raise ConfigError(f"compiling {c_dir / SOURCE_NAME} failed ({' '.join(cmd)}):\n{r.stderr[-4000:]}")
    return out


RT_DIR = Path(__file__).resolve().parent / "rt"
# an ARM Linux (32-bit, hard float) cross-compiler, Debian's gcc-arm-linux-gnueabihf: its static
# build of the real-time example runs under qemu-arm user mode (Debian's qemu-user)
ARM_LINUX_CC = "arm-linux-gnueabihf-gcc"
ARM_FLAGS = ("-mcpu=cortex-m7", "-mfpu=fpv5-d16", "-mfloat-abi=hard", "-mthumb", "-Os", "-std=c99", "-Wall",
             "-Wextra", "-Werror", "-ffp-contract=off")


def build_rt_example(c_dir, out, float32: bool = False, cc: str | None = None,
                     extra: tuple[str, ...] = ()) -> Path:
    """The real-time Linux example (``impact_env/deploy/rt``: main.c, the replay driver) linked
    with ``c_dir``'s impact_policy.c; returns the executable.  ``cc``: another compiler (e.g.
    :data:`ARM_LINUX_CC` with ``extra=("-static",)`` for a build that ``qemu-arm`` runs)."""
    c_dir, out = Path(c_dir), Path(out)
    cmd = [cc or find_cc(), *CFLAGS, *extra, *(("-DIMPACT_FLOAT32",) if float32 else ()), f"-I{c_dir}",
           f"-I{RT_DIR}",
           "-o", str(out), str(RT_DIR / "main.c"), str(RT_DIR / "replay_driver.c"), str(c_dir / SOURCE_NAME),
           "-lm"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    if r.returncode != 0:
        raise ConfigError(f"compiling the real-time example failed ({' '.join(cmd)}):\n{r.stderr[-4000:]}")
    return out


def build_arm(c_dir, out, float32: bool = False, cc: str = "arm-none-eabi-gcc") -> dict[str, int]:
    """Compile ``c_dir``'s impact_policy.c for a Cortex-M7 with its double FPU (:data:`ARM_FLAGS`,
    Debian's gcc-arm-none-eabi) into object ``out``; returns its sizes (bytes: text, data, bss)
    from ``arm-none-eabi-size``."""
    c_dir, out = Path(c_dir), Path(out)
    exe = shutil.which(cc)
    if exe is None:
        raise ConfigError(f"{cc} not found: install Debian's gcc-arm-none-eabi")
    cmd = [exe, *ARM_FLAGS, *(("-DIMPACT_FLOAT32",) if float32 else ()), "-c", "-o", str(out),
           str(c_dir / SOURCE_NAME)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    if r.returncode != 0:
        raise ConfigError(f"cross-compiling failed ({' '.join(cmd)}):\n{r.stderr[-4000:]}")
    size_exe = shutil.which("arm-none-eabi-size") or "arm-none-eabi-size"
    lines = subprocess.run([size_exe, str(out)], capture_output=True, text=True, timeout=60,
                           check=True).stdout.split("\n")
    size = lines[1].split()
    return {"text": int(size[0]), "data": int(size[1]), "bss": int(size[2])}


class CPolicy:
    """A built library: one ``impact_state`` (caller-owned memory, here a ctypes buffer) and its
    four functions."""

    def __init__(self, lib_path, float32: bool = False):
        self.lib = ctypes.CDLL(str(lib_path))
        self.real = ctypes.c_float if float32 else ctypes.c_double
        self.dtype = np.float32 if float32 else np.float64
        self.lib.impact_state_bytes.restype = ctypes.c_ulong
        self.state = ctypes.create_string_buffer(int(self.lib.impact_state_bytes()))
        self.lib.impact_step.restype = ctypes.c_uint32
        ptr = ctypes.POINTER(self.real)
        self.lib.impact_step.argtypes = [ctypes.c_void_p, ptr, ptr, ptr]
        self.lib.impact_idle.argtypes = [ctypes.c_void_p, ctypes.c_int64]
        self.lib.impact_contact.argtypes = [ctypes.c_void_p]
        self.lib.impact_contact.restype = ctypes.c_int
        self._r = np.zeros(4, dtype=self.dtype)
        self._cmd, self._f = self.real(), self.real()
        self.lib.impact_init(self.state)

    def init(self) -> None:
        """Power-on: all state zero, the RMS window cool."""
        self.lib.impact_init(self.state)

    def reset(self) -> None:
        self.lib.impact_reset(self.state)

    def idle(self, ticks: int) -> None:
        self.lib.impact_idle(self.state, int(ticks))

    def step(self, readings) -> tuple[float, float, int]:
        """(command, force N, status bits) of one tick."""
        self._r[:] = readings
        st = self.lib.impact_step(self.state, self._r.ctypes.data_as(ctypes.POINTER(self.real)),
                                  ctypes.byref(self._cmd), ctypes.byref(self._f))
        return float(self._cmd.value), float(self._f.value), int(st)

    def contact(self) -> int:
        """The front end's contact detector bit after the last step (0 or 1)."""
        return int(self.lib.impact_contact(self.state))


def numba_controller(policy: CompiledPolicy, scene, horizon_ticks: int):
    """The rig target's controller for ``policy`` in onboard mode (its residual law included)."""

    layout = make_layout(scene, policy.observation, policy.history)
    return Controller(scene, layout, policy.hold_ticks, horizon_ticks, "onboard", policy,
                      policy.residual_policy())


def _numba_tick(ctl, m: int, raw: np.ndarray) -> tuple[float, float, int]:
    if m == 0:
        ctl.start(raw, None)
    else:
        ctl.observe(m, raw, None)
    cmd, f, status, _row = ctl.act(m, 0.0, -1, -1, m, raw)  # onboard: no host command
    return float(cmd), float(f), int(status)


@dataclass
class Recording:
    """One closed-loop episode of the numba target on the virtual rig: the readings of every
    tick (float64[n, 4]) and what the target answered (command, force N, status)."""

    readings: np.ndarray
    command: np.ndarray
    force: np.ndarray
    status: np.ndarray
    records: np.ndarray | None = None  # the virtual rig's true records (float64[n, N_REC]), closed loops
    detected: np.ndarray | None = None  # int64[n]: the front end's contact detector bit of each tick
    memory: np.ndarray | None = None  # the numba target's policy memory row after the last tick (recorded)


def _true_record(drv, m: int, u: float) -> np.ndarray:
    """The virtual rig's true record of tick m (:mod:`impact_env.sim.records`), after ``apply``."""

    r = np.zeros(sim_records.N_REC)
    info = drv.last_info
    r[sim_records.REC.t] = (m + 1.0) / drv.scene.control_rate
    r[sim_records.REC.x1:sim_records.REC.v2 + 1] = drv.truth()
    r[sim_records.REC.u] = u
    r[sim_records.REC.f_demand] = info[hardware_stage.INFO_F_DEMAND]
    r[sim_records.REC.f_applied] = info[hardware_stage.INFO_F_APPLIED]
    r[sim_records.REC.saturated] = info[hardware_stage.INFO_SATURATED]
    r[sim_records.REC.contact_force] = info[hardware_stage.INFO_CONTACT_FORCE]
    r[sim_records.REC.status] = info[hardware_stage.INFO_STATUS]
    return r


def episode_metrics(scene, seed: int, records: np.ndarray) -> dict[str, float]:
    """compare's metrics (:class:`~impact_env.sim.metrics.EpisodeMetrics`) of a closed loop's
    true records, the drop's constants drawn from ``seed`` as the virtual rig drew them (as
    :func:`impact_env.rig.log_metrics.exact_metrics` does for a virtual rig's log)."""
    from gymnasium.utils import seeding

    hw = Hardware(scene, 1)
    hw.reset([seeding.np_random(int(seed))[0]])
    m = EpisodeMetrics(1, 1.0 / scene.control_rate)
    m.start(hw.t_touch, hw.impact_speed, hw.impact_energy, hw.Y[:, 0] - hw.Y[:, 2] > 0.0)
    m.step(records[None, :, :], hw.P)

    failed = np.array([bool(np.any(records[:, sim_records.REC.status] != 0.0))])
    return {k: float(v[0]) for k, v in m.finish(failed).items()}


def record(policy: CompiledPolicy, scene, seed: int, ticks: int) -> Recording:
    """The numba target in closed loop with the virtual rig for ``ticks`` ticks of the drop
    ``seed`` (the drop and noise ``ImpactCatch-v0`` meets for that reset seed)."""

    drv = VirtualRig(scene)
    drv.initialise()
    drv.arm(int(seed))
    drv.release()
    ctl = numba_controller(policy, scene, ticks)
    raw = np.zeros((ticks, 4))
    out = np.zeros((3, ticks))
    det = np.zeros(ticks, np.int64)
    for m in range(ticks):
        raw[m] = drv.read()
        cmd, f, st = _numba_tick(ctl, m, raw[m].copy())
        out[:, m] = cmd, f, st
        det[m] = int(ctl.fe.detected[0] != 0.0)
        drv.apply(cmd)
    drv.shutdown()
    return Recording(raw, out[0], out[1], out[2].astype(np.int64), detected=det,
                     memory=ctl.state.memory[0].copy())


def readings_from_log(log) -> np.ndarray:
    """The raw readings of a rig episode log (:class:`impact_env.rig.log.EpisodeLog`) as the C
    tick takes them: float64[n, 4], one row per tick from tick 0 (accelerometer m/s^2, force N,
    potentiometer m, and NaN for the body-1 sensor, which the log does not hold: the rig has
    none).  ConfigError when ticks are missing (skipped by overruns: their readings were never
    read, and a replay needs every tick)."""
    tick = np.asarray(log["tick"], dtype=np.int64)
    if tick.size == 0:
        raise ConfigError("the log has no rows")
    gaps = np.flatnonzero(np.diff(tick) != 1)
    if tick[0] != 0 or gaps.size:
        where = f"tick {int(tick[gaps[0]]) + 1}" if gaps.size else f"ticks 0 to {int(tick[0]) - 1}"
        raise ConfigError(f"the log misses {int(tick[-1]) + 1 - tick.size} ticks (first: {where}; skipped by "
                          "overruns, their readings never read): a replay needs every tick; record it in "
                          "lock-step (rig serve --lockstep) or on an idle core")
    out = np.full((tick.size, 4), np.nan)
    for j, name in enumerate(("accelerometer_mps2", "force_N", "potentiometer_m")):
        out[:, j] = log[name]
    return out


def replay(cp: CPolicy, rec: Recording, before_tick=None) -> Recording:
    """The C step on the recorded readings (open loop), from power-on as the recording's fresh
    controller (a cool RMS window): its commands, forces and status.  ``before_tick(m)``, when
    given, runs before tick m's step (a diagnostic that sets a global of the library)."""
    cp.init()
    cp.reset()
    n = rec.readings.shape[0]
    out = np.zeros((3, n))
    det = np.zeros(n, np.int64)
    for m in range(n):
        if before_tick is not None:
            before_tick(m)
        out[:, m] = cp.step(rec.readings[m])
        det[m] = cp.contact()
    return Recording(rec.readings, out[0], out[1], out[2].astype(np.int64), detected=det)


def closed_loop(cp: CPolicy, scene, seed: int, ticks: int, perturb: np.ndarray | None = None) -> Recording:
    """The C step in closed loop with the virtual rig (its hardware stage as the plant), with
    the rig's true records.  ``perturb`` (float64[ticks]): added to each tick's command on its way
    to the rig (the C state does not see it): a model of a build's command error, for the
    sensitivity of the metrics to it."""

    drv = VirtualRig(scene)
    drv.initialise()
    drv.arm(int(seed))
    drv.release()
    cp.init()
    cp.reset()
    raw = np.zeros((ticks, 4))
    out = np.zeros((3, ticks))
    recs = []
    for m in range(ticks):
        raw[m] = drv.read()
        out[:, m] = cp.step(raw[m])
        u = out[0, m] + (0.0 if perturb is None else float(perturb[m]))
        drv.apply(u)
        recs.append(_true_record(drv, m, u))
    drv.shutdown()
    return Recording(raw, out[0], out[1], out[2].astype(np.int64), np.array(recs))


#: double closed loops with random command errors of the float32 build's size, and the factor on
#: their largest deviation (eight draws understate the family's reach, and float32's errors are
#: correlated along the trajectory, not independent)
ENSEMBLE = 8
ENVELOPE_FACTOR = 2.0


@dataclass(frozen=True)
class ClosedLoopMetric:
    """One metric of a float32 closed loop against the double one, and its bound."""

    double: float
    float32: float
    bound: float

    @property
    def deviation(self) -> float:
        """|float32 - double|, 0 when both are the same infinity (not caught in the horizon)."""
        return 0.0 if self.float32 == self.double else abs(self.float32 - self.double)

    @property
    def within(self) -> bool:
        return self.deviation <= self.bound


def closed_loop_check(c64: CPolicy, c32: CPolicy, scene, seed: int,
                      ticks: int) -> dict[str, ClosedLoopMetric]:
    """The float32 build's closed loop against the double build's, by compare's metrics (energy
    integral, time to catch, peak force), each against the bound its command error implies: float32
    changes each tick's command by at most :data:`F32_BOUND` of full scale where the builds decide
    alike, and the contacts amplify such a change (a bounce moves by a tick, the catch-energy ratio
    crosses 1 % at another time), so the bound is how far the metric moves when the double loop's
    commands carry random errors of that size: the largest deviation of :data:`ENSEMBLE` such runs
    (uniform in +-F32_BOUND, seeded by ``1000 + seed``) times :data:`ENVELOPE_FACTOR`, plus the
    metric's resolution (1e-4 relative for the integral, one period for the catch time, one
    F32_BOUND of full scale for the peak force)."""
    def metrics(cp: CPolicy, err: np.ndarray | None = None) -> dict[str, float]:
        records = closed_loop(cp, scene, seed, ticks, err).records
        assert records is not None  # a closed loop keeps the rig's true records
        return episode_metrics(scene, seed, records)

    m64, m32 = metrics(c64), metrics(c32)
    floors = {"energy_integral_ms": 1e-4 * m64["energy_integral_ms"],
              "time_to_catch_s": 1.0 / scene.control_rate,
              "peak_force_N": F32_BOUND * scene.effects.command_scale}
    rng = np.random.default_rng(1000 + seed)
    reach = dict.fromkeys(floors, 0.0)
    for _ in range(ENSEMBLE):
        err = rng.uniform(-F32_BOUND, F32_BOUND, ticks)
        mp = metrics(c64, err)
        for k in floors:
            reach[k] = max(reach[k], ClosedLoopMetric(m64[k], mp[k], 0.0).deviation)
    return {k: ClosedLoopMetric(m64[k], m32[k], ENVELOPE_FACTOR * reach[k] + floor)
            for k, floor in floors.items()}


def numba_sequence(policy: CompiledPolicy, scene, episodes, idle_ticks) -> list[Recording]:
    """The numba target over consecutive episodes on given readings (``episodes``: float64[n_k, 4]
    each), as one target process runs them: one :class:`~impact_env.rig.controller.Controller`
    from power-on, ``idle_ticks[k - 1]`` disarmed ticks before episode k > 0
    (:meth:`~impact_env.rig.controller.Controller.drain`: the RMS window cools, and keeps the
    heat the idle time does not cover), then the release (``start``: latches cleared)."""
    ctl = numba_controller(policy, scene, max(len(r) for r in episodes))
    out = []
    for k, raw in enumerate(episodes):
        if k:
            ctl.drain(int(idle_ticks[k - 1]))
        res = np.zeros((3, len(raw)))
        for m in range(len(raw)):
            res[:, m] = _numba_tick(ctl, m, np.array(raw[m], dtype=np.float64))
        out.append(Recording(np.asarray(raw), res[0], res[1], res[2].astype(np.int64)))
    return out


def c_sequence(cp: CPolicy, episodes, idle_ticks) -> list[Recording]:
    """:func:`numba_sequence` for the C step: ``impact_init`` once (power-on), then per episode
    ``impact_idle(idle_ticks[k - 1])`` (k > 0), ``impact_reset`` and one ``impact_step`` a tick."""
    cp.init()
    out = []
    for k, raw in enumerate(episodes):
        if k:
            cp.idle(int(idle_ticks[k - 1]))
        cp.reset()
        res = np.zeros((3, len(raw)))
        for m in range(len(raw)):
            res[:, m] = cp.step(raw[m])
        out.append(Recording(np.asarray(raw), res[0], res[1], res[2].astype(np.int64)))
    return out


@dataclass
class ParityReport:
    """How a build compares with the numba target: ticks compared, ticks whose command differs
    bitwise, the largest |command difference| (of full scale: commands are in units of it) and the
    status words that differ; ``flipped``: the ticks whose discrete decisions differ (status bits or
    the contact detector, :func:`decisions_differ`), ``max_abs_same`` the largest |command
    difference| on the other ticks."""

    ticks: int
    differing: int
    max_abs: float
    status_differing: int
    flipped: int = 0
    max_abs_same: float = 0.0

    def __str__(self) -> str:
        return (f"{self.ticks} ticks: {self.differing} commands differ (max |diff| {self.max_abs:.3g}), "
                f"{self.status_differing} status words differ")

    def verdict(self, float32: bool) -> tuple[bool, str]:
        """(passed, a line saying against which bound of docs/rig/c-export.md): the double build bitwise; the
        float32 build within :data:`F32_BOUND` of full scale where the decisions agree, and at most
        :data:`F32_FLIP_FRACTION` of the ticks deciding differently."""
        if not float32:
            ok = self.differing == 0 and self.status_differing == 0
            return ok, (f"{'PASS' if ok else 'FAIL'}: {self.differing} of {self.ticks} commands and "
                        f"{self.status_differing} status words differ (bound: 0, bitwise)")
        frac = self.flipped / max(self.ticks, 1)
        ok = self.max_abs_same <= F32_BOUND and frac <= F32_FLIP_FRACTION
        return ok, (f"{'PASS' if ok else 'FAIL'}: on the {self.ticks - self.flipped} ticks with the same "
                    f"decisions max |diff| {self.max_abs_same:.3g} of full scale (bound {F32_BOUND:g}); "
                    f"{self.flipped} ticks ({100 * frac:.2f} %) decide differently (status bits or contact "
                    f"detector; bound {100 * F32_FLIP_FRACTION:g} %), there max |diff| {self.max_abs:.3g}")


def decisions_differ(a: Recording, b: Recording, hold: int = 1) -> np.ndarray:
    """bool[n]: the ticks where the two runs take different discrete decisions: other status bits,
    another contact-detector bit (the laws gate their force on it), or another detector bit at the
    first tick of the tick's policy step (the policy read it there and holds its action)."""
    flip = a.status != b.status
    if a.detected is not None and b.detected is not None:
        det = a.detected != b.detected
        first = np.arange(det.size) // hold * hold
        flip = flip | det | det[first]
    return flip


def compare_runs(a: Recording, b: Recording, hold: int = 1) -> ParityReport:
    d = np.abs(a.command - b.command)
    flip = decisions_differ(a, b, hold)
    same = d[~flip]
    return ParityReport(int(a.command.size), int(np.count_nonzero(a.command != b.command)), float(d.max()),
                        int(np.count_nonzero(a.status != b.status)), int(np.count_nonzero(flip)),
                        float(same.max()) if same.size else 0.0)


def check(policy: CompiledPolicy, scene, c_dir, seeds=(0, 1), ticks: int = 2000,
          float32: bool = False) -> list[ParityReport]:
    """Build ``c_dir`` and replay recorded readings of each seed through it; one report per
    seed (:func:`compare_runs`).  ConfigError for a float32 build the policy has none of
    (:func:`impact_env.deploy.c_export.float32_refusal`)."""
    if float32 and float32_refusal(policy):
        raise ConfigError(f"--check float32: {float32_refusal(policy)}")
    with tempfile.TemporaryDirectory(prefix="impact-c-") as tmp:
        lib = build_shared(c_dir, Path(tmp) / "libimpact.so", float32)
        cp = CPolicy(lib, float32)
        out = []
        for s in seeds:
            rec = record(policy, scene, s, ticks)
            out.append(compare_runs(rec, replay(cp, rec), policy.hold_ticks))
        return out


__all__ = ["CPolicy", "F32_BOUND", "F32_FLIP_FRACTION", "HEADER_NAME", "ParityReport",
           "decisions_differ", "readings_from_log", "Recording", "build_shared", "c_sequence", "check",
           "closed_loop", "compare_runs", "episode_metrics", "numba_sequence", "record", "replay"]
