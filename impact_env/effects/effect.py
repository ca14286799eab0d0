"""What an effect declares about itself (:class:`Effect`); the list of them is
:mod:`impact_env.effects.registry`, from which every other list of effects is derived."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

HARDWARE = "hardware"  # between the drive command and the raw readings (impact_env.hardware)
CONTROLLER = "controller"  # between the raw readings and the policy (impact_env.control)

#: a hardware effect's packer: (its config section, control rate Hz, whether the scene switches
#: it on) -> (its parameter block float64[:], the size of its state block)
Packer = Callable[[Any, float, bool], tuple[np.ndarray, int]]


@dataclass(frozen=True)
class Effect:
    """What an effect is.  Its flag bit in its side's flag word is given in its registry line
    (:data:`impact_env.effects.registry.REGISTRY`)."""

    name: str  # in the scene's effects.active
    side: str  # HARDWARE or CONTROLLER
    section: str  # the scene's [effects] section that holds its parameters (both delays share "delay")
    config: type  # that section's frozen dataclass (the scene's EffectsConfig gets one field per section)
    doc: str  # one line for the docs' table of effects
    readings_only: bool  # it computes readings only: the bodies move the same without it
    pack: Packer | None = None  # HARDWARE: its blocks in the hardware stage's packed rows
    options: tuple[str, ...] = ()  # bool fields of its section that switch a branch of its kernel:
    #                                each gets a bit of its side's flag word in its registry line

    def __post_init__(self):
        if self.side not in (HARDWARE, CONTROLLER):
            raise ValueError(f"effect {self.name!r}: side {self.side!r} is not {HARDWARE!r} or "
                             f"{CONTROLLER!r}")
        if (self.pack is not None) != (self.side == HARDWARE):
            raise ValueError(f"effect {self.name!r}: a hardware effect, and only one, packs its blocks")
