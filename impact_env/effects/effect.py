"""What an effect declares about itself (:class:`Effect`); the list of them is
:mod:`impact_env.effects.registry`."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

HARDWARE = "hardware"  # between the drive command and the raw readings (impact_env.hardware)
CONTROLLER = "controller"  # between the raw readings and the policy (impact_env.control)


@dataclass(frozen=True)
class Effect:
    """What an effect is (see the module doc)."""

    name: str  # in the scene's effects.active
    side: str  # HARDWARE or CONTROLLER
    config: str  # the [effects] section holding its parameters (both delays share "delay")
    flag: int  # its bit in its side's flag word (hardware.stage, control.front_end)
    readings_only: bool  # it computes readings only: the bodies move the same without it
    params: bool  # it has a per-env parameter block in the hardware stage's packed rows
    state: bool  # it has a per-env state block (hardware) or state arrays (controller)
    step: Callable  # its kernel (on one env's packed block, or on the front end's arrays)

    def __post_init__(self):
        if self.side not in (HARDWARE, CONTROLLER):
            raise ValueError(f"effect {self.name!r}: side {self.side!r} is not {HARDWARE!r} or "
                             f"{CONTROLLER!r}")
