"""Domain randomisation: ``[lo, hi]`` ranges on a scene's parameters, and the seed policy.

A scene's ``[randomize]`` section (:class:`RandomizeConfig`) gives, per parameter, a range
``[lo, hi]`` from which every episode draws its own value; an empty list (the default) keeps
the scene's own value.  The scene's fixed values are the *nominal* ones: ``simulate(scene)``
without a generator, ``impact-env drop`` without ``--seed`` and ``scene show`` use them.

Fields, what they set and how they are drawn (``uniform``: ``lo + u (hi - lo)``;
``log-uniform``: ``lo (hi/lo)^u``, for scale parameters that span a factor; ``samples``:
a whole number of control periods, uniform over ``round(lo rate) .. round(hi rate)``):

==========================  ==================================  ============
field                       sets                                draw
==========================  ==================================  ============
``m1``                      ``plant.m1`` (kg)                   uniform
``drop_height``             ``initial.drop_height`` (m)         uniform
``impact_speed``            ``initial.impact_speed`` (m/s)      uniform
``c``                       ``plant.c`` (N/m^1.5)               log-uniform
``restitution``             ``plant.restitution``               uniform
``suspension_stiffness``    ``plant.suspension_stiffness``      uniform
``suspension_damping``      ``plant.suspension_damping``        uniform
``noise_scale``             factor on every sensor's noise_std  log-uniform
``command_gain``            factor on ``effects.command_scale`` uniform
``shaker_lowpass_hz``       ``effects.shaker.lowpass_hz``       log-uniform
``shaker_coil_inductance``  ``effects.shaker.coil_inductance``  log-uniform
``sensor_delay_s``          ``effects.delay.sensor_s``          samples
``actuator_delay_s``        ``effects.delay.actuator_s``        samples
``m2``                      ``plant.m2`` (kg)                   uniform
``top_mass``                ``effects.sensors.force.top_mass``  uniform
==========================  ==================================  ============

Seed policy.  Each env owns a numpy ``Generator`` (the caller's, e.g. the Gymnasium env's
``np_random``).  At every reset it draws, *before anything else*, one ``rng.random()`` per
field that has a range, in the order of the table above (``rng.random(k)`` for the k ranged
fields), and maps each to its value as stated.  Sensor noise is drawn from the same generator
afterwards, as the episode runs (:mod:`impact_env.sim.simulator`).  A field with no range draws
nothing, so a scene without ranges (``ideal``, ``rig``) consumes no randomness at reset and its
noise sequence is the same as if this module did not exist; a range with ``lo == hi`` still
draws (and gives ``lo``).  The same generator state therefore gives the same episode, in the
Simulator and in ``simulate(scene, rng=...)`` (which draws the same values with
:meth:`impact_env.scene.Scene.sample`).

Validation (at scene construction): a range is ``[]`` or ``[lo, hi]`` with ``lo <= hi``, both
inside the field's own valid range (log-uniform fields need ``lo > 0``); a delay's ends must
be whole control periods; a range needs the thing it varies (``drop_height`` needs a scene given
by drop height, ``impact_speed`` one given by impact speed, ``noise_scale`` the ``sensors``
effect, the shaker fields the ``shaker`` effect with ``model = coil``, the delays their delay
effect); the scenes at both ends of every range must be valid scenes.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from impact_env.config import ConfigError, get_dotted, replace_dotted
from impact_env.effects.delay import delay_samples

UNIFORM, LOG, SAMPLES = "uniform", "log-uniform", "samples"


def _r(unit: str, dist: str, target: str, lo: float, hi: float | None, lo_open: bool, doc: str):
    """A range field: ``[]`` (fixed) or ``[lo, hi]``; ``lo``/``hi``/``lo_open`` bound the values."""
    return dataclasses.field(default=(), metadata={
        "unit": unit,
        "doc": f"[lo, hi] range, {dist}, for {target}; [] = fixed" + (f". {doc}" if doc else ""),
        "dist": dist, "target": target, "bounds": (lo, hi, lo_open)})


@dataclass(frozen=True)
class RandomizeConfig:
    """Per-episode ranges on scene parameters (see :mod:`impact_env.scene.randomize`)."""

    m1: tuple[float, ...] = _r("kg", UNIFORM, "plant.m1", 1e-9, 1e6, False, "")
    drop_height: tuple[float, ...] = _r("m", UNIFORM, "initial.drop_height", 0.0, 100.0, False, "")
    impact_speed: tuple[float, ...] = _r("m/s", UNIFORM, "initial.impact_speed", 0.0, 1000.0, False, "")
    c: tuple[float, ...] = _r("N/m^1.5", LOG, "plant.c", 1.0, 1e15, False, "")
    restitution: tuple[float, ...] = _r("", UNIFORM, "plant.restitution", 1e-3, 1.0, False, "")
    suspension_stiffness: tuple[float, ...] = _r("N/m", UNIFORM, "plant.suspension_stiffness", 0.0, 1e12,
                                                 False, "")
    suspension_damping: tuple[float, ...] = _r("N s/m", UNIFORM, "plant.suspension_damping", 0.0, 1e9,
                                               False, "")
    noise_scale: tuple[float, ...] = _r("", LOG, "every effects.sensors.*.noise_std", 0.0, 1e6, True,
                                        "Factor on the scene's noise levels")
    command_gain: tuple[float, ...] = _r("", UNIFORM, "effects.command_scale", 0.0, 100.0, True,
                                         "Factor on the scene's command scale (amplifier gain error)")
    shaker_lowpass_hz: tuple[float, ...] = _r("Hz", LOG, "effects.shaker.lowpass_hz", 1e-3, 1e7, False, "")
    shaker_coil_inductance: tuple[float, ...] = _r("H", LOG, "effects.shaker.coil_inductance", 1e-9, 10.0,
                                                   False, "")
    sensor_delay_s: tuple[float, ...] = _r("s", SAMPLES, "effects.delay.sensor_s", 0.0, 10.0, False,
                                           "Ends must be whole control periods")
    actuator_delay_s: tuple[float, ...] = _r("s", SAMPLES, "effects.delay.actuator_s", 0.0, 10.0, False,
                                             "Ends must be whole control periods")
    # (appended: a scene that ranges none of these draws exactly as before they existed)
    m2: tuple[float, ...] = _r("kg", UNIFORM, "plant.m2", 1e-9, 1e6, False, "")
    top_mass: tuple[float, ...] = _r("kg", UNIFORM, "effects.sensors.force.top_mass", 0.0, 1e6, False,
                                     "The force transducer's m2' as the hardware has it (the controller's "
                                     "eq 4.4 keeps the fixed value)")

    def __post_init__(self):
        for f in dataclasses.fields(self):
            r = getattr(self, f.name)
            name = f"randomize.{f.name}"
            if len(r) == 0:
                continue
            if len(r) != 2:
                raise ConfigError(f"{name} = {list(r)!r} must be [] (fixed) or [lo, hi]")
            lo, hi = r
            u = f" {f.metadata['unit']}" if f.metadata["unit"] else ""
            blo, bhi, open_ = f.metadata["bounds"]
            for which, v in (("lo", lo), ("hi", hi)):
                below = v <= blo if open_ else v < blo
                if not math.isfinite(v) or below or (bhi is not None and v > bhi):
                    allowed = (f"> {blo:g}" if open_ else f">= {blo:g}") + \
                        ("" if bhi is None else f" and <= {bhi:g}")
                    raise ConfigError(f"{name} = [{lo!r}, {hi!r}]{u}: {which} = {v!r} is out of range: "
                                      f"must be {allowed}{u} (the range of {f.metadata['target']})")
            if lo > hi:
                raise ConfigError(f"{name} = [{lo!r}, {hi!r}]{u}: lo must be <= hi")

    # -- queries ----------------------------------------------------------------------------
    def ranged(self) -> tuple[str, ...]:
        """Names of the fields that have a range, in draw order."""
        return tuple(f.name for f in dataclasses.fields(self) if len(getattr(self, f.name)))

    def any(self) -> bool:
        return bool(self.ranged())

    @staticmethod
    def dist(name: str) -> str:
        return _FIELDS[name].metadata["dist"]

    @staticmethod
    def target(name: str) -> str:
        """The dotted scene field that the range ``name`` varies."""
        return _FIELDS[name].metadata["target"]

    # -- drawing ----------------------------------------------------------------------------
    def values_at(self, u: np.ndarray | float, rate: float) -> dict[str, float]:
        """The values of the ranged fields at quantiles ``u`` (one per ranged field, or one
        for all) in [0, 1): the mapping the draws use; ``u = 0`` gives every ``lo``."""
        names = self.ranged()
        u = np.broadcast_to(np.asarray(u, dtype=np.float64), (len(names),))
        out = {}
        for name, ui in zip(names, u, strict=True):
            lo, hi = getattr(self, name)
            dist = self.dist(name)
            if dist == UNIFORM:
                v = lo + float(ui) * (hi - lo)
            elif dist == LOG:
                v = lo * (hi / lo) ** float(ui)
            else:
                klo, khi = int(round(lo * rate)), int(round(hi * rate))
                k = klo + min(int(float(ui) * (khi - klo + 1)), khi - klo)
                v = k / rate
            out[name] = min(max(v, lo), hi)
        return out

    def draw(self, rng: np.random.Generator, rate: float) -> dict[str, float]:
        """One episode's values (the seed policy: one ``rng.random()`` per ranged field, in field
        order; nothing is drawn when no field has a range).  ``rate``: control rate, Hz."""
        names = self.ranged()
        if not names:
            return {}
        return self.values_at(rng.random(len(names)), rate)

    def ends(self, pick: dict[str, str] | None = None, default: str = "lo") -> dict[str, float]:
        """Values at the ends of the ranges: ``pick[name]`` ("lo" or "hi"), else ``default``."""
        pick = pick or {}
        return {name: getattr(self, name)[0 if pick.get(name, default) == "lo" else 1]
                for name in self.ranged()}

    def stiffest(self) -> dict[str, float]:
        """The corner whose drop excites the stiffest contact oscillation (smallest m1, stiffest
        pad, fastest impact, least damping): the one the integrator's stability check needs."""
        return self.ends({"m1": "lo", "c": "hi", "drop_height": "hi", "impact_speed": "hi",
                                "restitution": "hi", "m2": "lo"})


_FIELDS = {f.name: f for f in dataclasses.fields(RandomizeConfig)}


def overrides_for(scene, values: dict[str, float]) -> dict[str, Any]:
    """Dotted overrides that give ``scene`` the drawn ``values`` (and clear its ranges, and with them
    the list of the known ones: every value is then the scene's own)."""
    ov: dict[str, Any] = {"randomize": {}}
    if scene.control.known_hardware:
        ov["control.known_hardware"] = ()
    fx = scene.effects
    for name, v in values.items():
        if name == "noise_scale":
            for ch in ("accelerometer", "force", "potentiometer", "body1_displacement"):
                ov[f"effects.sensors.{ch}.noise_std"] = getattr(fx.sensors, ch).noise_std * v
        elif name == "command_gain":
            ov["effects.command_scale"] = fx.command_scale * v
        else:
            ov[_FIELDS[name].metadata["target"]] = v
    return ov


#: the ranges of the drop itself; every other range is of the hardware
DROP_FIELDS = ("m1", "drop_height", "impact_speed")


def known_hardware(scene):
    """``scene`` with the hardware its controller is told: each field that
    ``control.known_hardware`` lists, a one-point range ``[v, v]``, folded into the field it sets
    (as :func:`overrides_for` sets it); every other range kept.  ``scene`` itself when it lists none.

    A calibrated scene file (``impact-env identify``) writes the identified values of the fields a
    controller also reads (the pad's c, m2, the transducer's top mass, the command scale) as such
    ranges, so that every policy keeps the observation scales and constants it was made for
    while the simulated hardware is the identified one, and lists them as known.  A law whose
    model is the plant (``mpc``, ``mpc-state``, the filter before a network) takes its model from
    this scene: on a calibrated rig, the rig's own numbers.  A one-point range that is not listed
    is a rig that departs from its description unbeknown to the controller (``impact-env
    robustness`` moves the hardware so)."""
    rz = scene.randomize
    known = {name: getattr(rz, name)[0] for name in scene.control.known_hardware}
    if not known:
        return scene
    ov = overrides_for(scene, known)
    ov["randomize"] = {name: list(getattr(rz, name)) for name in rz.ranged() if name not in known}
    return replace_dotted(scene, ov)


def untold_hardware(scene) -> tuple[str, ...]:
    """The hardware ranges of ``scene`` that its controller is not told: every ranged field but the
    drop's (:data:`DROP_FIELDS`) and those ``control.known_hardware`` lists, less the one-point
    ranges that sit on the value the scene itself gives their field (those depart from nothing).
    Empty on a nominal or a calibrated rig; on ``rig-randomized`` every hardware range."""
    rz = scene.randomize
    known = set(scene.control.known_hardware)
    out = []
    for name in rz.ranged():
        if name in DROP_FIELDS or name in known:
            continue
        lo, hi = getattr(rz, name)[0], getattr(rz, name)[-1]
        if lo == hi:
            fields = {k: v for k, v in overrides_for(scene, {name: lo}).items()
                      if k not in ("randomize", "control.known_hardware")}
            if all(get_dotted(scene, k) == v for k, v in fields.items()):
                continue
        out.append(name)
    return tuple(out)


def known_command_gain(scene) -> float:
    """The amplifier gain the controller is told (:func:`known_hardware`'s command scale over the
    scene's own): 1 unless ``control.known_hardware`` lists ``command_gain``."""
    return known_hardware(scene).effects.command_scale / scene.effects.command_scale


def check_scene_ranges(scene) -> None:
    """Cross-field checks of ``scene.randomize`` against the rest of the scene (ConfigError)."""

    rz = scene.randomize
    names = rz.ranged()
    if not names:
        return
    fx = scene.effects
    need = {"noise_scale": "sensors", "top_mass": "sensors", "shaker_lowpass_hz": "shaker",
            "shaker_coil_inductance": "shaker",
            "sensor_delay_s": "sensor_delay", "actuator_delay_s": "actuator_delay"}
    for name in names:
        if name in need and not fx.on(need[name]):
            raise ConfigError(f"randomize.{name} varies the {need[name]!r} effect, which is not in "
                              f"effects.active; add it or clear the range")
        if name.startswith("shaker_") and fx.shaker.model != "coil":
            raise ConfigError(f"randomize.{name} varies the coil model, but effects.shaker.model = "
                              f"{fx.shaker.model!r}")
    if "drop_height" in names and "impact_speed" in names:
        raise ConfigError("randomize.drop_height and randomize.impact_speed are both ranged: give a range on "
                          "one of them (clear the other with [])")
    if "drop_height" in names and scene.initial.drop_height is None:
        raise ConfigError("randomize.drop_height: the scene is given by initial.impact_speed; "
                          "range randomize.impact_speed instead (or set initial.drop_height)")
    if "impact_speed" in names and scene.initial.impact_speed is None:
        raise ConfigError("randomize.impact_speed: the scene is given by initial.drop_height; "
                          "range randomize.drop_height instead (or set initial.impact_speed)")
    rate = scene.control_rate
    for name in ("sensor_delay_s", "actuator_delay_s"):
        if name in names:
            for v in getattr(rz, name):
                delay_samples(v, rate, f"randomize.{name}")
    for end in ("lo", "hi"):
        try:
            scene.with_overrides(overrides_for(scene, rz.ends(default=end)))
        except ConfigError as exc:
            raise ConfigError(f"randomize: with every range at its {end} end the scene is invalid: {exc}") \
                from None
