"""The classic laws as policies with stable-baselines3's ``predict``: one class per law of
:data:`impact_env.control.laws.REGISTRY`, derived from its declaration (:data:`LAW_POLICIES`), and
:class:`Policy`, their base, for a policy written in Python (override :meth:`Policy.force`).


A baseline is built from a scene (the controller knows the masses, the pad stiffness and the
force that action +1 demands) and its gains, and is then used exactly like a trained SB3 model::

    action, state = policy.predict(obs, state=None, episode_start=None, deterministic=True)

* ``obs``: one observation (float[size]) or a batch (float[N, size]) in the env's layout
  (:mod:`impact_env.control.observation`): each entry divided by its reference scale.  The policy
  reads the first frame (the current sample); with ``history > 1`` the older frames and the
  past actions that follow are ignored.
* ``action``: float64[1] or float64[N, 1], the force demand divided by
  ``scene.effects.command_scale`` (N per unit action) and **clipped to [-1, 1]**, the env's
  action space (float64, as the compiled law gives it: the env takes float64 actions as they
  are, so a baseline and its compiled policy run bitwise the same episodes).  A law that asks
  for more than ``command_scale`` newtons gets the limit, as the env would give it anyway;
  :meth:`Policy.force` returns the unclipped demand in N.
* ``state``: the policy's memory (float64[N, k]; ``None`` for memoryless laws).  Pass the state
  returned by the previous call back in, or pass ``None`` and the policy keeps its memory
  internally (one row per env of the batch).  Rows where ``episode_start`` is true are reset.
* ``deterministic`` is accepted for compatibility; every baseline is deterministic.

Each class says which observation it needs in the class attribute ``observation``
(``"sensors"`` or ``"privileged"``), its CLI name in ``name``, and its gains in ``PARAMS``
(default, unit, meaning), which :func:`baselines.make_policy` parses from ``name:k=v,...``.
Gains may be numbers or arrays over the batch (one gain set per env, used by the gain sweep).

The law itself is written once, as the compiled kernel of :mod:`impact_env.control.laws`: a
law's class (:func:`law_policy`) names it (``name``), gives its constants
(:meth:`Policy.law_constants`, from the law's ``constants_of``) and the default
:meth:`Policy.force` runs it on the batch.  A policy that is not one of those laws overrides
:meth:`Policy.force`.
"""

from __future__ import annotations

import re
from typing import Any, ClassVar

import numpy as np

from impact_env.config import ConfigError
from impact_env.control import laws
from impact_env.control.laws.law import Law, Param
from impact_env.control.observation import ObservationLayout, make_layout
from impact_env.control.policy import CompiledPolicy
from impact_env.scene import Scene, load_scene

__all__ = ["LAW_POLICIES", "Param", "Policy", "law_policy"]


class Policy:
    """Base class: observation bookkeeping, batching, clipping and memory.  Subclasses implement
    :meth:`force` (the law, in N) and, if they keep memory, set ``memory_size``."""

    name: ClassVar[str] = ""
    observation: ClassVar[str] = "sensors"
    memory_size: ClassVar[int] = 0
    PARAMS: ClassVar[dict[str, Param]] = {}
    reads: ClassVar[tuple[str, ...]] = ()  # the observation entries it needs
    law: ClassVar[Law | None] = None  # the compiled law it runs, if any
    _constants: dict[str, Any] | None = None  # law_constants(), once derived (force())

    def __init__(self, scene: Scene | str | dict, **params):
        self.scene = load_scene(scene)
        unknown = sorted(set(params) - set(self.PARAMS))
        if unknown:
            raise ConfigError(f"unknown parameter(s) {', '.join(unknown)} for policy {self.name!r} "
                              f"(valid: {', '.join(self.PARAMS) or 'none'})")
        self.params: dict[str, Any] = {}
        for key, spec in self.PARAMS.items():
            value = params.get(key, spec.default)
            self.params[key] = spec.check(self.name, key, value)
            if self.params[key] is None and spec.from_scene is not None:
                self.params[key] = spec.from_scene(self.scene)
        self.layout: ObservationLayout = make_layout(self.scene, self.observation, history=1)
        self.command_scale = float(self.scene.effects.command_scale)
        self._memory: np.ndarray | None = None
        for entry in self.reads:  # fail at construction, not mid-run
            self.column(np.zeros((1, self.layout.frame_size)), entry)

    # -- the law ---------------------------------------------------------------------------
    def force(self, values: np.ndarray, memory: np.ndarray | None) -> np.ndarray:
        """Shaker force demand (N, upwards) per env from the current frame in SI units
        (``values[N, frame_size]``, named by ``self.layout.names``); may update ``memory``.
        Default: the compiled law ``name`` (:func:`impact_env.control.laws.law_forces`) with
        :meth:`law_constants`, one set per env."""
        if self.name not in laws.KIND:
            raise NotImplementedError(f"{type(self).__name__} is not a compiled law: override force()")
        n = values.shape[0]
        if self._constants is None:
            # they follow from the scene and the parameters, both fixed at construction; a filter's
            # (mpc's) take milliseconds to derive, which once per step was most of compare's time
            self._constants = self.law_constants()
        K = laws.constants_rows(self.name, self._constants, n)
        # a law's kernel reads only its own memory (law.memory floats), not the widest law's
        wide = memory is not None and memory.shape[1] >= self.memory_size
        mem = memory if wide else np.zeros((n, laws.MEMORY))
        slots = laws.law_slots(self.name, self.layout.names)
        return laws.law_forces(laws.KIND[self.name], slots, K, np.ascontiguousarray(values, dtype=np.float64),
                             np.ascontiguousarray(mem), np.empty(n))

    def reset_memory(self, memory: np.ndarray, rows: np.ndarray) -> None:
        """Set the memory of ``rows`` (bool[N]) to the start-of-episode value (default 0)."""
        memory[rows] = 0.0

    # -- the SB3 interface ------------------------------------------------------------------
    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        u, memory = self.command(obs, state, episode_start)
        action = u.reshape(-1, 1)
        return (action[0] if np.ndim(obs) == 1 else action), memory

    def command(self, obs, state=None, episode_start=None) -> tuple[np.ndarray, np.ndarray | None]:
        """(float64[N] commands in [-1, 1], memory): :meth:`predict`'s actions, as one array."""
        x = np.asarray(obs, dtype=np.float64)
        if x.ndim == 1:
            x = x[None, :]
        if x.ndim != 2:
            raise ValueError(f"{self.name}: observation must be 1-d or 2-d [N, size], got shape {x.shape}")
        self._check_size(x.shape[1])
        n = x.shape[0]
        values = x[:, :self.layout.frame_size] * self.layout.scales
        memory = None
        if self.memory_size:
            memory = self._memory_for(n, state)
            if episode_start is not None:
                starts = np.asarray(episode_start, dtype=bool).reshape(-1)
                if starts.size not in (1, n):
                    raise ValueError(f"{self.name}: episode_start has {starts.size} entries for {n} envs")
                self.reset_memory(memory, np.broadcast_to(starts, (n,)))
        f = np.asarray(self.force(values, memory), dtype=np.float64).reshape(n)
        return np.clip(f / self.command_scale, -1.0, 1.0), memory

    def __call__(self, obs, state=None, episode_start=None, deterministic: bool = True):
        return self.predict(obs, state, episode_start, deterministic)

    # -- helpers ----------------------------------------------------------------------------
    def _memory_for(self, n: int, state) -> np.ndarray:
        if state is not None:
            mem = np.asarray(state)
            if mem.shape != (n, self.memory_size) or mem.dtype != np.float64:
                raise ValueError(f"{self.name}: state must be the float64[{n}, {self.memory_size}] array "
                                 f"returned by the previous predict, got {getattr(mem, 'shape', mem)}")
            self._memory = mem
        elif self._memory is None or self._memory.shape[0] != n:
            # a new batch size is a new set of episodes
            self._memory = np.zeros((n, self.memory_size))
            self.reset_memory(self._memory, np.ones(n, dtype=bool))
        return self._memory

    def _check_size(self, size: int) -> None:
        k = self.layout.frame_size
        if size == k or (size > k and size % (k + 1) == 0 and size // (k + 1) > 1):
            return
        raise ValueError(f"{self.name}: observation has {size} entries; with the {self.observation!r} "
                         f"layout of scene {self.scene.name!r} ({', '.join(self.layout.names)}) it must have "
                         f"{k} (history 1) or {k + 1} * history (history > 1)")

    def column(self, values: np.ndarray, name: str) -> np.ndarray:
        """Column ``name`` of the SI frame ``values`` (raises naming the missing channel)."""
        if name not in self.layout.names:
            raise ConfigError(f"{self.name} needs the {name!r} channel, which scene {self.scene.name!r} "
                              f"does not provide (it gives {', '.join(self.layout.names)})")
        return values[:, self.layout.names.index(name)]

    # -- compiled ---------------------------------------------------------------------------------
    def law_constants(self) -> dict[str, float]:
        """The constants of this law's compiled kernel (:mod:`impact_env.control.laws`)."""
        return {} if self.law is None else self.law.constants_of(self.scene, self.params)

    def force_from_state(self, x1, v1, x2, v2):
        """A privileged law on the true state (arrays or floats, SI, thesis frame) -> f2 in N
        (unclipped)."""
        if self.layout.names != ("x1", "v1", "x2", "v2"):
            raise ConfigError(f"{self.name} reads {self.layout.names}, not the true state")
        cols = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (x1, v1, x2, v2)))
        shape = cols[0].shape
        values = np.stack([c.reshape(-1) for c in cols], axis=1)  # the privileged frame: x1, v1, x2, v2
        return self.force(values, None).reshape(shape)

    def compiled(self) -> CompiledPolicy:
        """This law as a :class:`~impact_env.control.policy.CompiledPolicy` (a numba kernel with
        the same arithmetic; ``impact-env export`` writes it to a file)."""
        for key, v in self.params.items():
            if isinstance(v, np.ndarray):
                raise ConfigError(f"{self.name}: parameter {key} holds {v.size} values (one per env); a "
                                  "compiled policy takes one value per parameter")
        params = {k: v for k, v in self.params.items() if not isinstance(v, str)}
        return CompiledPolicy.from_law(self.name, params, self.law_constants(), self.scene, self.observation,
                                       source={"spec": self.describe()})

    def describe(self) -> str:
        gains = ",".join(f"{k}={_fmt(v)}" for k, v in self.params.items())
        return f"{self.name}:{gains}" if gains else self.name

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.describe()} scene={self.scene.name!r}>"


def _fmt(v) -> str:
    if isinstance(v, np.ndarray):
        return f"[{v.size} values]"
    return f"{v:g}" if isinstance(v, float) else str(v)


def law_policy(law: Law) -> type[Policy]:
    """The policy class of ``law`` (named after it: ``thesis-rig`` -> ``ThesisRig``), with its
    gains as ``PARAMS``; its docs are the law module's."""
    name = "".join(part.capitalize() for part in re.split(r"[^0-9a-zA-Z]+", law.name))
    return type(name, (Policy,), {
        # (a law with memory gets the packed row of every law, laws.MEMORY: the one kernel,
        # law_forces, reads rows of that width, and force() replaces a narrower row by zeros)
        "name": law.name, "observation": law.observation, "memory_size": laws.MEMORY if law.memory else 0,
        "PARAMS": law.params,
        "reads": law.required(), "law": law, "__module__": __name__,
        "__doc__": f"The classic law ``{law.name}``: {law.doc}",
    })


#: every classic law's policy class, by name (impact_env.policy.registry finds them here)
LAW_POLICIES: dict[str, type[Policy]] = {law.name: law_policy(law) for law in laws.REGISTRY}
globals().update({cls.__name__: cls for cls in LAW_POLICIES.values()})  # (so that pickle finds them)
