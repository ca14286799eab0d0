"""Learnability options as wrappers, until the env has them natively: ``hold_ticks``, ``residual``
and ``chatter_weight``.

These are experiments (issue 11, item 3).  The env is getting the same options compiled; the
semantics below are the contract the in-env versions keep, so that a run made with these
wrappers can be repeated with ``env_kwargs`` alone once they land (``agents.train`` passes an
option to the env itself as soon as the env's constructor accepts it).

Semantics, per env, for one **policy step** with action ``a`` (``float[1]``, first clipped to
[-1, 1] like the env's own action; NaN or inf raise ``ValueError``):

* ``hold_ticks = k`` (int >= 1): the inner env (one tick = one control period, 100 us on ``rig``)
  is stepped k times.  Tick j (j = 1..k) applies the command

  - ``u_j = a`` without ``residual``;
  - ``u_j = clip(law(o_{j-1}) + a, -1, 1)`` with ``residual = "pd-penetration"`` (any named
    policy spec of :func:`baselines.make_policy` that reads the sensor frame), where ``o_0`` is the
    observation the policy acted on and ``o_j`` the inner env's observation after tick j: the law
    runs at the control rate on every tick's observation, exactly as ``impact-env compare`` runs
    it, and its memory (previous penetration estimate, previous x2) is reset at each episode's
    first tick and is the law's alone (one row per env).

  The policy step's reward is the sum of the ticks' rewards; its observation is ``o_J``, the
  inner env's observation after the last tick J taken.
* The episode can end at a tick J < k (caught, diverged, horizon): the policy step stops there
  (J ticks), ``done`` is true, ``infos[i]["terminal_observation"] = o_J``,
  ``infos[i]["TimeLimit.truncated"]`` is true when the end was the horizon alone, and the final
  ``caught``, ``diverged``, ``catch_energy_ratio``, ``t`` come with it (as in
  :mod:`impact_env.env.sb3`); the returned observation is the next episode's first.  The next
  episode starts exactly as if the env had been reset after tick J: in the vector wrapper the
  other envs go on with their ticks, and the rows of an env that ended are restored to their
  reset state afterwards (:meth:`CatchTask.save_rows`), Generator included, so env i of
  :class:`HoldResidualVecEnv` equals :class:`HoldResidualWrapper` around a single
  ``ImpactCatch-v0`` seeded ``seed + i`` in SB3's ``DummyVecEnv``, bitwise (tested).
* ``chatter_weight = w`` (>= 0): the policy step's reward is lowered by ``w |a - a_prev|``, with
  ``a_prev`` the policy's previous action in the same episode (0 at its first step), i.e. an
  episode pays ``w`` times the total variation of the policy's action.  It is charged on the
  policy's own action, not on the command ``u``: with ``residual`` the law's variation is the
  baseline's and not the agent's to pay for; without it ``u = a``.  No time factor: a smooth
  command costs the same at any policy rate, a chattering one costs more the faster it flips.
* The effort penalty is the env's own ``effort_weight`` (``(f_applied / F_cmd)^2`` per tick, see
  :class:`~impact_env.env.catch_env.ImpactCatchEnv`); pass it in ``env_kwargs``.
* Observation history is the env's own ``history`` (frames and commands of the last ticks, at
  the control rate: with ``history = hold_ticks`` the policy sees every tick of its last hold).
  The stacked actions are the commands ``u`` applied.
* Episode start at the electromagnet's release: the scene override
  ``{"initial.pre_contact_time": 1.0}`` (clipped by the scene to the fall time, 0.101 s for
  the 50 mm drop of ``rig``); nothing to wrap.

``VecMonitor`` above the vector wrapper counts episode lengths in policy steps and returns with
the chatter penalty; under RL Zoo the ``Monitor`` sits below :class:`HoldResidualWrapper` and
counts ticks and the env's rewards.

:class:`HeldPolicy` runs a model trained through these wrappers tick by tick, with the same
hold and residual, in :func:`impact_env.eval.rollout.rollout` (and so on the same held-out
drops and metrics as ``impact-env compare``): see :mod:`agents.evaluate`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnvWrapper

from impact_env.config import ConfigError, check_range
from impact_env.env.sb3 import FINAL_KEYS, SB3VecEnv

OPTION_KEYS = ("hold_ticks", "residual", "chatter_weight")


@dataclass(frozen=True)
class LearnabilityOptions:
    """``hold_ticks`` (ticks per policy step, >= 1), ``residual`` (a named policy spec or None),
    ``chatter_weight`` (>= 0, per unit of the action's total variation)."""

    hold_ticks: int = 1
    residual: str | None = None
    chatter_weight: float = 0.0

    def __post_init__(self):
        h = self.hold_ticks
        if isinstance(h, bool) or not isinstance(h, (int, np.integer)) or not 1 <= h <= 10_000:
            raise ConfigError(f"hold_ticks = {h!r} must be an integer from 1 to 10000 (control periods "
                              "per policy step)")
        check_range("chatter_weight", self.chatter_weight, "(per unit change of the action)", 0.0)
        if self.residual is not None and (not isinstance(self.residual, str) or not self.residual.strip()):
            raise ConfigError(f"residual = {self.residual!r} must be a named policy (e.g. 'pd-penetration') "
                              "or None")

    @property
    def trivial(self) -> bool:
        return self.hold_ticks == 1 and self.residual is None and self.chatter_weight == 0.0

    def as_dict(self) -> dict:
        return {"hold_ticks": int(self.hold_ticks), "residual": self.residual,
                "chatter_weight": float(self.chatter_weight)}

    def make_law(self, scene):
        """The residual's law for ``scene``, checked to read the sensor frame (None without one)."""
        if self.residual is None:
            return None
        from baselines import POLICIES, parse_spec

        # the classic laws of this project by name (baselines.POLICIES), not the entry-point
        # registry: the residual is one of them, whatever other packages register
        name, params = parse_spec(self.residual)
        if name not in POLICIES:
            raise ConfigError(f"residual = {self.residual!r}: unknown policy {name!r}; expected one of the "
                              f"classic laws {', '.join(POLICIES)} (e.g. 'pd-penetration')")
        law = POLICIES[name](scene, **params)
        if law.observation != "sensors":
            raise ConfigError(f"residual = {self.residual!r} reads the {law.observation!r} observation; "
                              "the residual option needs a law on the sensor frame")
        return law


def check_residual_observation(options: LearnabilityOptions, observation: str) -> None:
    """The law reads the sensor frame, so the policy's observation must hold it."""
    if options.residual is not None and observation not in ("sensors", "both"):
        raise ConfigError(f"residual = {options.residual!r} needs observation = 'sensors' or 'both' (the law "
                          f"reads the sensor frame), got {observation!r}")


def law_input(law, observation: str):
    """What of the policy's observation the law reads: all of it on the sensor layout (the law
    takes the current frame of a stacked one), the sensor part of the current frame with
    ``observation="both"`` (sensors first, then the true state)."""
    if law is None or observation == "sensors":
        return slice(None)
    return slice(0, law.layout.frame_size)


def _check_action(a, n: int) -> np.ndarray:
    x = np.asarray(a, dtype=np.float64).reshape(-1)
    if x.size != n:
        raise ValueError(f"action has shape {np.shape(a)}; expected ({n}, 1): one command in [-1, 1] per env")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"action contains NaN or inf: {x[~np.isfinite(x)][:4]}; expected values in [-1, 1]")
    return np.clip(x, -1.0, 1.0)


class HoldResidualVecEnv(VecEnvWrapper):
    """The options of :class:`LearnabilityOptions` around an :class:`~impact_env.env.sb3.SB3VecEnv`
    (module docstring: semantics).  ``ticks`` counts the control periods simulated."""

    def __init__(self, venv: SB3VecEnv, options: LearnabilityOptions):
        if not isinstance(venv, SB3VecEnv):
            raise TypeError("HoldResidualVecEnv wraps an SB3VecEnv (make_sb3_vec_env), got "
                            f"{type(venv).__name__}")
        super().__init__(venv)
        self.options = options
        self.vector = venv.venv  # the native ImpactCatchVectorEnv (SAME_STEP autoreset)
        self.task = self.vector.task
        self.law = options.make_law(self.vector.scene)
        if self.law is not None:
            check_residual_observation(options, self.task.config.observation)
        self._law_cols = law_input(self.law, self.task.config.observation)
        n = self.num_envs
        self._law_start = np.ones(n, dtype=bool)
        self._prev = np.zeros(n)
        self._actions: np.ndarray | None = None
        self.ticks = 0

    def reset(self):
        obs = self.venv.reset()
        self._law_start[:] = True
        self._prev[:] = 0.0
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        n = self.num_envs
        a = _check_action(self._actions, n)
        opt = self.options
        vec, task = self.vector, self.task
        total = np.zeros(n)
        active = np.ones(n, dtype=bool)
        dones = np.zeros(n, dtype=bool)
        infos: list[dict[str, Any]] = [{} for _ in range(n)]
        frozen: list[tuple[np.ndarray, list]] = []
        obs = task.obs  # o_0, the observation the policy acted on
        for _ in range(opt.hold_ticks):
            if self.law is not None:
                law_a, _ = self.law.predict(obs[:, self._law_cols], episode_start=self._law_start | ~active)
                u = np.clip(law_a.reshape(n).astype(np.float64) + a, -1.0, 1.0)
            else:
                u = a
            obs, rewards, terminated, truncated, tinfo = vec.step_arrays(u, infos=False)
            self.ticks += int(active.sum())
            total += np.where(active, rewards, 0.0)
            self._law_start[active] = False
            ended = (terminated | truncated) & active
            if ended.any():
                idx = np.nonzero(ended)[0]
                final = tinfo["final_info"]
                for i in idx:
                    d = infos[i]
                    d["terminal_observation"] = tinfo["final_obs"][i]
                    d["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
                    for k in FINAL_KEYS:
                        d[k] = final[k][i].item()
                dones |= ended
                active &= ~ended
                # the next episode starts from its reset state: undo the ticks still to come
                frozen.append((idx, task.save_rows(idx)))
            if not active.any():
                break
        for idx, saved in reversed(frozen):
            task.restore_rows(idx, saved)
        total -= opt.chatter_weight * np.abs(a - self._prev)
        self._prev = np.where(dones, 0.0, a)
        self._law_start |= dones
        return task.obs.copy(), total.astype(np.float32), dones, infos


class HoldResidualWrapper(gym.Wrapper):
    """The same options around one ``ImpactCatch-v0`` (what RL Zoo's ``env_wrapper`` takes)::

        env_wrapper:
          - agents.experimental_wrappers.HoldResidualWrapper:
              hold_ticks: 4
              residual: pd-penetration
    """

    def __init__(self, env: gym.Env, hold_ticks: int = 1, residual: str | None = None,
                 chatter_weight: float = 0.0):
        super().__init__(env)
        self.options = LearnabilityOptions(hold_ticks, residual, chatter_weight)
        base = env.unwrapped
        self.law = self.options.make_law(base.scene)
        if self.law is not None:
            check_residual_observation(self.options, base.task.config.observation)
        self._law_cols = law_input(self.law, base.task.config.observation)
        self._obs = None
        self._prev = 0.0
        self._law_start = True

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._obs = obs
        self._prev = 0.0
        self._law_start = True
        return obs, info

    def step(self, action):
        a = float(_check_action(action, 1)[0])
        total = 0.0
        obs, terminated, truncated, info = self._obs, False, False, {}
        for _ in range(self.options.hold_ticks):
            if self.law is not None:
                start = np.array([self._law_start])
                law_a, _ = self.law.predict(obs[None, self._law_cols], episode_start=start)
                u = np.clip(np.array([float(law_a[0, 0]) + a]), -1.0, 1.0)
            else:
                u = np.array([a])
            self._law_start = False
            obs, r, terminated, truncated, info = self.env.step(u)
            total += r
            if terminated or truncated:
                break
        total -= self.options.chatter_weight * abs(a - self._prev)
        self._prev = a
        self._obs = obs
        return obs, total, terminated, truncated, info


class HeldPolicy:
    """A model trained with :class:`LearnabilityOptions`, run at the control rate: ``predict`` is
    called once per tick (as :func:`impact_env.eval.rollout.rollout` does) and asks the model for
    a new action on every ``hold_ticks``-th tick of an episode (its first included), holds it, and
    adds the residual's law evaluated on every tick.  Same semantics as the wrappers."""

    def __init__(self, model, options: LearnabilityOptions, scene, observation: str = "sensors",
                 history: int = 1, name: str = ""):
        self.model = model
        self.options = options
        self.observation = observation
        self.history = history
        self.name = name
        self.law = options.make_law(scene)
        check_residual_observation(options, observation)
        self._law_cols = law_input(self.law, observation)
        self._tick: np.ndarray | None = None
        self._held: np.ndarray | None = None

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        x = np.asarray(obs)
        n = x.shape[0]
        if self._tick is None or self._tick.shape[0] != n:
            self._tick = np.zeros(n, dtype=np.int64)
            self._held = np.zeros(n)
        starts = np.zeros(n, dtype=bool) if episode_start is None else \
            np.broadcast_to(np.asarray(episode_start, dtype=bool).reshape(-1), (n,))
        self._tick[starts] = 0
        ask = self._tick % self.options.hold_ticks == 0
        if ask.any():
            act, _ = self.model.predict(x, deterministic=deterministic)
            a = _check_action(act, n)
            self._held = np.where(ask, a, self._held)
        self._tick += 1
        u = self._held
        if self.law is not None:
            law_a, _ = self.law.predict(x[:, self._law_cols], episode_start=starts)
            u = np.clip(law_a.reshape(n).astype(np.float64) + u, -1.0, 1.0)
        # float64, not float32: the wrappers apply the sum in float64 too (bitwise the same)
        return u.reshape(n, 1), None
