"""The catch task on a batch of rigs: observation, reward, termination (dm_control's Task).

:class:`CatchTask` is the one place where the episode logic lives.  The single env
(:mod:`impact_env.env.catch_env`) is a task of one rig, the vector env
(:mod:`impact_env.env.vector`) a task of N, both stepping the same
:class:`~impact_env.sim.simulator.Simulator` (one numba call for the whole batch), so the vector env
is the single env's physics batched, not a copy of it.

Reward (per control step, per env)::

    r = -(E / E0 + w_effort (f_applied / F_cmd)^2 + w_limit [saturated]) * T / t_unit

E is body 1's catch energy after the step (kinetic + gravitational relative to resting on body 2
+ elastic pad energy, J, :func:`impact_env.plant.energy.catch_energy`), E0 its value at the
episode start (the impact energy), F_cmd the scene's ``effects.command_scale`` (N), T the control
period (s) and ``t_unit = 1 ms``.  The factor T / t_unit makes the return independent of the
control rate: an episode's return is minus the time integral of the normalised energy in
milliseconds (about -48 for an uncontrolled drop on ``rig``).  ``w_effort`` and ``w_limit`` are 0
by default (the thesis's objective is the energy alone).

Episode end: ``terminated`` when body 1 is caught (E / E0 below ``catch_threshold`` for at least
``catch_hold`` s) or when the simulation diverges (``info["diverged"]``; the observation is then the
last finite one and the reward is ``-1 * T / t_unit``); ``truncated`` at the horizon.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from impact_env.config import ConfigError, check_choice, check_range
from impact_env.env import task_kernel as TK
from impact_env.plant import layout as L
from impact_env.scene import Scene, load_scene
from impact_env.sim.observation import OBS_LIMIT, ObservationLayout, make_layout
from impact_env.sim.simulator import Simulator

REWARD_TIME_UNIT = 1e-3  # s


@dataclass(frozen=True)
class TaskConfig:
    """Episode and reward settings of the catch task (SI units)."""

    observation: str = "sensors"
    history: int = 1
    horizon: float | None = None  # s; None: the scene's episode.horizon
    catch_threshold: float = 0.01  # of the impact energy
    catch_hold: float = 0.01  # s
    terminate_on_catch: bool = True
    effort_weight: float = 0.0
    limit_weight: float = 0.0
    action_bounds: str = "clip"  # or "raise"

    def __post_init__(self):
        if self.horizon is not None:
            check_range("horizon", self.horizon, "s", 0.0, 1e4, lo_open=True)
        check_range("catch_threshold", self.catch_threshold, "(fraction of the impact energy)", 0.0, 1.0,
                    lo_open=True)
        check_range("catch_hold", self.catch_hold, "s", 0.0, 10.0)
        check_range("effort_weight", self.effort_weight, "", 0.0)
        check_range("limit_weight", self.limit_weight, "", 0.0)
        check_choice("action_bounds", self.action_bounds, ("clip", "raise"))
        if not isinstance(self.terminate_on_catch, bool):
            raise ConfigError(f"terminate_on_catch must be true or false, got {self.terminate_on_catch!r}")


class CatchTask:
    """N rigs of one scene with the catch task on top.  All arrays are over envs."""

    def __init__(self, scene: Scene | str | dict, num_envs: int, config: TaskConfig, overrides=None):
        self.scene = scene = load_scene(scene, overrides)
        self.config = config
        self.layout: ObservationLayout = make_layout(scene, config.observation, config.history)
        self.sim = Simulator(scene, num_envs)
        self.n = n = self.sim.n
        self.period = scene.control_period
        self.horizon = config.horizon if config.horizon is not None else scene.episode.horizon
        # round, not floor: the horizon is usually a whole number of periods up to float noise
        self.max_steps = max(1, int(round(self.horizon / self.period)))
        self.hold_steps = max(1, int(np.ceil(config.catch_hold / self.period - 1e-9)))
        self.command_scale = scene.effects.command_scale
        tp = np.zeros(TK.N_TASK)
        tp[TK.T_STEP_WEIGHT] = self.period / REWARD_TIME_UNIT
        tp[TK.T_THRESHOLD] = config.catch_threshold
        tp[TK.T_HOLD] = self.hold_steps
        tp[TK.T_TERMINATE] = 1.0 if config.terminate_on_catch else 0.0
        tp[TK.T_EFFORT] = config.effort_weight
        tp[TK.T_LIMIT] = config.limit_weight
        tp[TK.T_CMD] = self.command_scale
        tp[TK.T_MAX_STEPS] = self.max_steps
        tp[TK.T_OBS_LIMIT] = OBS_LIMIT
        self.tp = tp
        lay = self.layout
        F, H = lay.frame_size, lay.history
        self.frames = np.zeros((n, H, F))  # newest first, scaled
        self.past_actions = np.zeros((n, H))
        self.obs = np.zeros((n, lay.size), dtype=np.float32)
        self.steps = np.zeros(n, dtype=np.int64)
        self.below = np.zeros(n, dtype=np.int64)  # consecutive steps below the catch threshold
        self.energy = np.zeros(n)
        self.impact_speed = np.zeros(n)
        self.diverged = np.zeros(n, dtype=bool)
        self.rewards = np.zeros(n)
        self.terminated = np.zeros(n, dtype=bool)
        self.truncated = np.zeros(n, dtype=bool)
        self.rows = np.zeros((n, TK.N_ROW))
        self._a1 = np.zeros(1)
        self._obs_args = (lay.sensor_channels, lay.detector, lay.privileged, lay.scales, tp,
                          self.frames, self.past_actions, self.obs, self.steps, self.below, self.diverged,
                          self.energy)

    # -- episodes ------------------------------------------------------------------------------
    def reset(self, rngs, mask=None) -> None:
        sim = self.sim
        sim.reset(rngs, mask)
        idx = np.arange(self.n) if mask is None else np.nonzero(mask)[0]
        y = sim.Y[idx]
        g = sim.P[idx, L.G]
        gap = np.maximum(y[:, L.X2] - y[:, L.X1], 0.0)
        self.impact_speed[idx] = np.sqrt(np.maximum(y[:, L.V1] - y[:, L.V2], 0.0) ** 2 + 2.0 * g * gap)
        self.rows[idx, TK.R_TTOUCH] = sim.t_touch[idx]  # kept by the kernels, which skip this column
        TK.task_reset_rows(idx, sim.readings, sim.info, sim.Y, sim.P, sim.t, sim.impact_energy,
                           self.impact_speed, *self._obs_args, self.rows)

    def check_actions(self, actions) -> np.ndarray:
        """float64[N] actions from what the caller gave; NaN or a wrong shape raises ValueError;
        values outside [-1, 1] are clipped (``action_bounds = "clip"``) or raise."""
        if self.n == 1 and type(actions) is np.ndarray and actions.shape == (1,):
            x = float(actions[0])  # the common single-env case, without numpy reductions
            if -1.0 <= x <= 1.0:
                self._a1[0] = x
                return self._a1
        a = np.asarray(actions, dtype=np.float64)
        if a.size != self.n or (a.ndim > 1 and a.shape[-1] != 1) or a.ndim > 2:
            raise ValueError(f"action has shape {np.shape(actions)}; expected ({self.n}, 1) "
                             f"(or (1,) for a single env): one shaker command in [-1, 1] per env")
        a = a.reshape(self.n)
        lo, hi = a.min(), a.max()
        if not (-1.0 <= lo and hi <= 1.0):
            if not np.all(np.isfinite(a)):
                raise ValueError(f"action contains NaN or inf: {a[~np.isfinite(a)][:4]}; expected values in "
                                 f"[-1, 1] (1 = {self.command_scale:g} N upwards)")
            if self.config.action_bounds == "raise":
                raise ValueError(f"action {a[np.abs(a) > 1][:4]} outside [-1, 1] "
                                 f"(1 = {self.command_scale:g} N upwards; action_bounds = 'raise')")
            a = np.clip(a, -1.0, 1.0)
        return a

    def step(self, a: np.ndarray):
        """One control period for every env under float64[N] actions already checked.
        Returns (rewards float64[N], terminated bool[N], truncated bool[N]), arrays owned by the
        task (copy them to keep them)."""
        sim = self.sim
        sim.step(a)
        TK.task_step(a, sim.readings, sim.info, sim.Y, sim.P, sim.t, sim.impact_energy, self.impact_speed,
                     *self._obs_args, self.rewards, self.terminated, self.truncated, self.rows)
        return self.rewards, self.terminated, self.truncated

    # -- undoing a step for some envs (NEXT_STEP autoreset) -----------------------------------------
    def save_rows(self, idx) -> list:
        """Copies of every per-env row (task, simulator and Generator state) of envs ``idx``,
        so that :meth:`restore_rows` can undo the step those envs are about to take."""
        saved = []
        for obj in (self, self.sim):
            for name, value in vars(obj).items():
                if isinstance(value, np.ndarray) and value.ndim and value.shape[0] == self.n:
                    saved.append((obj, name, value[idx].copy()))
        rngs = self.sim._rngs
        saved.append((None, "rng", [rngs[i].bit_generator.state for i in idx]))
        return saved

    def restore_rows(self, idx, saved) -> None:
        for obj, name, rows in saved:
            if obj is None:
                for i, state in zip(idx, rows, strict=True):
                    self.sim._rngs[i].bit_generator.state = state
            else:
                getattr(obj, name)[idx] = rows
        self.sim._refill_in = 0  # restored noise cursors may point past their blocks again

    # -- info ---------------------------------------------------------------------------------
    def info_arrays(self) -> dict[str, np.ndarray]:
        """Per-env diagnostics after the last step or reset (SI units), from the info rows."""
        rows = self.rows
        out = {}
        for j, key in enumerate(TK.INFO_KEYS[:TK.R_X1]):
            out[key] = rows[:, j] > 0.5 if key in TK.BOOL_KEYS else rows[:, j].copy()
        out["state"] = rows[:, TK.R_X1:TK.R_V2 + 1].copy()
        out["diverged"] = rows[:, TK.R_DIV] > 0.5
        out["caught"] = rows[:, TK.R_CAUGHT] > 0.5
        out["t_touch"] = rows[:, TK.R_TTOUCH].copy()
        return out

    def info_dict(self, i: int) -> dict:
        """Env i's info as Python scalars (and ``state`` as float64[4])."""
        vals = self.rows[i].tolist()
        out = dict(zip(TK.INFO_KEYS, vals, strict=True))
        for key in TK.BOOL_KEYS:
            out[key] = out[key] > 0.5
        del out["x1"], out["v1"], out["x2"], out["v2"]
        out["state"] = np.array(vals[TK.R_X1:TK.R_V2 + 1])
        return out
