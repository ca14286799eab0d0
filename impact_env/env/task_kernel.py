"""The catch task's arithmetic for a batch, compiled: energy, reward, termination and the info
row, in one call after the simulator's step, from the step's per-tick records
(:mod:`impact_env.sim.records`).

Kept apart from :mod:`impact_env.env.task` (the Python layer that owns the arrays) so that a
step costs two compiled calls (simulator, task) and no per-env Python.
"""

from __future__ import annotations

import numpy as np

from impact_env._jit import jit
from impact_env.plant.energy import catch_energy_at
from impact_env.plant.layout import M1, V1, X1, X2, C, G
from impact_env.sim import records as R

# task parameters (float64 vector built by CatchTask)
T_STEP_WEIGHT, T_THRESHOLD, T_HOLD, T_TERMINATE, T_EFFORT, T_LIMIT, T_CMD, T_MAX_STEPS = range(8)
N_TASK = 8

# columns of the per-env info row
INFO_KEYS = ("t", "catch_energy", "catch_energy_ratio", "impact_energy", "impact_speed", "contact",
             "contact_force", "force_demand", "force_applied", "saturated", "detected", "x1", "v1", "x2",
             "v2", "diverged", "caught", "t_touch")
BOOL_KEYS = ("contact", "saturated", "detected", "diverged", "caught")
(COL_T, COL_E, COL_RATIO, COL_E0, COL_V0, COL_CONTACT, COL_FC, COL_FD, COL_FA, COL_SAT, COL_DET, COL_X1,
 COL_V1, COL_X2, COL_V2, COL_DIV, COL_CAUGHT, COL_TTOUCH) = range(len(INFO_KEYS))
N_COL = len(INFO_KEYS)


@jit
def task_step(active, records, Y, P, impact_energy, impact_speed, tp, steps, below, diverged, energy,
              rewards, terminated, truncated, rows):
    """After the simulator's step: reward, flags and info row of every active env (an inactive
    env gets reward 0 and no flags, and keeps its row)."""
    for i in range(records.shape[0]):
        if not active[i]:
            rewards[i] = 0.0
            terminated[i] = False
            truncated[i] = False
            continue
        steps[i] += 1
        e0 = impact_energy[i]
        total = 0.0
        bad = False
        for k in range(records.shape[1]):
            r = records[i, k]
            if r[R.REC_STATUS] != 0.0:
                bad = True
                diverged[i] = True
                below[i] = 0
                cost = 1.0
            else:
                e = catch_energy_at(r[R.REC_X1], r[R.REC_V1], r[R.REC_X2], P[i, M1], P[i, C], P[i, G])
                energy[i] = e
                ratio = e / e0
                cost = ratio
                if tp[T_EFFORT] != 0.0:
                    u = r[R.REC_F_APPLIED] / tp[T_CMD]
                    cost += tp[T_EFFORT] * u * u
                if tp[T_LIMIT] != 0.0:
                    cost += tp[T_LIMIT] * r[R.REC_SATURATED]
                below[i] = below[i] + 1 if ratio < tp[T_THRESHOLD] else 0
            total += cost
        term = bad or (tp[T_TERMINATE] != 0.0 and below[i] >= tp[T_HOLD])
        rewards[i] = -total * tp[T_STEP_WEIGHT]
        terminated[i] = term
        truncated[i] = (steps[i] >= tp[T_MAX_STEPS]) and not term
        last = records[i, records.shape[1] - 1]
        fill_row(i, Y, P, last, impact_energy, impact_speed, energy, diverged, below, tp, rows)


@jit
def fill_row(i, Y, P, last, impact_energy, impact_speed, energy, diverged, below, tp, rows):
    """Env i's info row (columns INFO_KEYS, SI units; booleans as 0/1; the state of a
    diverged env reads 0 where it is not finite) from its state and its last tick's record."""
    r = rows[i]
    r[COL_T] = last[R.REC_T]
    r[COL_E] = energy[i]
    r[COL_E0] = impact_energy[i]
    r[COL_RATIO] = energy[i] / impact_energy[i]
    r[COL_V0] = impact_speed[i]
    for k in range(4):
        v = Y[i, k]
        r[COL_X1 + k] = v if np.isfinite(v) else 0.0
    r[COL_CONTACT] = 1.0 if r[COL_X1] - r[COL_X2] > 0.0 else 0.0
    r[COL_FC] = last[R.REC_CONTACT_FORCE]
    r[COL_FD] = last[R.REC_F_DEMAND]
    r[COL_FA] = last[R.REC_F_APPLIED]
    r[COL_SAT] = last[R.REC_SATURATED]
    r[COL_DET] = last[R.REC_DETECTED]
    r[COL_DIV] = 1.0 if diverged[i] else 0.0
    r[COL_CAUGHT] = 1.0 if below[i] >= tp[T_HOLD] else 0.0


@jit
def task_reset_rows(idx, records, Y, P, impact_energy, impact_speed, tp, steps, below, diverged, energy,
                    rows):
    """Episode start for envs ``idx``: clear the task state and write the first info row
    (Y and impact_energy are the simulator's reset values, the records are zero)."""
    for m in range(idx.shape[0]):
        i = idx[m]
        steps[i] = 0
        below[i] = 0
        diverged[i] = False
        energy[i] = catch_energy_at(Y[i, X1], Y[i, V1], Y[i, X2], P[i, M1], P[i, C], P[i, G])
        fill_row(i, Y, P, records[i, 0], impact_energy, impact_speed, energy, diverged, below, tp, rows)
