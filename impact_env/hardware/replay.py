"""Replay recorded drive commands through the hardware stage: what a fit of the scene to a rig's
logs simulates (:mod:`impact_env.ident`).

Each env of a :class:`~impact_env.hardware.batch.Hardware` batch may hold a different candidate
scene (:meth:`Hardware.set_scene`); :func:`replay` drives env i with its own command sequence
and returns the raw readings tick by tick, exactly as the target's log rows hold them: row m is
what the DAQ read at tick m, after the commands of ticks 0 .. m-1 (row 0: the readings at the
release, before any command).  The noise is the caller's (zeros for a noise-free model).
"""

from __future__ import annotations

import numba
import numpy as np

from impact_env._borrow import borrow
from impact_env._jit import jit
from impact_env.hardware.stage import (
    HW_INFO,
    EffectParams,
    HardwareParams,
    HardwareState,
    Noise,
    PlantParams,
    PlantState,
    Readings,
    StageConfig,
    tick,
)


@jit(parallel=True)
def replay_kernel(commands, p, s, readings):
    """``readings[i, m]`` (float64[n_envs, n, 4]) = raw readings of env i at tick m under
    ``commands[i]`` (float64[n_envs, n]; ``commands[i, n - 1]`` is not used: its readings would be
    row n).  Returns int64[n_envs]: the first tick at which env i's plant failed (n: never); the
    rows after it are NaN.  Envs run in parallel
    threads (numba's, ``numba.set_num_threads``): each touches only its own rows, so the
    result does not depend on the thread count."""
    n_envs, n = commands.shape
    failed = np.full(n_envs, n, dtype=np.int64)
    # numba's parallel loop takes arrays and scalars, not named tuples: the leaves go in by name
    # and the tuples are built again inside it
    c, pp, fx = p.cfg, p.plant, p.effects
    flags, method, dt, rtol, period = c.flags, c.method, c.dt, c.rtol, c.period
    plant_params, scale = pp.p, pp.scale
    rows, offsets, state_offsets = fx.rows, fx.offsets, fx.state_offsets
    ps = s.plant
    y, mode, h, events, n_events, t = ps.y, ps.mode, ps.h, ps.events, ps.n_events, ps.t
    st, z, cursor, raw, info = s.effects, s.noise.z, s.noise.cursor, s.out.raw, s.out.info
    for i in numba.prange(n_envs):
        hp = HardwareParams(StageConfig(flags, method, dt, rtol, period), PlantParams(plant_params, scale),
                            EffectParams(rows, offsets, state_offsets))
        hs = HardwareState(PlantState(y, mode, h, events, n_events, t), st, Noise(z, cursor),
                           Readings(raw, info))
        # the parallel loop's index is unsigned, the loop typed before it a signed one: one type
        # for both, or numba compiles this env's replay and the hardware tick for each
        failed[i] = _replay_env(np.int64(i), commands, hp, hs, readings)
    return failed


@jit
def _replay_env(i, commands, p, s, readings):
    """Env i of :func:`replay_kernel` (``p``, ``s``: the stage's HardwareParams and HardwareState)."""
    commands, p, s, readings = borrow(commands), borrow(p), borrow(s), borrow(readings)  # (_borrow)
    n = commands.shape[1]
    raw = s.out.raw
    info = s.out.info
    plant_states = s.plant.y
    for c in range(raw.shape[1]):
        readings[i, 0, c] = raw[i, c]
    for m in range(n - 1):
        tick(i, commands[i, m], p, s)
        ok = info[i, HW_INFO.status] == 0.0
        for k in range(4):
            if not np.isfinite(plant_states[i, k]):
                ok = False
        if not ok:
            for mm in range(m + 1, n):
                for c in range(raw.shape[1]):
                    readings[i, mm, c] = np.nan
            return m + 1
        for c in range(raw.shape[1]):
            readings[i, m + 1, c] = raw[i, c]
    return n


def replay(hw, commands: np.ndarray, held: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Reset every env of ``hw`` (its scenes as set; ``held``: body 1 kept on the electromagnet,
    :meth:`Hardware.hold_body1`) and drive env i with ``commands[i]`` (float64[n_envs, n], or [n]
    for all); returns (readings float64[n_envs, n, 4], first failed tick int64[n_envs]).  Noise-free: the
    sensors' noise draws are zeros (give the candidate scenes noise_std = 0 anyway)."""
    n_envs = hw.n
    # always a writable copy: a one-env broadcast is a read-only view, for which numba would
    # compile a second copy of the kernel
    commands_rows = np.array(np.broadcast_to(np.asarray(commands, dtype=np.float64),
                                             (n_envs, np.shape(commands)[-1])), order="C")
    n = commands_rows.shape[1]
    hw.reset([None] * n_envs)
    if held:
        hw.hold_body1(np.arange(n_envs))
    shape = (n_envs, max(n, 1), hw.noise.shape[2])
    # (zeros stay zeros: the kernel reads them only)
    if hw.noise.shape != shape or hw.noise_block != shape[1]:
        hw.noise = np.zeros(shape)
        hw.noise_block = shape[1]
    hw.cursor[:] = 0
    readings = np.empty((n_envs, n, hw.raw.shape[1]))
    failed = replay_kernel(commands_rows, hw.params, hw.state, readings)
    return readings, failed
