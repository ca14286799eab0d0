"""What a policy sees: the observation vector's layout, units and scaling.

A frame holds, in this order:

1. ``sensors`` part (unless ``observation="privileged"``): the scene's enabled sensor channels,
   in sensor-vector order (``accelerometer`` m/s^2, ``force`` N, ``potentiometer`` m,
   ``body1_displacement`` m), as the controller would read them: after the scene's sensor,
   filter and delay effects (true values where the scene has no ``sensors`` effect), followed
   by ``contact_detected`` (0 or 1) when the scene has the ``detector`` effect.
2. ``privileged`` part (with ``observation="privileged"`` or ``"both"``): the true state
   ``x1`` (m), ``v1`` (m/s), ``x2`` (m), ``v2`` (m/s) in the thesis's frame (x down, facing
   surfaces as references; penetration is ``x1 - x2``).

Every entry is divided by a reference scale so that it is of order one for the scene's nominal
drop: lengths by the Hertz peak penetration ``d_ref = (5 m v0^2 / 4c)^(2/5)``, speeds by the
impact speed ``v0``, forces by ``F_ref = c d_ref^1.5`` (the elastic peak contact force),
accelerations by ``F_ref / m2``.  ``v0`` is the scene's nominal impact speed (at least 0.1 m/s,
so that a grazing scene does not blow the scales up).  Scales are fixed per scene, also for
randomised scenes, so that one policy reads every episode in the same units.

With ``history = k > 1`` the observation is ``[frame_t, frame_t-1, ..., frame_t-k+1,
action_t-1, ..., action_t-k]`` (frames and actions before the episode start are zeros), which
lets a memoryless policy see through delays.

Every entry is clipped to +-``OBS_LIMIT`` (1e4 reference units), so that observations stay in
the (finite) observation space whatever happens.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from impact_env.config import ConfigError, check_choice
from impact_env.effects.sensors import CHANNELS, UNITS
from impact_env.plant import hertz
from impact_env.scene import Scene

OBSERVATIONS = ("sensors", "privileged", "both")
PRIVILEGED = ("x1", "v1", "x2", "v2")
PRIVILEGED_UNITS = ("m", "m/s", "m", "m/s")
MIN_REF_SPEED = 0.1  # m/s
OBS_LIMIT = 1.0e4  # |obs| bound: entries are clipped to it (that large means a runaway or a huge drop)


@dataclass(frozen=True)
class References:
    """Reference scales of a scene (SI): length m, speed m/s, force N, acceleration m/s^2."""

    length: float
    speed: float
    force: float
    accel: float

    @classmethod
    def of(cls, scene: Scene) -> References:
        p = scene.plant
        v0 = max(scene.impact_speed, MIN_REF_SPEED)
        d = hertz.max_penetration(p.effective_mass, p.c, v0)
        f = hertz.peak_force(p.effective_mass, p.c, v0)
        return cls(length=d, speed=v0, force=f, accel=f / p.m2)


@dataclass(frozen=True)
class ObservationLayout:
    """Names, units and scales of one observation vector (``obs = value / scale``)."""

    names: tuple[str, ...]
    units: tuple[str, ...]
    scales: np.ndarray  # float64[frame_size]
    sensor_channels: np.ndarray  # int64: indices into the sensor vector, in frame order
    detector: bool
    privileged: bool
    history: int
    refs: References

    @property
    def frame_size(self) -> int:
        return len(self.names)

    @property
    def size(self) -> int:
        return self.frame_size * self.history + (self.history if self.history > 1 else 0)

    def index(self, name: str) -> int:
        """Position of ``name`` in the current frame (the first ``frame_size`` entries)."""
        check_choice("observation name", name, self.names)
        return self.names.index(name)

    def describe(self) -> list[tuple[int, str, str, float]]:
        """(index, name, unit, scale) for every entry of the current frame."""
        rows = zip(self.names, self.units, self.scales, strict=True)
        return [(i, n, u, float(s)) for i, (n, u, s) in enumerate(rows)]


def make_layout(scene: Scene, observation: str = "sensors", history: int = 1) -> ObservationLayout:
    check_choice("observation", observation, OBSERVATIONS)
    if isinstance(history, bool) or not isinstance(history, (int, np.integer)) or not 1 <= history <= 64:
        raise ConfigError(f"history = {history!r} is out of range: an integer number of control steps "
                          "in [1, 64]")
    refs = References.of(scene)
    unit_scale = {"m/s^2": refs.accel, "N": refs.force, "m": refs.length, "m/s": refs.speed, "": 1.0}
    names: list[str] = []
    units: list[str] = []
    channels: list[int] = []
    detector = False
    if observation in ("sensors", "both"):
        mask = scene.effects.sensors.enabled_mask
        for i, name in enumerate(CHANNELS):
            if mask[i]:
                channels.append(i)
                names.append(name)
                units.append(UNITS[i])
        if scene.effects.on("detector"):
            detector = True
            names.append("contact_detected")
            units.append("")
        if not names:
            raise ConfigError("observation = 'sensors' but the scene enables no sensor channel; "
                              "enable one in effects.sensors or use observation = 'privileged'")
    priv = observation in ("privileged", "both")
    if priv:
        names += PRIVILEGED
        units += PRIVILEGED_UNITS
    scales = np.array([unit_scale[u] for u in units], dtype=np.float64)
    return ObservationLayout(tuple(names), tuple(units), scales, np.array(channels, dtype=np.int64),
                             detector, priv, int(history), refs)
