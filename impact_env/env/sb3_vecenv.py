"""Stable-Baselines3 ``VecEnv`` adapter for the native vector env.

SB3 does not take Gymnasium vector envs.  :class:`SB3VecEnv` runs an
:class:`~impact_env.env.vector.ImpactCatchVectorEnv` in ``SAME_STEP`` autoreset mode, which is
SB3's own convention: a finished env is reset within the step, ``dones[i]`` is
``terminated or truncated``, ``infos[i]["terminal_observation"]`` holds the last observation and
``infos[i]["TimeLimit.truncated"]`` says whether the end was the horizon.  To keep a step cheap
with thousands of envs, ``infos[i]`` of an env that did not finish is an empty dict; a finished
env's dict also carries the final ``caught``, ``diverged``, ``catch_energy_ratio`` and ``t``.

Seeding follows SB3: ``env.seed(s)`` (what ``model.set_random_seed`` calls) makes the next
``reset()`` seed env i with ``s + i``.

    >>> import torch
    >>> from stable_baselines3 import PPO
    >>> from impact_env.env.sb3_vecenv import make_sb3_vec_env
    >>> torch.set_num_threads(1)  # small networks: more threads only cost (bench_torch_threads.py)
    >>> env = make_sb3_vec_env("rig", num_envs=64)  # an SB3 VecEnv in a VecMonitor
    >>> model = PPO("MlpPolicy", env)  # doctest: +SKIP
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode

try:
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvWrapper
except ImportError as exc:  # the optional extra: say how to get it
    raise ImportError("impact_env.env.sb3_vecenv adapts the vector env to stable-baselines3, which is not "
                      "installed: pip install 'impact-env[sb3]' (stable-baselines3 and torch)") from exc

from impact_env.env.vector import ImpactCatchVectorEnv

FINAL_KEYS = ("caught", "diverged", "catch_energy_ratio", "t")


class SB3VecEnv(VecEnv):
    """An :class:`ImpactCatchVectorEnv` as an SB3 ``VecEnv`` (see the module docstring)."""

    def __init__(self, venv: ImpactCatchVectorEnv):
        if venv.metadata["autoreset_mode"] != AutoresetMode.SAME_STEP:
            raise ValueError("SB3VecEnv needs the vector env in autoreset_mode SAME_STEP; "
                             "build it with make_sb3_vec_env() or autoreset_mode='SameStep'")
        self.venv = venv
        self.render_mode = venv.render_mode
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        seed = self._seeds[0]
        seeds = None
        if seed is not None:
            seeds = [s if s is not None else seed + i for i, s in enumerate(self._seeds)]
        obs, _ = self.venv.reset(seed=seeds)
        self._reset_seeds()
        self._reset_options()
        self.reset_infos: list[dict] = [{} for _ in range(self.num_envs)]
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        obs, rewards, terminated, truncated, infos = self.venv.step_arrays(self._actions, infos=False)
        dones = terminated | truncated
        out: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        if dones.any():
            final = infos["final_info"]
            for i in np.nonzero(dones)[0]:
                d = out[i]
                d["terminal_observation"] = infos["final_obs"][i]
                d["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
                for k in FINAL_KEYS:
                    d[k] = final[k][i].item()
        return obs, rewards.astype(np.float32), dones, out

    def close(self) -> None:
        self.venv.close()

    # -- attribute access (one env object underneath: every index sees the same value) ---------
    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [getattr(self.venv, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        method = getattr(self.venv, method_name)
        return [method(*method_args, **method_kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self):
        frames = self.venv.render()
        return list(frames) if frames is not None else [None] * self.num_envs


class ActionLimit(VecEnvWrapper):
    """The action space narrowed to ``[-limit, limit]`` (fractions of the command scale), actions
    passed on unchanged: a bound for a residual on a classic law, as SB3's algorithms see it.

    SAC squashes its Gaussian with a tanh into the action space's bounds (and PPO clips to them),
    so the bound is part of the policy: saved in ``model.zip``, honoured by ``predict``, by the
    compiled export (which reads the model's bounds) and so by ``compare`` and the rig.  A
    residual needs a fraction of the shaker's range (the shipped PPO agent's residual stays within
    about +-0.2, docs/agents.md); the full +-1 (+-200 N on top of the law) lets an early, wrong
    critic drive the actor to saturation.  In RL Zoo's YAML::

        vec_env_wrapper:
          - impact_env.env.sb3_vecenv.ActionLimit: {limit: 0.25}
    """

    def __init__(self, venv, limit: float):
        limit = float(limit)
        if not 0.0 < limit <= 1.0:
            raise ValueError(f"ActionLimit limit = {limit!r} must be in (0, 1] (a fraction of the command "
                             "scale)")
        import gymnasium

        self.limit = limit
        space = gymnasium.spaces.Box(-limit, limit, shape=venv.action_space.shape, dtype=np.float32)
        super().__init__(venv, action_space=space)

    def reset(self):
        return self.venv.reset()

    def step_async(self, actions: np.ndarray) -> None:
        self.venv.step_async(actions)

    def step_wait(self):
        return self.venv.step_wait()


def make_sb3_vec_env(scene="rig", num_envs: int = 16, monitor: bool = True, **kwargs):
    """An SB3 ``VecEnv`` of ``num_envs`` rigs, wrapped in SB3's ``VecMonitor`` (episode returns
    and lengths in ``infos[i]["episode"]``, which SB3's logger reads); ``monitor=False`` gives
    the bare :class:`SB3VecEnv`.  ``kwargs`` as for ``ImpactCatch-v0``.

    With one env (or a few), set ``torch.set_num_threads(1)`` before training: PPO's small
    networks gain nothing from more threads and lose to their synchronisation
    (``python scripts/bench_torch_threads.py`` measures it)."""
    from stable_baselines3.common.vec_env import VecMonitor

    env = SB3VecEnv(ImpactCatchVectorEnv(num_envs, scene, autoreset_mode=AutoresetMode.SAME_STEP, **kwargs))
    return VecMonitor(env) if monitor else env
