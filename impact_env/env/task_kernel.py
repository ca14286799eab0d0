"""The catch task's arithmetic for a batch, compiled: energy, reward, termination and the info
row, in one call after the simulator's step, from the step's per-tick records
(:mod:`impact_env.sim.records`).

Kept apart from :mod:`impact_env.env.task` (the Python layer that owns the arrays).  An env's
step is one compiled call, :func:`catch_step`: the simulator's step and the task's, env by env
(or one call per block of envs, the blocks at once: :class:`impact_env._threads.BlockRunner`),
and no per-env Python; :func:`task_step` is the task's part alone, after a step simulated elsewhere (the rig's
host).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from impact_env._borrow import borrow
from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.plant.energy import catch_energy_at
from impact_env.plant.layout import PARAM, STATE
from impact_env.sim.records import REC
from impact_env.sim.step import sim_step


class TaskState(NamedTuple):
    """Per-env episode state (:func:`reset_task` starts it)."""

    steps: np.ndarray  # int64[N]: policy steps taken
    below: np.ndarray  # int64[N]: consecutive ticks below the catch threshold
    diverged: np.ndarray  # bool[N]
    energy: np.ndarray  # float64[N]: J, the catch energy after the last tick


class Drop(NamedTuple):
    """What the task reads of the simulated drop."""

    plant_state: np.ndarray  # float64[N, N_STATE] (impact_env.plant.layout.STATE)
    plant_parameters: np.ndarray  # float64[N, N_PARAM] (impact_env.plant.layout.PARAM)
    impact_energy: np.ndarray  # float64[N], J
    impact_speed: np.ndarray  # float64[N], m/s


class TaskOut(NamedTuple):
    """What a task step gives."""

    rewards: np.ndarray  # float64[N]
    terminated: np.ndarray  # bool[N]
    truncated: np.ndarray  # bool[N]
    rows: np.ndarray  # float64[N, N_COL]: the info rows



class InfoRow(NamedTuple):
    """The per-env info row's columns (float64[N_COL], SI units; booleans as 0/1), read by name:
    ``rows[i, INFO.x1]``; the env's info dict has these keys (``state`` for x1 .. v2)."""

    t: float  # s since the episode start
    catch_energy: float  # J
    catch_energy_ratio: float  # over the impact energy
    impact_energy: float  # J
    impact_speed: float  # m/s
    contact: float  # true contact
    contact_force: float  # N
    force_demand: float  # N
    force_applied: float  # N
    saturated: float
    detected: float
    x1: float  # the true state: x1, v1, x2, v2 (m, m/s)
    v1: float
    x2: float
    v2: float
    diverged: float
    caught: float
    t_touch: float  # s, the first touch after the episode start (written by the task, kept by the kernels)


INFO = positions(InfoRow)
INFO_KEYS = InfoRow._fields
BOOL_KEYS = ("contact", "saturated", "detected", "diverged", "caught")
N_COL = len(INFO)


@jit(inline="always")
def task_env(i, on, records, d, p, s, out):
    """Env i's reward, flags and info row after its step (``on``: it was stepped; else reward
    0, no flags, its row kept): :func:`task_step`'s arithmetic for one env."""
    rewards, terminated, truncated = out.rewards, out.terminated, out.truncated
    steps, below, diverged, energy = s.steps, s.below, s.diverged, s.energy
    plant_params = d.plant_parameters
    if not on:
        rewards[i] = 0.0
        terminated[i] = False
        truncated[i] = False
        return
    steps[i] += 1
    e0 = d.impact_energy[i]
    total = 0.0
    bad = False
    for k in range(records.shape[1]):
        r = records[i, k]
        if r[REC.status] != 0.0:
            bad = True
            diverged[i] = True
            below[i] = 0
            cost = 1.0
        else:
            e = catch_energy_at(r[REC.x1], r[REC.v1], r[REC.x2], plant_params[i, PARAM.m1],
                                plant_params[i, PARAM.c], plant_params[i, PARAM.g])
            energy[i] = e
            ratio = e / e0
            cost = ratio
            if p.effort_weight != 0.0:
                u = r[REC.f_applied] / p.command_scale
                cost += p.effort_weight * u * u
            if p.limit_weight != 0.0:
                cost += p.limit_weight * r[REC.saturated]
            below[i] = below[i] + 1 if ratio < p.catch_threshold else 0
        total += cost
    term = bad or (p.terminate_on_catch != 0.0 and below[i] >= p.hold)
    rewards[i] = -total * p.step_weight
    terminated[i] = term
    truncated[i] = (steps[i] >= p.max_steps) and not term
    last = records[i, records.shape[1] - 1]
    fill_row(i, last, d, p, s, out.rows)


@jit
def task_step(active, records, d, p, s, out):
    """After the simulator's step: reward, flags and info row of every active env (an inactive
    env gets reward 0 and no flags, and keeps its row).  ``d``: Drop, ``p``: TaskParams (the
    options the kernel reads, by their names, and what the task derives from them:
    :mod:`impact_env.env.task`), ``s``: TaskState, ``out``: TaskOut."""
    active, records, d = borrow(active), borrow(records), borrow(d)
    p, s, out = borrow(p), borrow(s), borrow(out)
    for i in range(records.shape[0]):
        task_env(i, active[i], records, d, p, s, out)


@jit(nogil=True)
def catch_step(i0, i1, actions, active, sp, ss, d, p, s, out, cols):
    """The env's whole step for envs ``i0 .. i1 - 1``: the simulator's step
    (:func:`impact_env.sim.step.sim_step`) and then the task's (:func:`task_env`), in one call
    from Python (``sp``, ``ss``: SimParams, SimState; the rest as :func:`task_step`'s).  Env i
    reads and writes only its own rows, so blocks of envs may run at once
    (:class:`impact_env._threads.BlockRunner`).  ``sim_step`` is called, not inlined here: it
    is compiled once for both (inlined here too, the simulator's step took about 40 s more of a
    core of a first run), for one call per step of the block.  ``cols``: float64[N_COL, N],
    every env's info row also written as a column (the vector env's info arrays, without a
    transposing copy after the step), or float64[N_COL, 0]: not written."""
    actions, active, sp, ss = borrow(actions), borrow(active), borrow(sp), borrow(ss)  # (impact_env._borrow)
    d, p, s, out, cols = borrow(d), borrow(p), borrow(s), borrow(out), borrow(cols)
    sim_step(i0, i1, actions, active, sp, ss)
    records = ss.records
    rows = out.rows
    for i in range(i0, i1):
        task_env(i, active[i], records, d, p, s, out)
        if cols.shape[1] > 0:
            for j in range(cols.shape[0]):
                cols[j, i] = rows[i, j]


@jit
def fill_row(i, last, d, p, s, rows):
    """Env i's info row (columns INFO_KEYS, SI units; booleans as 0/1; the state of a
    diverged env reads 0 where it is not finite) from its state and its last tick's record."""
    r = rows[i]
    r[INFO.t] = last[REC.t]
    r[INFO.catch_energy] = s.energy[i]
    r[INFO.impact_energy] = d.impact_energy[i]
    r[INFO.catch_energy_ratio] = s.energy[i] / d.impact_energy[i]
    r[INFO.impact_speed] = d.impact_speed[i]
    for slot, col in ((STATE.x1, INFO.x1), (STATE.v1, INFO.v1), (STATE.x2, INFO.x2), (STATE.v2, INFO.v2)):
        v = d.plant_state[i, slot]
        r[col] = v if np.isfinite(v) else 0.0
    r[INFO.contact] = 1.0 if r[INFO.x1] - r[INFO.x2] > 0.0 else 0.0
    r[INFO.contact_force] = last[REC.contact_force]
    r[INFO.force_demand] = last[REC.f_demand]
    r[INFO.force_applied] = last[REC.f_applied]
    r[INFO.saturated] = last[REC.saturated]
    r[INFO.detected] = last[REC.detected]
    r[INFO.diverged] = 1.0 if s.diverged[i] else 0.0
    r[INFO.caught] = 1.0 if s.below[i] >= p.hold else 0.0


@jit(inline="always")
def reset_task(s, i, d):
    """Env i's task state at an episode start (``d``: the drop's start values)."""
    s.steps[i] = 0
    s.below[i] = 0
    s.diverged[i] = False
    plant_states, plant_params = d.plant_state, d.plant_parameters
    s.energy[i] = catch_energy_at(plant_states[i, STATE.x1], plant_states[i, STATE.v1],
                                  plant_states[i, STATE.x2], plant_params[i, PARAM.m1],
                                  plant_params[i, PARAM.c], plant_params[i, PARAM.g])


@jit
def task_reset_rows(idx, records, d, p, s, rows):
    """Episode start for envs ``idx``: reset the task state and write the first info row
    (d.plant_state and d.impact_energy are the simulator's reset values, the records are zero)."""
    for m in range(idx.shape[0]):
        i = idx[m]
        reset_task(s, i, d)
        fill_row(i, records[i, 0], d, p, s, rows)
