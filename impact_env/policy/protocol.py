"""Bring your own policy: the protocol a plain Python object follows to be benchmarked.

A policy of your own is a class (or any callable) ``Factory(scene, **params)`` that returns an
object with::

    observation = "sensors"         # optional: "sensors" (default), "privileged" or "both"
    def reset(self, seed): ...      # a new episode begins; seed: the drop's seed (int, or None)
    def act(self, observation):     # float32[size] in the env's layout -> the action, a float in
        ...                         # [-1, 1] (1 = scene.effects.command_scale N up; clipped)

``scene`` is the :class:`~impact_env.scene.Scene` the policy runs on (its masses, its
``effects.command_scale``, ...), ``params`` the spec's ``KEY=VALUE`` pairs (numbers as floats,
other values as strings).  The observation is what ``ImpactCatch-v0`` gives an agent (docs/env.md
lists its entries, each divided by its reference scale).  One object is made per episode, so an
object may keep its own memory between ``act`` calls; ``reset`` is called once, before the
episode's first ``act``.

:func:`wrap` turns such a factory into what the rollouts run (SB3's ``predict`` on a batch):
:class:`StepPolicy`.  A class that already has ``predict`` (a subclass of
:class:`impact_env.policy.laws.Policy`, a loaded SB3 model's wrapper) is used as it is.  It runs
from Python, one call per episode per control step: expect about 1 us per call of your ``act``
on top of the simulation, where a compiled policy (``impact-env export``, ``compiled:FILE``)
costs nothing of the kind.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from impact_env.config import ConfigError


@runtime_checkable
class StepProtocol(Protocol):
    """The object a factory returns (module doc)."""

    def reset(self, seed: int | None) -> None: ...

    def act(self, observation: np.ndarray) -> Any: ...


class StepPolicy:
    """A :class:`StepProtocol` factory as a batch policy: one object per episode."""

    def __init__(self, factory, scene, params: dict, name: str):
        self.factory, self.scene, self.params, self.name = factory, scene, dict(params), name
        first = self._make()
        self.observation = getattr(first, "observation", "sensors")
        self.history = int(getattr(first, "history", 1))
        self.open_loop = None  # the rollout's hook: not an open-loop policy
        self._objects: list = [first]
        self._fresh = True  # the first object is not reset yet
        self._started = np.zeros(1, dtype=bool)  # episodes that have acted (a new start resets them)

    def _make(self):
        try:
            obj = self.factory(self.scene, **self.params)
        except TypeError as exc:
            raise ConfigError(f"policy {self.name!r}: {exc} (a policy of your own is called as "
                              "Factory(scene, **params); params from the spec's KEY=VALUE pairs)") from None
        if not isinstance(obj, StepProtocol):
            raise ConfigError(f"policy {self.name!r}: {type(obj).__name__} has neither predict (SB3) nor "
                              "reset(seed) and act(observation) (impact_env.policy.protocol)")
        return obj

    def prepare(self, scene, seeds, horizon, warm_starts) -> None:
        """The rollout's hook, before the first step: one object per episode, reset with its seed."""
        first = self._objects[:1] if self._fresh else []
        self._objects = first + [self._make() for _ in range(len(seeds) - len(first))]
        for obj, seed in zip(self._objects, seeds, strict=True):
            obj.reset(int(seed))
        self._fresh = False
        self._started = np.zeros(len(seeds), dtype=bool)

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        batch = np.atleast_2d(np.asarray(obs))
        n = batch.shape[0]
        if len(self._objects) != n or self._fresh:  # used outside a rollout: no seeds known
            self._objects = [self._make() for _ in range(n)]
            for obj in self._objects:
                obj.reset(None)
            self._fresh = False
            self._started = np.zeros(n, dtype=bool)
        elif episode_start is not None:
            for row in np.flatnonzero(np.asarray(episode_start, dtype=bool).reshape(-1) & self._started):
                self._objects[row].reset(None)
        self._started = np.ones(n, dtype=bool)
        actions = np.empty((n, 1), dtype=np.float64)
        for i, obj in enumerate(self._objects):
            actions[i, 0] = float(np.asarray(obj.act(batch[i]), dtype=np.float64).reshape(-1)[0])
        out = np.clip(actions, -1.0, 1.0)
        out[~np.isfinite(actions)] = np.nan  # a non-finite action fails its episode (the rollout says so)
        return (out if np.ndim(obs) > 1 else out[0]), state


def wrap(target, scene, params: dict, name: str):
    """The policy ``target(scene, **params)`` as the rollouts run it (module doc)."""
    if hasattr(target, "predict"):
        return target(scene, **params)
    return StepPolicy(target, scene, params, name)
