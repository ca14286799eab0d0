"""The catch task on a batch of rigs: reward, termination and info (dm_control's Task).

:class:`CatchTask` is the one place where the episode logic lives.  It does not observe: the
simulator's step ends with the controller's front end writing the observation, as the rig's
target does (docs/architecture.md, "Who does what"); the task reads the true records of the
step's ticks.  The single env
(:mod:`impact_env.env.catch_env`) is a task of one rig, the vector env
(:mod:`impact_env.env.vector`) a task of N, both stepping the same
:class:`~impact_env.sim.simulator.Simulator` (one numba call for the whole batch), so the vector env
is the single env's physics batched, not a copy of it.

Reward (per control step, per env; :data:`REWARD_FORMULA`, which every env's docs print)::

    REWARD_FORMULA_DOC

E is body 1's catch energy after the step (kinetic + gravitational relative to resting on body 2
+ elastic pad energy, J, :func:`impact_env.plant.energy.catch_energy`), E0 its value at the
episode start (the impact energy), F_cmd the scene's ``effects.command_scale`` (N), T the control
period (s) and ``t_unit = 1 ms``.  The factor T / t_unit makes the return independent of the
control rate: an episode's return is minus the time integral of the normalised energy in
milliseconds (about -48 for an uncontrolled drop on ``rig``).  The ``*_weight`` options are 0
by default (the thesis's objective is the energy alone).

Episode end: ``terminated`` when body 1 is caught (E / E0 below ``catch_threshold`` for at least
``catch_hold`` s) or when the simulation diverges (``info["diverged"]``; the observation is then the
last finite one and the reward is ``-1 * T / t_unit``); ``truncated`` at the horizon.
"""

from __future__ import annotations

import collections
import difflib
import inspect
from collections.abc import Callable
from dataclasses import MISSING, dataclass, field, fields
from typing import Any

import numpy as np

from impact_env._threads import BlockRunner
from impact_env.config import ConfigError, check_choice, check_hold_ticks, check_range
from impact_env.control.observation import ObservationLayout, make_layout
from impact_env.env import task_kernel
from impact_env.policy.export import export_policy
from impact_env.scene import Scene, load_scene
from impact_env.sim.simulator import Simulator

# info_dict's scalar entries in INFO_KEYS order: (key, column, is a flag); the state goes as one array
_INFO_SCALARS = tuple((key, j, key in task_kernel.BOOL_KEYS) for j, key in enumerate(task_kernel.INFO_KEYS)
                      if not task_kernel.INFO.x1 <= j <= task_kernel.INFO.v2)

REWARD_TIME_UNIT = 1e-3  # s
#: the reward per control step and env, as the task kernel computes it (:func:`task_kernel.task_env`):
#: every ``*_weight`` option is a term here (tests/test_env_options.py), and the docs of every env
#: of the task print this line
REWARD_FORMULA = ("r = -(E/E0 + effort_weight (f_applied/F_cmd)^2 + limit_weight [saturated]) "
                  "* T / t_unit")
__doc__ = (__doc__ or "").replace("REWARD_FORMULA_DOC", REWARD_FORMULA)


def _option(default: Any, doc: str, unit: str = "", *, bounds: tuple | None = None, kernel: bool = False,
            evaluation: Any = MISSING) -> Any:
    """A task option: its default, meaning and unit; ``bounds`` = (lo, hi, lo_open), checked when
    the config is built; ``kernel``: the task kernel reads it (as a float, by its own name, in
    :data:`TaskParams`); ``evaluation``: its value when an agent is evaluated on the test's
    objective (a reward penalty is 0 there: ``agents.train``)."""
    meta = {"doc": doc, "unit": unit, "bounds": bounds, "kernel": kernel}
    if evaluation is not MISSING:
        meta["evaluation"] = evaluation
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class TaskConfig:
    """Episode and reward settings of the catch task (SI units).  Each field is an option of
    every env of the task; its metadata says what the docs, the kernel and the evaluation
    derive from it (:func:`_option`)."""

    observation: str = _option("sensors", "what the policy sees: sensors, privileged (true state) or both")
    history: int = _option(1, "frames (and past actions) stacked in the observation")
    hold_ticks: int = _option(1, "control periods per policy step (the action held, rewards summed)")
    residual: str | None = _option(None, "a classic law's spec: the action adds to its command, every tick")
    horizon: float | None = _option(None, "episode length; None: the scene's episode.horizon", "s",
                                    bounds=(0.0, 1e4, True))
    catch_threshold: float = _option(0.01, "caught below this catch energy",
                                     "(fraction of the impact energy)", bounds=(0.0, 1.0, True), kernel=True)
    catch_hold: float = _option(0.01, "for at least this long", "s", bounds=(0.0, 10.0, False))
    terminate_on_catch: bool = _option(True, "a catch ends the episode", kernel=True, evaluation=False)
    effort_weight: float = _option(0.0, "reward penalty on (f_applied / command_scale)^2",
                                   bounds=(0.0, None, False), kernel=True, evaluation=0.0)
    limit_weight: float = _option(0.0, "reward penalty per saturated tick", bounds=(0.0, None, False),
                                  kernel=True, evaluation=0.0)
    action_bounds: str = _option("clip", "an action outside [-1, 1]: clip, or raise")

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if f.metadata["bounds"] is not None and value is not None:
                lo, hi, lo_open = f.metadata["bounds"]
                check_range(f.name, value, f.metadata["unit"], lo, hi, lo_open=lo_open)
        check_choice("action_bounds", self.action_bounds, ("clip", "raise"))
        check_hold_ticks(self.hold_ticks)
        if self.residual is not None and (not isinstance(self.residual, str) or not self.residual.strip()):
            raise ConfigError(f"residual = {self.residual!r} must be a classic law's spec, e.g. "
                              "'pd-penetration' or 'compiled:FILE', or None")
        if not isinstance(self.terminate_on_catch, bool):
            raise ConfigError(f"terminate_on_catch must be true or false, got {self.terminate_on_catch!r}")

    @classmethod
    def from_options(cls, options: dict, env_init: Callable | None = None) -> TaskConfig:
        """The config of the keyword options an env was given.  An unknown one is a TypeError that
        names it, the closest known name, and every argument the env takes: its own (from
        ``env_init``'s signature, e.g. ``scene``) and the task's options."""
        unknown = sorted(set(options) - set(TASK_OPTIONS))
        if unknown:
            own = [] if env_init is None else [
                name for name, param in inspect.signature(env_init).parameters.items()
                if name != "self" and param.kind not in (param.VAR_KEYWORD, param.VAR_POSITIONAL)]
            known = [*own, *TASK_OPTIONS]
            hints = []
            for name in unknown:
                close = difflib.get_close_matches(name, known, 1)
                hints.append(f"{name!r} (did you mean {close[0]!r}?)" if close else repr(name))
            takes = f"{', '.join(own)} and " if own else ""
            raise TypeError(f"unknown keyword argument(s) {', '.join(hints)}; the env takes {takes}the catch "
                            f"task's options {', '.join(TASK_OPTIONS)}")
        return cls(**options)

    def horizon_on(self, scene: Scene) -> float:
        """The episode's horizon (s): this config's, or the scene's ``episode.horizon``."""
        return self.horizon if self.horizon is not None else scene.episode.horizon

    def params(self, scene: Scene):
        """The kernels' task parameters (:data:`TaskParams`) of this config on ``scene``."""
        return task_params(self, scene.control_period, self.hold_ticks, self.horizon_on(scene),
                           scene.effects.command_scale)


#: the catch task's options, the keyword arguments every env of it takes (ImpactCatch-v0, the vector
#: env, ImpactCatchRig-v0): TaskConfig's fields
TASK_OPTIONS = tuple(f.name for f in fields(TaskConfig))
#: the options at evaluation on the test's objective (no reward penalty, every episode the whole horizon)
EVALUATION_OPTIONS = {f.name: f.metadata["evaluation"] for f in fields(TaskConfig)
                      if "evaluation" in f.metadata}
#: what the task kernel reads (impact_env.env.task_kernel), as floats: the options it reads, by their
#: own names, then what the task derives from the options and the scene: the reward's factor
#: T / t_unit, the ticks below the threshold that make a catch, N per unit command, the policy
#: steps to the horizon
_namedtuple: Any = collections.namedtuple  # (a class of fields known at run time: typed Any)
TaskParams = _namedtuple(
    "TaskParams", [f.name for f in fields(TaskConfig) if f.metadata["kernel"]]
    + ["step_weight", "hold", "command_scale", "max_steps"])


def options_doc(indent: str = "") -> str:
    """The task's options, one line each (name = default, unit, meaning): the docs of every env
    of the task list them from here."""
    lines = []
    for f in fields(TaskConfig):
        unit = f" {f.metadata['unit']}" if f.metadata["unit"] else ""
        lines.append(f"{indent}* ``{f.name}={f.default!r}``{unit}: {f.metadata['doc']}")
    return "\n".join(lines)


def check_actions(actions, n: int, action_bounds: str, command_scale: float,
                  scratch: np.ndarray | None = None) -> np.ndarray:
    """float64[n] actions from what the caller gave; NaN or a wrong shape raises ValueError;
    values outside [-1, 1] are clipped (``action_bounds = "clip"``) or raise.  ``scratch``
    (float64[1]): a single env's action in [-1, 1] is written there, without numpy's reductions."""
    if n == 1 and scratch is not None and type(actions) is np.ndarray and actions.shape == (1,):
        x = float(actions[0])
        if -1.0 <= x <= 1.0:
            scratch[0] = x
            return scratch
    a = np.asarray(actions, dtype=np.float64)
    if a.size != n or (a.ndim > 1 and a.shape[-1] != 1) or a.ndim > 2:
        raise ValueError(f"action has shape {np.shape(actions)}; expected ({n}, 1) "
                         f"(or (1,) for a single env): one shaker command in [-1, 1] per env")
    a = a.reshape(n)
    lo, hi = a.min(), a.max()
    if not (-1.0 <= lo and hi <= 1.0):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action contains NaN or inf: {a[~np.isfinite(a)][:4]}; expected values in "
                             f"[-1, 1] (1 = {command_scale:g} N upwards)")
        if action_bounds == "raise":
            raise ValueError(f"action {a[np.abs(a) > 1][:4]} outside [-1, 1] "
                             f"(1 = {command_scale:g} N upwards; action_bounds = 'raise')")
        a = np.clip(a, -1.0, 1.0)
    return a


def info_from_row(row: np.ndarray) -> dict:
    """One env's info from its info row: every column of INFO_KEYS but the state as a Python
    float (a flag as a bool), and ``state`` (x1, v1, x2, v2) as a float64[4] copy."""
    values = row.tolist()
    info: dict = {key: values[j] > 0.5 if flag else values[j] for key, j, flag in _INFO_SCALARS}
    info["state"] = row[task_kernel.INFO.x1:task_kernel.INFO.v2 + 1].copy()
    return info


def task_params(config: TaskConfig, period: float, hold_ticks: int, horizon: float, command_scale: float):
    """The kernels' task parameters (:data:`TaskParams`) for ``config`` at the control ``period``
    (s), ``hold_ticks`` per policy step, a ``horizon`` (s) and ``command_scale`` (N per unit
    command)."""
    max_steps = max(1, int(round(horizon / (period * hold_ticks))))  # round: whole periods up to noise
    hold_steps = max(1, int(np.ceil(config.catch_hold / period - 1e-9)))  # ticks
    options = {f.name: float(getattr(config, f.name)) for f in fields(config) if f.metadata["kernel"]}
    return TaskParams(**options, step_weight=period / REWARD_TIME_UNIT, hold=float(hold_steps),
                      command_scale=float(command_scale), max_steps=float(max_steps))


def new_task_state(n: int) -> task_kernel.TaskState:
    return task_kernel.TaskState(np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64),
                                 np.zeros(n, dtype=bool), np.zeros(n))


def new_task_out(n: int) -> task_kernel.TaskOut:
    return task_kernel.TaskOut(np.zeros(n), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool),
                               np.zeros((n, task_kernel.N_COL)))


def make_catch_task(scene: Scene | str | dict, num_envs: int, config: TaskConfig,
                    overrides=None, threads: int | str | None = None) -> CatchTask:
    """The simulator of ``num_envs`` rigs of ``scene`` (with ``overrides``) that ``config`` asks
    for (observation layout, hold_ticks), stepping in ``threads`` threads (Simulator), and the
    catch task on it."""
    scene = load_scene(scene, overrides)
    layout = make_layout(scene, config.observation, config.history)
    residual = None
    if config.residual is not None:
        residual = export_policy(config.residual, scene)
    return CatchTask(Simulator(scene, num_envs, layout, config.hold_ticks, residual, threads=threads), config)


class CatchTask:
    """The catch task on a :class:`~impact_env.sim.simulator.Simulator`'s batch: reward,
    termination and info from the true state, as the dm_control split has it (the simulator
    observes, the task rewards).  All arrays are over envs."""

    def __init__(self, sim: Simulator, config: TaskConfig):
        self.sim = sim
        self.scene = scene = sim.scene
        self.config = config
        self.layout: ObservationLayout = sim.layout
        self.n = n = sim.n
        self.period = scene.control_period
        self.hold_ticks = sim.hold
        self.horizon = config.horizon_on(scene)
        self.command_scale = scene.effects.command_scale
        self.params = config.params(scene)
        self.max_steps = int(self.params.max_steps)
        self.hold_steps = int(self.params.hold)
        self.state = new_task_state(n)
        self.steps, self.below, self.diverged, self.energy = self.state
        self.impact_speed = sim.hw.impact_speed
        self.out = new_task_out(n)
        self.rewards, self.terminated, self.truncated, self.rows = self.out
        self.drop = task_kernel.Drop(sim.plant_state, sim.plant_parameters, sim.impact_energy,
                                     self.impact_speed)
        self._a1 = np.zeros(1)  # a single env's checked action
        # the simulator's step and the task's in one compiled call, over the simulator's blocks of envs
        self._run = BlockRunner(task_kernel.catch_step)
        self._no_cols = np.zeros((task_kernel.N_COL,
                                  0))  # catch_step's ``cols`` when no info columns are wanted

    @property
    def obs(self) -> np.ndarray:
        """The observation rows (float32[N, layout.size]), written by the simulator."""
        return self.sim.obs

    # -- episodes ------------------------------------------------------------------------------
    def reset(self, rngs, mask=None) -> None:
        sim = self.sim
        idx = sim.reset(rngs, mask)
        self.rows[idx,
                  task_kernel.INFO.t_touch] = sim.t_touch[idx]  # kept by the kernels, which skip this column
        task_kernel.task_reset_rows(idx, sim.records, self.drop, self.params, self.state, self.rows)

    def check_actions(self, actions) -> np.ndarray:
        """:func:`check_actions` for this batch and config."""
        return check_actions(actions, self.n, self.config.action_bounds, self.command_scale, self._a1)

    def step(self, a: np.ndarray, active=None, cols: np.ndarray | None = None):
        """One policy step for every env (or those where ``active`` is true; the others are left
        as they are, with reward 0 and no flags) under float64[N] actions already checked.
        Returns (rewards float64[N], terminated bool[N], truncated bool[N]), arrays owned by the
        task (copy them to keep them).  ``cols``: a new float64[N_COL, N] that the step fills with
        the info rows as columns, for :meth:`info_arrays` (the vector env's infos)."""
        sim = self.sim
        self._run(sim.blocks, sim.step_args(a, active) + (self.drop, self.params, self.state, self.out,
                                                         self._no_cols if cols is None else cols))
        return self.rewards, self.terminated, self.truncated

    # -- info ---------------------------------------------------------------------------------
    def info_arrays(self, cols: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Per-env diagnostics after the last step or reset (SI units), from the info rows; or
        from ``cols``, the columns a step wrote (:meth:`step`; the arrays returned are views
        of it, which the caller gives away)."""
        rows = self.rows
        if cols is None:
            cols = np.ascontiguousarray(rows.T)  # one copy of the rows; each column a contiguous array in it
        out = {}
        for j, key in enumerate(task_kernel.INFO_KEYS[:task_kernel.INFO.x1]):
            out[key] = cols[j] > 0.5 if key in task_kernel.BOOL_KEYS else cols[j]
        out["state"] = rows[:, task_kernel.INFO.x1:task_kernel.INFO.v2 + 1].copy()
        out["diverged"] = cols[task_kernel.INFO.diverged] > 0.5
        out["caught"] = cols[task_kernel.INFO.caught] > 0.5
        out["t_touch"] = cols[task_kernel.INFO.t_touch]
        return out

    def info_dict(self, i: int) -> dict:
        """Env i's info as Python scalars (and ``state`` as float64[4])."""
        return info_from_row(self.rows[i])
