"""The effects, declared once: each effect module says what it is (:class:`Effect`: its name in
``effects.active``, its side of the DAQ card, the config section that holds its parameters and
that section's dataclass, whether it only computes readings, and for a hardware effect how its
packed blocks are built), and :data:`REGISTRY` lists them.  Every list that names effects is
derived from it: the scene's ``[effects]`` sections and :data:`impact_env.scene.effects.EFFECTS`,
the flag bits of both sides (:func:`flag`), the hardware stage's packed blocks and their sizes
(:mod:`impact_env.hardware.stage`, :mod:`impact_env.hardware.batch`), the oracle's physics-only
scene (:data:`READINGS_ONLY`) and the docs' table (:func:`markdown_table`, docs/scenes.md).

Adding an effect: its module (config, kernels, ``EFFECT = Effect(...)``), its line below, its
test; a new stage of the signal path also gets its call where the path is written (the
hardware stage's ``hardware_tick`` or the front end's ``condition``).
"""

from __future__ import annotations

from impact_env.effects import delay, detector, filters, saturation, sensors, shaker
from impact_env.effects.effect import CONTROLLER, HARDWARE, Effect

__all__ = ["BY_NAME", "CONTROLLER", "HARDWARE", "NAMES", "READINGS_ONLY", "REGISTRY", "SECTIONS", "Effect",
           "flag", "flags", "markdown_table", "option_flag", "side"]

#: every effect, in the order the scene's docs list them (the signal path's order is the stages');
#: an effect's place among its side's effects is its flag bit
REGISTRY: tuple[Effect, ...] = (
    delay.ACTUATOR_DELAY,
    shaker.EFFECT,
    saturation.EFFECT,
    sensors.EFFECT,
    filters.EFFECT,
    delay.SENSOR_DELAY,
    detector.EFFECT,
)
BY_NAME = {e.name: e for e in REGISTRY}
NAMES = tuple(e.name for e in REGISTRY)
#: the effects that compute readings only (no force on the plant)
READINGS_ONLY = tuple(e.name for e in REGISTRY if e.readings_only)
#: the scene's [effects] sections: name -> dataclass, in the order the effects' parameters are
#: documented (a section shared by two effects sits at the later one, with its sibling)
SECTIONS: dict[str, type] = {}
for _e in reversed(REGISTRY):
    SECTIONS.setdefault(_e.section, _e.config)
SECTIONS = dict(reversed(SECTIONS.items()))


def side(which: str) -> tuple[Effect, ...]:
    """The effects of one side, in registry order."""
    return tuple(e for e in REGISTRY if e.side == which)


def flag(name: str) -> int:
    """The bit of effect ``name`` in its side's flag word."""
    e = BY_NAME[name]
    return 1 << side(e.side).index(e)


def option_flag(name: str, option: str) -> int:
    """The bit of effect ``name``'s option ``option`` (one of its ``options``) in its side's flag
    word: after every effect's bit of that side."""
    e = BY_NAME[name]
    opts = [(x.name, o) for x in side(e.side) for o in x.options]
    return 1 << (len(side(e.side)) + opts.index((name, option)))


def flags(which: str, fx) -> int:
    """The flag word of side ``which`` for the effects config ``fx`` (the scene's
    ``EffectsConfig``): the bits of the effects it names in ``active``, and of their options
    that its sections switch on."""
    word = 0
    for e in side(which):
        if e.name in fx.active:
            word |= flag(e.name)
            section = getattr(fx, e.section)
            for o in e.options:
                if getattr(section, o):
                    word |= option_flag(e.name, o)
    return word


def markdown_table() -> str:
    """The docs' table of effects (docs/scenes.md, between its ``effects-table`` markers)."""
    rows = ["| effect | side | section | flag | readings only | what |",
            "| --- | --- | --- | --- | --- | --- |"]
    for e in REGISTRY:
        bit = str(flag(e.name)) + "".join(f", {o}: {option_flag(e.name, o)}" for o in e.options)
        rows.append(f"| `{e.name}` | {e.side} | `[effects.{e.section}]` | {bit} | "
                    f"{'yes' if e.readings_only else 'no'} | {e.doc} |")
    return "\n".join(rows)


def _check() -> None:
    if len(BY_NAME) != len(REGISTRY):
        raise ValueError(f"an effect is declared twice: {NAMES}")
    for e in REGISTRY:
        if SECTIONS[e.section] is not e.config:
            raise ValueError(f"effects {e.name!r} and another share section {e.section!r} with two configs")


_check()
