"""What a classic law declares about itself (:class:`Law`), and the gains it takes (:class:`Param`).

A law module of :mod:`impact_env.control.laws` holds everything about one law: its docs, its
gains, the scene's constants it needs, the observation entries it reads, its compiled kernel and
its C text; :mod:`impact_env.control.laws` lists the modules, and the policies by name, the
baselines' classes, the kind codes and the docs' table follow from that list.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from impact_env.config import ConfigError


@dataclass(frozen=True)
class Param:
    """One gain or setting of a law: default, unit, meaning, allowed range or choices.
    ``default=None`` with ``from_scene``: the scene gives the default (``from_scene(scene)``)."""

    default: Any
    unit: str
    doc: str
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] = ()
    from_scene: Callable[[Any], float] | None = None

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


@dataclass(frozen=True, eq=False)  # (compared and hashed by identity: one object per law)
class Law:
    """A classic law, as its module declares it."""

    name: str  # its policy name (``impact-env compare --policies NAME:k=v``)
    observation: str  # the observation it reads: "sensors" or "privileged"
    doc: str  # one line for the docs' table of laws
    reads: Any  # NamedTuple class of the observation entries it reads, in slot order; a field with a
    #              default (-1) may be absent from the observation
    constants: Any  # NamedTuple class naming its constants vector, in order
    constants_of: Callable[[Any, dict], dict]  # (scene, gains) -> {constant: value}
    memory: int = 0  # floats of memory per env (zeroed at an episode start)
    params: dict[str, Param] = field(default_factory=dict)  # its gains and settings
    c_body: Callable[[str, dict[str, int]], str] | None = None  # (constant prefix, slot of each read) -> the
    #   C statements that set ``f`` (N) from ``v`` (the frame, SI) and ``mem``; None: not exportable.
    #   The constants are there one by one (``{prefix}_{NAME}``) and as the array ``{prefix}_CONSTANTS``
    c_prelude: Callable[[], str] | None = None  # file-scope C text the body calls (its static functions)
    c_double_only: str = ""  # why its C has no float32 build (the export refuses one); "": it has one

    def required(self) -> tuple[str, ...]:
        """The entries the observation must hold."""
        defaults = self.reads._field_defaults
        return tuple(f for f in self.reads._fields if f not in defaults)
