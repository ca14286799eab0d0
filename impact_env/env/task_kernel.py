"""The catch task's per-step arithmetic for a batch, compiled: energy, reward, termination,
observation frames and the info row, in one call after the simulator's step.

Kept apart from :mod:`impact_env.env.task` (the Python layer that owns the arrays) so that a
step costs two compiled calls and no per-env Python.
"""

from __future__ import annotations

import numpy as np

from impact_env._jit import jit
from impact_env.plant.layout import M1, OK, V1, X1, X2, C, G
from impact_env.sim import pipeline_kernel as K

# task parameters (float64 vector built by CatchTask)
T_STEP_WEIGHT, T_THRESHOLD, T_HOLD, T_TERMINATE, T_EFFORT, T_LIMIT, T_CMD, T_MAX_STEPS, T_OBS_LIMIT = range(9)
N_TASK = 9

# columns of the per-env info row
INFO_KEYS = ("t", "catch_energy", "catch_energy_ratio", "impact_energy", "impact_speed", "contact",
             "contact_force", "force_demand", "force_applied", "saturated", "detected", "x1", "v1", "x2",
             "v2", "diverged", "caught", "t_touch")
BOOL_KEYS = ("contact", "saturated", "detected", "diverged", "caught")
(R_T, R_E, R_RATIO, R_E0, R_V0, R_CONTACT, R_FC, R_FD, R_FA, R_SAT, R_DET, R_X1, R_V1, R_X2, R_V2, R_DIV,
 R_CAUGHT, R_TTOUCH) = range(len(INFO_KEYS))
N_ROW = len(INFO_KEYS)


@jit(inline="always")
def _catch_energy(x1, v1, x2, m1, c, g):
    d = x1 - x2
    ds = (m1 * g / c) ** (2.0 / 3.0)
    dp = d if d > 0.0 else 0.0
    return 0.5 * m1 * v1 * v1 + m1 * g * (0.6 * ds - d) + 0.4 * c * dp * dp * np.sqrt(dp)


@jit
def write_frames(i, readings, sim_info, Y, channels, detector, privileged, scales, obs_limit,
                 frames, past_actions, obs):
    """Shift env i's history, put the current frame first and write its observation row."""
    H = frames.shape[1]
    F = frames.shape[2]
    for h in range(H - 1, 0, -1):
        for j in range(F):
            frames[i, h, j] = frames[i, h - 1, j]
    j = 0
    for k in range(channels.shape[0]):
        frames[i, 0, j] = readings[i, channels[k]]
        j += 1
    if detector:
        frames[i, 0, j] = sim_info[i, K.I_DETECTED]
        j += 1
    if privileged:
        for k in range(4):
            frames[i, 0, j + k] = Y[i, k]
    for j in range(F):
        v = frames[i, 0, j] / scales[j]
        if v > obs_limit:
            v = obs_limit
        elif v < -obs_limit:
            v = -obs_limit
        frames[i, 0, j] = v
    for h in range(H):
        for j in range(F):
            obs[i, h * F + j] = frames[i, h, j]
    if H > 1:
        for h in range(H):
            obs[i, H * F + h] = past_actions[i, h]


@jit
def task_step(actions, readings, sim_info, Y, P, t, impact_energy, impact_speed,
              channels, detector, privileged, scales, tp,
              frames, past_actions, obs, steps, below, diverged, energy,
              rewards, terminated, truncated, rows):
    """After the simulator's step: reward, flags, observation and info row of every env."""
    n = actions.shape[0]
    H = past_actions.shape[1]
    for i in range(n):
        steps[i] += 1
        if H > 1:
            for h in range(H - 1, 0, -1):
                past_actions[i, h] = past_actions[i, h - 1]
            past_actions[i, 0] = actions[i]
        bad = sim_info[i, K.I_STATUS] != OK
        for k in range(4):
            if not np.isfinite(Y[i, k]):
                bad = True
        e0 = impact_energy[i]
        if bad:
            cost = 1.0
            diverged[i] = True
            below[i] = 0
            term = True
        else:
            e = _catch_energy(Y[i, X1], Y[i, V1], Y[i, X2], P[i, M1], P[i, C], P[i, G])
            energy[i] = e
            ratio = e / e0
            cost = ratio
            if tp[T_EFFORT] != 0.0:
                u = sim_info[i, K.I_F_APPLIED] / tp[T_CMD]
                cost += tp[T_EFFORT] * u * u
            if tp[T_LIMIT] != 0.0:
                cost += tp[T_LIMIT] * sim_info[i, K.I_SATURATED]
            below[i] = below[i] + 1 if ratio < tp[T_THRESHOLD] else 0
            term = tp[T_TERMINATE] != 0.0 and below[i] >= tp[T_HOLD]
            write_frames(i, readings, sim_info, Y, channels, detector, privileged, scales, tp[T_OBS_LIMIT],
                         frames, past_actions, obs)
        rewards[i] = -cost * tp[T_STEP_WEIGHT]
        terminated[i] = term
        truncated[i] = (steps[i] >= tp[T_MAX_STEPS]) and not term
        fill_row(i, Y, P, sim_info, t, impact_energy, impact_speed, energy, diverged, below, tp, rows)


@jit
def fill_row(i, Y, P, sim_info, t, impact_energy, impact_speed, energy, diverged, below, tp, rows):
    """Env i's info row (columns INFO_KEYS, SI units; booleans as 0/1; the state of a
    diverged env reads 0 where it is not finite)."""
    r = rows[i]
    r[R_T] = t[i]
    r[R_E] = energy[i]
    r[R_E0] = impact_energy[i]
    r[R_RATIO] = energy[i] / impact_energy[i]
    r[R_V0] = impact_speed[i]
    for k in range(4):
        v = Y[i, k]
        r[R_X1 + k] = v if np.isfinite(v) else 0.0
    r[R_CONTACT] = 1.0 if r[R_X1] - r[R_X2] > 0.0 else 0.0
    r[R_FC] = sim_info[i, K.I_CONTACT_FORCE]
    r[R_FD] = sim_info[i, K.I_F_DEMAND]
    r[R_FA] = sim_info[i, K.I_F_APPLIED]
    r[R_SAT] = sim_info[i, K.I_SATURATED]
    r[R_DET] = sim_info[i, K.I_DETECTED]
    r[R_DIV] = 1.0 if diverged[i] else 0.0
    r[R_CAUGHT] = 1.0 if below[i] >= tp[T_HOLD] else 0.0


@jit
def task_reset_rows(idx, readings, sim_info, Y, P, t, impact_energy, impact_speed,
                    channels, detector, privileged, scales, tp,
                    frames, past_actions, obs, steps, below, diverged, energy, rows):
    """Episode start for envs ``idx``: clear the task state, write the first observation and
    info row.  Y, readings and impact_energy are the simulator's reset values."""
    for m in range(idx.shape[0]):
        i = idx[m]
        steps[i] = 0
        below[i] = 0
        diverged[i] = False
        frames[i] = 0.0
        past_actions[i] = 0.0
        energy[i] = _catch_energy(Y[i, X1], Y[i, V1], Y[i, X2], P[i, M1], P[i, C], P[i, G])
        write_frames(i, readings, sim_info, Y, channels, detector, privileged, scales, tp[T_OBS_LIMIT],
                     frames, past_actions, obs)
        fill_row(i, Y, P, sim_info, t, impact_energy, impact_speed, energy, diverged, below, tp, rows)
