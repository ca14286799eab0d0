"""``passive``: no shaker force at all (the uncontrolled drop, thesis fig 4.8 'control off').
Reads the sensor observation only to know the batch size."""

from __future__ import annotations

from typing import NamedTuple

from impact_env._jit import jit
from impact_env.control.laws.law import Law


class Reads(NamedTuple):
    """Nothing."""


class Constants(NamedTuple):
    """None."""


@jit(inline="always")
def force(slots, k, v, mem):
    return 0.0


def c_body(P: str, sl: dict[str, int]) -> str:
    return "\n    (void)v;\n    (void)mem;\n    f = 0.0;"


LAW = Law("passive", "sensors", "no force", Reads, Constants, lambda scene, gains: {}, c_body=c_body)
