"""The policy interface shared by every baseline: stable-baselines3's ``predict``.

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
baseline names it (``name``), gives its constants (:meth:`Policy.law_constants`) and the default
:meth:`Policy.force` runs it on the batch.  A policy that is not one of those laws overrides
:meth:`Policy.force`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from impact_env.config import ConfigError
from impact_env.control import laws as LW
from impact_env.control.observation import ObservationLayout, make_layout
from impact_env.scene import Scene, load_scene


@dataclass(frozen=True)
class Param:
    """One gain or setting of a baseline: default, unit, meaning, allowed range or choices."""

    default: Any
    unit: str
    doc: str
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] = ()

    def check(self, policy: str, key: str, value: Any) -> Any:
        """The value, validated (numbers and arrays of numbers, or one of ``choices``)."""
        where = f"{policy} parameter {key}"
        u = f" {self.unit}" if self.unit else ""
        if self.choices:
            if value not in self.choices:
                raise ConfigError(f"{where} = {value!r} is not one of {', '.join(self.choices)}")
            return value
        if value is None:
            return None
        arr = np.asarray(value, dtype=np.float64) if not isinstance(value, str) else None
        if arr is None or arr.ndim > 1:
            raise ConfigError(f"{where} must be a number{u} (or a 1-d array of numbers), got {value!r}")
        bad = ~np.isfinite(arr)
        if self.lo is not None:
            bad |= arr < self.lo
        if self.hi is not None:
            bad |= arr > self.hi
        if np.any(bad):
            rng = " and ".join(s for s in (f">= {self.lo:g}{u}" if self.lo is not None else "",
                                           f"<= {self.hi:g}{u}" if self.hi is not None else "") if s)
            shown = arr[bad][0] if arr.ndim else arr
            raise ConfigError(f"{where} = {float(shown)!r}{u} is out of range: must be finite"
                              + (f" and {rng}" if rng else ""))
        return float(arr) if arr.ndim == 0 else arr


class Policy:
    """Base class: observation bookkeeping, batching, clipping and memory.  Subclasses implement
    :meth:`force` (the law, in N) and, if they keep memory, set ``memory_size``."""

    name: ClassVar[str] = ""
    observation: ClassVar[str] = "sensors"
    memory_size: ClassVar[int] = 0
    PARAMS: ClassVar[dict[str, Param]] = {}

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
        self.layout: ObservationLayout = make_layout(self.scene, self.observation, history=1)
        self.command_scale = float(self.scene.effects.command_scale)
        self._memory: np.ndarray | None = None

    # -- the law ---------------------------------------------------------------------------
    def force(self, values: np.ndarray, memory: np.ndarray | None) -> np.ndarray:
        """Shaker force demand (N, upwards) per env from the current frame in SI units
        (``values[N, frame_size]``, named by ``self.layout.names``); may update ``memory``.
        Default: the compiled law ``name`` (:func:`impact_env.control.laws.law_forces`) with
        :meth:`law_constants`, one set per env."""
        if self.name not in LW.KIND:
            raise NotImplementedError(f"{type(self).__name__} is not a compiled law: override force()")
        n = values.shape[0]
        K = LW.constants_rows(self.name, self.law_constants(), n)
        mem = memory if memory is not None and memory.shape[1] >= LW.MEMORY else np.zeros((n, LW.MEMORY))
        slots = LW.law_slots(self.name, self.layout.names)
        return LW.law_forces(LW.KIND[self.name], slots, K, np.ascontiguousarray(values, dtype=np.float64),
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
        return {}

    def compiled(self):
        """This law as a :class:`~impact_env.control.policy.CompiledPolicy` (a numba kernel with
        the same arithmetic; ``impact-env export`` writes it to a file)."""
        from impact_env.control.policy import CompiledPolicy

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
