"""The effects, declared once: each effect module says what it is (:class:`Effect`: its name in
``effects.active``, its side of the DAQ card, the config section that holds its parameters and
that section's dataclass, whether it only computes readings, and for a hardware effect how its
packed blocks are built), and :data:`REGISTRY` lists them.  Every list that names effects is
derived from it: the scene's ``[effects]`` sections and :data:`impact_env.scene.effects.EFFECTS`,
the flag bits of both sides (:func:`flag`), the hardware stage's packed blocks and their sizes
(:mod:`impact_env.hardware.stage`, :mod:`impact_env.hardware.batch`), the oracle's physics-only
scene (:data:`READINGS_ONLY`) and the docs' table (:func:`markdown_table`, docs/scenes.md).

Adding an effect: its module (config, kernels, ``EFFECT = Effect(...)``), its line below (with a
flag bit its side does not use yet), its test; a new stage of the signal path also gets its call
where the path is written (the hardware stage's ``hardware_tick`` or the front end's
``condition``) and its name in the texts that spell the path out (``tests/test_signal_path.py``).
"""

from __future__ import annotations

from impact_env.effects import delay, detector, filters, saturation, sensors, shaker
from impact_env.effects.effect import CONTROLLER, HARDWARE, Effect

__all__ = ["BY_NAME", "CONTROLLER", "HARDWARE", "NAMES", "READINGS_ONLY", "REGISTRY", "SECTIONS", "Effect",
           "flag", "flags", "markdown_table", "option_flag", "side"]

#: every effect, in the order the scene's docs list them (the signal path's order is the stages'),
#: each with its bit in its side's flag word and its options' bits: fixed numbers, never moved or
#: reused (a compiled kernel, an exported C target and a rig log read them), checked unique per side
_LINES: tuple[tuple[Effect, int, dict[str, int]], ...] = (
    # effect                 bit      its options' bits
    (delay.ACTUATOR_DELAY,   1 << 0,  {}),
    (shaker.EFFECT,          1 << 1,  {"back_emf": 1 << 5}),
    (saturation.EFFECT,      1 << 2,  {}),
    (sensors.EFFECT,         1 << 3,  {}),
    (filters.EFFECT,         1 << 0,  {}),
    (delay.SENSOR_DELAY,     1 << 4,  {}),
    (detector.EFFECT,        1 << 1,  {}),
)
REGISTRY: tuple[Effect, ...] = tuple(e for e, _, _ in _LINES)
_FLAG = {e.name: bit for e, bit, _ in _LINES}
_OPTION_FLAG = {(e.name, option): bit for e, _, options in _LINES for option, bit in options.items()}
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
    """The bit of effect ``name`` in its side's flag word (its registry line)."""
    return _FLAG[name]


def option_flag(name: str, option: str) -> int:
    """The bit of effect ``name``'s option ``option`` (one of its ``options``) in its side's flag
    word (its registry line)."""
    return _OPTION_FLAG[(name, option)]


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
    for which in (HARDWARE, CONTROLLER):
        bits = [flag(e.name) for e in side(which)]
        bits += [option_flag(e.name, o) for e in side(which) for o in e.options]
        if any(b <= 0 or b & (b - 1) for b in bits) or len(set(bits)) != len(bits):
            raise ValueError(f"the {which} side's flag bits must be distinct powers of two, got {bits}")
    for e, _, options in _LINES:
        if set(options) != set(e.options):
            raise ValueError(f"effect {e.name!r}: its registry line gives bits to options {sorted(options)}, "
                             f"it declares {list(e.options)}")
    for e in REGISTRY:
        if SECTIONS[e.section] is not e.config:
            raise ValueError(f"effects {e.name!r} and another share section {e.section!r} with two configs")


_check()
