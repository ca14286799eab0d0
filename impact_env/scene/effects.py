"""The scene's ``[effects]`` section: which effects run, and each one's parameters."""

from __future__ import annotations

from dataclasses import dataclass, field

from impact_env.config import ConfigError, check_choice, check_range
from impact_env.effects import registry
from impact_env.effects.delay import DelayConfig
from impact_env.effects.detector import DetectorConfig
from impact_env.effects.filters import FiltersConfig
from impact_env.effects.saturation import SaturationConfig
from impact_env.effects.sensors import SensorsConfig
from impact_env.effects.shaker import ShakerConfig

EFFECTS = registry.NAMES  # every effect's name (impact_env.effects.registry)


@dataclass(frozen=True)
class EffectsConfig:
    """``active`` names the effects the scene uses (in any order; they always run in the
    signal path's order: :mod:`impact_env.hardware.stage`, then :mod:`impact_env.control.front_end`).
    The other sections hold parameters; those of an effect that is not active are validated but
    not used."""

    active: tuple[str, ...] = field(default=(), metadata={
        "unit": "", "doc": "effects that run: " + ", ".join(EFFECTS)})
    command_scale: float = field(default=200.0, metadata={
        "unit": "N", "doc": "force demanded by action +1 (thesis sec 4.3: about 200 N pulses)"})
    shaker: ShakerConfig = field(default_factory=ShakerConfig)
    saturation: SaturationConfig = field(default_factory=SaturationConfig)
    sensors: SensorsConfig = field(default_factory=SensorsConfig)
    filters: FiltersConfig = field(default_factory=FiltersConfig)
    delay: DelayConfig = field(default_factory=DelayConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)

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
