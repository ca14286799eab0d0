"""The fit's model: candidate scenes replayed through the project's own hardware stage.

Fitted parameters (:data:`PARAMS`) are kept as natural logarithms of their ratio to the base
scene's value, ``x_j = ln(theta_j / theta_j,base)``, so every step of the fit is relative and
positive quantities stay positive.  Body 2's mass enters the shaker-only episodes only through
ratios (body 1 is held: ``m2 a2 = -f - k2 x2 - c2 v2`` with ``f`` proportional to the command
scale), so the parameters are the ratios and m2 itself, which the drops see (the pad's contact
force against body 2's acceleration): ``drive/m2``, ``k2/m2``, ``c2/m2`` and ``m2``; the scene's
fields follow (:meth:`Model.fields`).  Delays are whole ticks: the actuator delay shifts the
commands, the sensor delay the readings, exactly as the delay effects' lines do (zeros until
they fill), so one replay serves every sensor delay.

A candidate scene is the base with the fitted fields set, the sensors' offsets from the quiet
episodes, no noise and an ideal converter (the fit compares with the mean; the ADC's quantum,
15 mN on the force channel, is far below the noise and is in the residuals' weights).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from impact_env.config import get_dotted, with_overrides
from impact_env.effects.sensors import CHANNELS
from impact_env.hardware.batch import Hardware
from impact_env.hardware.replay import replay
from impact_env.ident.experiments import Experiment
from impact_env.plant.restitution import ZetaTable, zeta_table
from impact_env.scene import Scene

BOUND = math.log(4.0)  # the fit looks within a factor 4 of the base value either way (log-ratio)
SENSOR_CHANNELS = CHANNELS[:3]  # accelerometer, force, potentiometer (the rig's; no body-1 sensor)


@dataclass(frozen=True)
class Param:
    """One fitted quantity: ``name``, its unit, what it is, the episode kinds that inform it."""

    name: str
    unit: str
    doc: str
    stage: str  # "shaker" or "drop"


PARAMS = (
    Param("drive_per_m2", "N/kg", "effects.command_scale / plant.m2: body 2's acceleration per unit "
          "command, mid-band", "shaker"),
    Param("k2_per_m2", "1/s^2", "plant.suspension_stiffness / plant.m2 (the suspension's omega^2)", "shaker"),
    Param("c2_per_m2", "1/s", "plant.suspension_damping / plant.m2", "shaker"),
    Param("highpass_hz", "Hz", "effects.shaker.highpass_hz", "shaker"),
    Param("lowpass_hz", "Hz", "effects.shaker.lowpass_hz", "shaker"),
    Param("coil_inductance", "H", "effects.shaker.coil_inductance (with coil_resistance fixed: only R/L, "
          "the coil pole, enters the force)", "shaker"),
    Param("top_mass", "kg", "effects.sensors.force.top_mass (m2' of eq 4.4)", "shaker"),
    Param("m2", "kg", "plant.m2", "drop"),
    Param("m1", "kg", "plant.m1 (the identification body)", "drop"),
    Param("c", "N/m^1.5", "plant.c", "drop"),
    Param("restitution", "", "plant.restitution", "drop"),
)
NAMES = tuple(p.name for p in PARAMS)
INDEX = {p.name: j for j, p in enumerate(PARAMS)}
STAGE = {s: np.array([j for j, p in enumerate(PARAMS) if p.stage == s]) for s in ("shaker", "drop")}

# the scene's fields and the parameters whose logs add up to each field's log-ratio
FIELDS = {
    "effects.command_scale": ("drive_per_m2", "m2"),
    "plant.suspension_stiffness": ("k2_per_m2", "m2"),
    "plant.suspension_damping": ("c2_per_m2", "m2"),
    "effects.shaker.highpass_hz": ("highpass_hz",),
    "effects.shaker.lowpass_hz": ("lowpass_hz",),
    "effects.shaker.coil_inductance": ("coil_inductance",),
    "effects.sensors.force.top_mass": ("top_mass",),
    "plant.m2": ("m2",),
    "plant.m1": ("m1",),
    "plant.c": ("c",),
    "plant.restitution": ("restitution",),
}
FIELD_MAP = np.array([[1.0 if name in FIELDS[f] else 0.0 for name in NAMES] for f in FIELDS])


def get_field(scene: Scene, dotted: str) -> float:
    return float(get_dotted(scene, dotted))


def model_base(scene: Scene, offsets: dict[str, float] | None = None) -> Scene:
    """The base of every candidate: ``scene`` with no ranges (its nominal drop), no delay
    effects (the model shifts by whole ticks instead), noise-free, ideal converters, and the
    sensors' offsets (per channel, the channel's unit)."""
    ov: dict = {"randomize": {}}
    active = [a for a in scene.effects.active if a not in ("sensor_delay", "actuator_delay")]
    ov["effects.active"] = active
    for ch in CHANNELS:
        ov[f"effects.sensors.{ch}.noise_std"] = 0.0
        ov[f"effects.sensors.{ch}.adc_bits"] = 0
    for ch, v in (offsets or {}).items():
        ov[f"effects.sensors.{ch}.offset"] = float(v)
    return _overrides(scene, ov)


def _overrides(scene: Scene, ov: dict) -> Scene:
    return with_overrides(scene, ov, parse=False)


class Model:
    """Candidate scenes (:data:`PARAMS` at ``x``, log-ratios to ``base``) replayed on experiments."""

    def __init__(self, base: Scene, offsets: dict[str, float] | None = None):
        self.base = model_base(base, offsets)
        self.theta0 = np.array([self._base_value(p.name) for p in PARAMS])
        self.field0 = np.array([get_field(self.base, f) for f in FIELDS])
        if np.any(self.field0 <= 0):
            bad = [f for f, v in zip(FIELDS, self.field0, strict=True) if v <= 0]
            raise ValueError(f"the base scene's {', '.join(bad)} must be > 0 to be fitted as ratios")
        self._hw: dict[tuple[int, int], Hardware] = {}
        # The pad's damping of a candidate restitution, from a table over the fit's range (base / 4,
        # less 1 % for rounding, to 1) instead of a new exact solve (a root search over ODE
        # solves, 0.3 s) for each restitution the fit tries: its damping delivers the restitution
        # to within 1e-11 (tests/test_identify.py), far below what the logs determine of it
        e0 = self.base.plant.restitution
        self.zeta: ZetaTable | None = zeta_table(0.99 * e0 * math.exp(-BOUND), 1.0) if e0 < 1.0 else None

    def _base_value(self, name: str) -> float:
        b, p = self.base, self.base.plant
        return {"drive_per_m2": b.effects.command_scale / p.m2, "k2_per_m2": p.suspension_stiffness / p.m2,
                "c2_per_m2": p.suspension_damping / p.m2, "highpass_hz": b.effects.shaker.highpass_hz,
                "lowpass_hz": b.effects.shaker.lowpass_hz,
                "coil_inductance": b.effects.shaker.coil_inductance,
                "top_mass": b.effects.sensors.force.top_mass, "m2": p.m2, "m1": p.m1, "c": p.c,
                "restitution": p.restitution}[name]

    def values(self, x: np.ndarray) -> np.ndarray:
        """The parameters' values at ``x`` (their units in :data:`PARAMS`)."""
        return self.theta0 * np.exp(x)

    def fields(self, x: np.ndarray) -> dict[str, float]:
        """The scene's fields at ``x`` (dotted name -> value, SI)."""
        v = self.field0 * np.exp(FIELD_MAP @ x)
        return {f: float(val) for f, val in zip(FIELDS, v, strict=True)}

    def scene(self, x: np.ndarray) -> Scene:
        return _overrides(self.base, self.fields(x))

    # -- simulation -------------------------------------------------------------------------------
    def _hardware(self, K: int, e: Experiment) -> Hardware:
        key = (K, id(e))
        hw = self._hw.get(key)
        if hw is None:
            hw = self._hw[key] = Hardware(self.base, K)
        return hw

    def simulate(self, e: Experiment, xs: np.ndarray, k_act: int = 0, k_sens: int = 0) -> np.ndarray:
        """Readings float64[K, n, 4] of experiment ``e`` for the candidates ``xs`` (float64[K, P]),
        with ``k_act`` ticks of actuator and ``k_sens`` of sensor delay (NaN rows once a
        candidate's plant failed)."""
        xs = np.atleast_2d(xs)
        K = xs.shape[0]
        hw = self._hardware(K, e)
        for i in range(K):
            hw.set_scene(i, self.scene(xs[i]), zeta_of=self.zeta)
        u = shift(e.commands, k_act)
        R, _failed = replay(hw, u, held=e.kind in ("shaker", "quiet"))
        if k_sens:
            R = shift_readings(R, k_sens)
        return R


def shift(u: np.ndarray, k: int) -> np.ndarray:
    """``u`` delayed by ``k`` ticks, zeros first (the actuator delay line)."""
    if k <= 0:
        return u
    out = np.zeros_like(u)
    out[k:] = u[:-k]
    return out


def shift_readings(R: np.ndarray, k: int) -> np.ndarray:
    """Readings R[..., n, 4] through a sensor delay line of ``k`` ticks: row m >= k + 1 reads row
    m - k, rows 1 .. k read zeros (the line's fill), row 0 (the release) is not delayed."""
    out = np.zeros_like(R)
    out[..., 0, :] = R[..., 0, :]
    n = R.shape[-2]
    if k + 1 < n:
        out[..., k + 1:, :] = R[..., 1:n - k, :]
    return out
