"""The scene's ``[effects]`` section: which effects run, and each one's parameters."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from impact_env.config import ConfigError, check_choice, check_range
from impact_env.effects import registry

EFFECTS = registry.NAMES  # every effect's name (impact_env.effects.registry)


def _with_sections(cls):
    """Give ``cls`` one field per section of the effects registry (its config dataclass, at its
    defaults), after the fields it declares itself."""
    for name, config in registry.SECTIONS.items():
        cls.__annotations__[name] = config
        setattr(cls, name, field(default_factory=config))
    return cls


@dataclass(frozen=True)
@_with_sections
class EffectsConfig:
    """``active`` names the effects the scene uses (in any order; they always run in the
    signal path's order: :mod:`impact_env.hardware.stage`, then :mod:`impact_env.control.front_end`).
    The other sections hold parameters, one per section of :data:`impact_env.effects.registry.SECTIONS`
    (``shaker``, ``saturation``, ``sensors``, ``filters``, ``delay``, ``detector``); those of an
    effect that is not active are validated but not used."""

    active: tuple[str, ...] = field(default=(), metadata={
        "unit": "", "doc": "effects that run: " + ", ".join(EFFECTS)})
    command_scale: float = field(default=200.0, metadata={
        "unit": "N", "doc": "force demanded by action +1 (thesis sec 4.3: about 200 N pulses)"})
    if TYPE_CHECKING:  # the sections, added from the registry (_with_sections)
        def __getattr__(self, name: str) -> Any: ...

    def __post_init__(self):
        for i, name in enumerate(self.active):
            check_choice(f"effects.active[{i}]", name, EFFECTS)
        if len(set(self.active)) != len(self.active):
            raise ConfigError(f"effects.active lists an effect twice: {list(self.active)}")
        check_range("effects.command_scale", self.command_scale, "N", 0.0, 1e7, lo_open=True)
        if "detector" in self.active and "sensors" not in self.active:
            raise ConfigError("effects.active: 'detector' works on sensor readings; add 'sensors'")

    def on(self, name: str) -> bool:
        return name in self.active
