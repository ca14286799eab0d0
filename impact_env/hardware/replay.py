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
    hardware_tick,
)


@jit(parallel=True)
def replay_kernel(U, p, s, R):
    """R[i, m] (float64[K, n, 4]) = raw readings of env i at tick m under commands U[i] (float64[K, n];
    U[i, n - 1] is not used: its readings would be row n).  Returns int64[K]: the first tick at
    which env i's plant failed (n: never); the rows after it are NaN.  Envs run in parallel
    threads (numba's, ``numba.set_num_threads``): each touches only its own rows, so the
    result does not depend on the thread count."""
    K, n = U.shape
    failed = np.full(K, n, dtype=np.int64)
    # numba's parallel loop takes arrays and scalars, not named tuples: the leaves go in by name
    # and the tuples are built again inside it
    c, pp, fx = p.cfg, p.plant, p.effects
    flags, method, dt, rtol, period = c.flags, c.method, c.dt, c.rtol, c.period
    P, scale, rows, offsets, state_offsets = pp.p, pp.scale, fx.rows, fx.offsets, fx.state_offsets
    ps = s.plant
    y, mode, h, events, n_events, t = ps.y, ps.mode, ps.h, ps.events, ps.n_events, ps.t
    st, z, cursor, raw, info = s.effects, s.noise.z, s.noise.cursor, s.out.raw, s.out.info
    for i in numba.prange(K):
        hp = HardwareParams(StageConfig(flags, method, dt, rtol, period), PlantParams(P, scale),
                            EffectParams(rows, offsets, state_offsets))
        hs = HardwareState(PlantState(y, mode, h, events, n_events, t), st, Noise(z, cursor),
                           Readings(raw, info))
        failed[i] = _replay_env(i, U, hp, hs, R)
    return failed


@jit
def _replay_env(i, U, p, s, R):
    """Env i of :func:`replay_kernel` (``p``, ``s``: the stage's HardwareParams and HardwareState)."""
    U, p, s, R = borrow(U), borrow(p), borrow(s), borrow(R)  # (impact_env._borrow)
    n = U.shape[1]
    raw = s.out.raw
    info = s.out.info
    Y = s.plant.y
    for c in range(raw.shape[1]):
        R[i, 0, c] = raw[i, c]
    for m in range(n - 1):
        hardware_tick(i, U[i, m], p, s)
        ok = info[i, HW_INFO.status] == 0.0
        for k in range(4):
            if not np.isfinite(Y[i, k]):
                ok = False
        if not ok:
            for mm in range(m + 1, n):
                for c in range(raw.shape[1]):
                    R[i, mm, c] = np.nan
            return m + 1
        for c in range(raw.shape[1]):
            R[i, m + 1, c] = raw[i, c]
    return n


def replay(hw, commands: np.ndarray, held: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Reset every env of ``hw`` (its scenes as set; ``held``: body 1 kept on the electromagnet,
    :meth:`Hardware.hold_body1`) and drive env i with ``commands[i]`` (float64[K, n], or [n] for
    all); returns (readings float64[K, n, 4], first failed tick int64[K]).  Noise-free: the
    sensors' noise draws are zeros (give the candidate scenes noise_std = 0 anyway)."""
    K = hw.n
    U = np.ascontiguousarray(np.broadcast_to(np.asarray(commands, dtype=np.float64),
                                             (K, np.shape(commands)[-1])))
    n = U.shape[1]
    hw.reset([None] * K)
    if held:
        hw.hold_body1(np.arange(K))
    shape = (K, max(n, 1), hw.noise.shape[2])
    # (zeros stay zeros: the kernel reads them only)
    if hw.noise.shape != shape or hw.noise_block != shape[1]:
        hw.noise = np.zeros(shape)
        hw.noise_block = shape[1]
    hw.cursor[:] = 0
    R = np.empty((K, n, hw.raw.shape[1]))
    failed = replay_kernel(U, hw.params, hw.state, R)
    return R, failed
