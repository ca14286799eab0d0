"""The scene: every number a simulation needs, as typed, frozen, validated records.

A :class:`Scene` is declarative: plant parameters, initial condition, integrator, control rate
and episode settings.  It is loaded from presets (:mod:`impact_env.scene.presets`), TOML files or dicts,
and changed with dotted overrides (``scene.with_overrides({"plant.m1": 0.05})``).  Unknown keys
raise an error that names the key and its nearest valid neighbour; every value is range-checked
at construction, before anything is simulated.

Units are SI throughout and are named in each field's ``unit`` metadata, which
``impact-env scene show`` prints next to the value.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field
from typing import Any

from impact_env.config import (
    ConfigError,
    check_choice,
    check_range,
    doc_field,
    dumps_toml,
    replace_dotted,
    to_dict,
    whole_multiple,
    with_overrides,
)
from impact_env.scene.effects import EffectsConfig
from impact_env.scene.randomize import RandomizeConfig, check_scene_ranges, overrides_for

METHODS = ("euler", "symplectic-euler", "rk4", "dopri5", "split")
ADAPTIVE = ("dopri5", "split")  # no fixed grid: any control rate, dt unused
DEFAULT_DROP_HEIGHT = 0.05  # m (notes' start value: about 1 m/s at the touch)
MAX_STEPS_PER_PERIOD = 1e6  # integration steps in one control period (one env step)


_f = doc_field


@dataclass(frozen=True)
class PlantConfig:
    """The two bodies, the pad contact between them and body 2's suspension."""

    m1: float = _f(0.1, "kg", "falling body (thesis gives only m2 = 10 m1; notes' start value)")
    m2: float = _f(1.0, "kg", "body 2: shaker armature + pad + fixture (thesis sec 4.4: 10 m1)")
    c: float = _f(2.0e6, "N/m^1.5", "Hertz contact stiffness of the pad (thesis sec 4.1, eq 4.1-4.2)")
    restitution: float = _f(1.0, "", "delivered coefficient of restitution of the pad, 0.001 to 1; "
                            "1 = elastic Hertz")
    gravity: float = _f(9.81, "m/s^2", "gravity on body 1 (body 2's weight is carried by its suspension)")
    suspension_stiffness: float = _f(0.0, "N/m", "spring pulling body 2 back to x2 = 0")
    suspension_damping: float = _f(0.0, "N s/m", "damper on body 2's motion")

    def __post_init__(self):
        # bounds: a nanogram to a thousand tonnes, a pad from 1 N/m^1.5 to steel on steel
        # (about 1e11) with room, a pad deader than e = 0.001 (its damping solve needs zeta = 35)
        # is a plastic stop; beyond these the plant's numbers overflow before anything is learnt
        check_range("plant.m1", self.m1, "kg", 1e-9, 1e6)
        check_range("plant.m2", self.m2, "kg", 1e-9, 1e6)
        check_range("plant.c", self.c, "N/m^1.5", 1.0, 1e15)
        check_range("plant.restitution", self.restitution, "", 1e-3, 1.0)
        check_range("plant.gravity", self.gravity, "m/s^2", 0.0, 1e3)
        check_range("plant.suspension_stiffness", self.suspension_stiffness, "N/m", 0.0, 1e12)
        check_range("plant.suspension_damping", self.suspension_damping, "N s/m", 0.0, 1e9)

    @property
    def effective_mass(self) -> float:
        """m1 m2 / (m1 + m2), kg."""
        return self.m1 * self.m2 / (self.m1 + self.m2)

    @property
    def static_penetration(self) -> float:
        """Penetration with body 1 resting on body 2, ``(m1 g / c)^(2/3)`` (eq 2.11), m."""
        return (self.m1 * self.gravity / self.c) ** (2.0 / 3.0)


@dataclass(frozen=True)
class InitialConfig:
    """How body 1 arrives: from a drop height, or at a given impact speed (give one of the two).

    Setting one of them (``--set initial.impact_speed=2``) clears the other.  The free fall is
    solved in closed form: the simulation starts ``pre_contact_time`` before the first touch
    (or at the release, if the fall is shorter), with body 2 at rest at x2 = 0.
    """

    drop_height: float | None = _f(None, "m", "gap between the facing surfaces at release; 0.05 (notes' "
                                   "start value) when impact_speed is not given either")
    impact_speed: float | None = _f(None, "m/s", "speed of body 1 at the first touch, instead of drop_height")
    pre_contact_time: float = _f(1.0e-3, "s", "simulated time before the first touch")

    def __post_init__(self):
        if self.drop_height is None and self.impact_speed is None:
            # the default drop; set here rather than as the field's default so that a scene given
            # by impact_speed alone (as its TOML is written) does not also get a drop height
            object.__setattr__(self, "drop_height", DEFAULT_DROP_HEIGHT)
        if self.drop_height is not None and self.impact_speed is not None:
            raise ConfigError("initial: give exactly one of drop_height (m) or impact_speed (m/s), "
                              f"got both ({self.drop_height!r} m and {self.impact_speed!r} m/s)")
        if self.drop_height is not None:
            check_range("initial.drop_height", self.drop_height, "m", 0.0, 100.0)
        if self.impact_speed is not None:
            check_range("initial.impact_speed", self.impact_speed, "m/s", 0.0, 1000.0)
        check_range("initial.pre_contact_time", self.pre_contact_time, "s", 0.0, 10.0)

    _override_clears = {"drop_height": ("impact_speed",), "impact_speed": ("drop_height",)}


@dataclass(frozen=True)
class IntegratorConfig:
    """Time integration of the plant."""

    method: str = _f("split", "", "split (exact free flight, dopri5 in contact; default) | euler (thesis eq 3.8) | "
                     "symplectic-euler | rk4 | dopri5 (adaptive)")
    dt: float = _f(1.0e-6, "s", "step of the fixed-step methods")
    rtol: float = _f(1.0e-13, "", "relative tolerance of dopri5 (split: in contact); 1e-13 puts split's "
                     "per-impact errors below RK4's at 1 us (scripts/split_accuracy.py, docs/plant.md)")
    event_location: bool = _f(True, "", "locate contact onset/separation instead of stepping across them")
    min_steps_per_contact: float = _f(8.0, "", "fixed-step methods: refuse a dt that takes the shortest "
                                      "contact in fewer steps (8: RK4's restitution within about 1e-3, "
                                      "measured by scripts/steps_per_contact.py); 0 = no check")

    def __post_init__(self):
        check_choice("integrator.method", self.method, METHODS)
        check_range("integrator.dt", self.dt, "s", 1e-10, 1e-2)
        check_range("integrator.rtol", self.rtol, "", 1e-14, 1e-2)
        check_range("integrator.min_steps_per_contact", self.min_steps_per_contact, "", 0.0, 1e6)


@dataclass(frozen=True)
class ControlConfig:
    """Digital control: the law is sampled at ``rate`` and held (zero-order hold) in between."""

    rate: float | None = _f(None, "Hz", "control (and default recording) rate; none = every integration "
                            "step (fixed-step methods only); must divide the integration grid")
    known_hardware: tuple[str, ...] = field(default=(), metadata={
        "unit": "", "doc": "[randomize] fields whose one-point range is the rig's measured value (a "
                           "calibrated scene's identified fields, written by impact-env identify): the laws "
                           "whose model is the plant (mpc, mpc-state, the filter before a network) plan on "
                           "it; any other range is hardware the controller is not told"})

    def __post_init__(self):
        if self.rate is not None:
            check_range("control.rate", self.rate, "Hz", 1.0, 1e8)
        if self.known_hardware:  # (a scene is built at every randomised reset: nothing to check, no work)
            self._check_known_hardware()

    def _check_known_hardware(self) -> None:
        from impact_env.scene.randomize import DROP_FIELDS, RandomizeConfig

        hardware = [f for f in RandomizeConfig.__dataclass_fields__ if f not in DROP_FIELDS]
        for name in self.known_hardware:
            if name not in hardware:
                raise ConfigError(f"control.known_hardware lists {name!r}: not a hardware field of "
                                  f"[randomize]; choose among {', '.join(hardware)}")
        if len(set(self.known_hardware)) != len(self.known_hardware):
            raise ConfigError(f"control.known_hardware lists a field twice: {list(self.known_hardware)}")


@dataclass(frozen=True)
class EpisodeConfig:
    """Length of a run."""

    horizon: float = _f(0.3, "s", "simulated time after the start (thesis fig 4.8 spans about 0.3 s)")

    def __post_init__(self):
        check_range("episode.horizon", self.horizon, "s", 0.0, 1e4, lo_open=True)


@dataclass(frozen=True)
class Scene:
    """Everything one simulation needs.  Build with :func:`load_scene` or the presets."""

    name: str = "custom"
    description: str = ""
    plant: PlantConfig = field(default_factory=PlantConfig)
    initial: InitialConfig = field(default_factory=InitialConfig)
    integrator: IntegratorConfig = field(default_factory=IntegratorConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    episode: EpisodeConfig = field(default_factory=EpisodeConfig)
    effects: EffectsConfig = field(default_factory=EffectsConfig)
    randomize: RandomizeConfig = field(default_factory=RandomizeConfig)

    # a drop given by impact speed has no drop height to range over, and the other way round
    _override_clears_dotted = {"initial.impact_speed": ("randomize.drop_height",),
                               "initial.drop_height": ("randomize.impact_speed",)}

    def __post_init__(self):
        for name in self.control.known_hardware:  # a known value is one value
            r = getattr(self.randomize, name)
            if len(r) != 2 or r[0] != r[1]:
                raise ConfigError(f"control.known_hardware lists {name!r}, but randomize.{name} = {list(r)} "
                                  "is not one point [v, v]: a value the controller knows is one value")
        if self.initial.drop_height is not None and self.initial.drop_height > 0 and self.plant.gravity == 0:
            raise ConfigError("initial.drop_height needs plant.gravity > 0; with no gravity give "
                              "initial.impact_speed (m/s) instead")
        if self.control.rate is None and self.integrator.method == "dopri5":
            raise ConfigError("control.rate (Hz) must be given with integrator.method = dopri5, "
                              "which has no fixed step to sample at")
        if self.integrator.method == "split" and not self.integrator.event_location:
            raise ConfigError("integrator.event_location = false needs a fixed-step method "
                              "(euler, symplectic-euler, rk4): split locates every contact event by "
                              "construction")
        if self.integrator.method not in ADAPTIVE and self.control.rate is not None:
            ratio = self.control_period / self.integrator.dt
            if not whole_multiple(ratio):
                raise ConfigError(
                    f"control.rate = {self.control.rate:g} Hz does not divide the integration grid: "
                    f"the control period {self.control_period:g} s must be a whole multiple of "
                    f"integrator.dt = {self.integrator.dt:g} s")
            if ratio > MAX_STEPS_PER_PERIOD:
                raise ConfigError(
                    f"control.rate = {self.control.rate:g} Hz holds {ratio:.3g} steps of integrator.dt = "
                    f"{self.integrator.dt:g} s per control period, more than {MAX_STEPS_PER_PERIOD:g}: one "
                    "env step would run for minutes; raise control.rate or integrator.dt")
        self._check_effects_at_rate()
        check_scene_ranges(self)

    def _check_effects_at_rate(self) -> None:
        rate = 1.0 / self.control_period
        fx = self.effects
        if fx.on("filters"):
            fx.filters.check_rate(rate)
        fx.delay.samples(rate)  # (always: the Simulator sizes its delay lines from them)
        if fx.on("shaker"):
            fx.shaker.check_coupling(self.plant.m2, rate)

    # -- derived quantities -------------------------------------------------------------
    @property
    def control_period(self) -> float:
        """Control (sample-and-hold) period, s."""
        return self.integrator.dt if self.control.rate is None else 1.0 / self.control.rate

    @property
    def control_rate(self) -> float:
        return 1.0 / self.control_period

    @property
    def impact_speed(self) -> float:
        """Speed of body 1 at the first touch, m/s."""
        if self.initial.impact_speed is not None:
            return self.initial.impact_speed
        h = typing.cast(float, self.initial.drop_height)  # one of the two is set (InitialConfig)
        return math.sqrt(2.0 * self.plant.gravity * h)

    def with_overrides(self, overrides: dict[str, Any] | None = None, **kw) -> Scene:
        """A copy with dotted keys set, e.g. ``{"plant.m1": 0.05, "integrator.method": "dopri5"}``.

        String values are parsed as TOML values (``"1e-6"`` -> 1e-6).
        """
        items = dict(overrides or {})
        items.update(kw)
        return with_overrides(self, items) if items else self

    # -- randomisation (see impact_env.scene.randomize for the ranges and the seed policy) ----------
    @property
    def randomized(self) -> bool:
        """True when ``[randomize]`` gives any range."""
        return self.randomize.any()

    def draw(self, rng) -> dict[str, float]:
        """One episode's values of the ranged fields, drawn from the numpy Generator ``rng``
        (nothing is drawn when the scene has no ranges)."""
        return self.randomize.draw(rng, self.control_rate)

    def with_draws(self, values: dict[str, float]) -> Scene:
        """The fixed scene with the given values of ranged fields, and no ranges left: the
        scene :meth:`with_overrides` gives for them (tested equal), built by replacing only the
        drawn fields (:func:`~impact_env.config.replace_dotted`; every episode of a randomised
        scene's env draws one, so its cost is a reset's)."""
        return replace_dotted(self, overrides_for(self, values))

    def sample(self, rng) -> Scene:
        """A fixed scene drawn from this one's ranges with ``rng`` (itself if it has none)."""
        return self.with_draws(self.draw(rng)) if self.randomized else self

    def to_dict(self) -> dict:
        return to_dict(self)

    def to_toml(self) -> str:
        return dumps_toml(self.to_dict(), _field_comments(Scene))


def _field_comments(cls, prefix: str = "") -> dict[str, str]:
    out = {}
    for f in dataclasses.fields(cls):
        key = f"{prefix}.{f.name}" if prefix else f.name
        tp = f.default_factory if f.default_factory is not dataclasses.MISSING else None
        if tp is not None and dataclasses.is_dataclass(tp):
            out.update(_field_comments(tp, key))
        elif "doc" in f.metadata:
            unit = f.metadata.get("unit", "")
            out[key] = f"[{unit}] {f.metadata['doc']}" if unit else f.metadata["doc"]
    return out
