"""The effects, declared once: each effect module says what it is (:class:`Effect`: its name in
``effects.active``, its side of the DAQ card, the config section that holds its parameters, its
flag bit, whether it only computes readings, its parameter and state blocks and its step kernel),
and :data:`REGISTRY` lists them.  Every list that names effects is derived from it:
:data:`impact_env.scene.effects.EFFECTS`, the hardware stage's flags and packed blocks
(:mod:`impact_env.hardware.stage`), the front end's flags (:mod:`impact_env.control.front_end`)
and the oracle's physics-only scene (:data:`READINGS_ONLY`).

Adding an effect: its module (config, ``EFFECT = Effect(...)``, kernels), its entry below, its
call in the stage it belongs to (the signal path's order is written there, once) and its test.
"""

from __future__ import annotations

from impact_env.effects import delay, detector, filters, saturation, sensors, shaker
from impact_env.effects.effect import CONTROLLER, HARDWARE, Effect

__all__ = ["BY_NAME", "CONTROLLER", "HARDWARE", "NAMES", "READINGS_ONLY", "REGISTRY", "Effect", "flags",
           "side"]

#: every effect, in the order the scene's docs list them (the signal path's order is the stages')
REGISTRY: tuple[Effect, ...] = (delay.ACTUATOR_DELAY, shaker.EFFECT, saturation.EFFECT, sensors.EFFECT,
                                filters.EFFECT, delay.SENSOR_DELAY, detector.EFFECT)
BY_NAME = {e.name: e for e in REGISTRY}
NAMES = tuple(e.name for e in REGISTRY)
#: the effects that compute readings only (no force on the plant)
READINGS_ONLY = tuple(e.name for e in REGISTRY if e.readings_only)


def side(which: str) -> tuple[Effect, ...]:
    """The effects of one side, in registry order."""
    return tuple(e for e in REGISTRY if e.side == which)


def flags(which: str, active) -> int:
    """The flag word of side ``which`` for the effects named in ``active``."""
    word = 0
    for e in side(which):
        if e.name in active:
            word |= e.flag
    return word


def _check() -> None:
    for which in (HARDWARE, CONTROLLER):
        bits = [e.flag for e in side(which)]
        if len(set(bits)) != len(bits) or any(b <= 0 or b & (b - 1) for b in bits):
            raise ValueError(f"the {which} effects' flags must be distinct single bits: {bits}")
    if len(BY_NAME) != len(REGISTRY):
        raise ValueError(f"an effect is declared twice: {NAMES}")


_check()
