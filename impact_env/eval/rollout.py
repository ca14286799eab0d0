"""Rollouts: one policy on a batch of seeded drops, stepped together, with the catch metrics kept
tick by tick (:class:`impact_env.sim.metrics.EpisodeMetrics`; the definitions are there).

A rollout runs a :class:`~impact_env.sim.simulator.Simulator` of one env per episode with the
observation layout and ``hold_ticks`` the policy asks for: the policy sees exactly the
observations a trained agent sees in ``ImpactCatch-v0``, and the batch is one compiled call per
step.  Env i is seeded with ``seeds[i]`` as Gymnasium seeds an env (``seeding.np_random``);
``impact-env compare`` gives episode ``j`` of a run with seed ``s`` the seed ``s + j``, which is
what ``ImpactCatchVectorEnv.reset(seed=s)`` gives its env ``j``, so every policy meets the same
drops and the same sensor noise.

Two paths, the same numbers:

* a policy with SB3's ``predict`` is called once per step from Python, for the whole batch;
* a :class:`~impact_env.control.policy.CompiledPolicy` runs inside one compiled loop (its
  :func:`~impact_env.control.policy.act`, the simulator step and the metrics, no Python per
  step), in chunks between which the progress bar moves.

A policy that raises, or returns a non-finite action, and a simulation that diverges, do not
stop the rollout: the episodes it failed are recorded in ``failures`` (episode, seed, time,
message), are not stepped any more and are left out of the metrics (NaN).

Open-loop policies (the hook :mod:`impact_env.eval.oracle` uses).  A policy with a method
``prepare(scene, seeds, horizon, warm_starts)`` has it called once before the first step with the
scene, the episodes' seeds (int64[N]), the horizon (s, a whole number of policy steps) and
``warm_starts`` (name -> float64[n_steps, N]: other policies' commands on the same episodes, or
``{}``); whatever it leaves in ``policy.stats`` (a dict) is returned in ``extras["policy_stats"]``.
A policy whose ``open_loop`` attribute is then not None (float[n_steps, N], commands in [-1, 1])
is replayed from it: step k applies ``open_loop[k - 1]`` and ``predict`` is never called.
``record_commands=True`` keeps the drive command of every control period (after clipping; with
``hold_ticks`` k, k periods per policy step; with a ``residual``, the law's part included; 0 for
failed episodes) in ``extras["commands"]`` (float64[n_steps * hold_ticks, N]): replaying them open
loop, one per period, on the same seeds reproduces the bodies' motion bitwise (sensor noise does
not move the bodies), whatever hold and residual the policy had.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from gymnasium.utils import seeding
from numba import prange

from impact_env._borrow import borrow
from impact_env._jit import jit
from impact_env._packed import positions
from impact_env._threads import BlockRunner, check_threads, env_blocks, resolve_threads, unflatten
from impact_env.control.observation import OBSERVATIONS, make_layout
from impact_env.control.policy import CompiledPolicy, PolicyArrays, act
from impact_env.plant.energy import catch_energy_at
from impact_env.plant.layout import PARAM, STATE
from impact_env.policy.export import export_policy
from impact_env.scene import Scene
from impact_env.sim.metrics import AC, EPISODE_METRICS, ST, EpisodeMetrics, MetricArrays, update
from impact_env.sim.records import REC
from impact_env.sim.simulator import Simulator
from impact_env.sim.step import SimParams, SimState, sim_step

__all__ = ["EPISODE_METRICS", "TRACE_KEYS", "RolloutResult", "rollout"]



class TraceRow(NamedTuple):
    """A trace sample's columns (SI): the state as ``ImpactCatch-v0``'s info gives it, then the
    last tick's record and catch energy."""

    x1: float
    v1: float
    x2: float
    v2: float
    force_demand: float
    force_applied: float
    contact_force: float
    catch_energy: float
    detected: float
    saturated: float


TR = positions(TraceRow)
TRACE_KEYS = TraceRow._fields
CHUNK = 200  # policy steps per progress report (and at most per compiled call)
#: envs per block at least when the compiled loop runs in threads: a block runs a whole chunk
#: (up to CHUNK steps, about 2.4 ms of work for 4 rig envs) per hand-off (50-90 us of a thread's
#: wake-up on a 2-core machine), so a few envs pay; scripts/bench_env.py ("threads") times N = 8
MIN_BLOCK_EPISODES = 4
FAIL_ACTION, FAIL_DIVERGED = 1, 2


@dataclass
class RolloutResult:
    """What a rollout returns: per-episode metrics, failures and decimated traces.

    ``metrics[name]``: float64[N] (:mod:`impact_env.sim.metrics`; NaN for failed episodes).
    ``traces[key]``: float64[T, M] sampled every ``trace_period`` s for the M traced episodes
    (``trace_rows``, positions in the seeds: all N by default), ``energy_trace``: float64[T, N],
    every episode's catch energy (J) at the same samples, ``trace_t``: float64[T] (s since the
    episode start); ``t_touch``: float64[N] (s, first touch).
    """

    policy: str
    episodes: np.ndarray
    seeds: np.ndarray
    metrics: dict[str, np.ndarray]
    failures: list[dict]
    trace_t: np.ndarray
    traces: dict[str, np.ndarray]
    energy_trace: np.ndarray
    trace_rows: np.ndarray
    t_touch: np.ndarray
    impact_energy: np.ndarray
    control_period: float
    wall_time_s: float = 0.0
    extras: dict = field(default_factory=dict)


@jit
def _energies(plant_states, plant_params, out):
    for i in range(plant_states.shape[0]):
        out[i] = catch_energy_at(plant_states[i, STATE.x1], plant_states[i, STATE.v1],
                                 plant_states[i, STATE.x2], plant_params[i, PARAM.m1],
                                 plant_params[i, PARAM.c], plant_params[i, PARAM.g])
    return out


@jit(inline="always")
def _trace_env(row, energy_row, slot, i, plant_states, records, acc_energy, detected):
    """Env i's trace sample: its catch energy in ``energy_row[i]``, and, where it has a slot
    (``slot[i] >= 0``: it is one of the traced episodes), every column of TRACE_KEYS in
    ``row[slot[i]]``: the state as ``ImpactCatch-v0``'s info gives it (non-finite entries read 0)
    and the last tick's record."""
    energy_row[i] = acc_energy[i]
    r = slot[i]
    if r < 0:
        return
    for j in range(4):
        v = plant_states[i, j]
        row[r, TR.x1 + j] = v if np.isfinite(v) else 0.0
    last = records[i, records.shape[1] - 1]
    row[r, TR.force_demand] = last[REC.f_demand]
    row[r, TR.force_applied] = last[REC.f_applied]
    row[r, TR.contact_force] = last[REC.contact_force]
    row[r, TR.catch_energy] = acc_energy[i]
    row[r, TR.detected] = detected[i]
    row[r, TR.saturated] = last[REC.saturated]


@jit
def _trace_row(row, energy_row, slot, plant_states, records, acc_energy, detected):
    """One trace sample of every env (:func:`_trace_env`)."""
    row, energy_row, slot = borrow(row), borrow(energy_row), borrow(slot)
    plant_states, records = borrow(plant_states), borrow(records)
    acc_energy, detected = borrow(acc_energy), borrow(detected)
    for i in range(plant_states.shape[0]):
        _trace_env(row, energy_row, slot, i, plant_states, records, acc_energy, detected)


class Failures(NamedTuple):
    """Per-episode failure marks of the compiled loop."""

    failed: np.ndarray  # bool[N]
    t: np.ndarray  # float64[N]: s, when
    code: np.ndarray  # int64[N]: FAIL_ACTION or FAIL_DIVERGED


class Steps(NamedTuple):
    """The policy steps a call of the compiled loop runs: k0 + 1 .. k1, a trace sample every
    ``stride`` steps."""

    k0: int
    k1: int
    stride: int


class LoopPolicy(NamedTuple):
    """The compiled loop's policy: its packed arrays and its per-env memory rows."""

    arrays: PolicyArrays
    memory: np.ndarray  # float64[N, memory size]


class LoopOut(NamedTuple):
    """Where the compiled loop writes: the metrics' (acc, consts, settings), the failure marks,
    the traces (float64[samples, traced episodes, len(TRACE_KEYS)]), every episode's catch
    energy at the trace samples (float64[samples, N]) and each env's row in the traces
    (int64[N], -1: not traced)."""

    metrics: MetricArrays
    fails: Failures
    traces: np.ndarray
    energy: np.ndarray
    slot: np.ndarray


@jit(nogil=True)
def _run_compiled(i0, i1, steps, pol, p, s, out):
    """Steps ``steps.k0 + 1 .. steps.k1`` of a compiled policy (``pol``: LoopPolicy) on every env
    ``i0 .. i1 - 1`` of the simulator (SimParams ``p``, SimState ``s``) that has not failed;
    writes ``out`` (LoopOut).

    Env by env, each for all its steps: env i reads and writes only its own rows (its policy
    memory, state, records, metrics, failure marks and trace column), so the order of envs, and
    blocks of envs run in threads at once (the GIL is released), give the same numbers."""
    pol, p, s, out = borrow(pol), borrow(p), borrow(s), borrow(out)  # no reference counting inside
    plant_states = s.hw.plant.y
    plant_params = p.hw.plant.p
    obs = s.obs.obs
    records = s.records
    plant_records = s.plant_records
    metrics, fails, traces, etrace, slot = out.metrics, out.fails, out.traces, out.energy, out.slot
    acc, consts, settings = metrics.acc, metrics.consts, metrics.settings
    energy = acc[:, AC.energy]
    detected = s.fe.detected
    failed = fails.failed
    period = settings[ST.period]
    hold = p.hold
    policy, memory = pol.arrays, pol.memory
    stride = steps.stride
    # the vector env's step on the one env i (actions[i], active[i]): its kernel, not a second
    # inlined copy of the step, which numba would compile again (about 55 s of a core)
    actions = np.zeros(plant_states.shape[0])
    active = np.ones(plant_states.shape[0], dtype=np.bool_)
    for i in range(i0, i1):
        for k in range(steps.k0 + 1, steps.k1 + 1):
            if not failed[i]:
                u = act(policy.ints, policy.floats, obs[i], memory[i])
                if not np.isfinite(u):
                    failed[i] = True
                    fails.t[i] = (k - 1) * period
                    fails.code[i] = FAIL_ACTION
                else:
                    actions[i] = u
                    sim_step(i, i + 1, actions, active, p, s)
                    ok = records[i, hold - 1, REC.status] == 0.0  # the step's last tick: the plant ok
                    for j in range(hold):
                        update(acc[i], records[i, j], plant_records[i, j], consts[i], plant_params[i],
                               settings)
                    if not ok:
                        failed[i] = True
                        fails.t[i] = k * period
                        fails.code[i] = FAIL_DIVERGED
            if k % stride == 0:  # (a failed env's sample too: its last state, as before)
                _trace_env(traces[k // stride], etrace[k // stride], slot, i, plant_states, records,
                           energy, detected)


@jit(nogil=True)
def _compiled_block(i0, i1, steps, fpol, fp, fs, fout):
    """:func:`_run_compiled` on envs ``i0 .. i1 - 1``, its nested named tuples rebuilt from their
    leaves (:func:`impact_env._threads.flatten`); False if it raised."""
    try:
        _run_compiled(i0, i1, steps, unflatten(fpol, LoopPolicy), unflatten(fp, SimParams),
                      unflatten(fs, SimState), unflatten(fout, LoopOut))
    except Exception:  # noqa: BLE001 - reported by the caller (impact_env._threads.BlockRunner)
        return False
    return True


@jit(nogil=True, parallel=True)
def _compiled_blocks(bounds, ok, steps, fpol, fp, fs, fout):
    """:func:`_run_compiled` on the blocks of envs ``bounds[b] .. bounds[b + 1] - 1`` in one
    compiled parallel region; ``ok[b]``: block b did not raise (:mod:`impact_env._threads`)."""
    for b in prange(bounds.shape[0] - 1):
        ok[b] = _compiled_block(bounds[b], bounds[b + 1], steps, fpol, fp, fs, fout)


def residual_law(policy, scene) -> CompiledPolicy | None:
    """The classic law a policy's actions add to, every tick (its ``residual``: a spec, or the
    law inside a compiled policy), or None."""
    if isinstance(policy, CompiledPolicy):
        return policy.residual_policy()
    spec = getattr(policy, "residual", None)
    if spec is None:
        return None

    return export_policy(spec, scene)


def rollout(scene: Scene, policy, seeds, horizon: float | None = None, episodes=None,
            trace_rate: float = 1.0e4, catch_fraction: float = 0.01, min_flight_s: float = 1.0e-3,
            name: str = "", progress: Callable[[int], None] | None = None,
            compiled: bool | None = None, warm_starts: dict[str, np.ndarray] | None = None,
            record_commands: bool = False, threads: int | str | None = None,
            trace_rows=None) -> RolloutResult:
    """Run ``policy`` (SB3 ``predict`` with attributes ``observation`` and optionally ``history``,
    ``hold_ticks`` and ``residual``, or a CompiledPolicy) on one episode per entry of ``seeds`` (ints) for
    ``horizon`` s (default ``scene.episode.horizon``).  ``episodes`` labels them in failure
    reports (default 0..N-1); traces are kept every ``1 / trace_rate`` s (rounded to whole policy
    steps); ``progress(k)`` is called with the number of policy steps done since its last call.
    ``compiled``: run a CompiledPolicy in the compiled loop (default) or, False, through its
    ``predict`` from Python (the two give the same numbers: tested).  ``warm_starts``,
    ``record_commands``: see "Open-loop policies" in the module doc.  ``threads``: the episodes
    run in this many threads at once (in the compiled loop, blocks of at least
    :data:`MIN_BLOCK_EPISODES` episodes, a chunk of steps per hand-off; in the Python loop, the
    simulator's step, :class:`~impact_env.sim.simulator.Simulator`); None or 1: serially.  The
    results do not depend on it, bitwise.  ``trace_rows``: the episodes (positions in ``seeds``)
    whose traces are kept, in that order (default: all); every episode's catch energy is kept
    at the trace samples whatever it says (``energy_trace``).  compare keeps one episode's
    traces: all of them are 128 MB at N = 400 and 0.4 s, whose first touch costs the kernel's
    page faults (0.03-0.07 us per env per period of compare's rollout: docs/env.md)."""
    threads = check_threads(threads)
    seeds = np.asarray(list(seeds), dtype=np.int64)
    n = len(seeds)
    if n < 1:
        raise ValueError("rollout needs at least one episode (seed)")
    episodes = np.arange(n) if episodes is None else np.asarray(list(episodes), dtype=np.int64)
    if len(episodes) != n:
        raise ValueError(f"episodes has {len(episodes)} labels for {n} seeds")
    rows = np.arange(n) if trace_rows is None else np.asarray(list(trace_rows), dtype=np.int64).reshape(-1)
    if rows.size and (rows.min() < 0 or rows.max() >= n or len(set(rows.tolist())) != rows.size):
        raise ValueError(f"trace_rows must be distinct positions in 0..{n - 1} (one per seed), "
                         f"got {rows.tolist()}")
    slot = np.full(n, -1, dtype=np.int64)
    slot[rows] = np.arange(rows.size)
    horizon = scene.episode.horizon if horizon is None else float(horizon)
    if not (horizon > 0 and math.isfinite(horizon)):
        raise ValueError(f"horizon = {horizon!r} s must be a finite time > 0 s")
    period = scene.control_period
    observation = getattr(policy, "observation", None)
    if observation not in OBSERVATIONS:
        raise ValueError(f"policy {name!r} must say which observation it needs (attribute 'observation' = "
                         f"'sensors', 'privileged' or 'both'), got {observation!r}")
    hold = int(getattr(policy, "hold_ticks", 1))
    step_s = period * hold
    n_steps = int(round(horizon / step_s))
    if n_steps < 1:
        raise ValueError(f"horizon = {horizon:g} s is shorter than one policy step ({step_s:g} s)")
    # traces every 1/trace_rate s in whole steps; trace_rate <= 0: only the start
    stride = max(1, int(round(1.0 / (trace_rate * step_s)))) if trace_rate > 0 else n_steps + 1
    if isinstance(policy, CompiledPolicy):
        policy.check_scene(scene)
        compiled = True if compiled is None else bool(compiled)
    elif compiled:
        raise ValueError(f"policy {name!r} is not a CompiledPolicy: it has no compiled loop")

    t_wall = time.perf_counter()
    layout = make_layout(scene, observation, int(getattr(policy, "history", 1)))
    sim = Simulator(scene, n, layout, hold, residual_law(policy, scene), threads=threads)
    sim.reset([seeding.np_random(int(s))[0] for s in seeds])
    Y0 = sim.Y
    metrics = EpisodeMetrics(n, period, catch_fraction, min_flight_s, horizon_s=n_steps * step_s,
                             plant_records=True)
    metrics.start(sim.t_touch, sim.hw.impact_speed, sim.impact_energy, Y0[:, 0] - Y0[:, 2] > 0.0)
    metrics.acc[:, AC.energy] = _energies(sim.Y, sim.P, np.empty(n))  # the catch energy at the start
    trace_t = np.arange(n_steps // stride + 1) * stride * step_s
    traces = np.zeros((len(trace_t), rows.size, len(TRACE_KEYS)))
    etrace = np.zeros((len(trace_t), n))
    _trace_row(traces[0], etrace[0], slot, sim.Y, sim.records, metrics.acc[:, AC.energy], sim.detected)
    fails = Failures(np.zeros(n, dtype=bool), np.zeros(n), np.zeros(n, dtype=np.int64))
    failed, fail_t, fail_code = fails
    failures: list[dict] = []

    def fail(rows, t, message):
        for i in np.nonzero(rows & ~failed)[0]:
            failures.append({"policy": name, "episode": int(episodes[i]), "seed": int(seeds[i]),
                             "row": int(i), "t_s": float(t), "error": message})
        failed[rows] = True

    extras: dict = {}
    open_loop = _prepare(policy, scene, seeds, n_steps, step_s, warm_starts, extras,
                         lambda msg: fail(np.ones(n, dtype=bool), 0.0, msg))
    commands = np.zeros((n_steps * hold, n)) if record_commands else None
    if compiled and (open_loop is not None or commands is not None):
        compiled = False  # replay and recording are Python-loop features (same numbers: tested)
    if compiled:
        pi, pf, m = policy.arrays()
        mem = policy.new_memory(n)
        chunk = max(1, min(CHUNK, sim.hw.noise_block // hold))  # a chunk's noise fits one block
        blocks = env_blocks(n, resolve_threads(threads, n, MIN_BLOCK_EPISODES), MIN_BLOCK_EPISODES)
        run = BlockRunner(_run_compiled, _compiled_blocks)
        loop_policy = LoopPolicy(PolicyArrays(pi, pf), mem)
        loop_out = LoopOut(metrics.arrays, fails, traces, etrace, slot)
        k = 0
        while k < n_steps:
            k1 = min(k + chunk, n_steps)
            sim.hw.refill_noise(hold * (k1 - k))  # the whole chunk's noise at once
            run(blocks, (Steps(k, k1, stride), loop_policy, sim.params, sim.state, loop_out))
            if progress is not None:
                progress(k1 - k)
            k = k1
        for i in np.nonzero(failed)[0]:
            what = "non-finite action" if fail_code[i] == FAIL_ACTION else "simulation diverged"
            failures.append({"policy": name, "episode": int(episodes[i]), "seed": int(seeds[i]),
                             "row": int(i), "t_s": float(fail_t[i]), "error": what})
    else:
        state = None
        starts = np.ones(n, dtype=bool)
        reported = 0
        for k in range(1, n_steps + 1):
            t_prev = (k - 1) * step_s
            try:
                if open_loop is not None:
                    a = np.asarray(open_loop[k - 1], dtype=np.float64).reshape(n)
                else:
                    action, state = policy.predict(sim.obs.copy(), state=state, episode_start=starts,
                                                   deterministic=True)
                    a = np.asarray(action, dtype=np.float64).reshape(n)
            except Exception as exc:  # a broken policy is reported, not fatal (see module doc)
                fail(np.ones(n, dtype=bool), t_prev, f"{type(exc).__name__}: {exc}")
                a = np.zeros(n)
            starts = np.zeros(n, dtype=bool)
            bad = ~np.isfinite(a)
            if bad.any():
                fail(bad, t_prev, f"non-finite action {a[bad][0]!r}")
            a = np.clip(np.where(failed, 0.0, a), -1.0, 1.0)  # the env's action space
            active = None if not failed.any() else ~failed
            sim.step(a, active)
            if commands is not None:  # every period's drive command (hold, residual law included)
                u = sim.records[:, :, REC.u].T
                commands[(k - 1) * hold:k * hold] = u if active is None else np.where(active, u, 0.0)
            metrics.step(sim.records, sim.P, active, sim.plant_records)
            div = sim.records[:, -1, REC.status] != 0.0
            if active is not None:
                div &= active
            if div.any():
                fail(div, k * step_s, "simulation diverged")
            if k % stride == 0:
                _trace_row(traces[k // stride], etrace[k // stride], slot, sim.Y, sim.records,
                           metrics.acc[:, AC.energy], sim.detected)
            if progress is not None and (k - reported >= CHUNK or k == n_steps):
                progress(k - reported)
                reported = k
    return RolloutResult(policy=name, episodes=episodes, seeds=seeds, metrics=metrics.finish(failed),
                         failures=failures, trace_t=trace_t,
                         traces={key: traces[:, :, j] for j, key in enumerate(TRACE_KEYS)},
                         energy_trace=etrace, trace_rows=rows,
                         t_touch=sim.t_touch.copy(), impact_energy=sim.impact_energy.copy(),
                         control_period=period, wall_time_s=time.perf_counter() - t_wall,
                         extras=extras if commands is None else {**extras, "commands": commands})


def _prepare(policy, scene, seeds, n_steps, step_s, warm_starts, extras, fail):
    """The open-loop hook (module doc): call ``policy.prepare`` if it has one and return its
    ``open_loop`` commands (float64[n_steps, N]) or None; a failing hook fails every episode."""
    prepare = getattr(policy, "prepare", None)
    if prepare is None:
        return None
    try:
        prepare(scene, seeds.copy(), n_steps * step_s, dict(warm_starts or {}))
        stats = getattr(policy, "stats", None)
        if stats is not None:
            extras["policy_stats"] = stats
        u = getattr(policy, "open_loop", None)
        if u is None:
            return None
        u = np.asarray(u, dtype=np.float64)
        if u.shape != (n_steps, len(seeds)):
            raise ValueError(f"open_loop has shape {u.shape}; expected ({n_steps}, {len(seeds)}) "
                             "(policy steps, episodes)")
        return u
    except Exception as exc:  # reported like a failing predict (module doc)
        fail(f"prepare: {type(exc).__name__}: {exc}")
        return np.zeros((n_steps, len(seeds)))
