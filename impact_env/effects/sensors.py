"""Sensors: the true plant signals as the rig's transducers and ADC would report them.

Channels (index, config key, unit, what it measures; thesis sec 4.1, fig 4.1 D/E/F):

=====  ======================  =======  ==========================================================
index  key                     unit     true value
=====  ======================  =======  ==========================================================
0      ``accelerometer``       m/s^2    a2, body 2's acceleration (D)
1      ``force``               N        force through the force transducer (E), see below
2      ``potentiometer``       m        x2, body 2's position (F)
3      ``body1_displacement``  m        x1, body 1's position (no such sensor on the rig: off)
=====  ======================  =======  ==========================================================

Frame and signs (the thesis's, as in :mod:`impact_env.plant.layout`): x points **down**,
positions are those of the facing surfaces (x2 = 0 with body 2 at rest), the shaker force f2 on
body 2 is positive **up**, the contact force Phi >= 0 pushes body 2 down.

Force transducer.  Body 2 is split at the transducer: the part above it (pad and top plate,
mass m2' = ``force.top_mass``; H in fig 4.1) and the rest (armature, driven by f2).  The
transducer reads the force T it transmits, **positive in compression** (the lower part pushing
the top part up).  Newton for the top part (down positive): ``m2' a2 = Phi - T``, so

    T = Phi - m2' a2          and the contact force is recovered as  Phi = m2' a2 + T,

which is the thesis's contact condition eq 4.4 (``m2' a2 + f > 0``, its "f2" being the
transducer's reading).  With no contact, T = m2' f2 / m2 (the force accelerating the top part).
The top part's static weight m2' g is left out, as body 2's weight is in the plant (carried by
its suspension); piezoelectric transducers do not report static loads anyway.  Add it with
``force.offset`` if wanted.  The accelerometer reads a2 in the same frame (down positive; use
``gain = -1`` for a sensor mounted the other way); gravity is likewise not in its reading
(piezoelectric accelerometers are AC-coupled).

Measurement model per enabled channel (all in the channel's unit):

    y = gain * true + offset + noise_std * z          z ~ N(0, 1), drawn by the caller
    y = q * floor(y / q + 1/2),  q = 2 adc_range / 2**adc_bits,  clipped to [-adc_range, adc_range - q]

(mid-tread quantiser, two's-complement code range).  ``adc_bits = 0`` is an ideal converter: no
quantisation and no clipping.  A disabled channel reads 0.0 (its normal is still consumed, so a
seed gives the same noise on the other channels whatever is switched on).

Defaults.  The thesis gives no noise levels, ranges or converter: every number below is an
**assumption**, chosen so that the noise is visible (the thesis had to filter, sec 4.2) and the
ranges hold the expected peaks (contact force about 90 N at 1 m/s, shaker up to about 200 N,
so |a2| up to about 300 m/s^2 with m2 = 1 kg).  ``adc_bits = 16``: the dSPACE board's converters
(e.g. the DS1104's 16-bit ADCs; the thesis does not name the board).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.config import ConfigError, check_choice, check_range, doc_field
from impact_env.effects.effect import HARDWARE, Effect

CHANNELS = ("accelerometer", "force", "potentiometer", "body1_displacement")
UNITS = ("m/s^2", "N", "m", "m")
ACCEL, FORCE, POT, BODY1 = 0, 1, 2, 3
N_CHANNELS = 4



class ChannelParams(NamedTuple):
    """A row of the parameter array built by :func:`sensor_params` (float64[N_CHANNELS, N_PARAM])."""

    enabled: float  # 1 if the channel reads, else 0 (it then reads 0)
    gain: float
    offset: float  # in the channel's unit
    noise_std: float  # in the channel's unit
    adc_step: float  # the ADC's quantisation step (0: no ADC)
    lo: float  # the ADC's lowest code (-inf: no ADC)
    hi: float  # the ADC's highest code (inf: no ADC)


CP = positions(ChannelParams)
N_PARAM = len(CP)


_f = doc_field


def channel_index(name: str, where: str = "effects.sensors.channel") -> int:
    """Index of channel ``name`` in the sensor vector; unknown names raise ConfigError naming ``where``."""
    check_choice(where, name, CHANNELS)
    return CHANNELS.index(name)


@dataclass(frozen=True)
class ChannelConfig:
    """One measurement channel.  Subclasses fix the channel (its config key, unit and defaults)."""

    _key: ClassVar[str] = ""
    unit: ClassVar[str] = ""

    enabled: bool = _f(True, "", "channel present")
    gain: float = _f(1.0, "", "sensitivity error: reading per true value (1 = calibrated)")
    offset: float = _f(0.0, "", "bias added to the reading, in the channel's unit")
    noise_std: float = _f(0.0, "", "standard deviation of white Gaussian noise per sample, channel's unit")
    adc_bits: int = _f(16, "", "ADC resolution in bits; 0 = ideal (no quantisation, no clipping)")
    adc_range: float = _f(1.0, "", "ADC full scale: readings are clipped to +-adc_range, channel's unit")
    max_step: float = _f(0.0, "", "largest plausible change of the true value between two ticks at the "
                         "control rate (the rig target's plausibility check), channel's unit; 0 = no jump "
                         "check")

    def __post_init__(self):
        p, u = f"effects.sensors.{self._key}", self.unit
        if not isinstance(self.enabled, bool):
            raise ConfigError(f"{p}.enabled must be true or false, got {self.enabled!r}")
        # bounds: readings of every channel stay far inside float range (1e6 times a reading
        # of 1e9 units), so filters and scaling cannot overflow
        check_range(f"{p}.gain", self.gain, "", -1e6, 1e6)
        if abs(self.gain) < 1e-6:
            raise ConfigError(f"{p}.gain = {self.gain!r} is out of range: |gain| must be between 1e-06 and "
                              "1e+06 (negative flips the sign)")
        check_range(f"{p}.offset", self.offset, u, -1e9, 1e9)
        check_range(f"{p}.noise_std", self.noise_std, u, 0.0, 1e9)
        if isinstance(self.adc_bits, bool) or not isinstance(self.adc_bits, int):
            raise ConfigError(f"{p}.adc_bits must be an integer (0 to 32), got {self.adc_bits!r}")
        check_range(f"{p}.adc_bits", self.adc_bits, "bits", 0, 32)
        check_range(f"{p}.adc_range", self.adc_range, u, 1e-9, 1e9)
        check_range(f"{p}.max_step", self.max_step, u, 0.0, 1e9)

    @property
    def quantum(self) -> float:
        """ADC step q in the channel's unit (0 when ``adc_bits = 0``)."""
        return 2.0 * self.adc_range / 2.0**self.adc_bits if self.adc_bits else 0.0


@dataclass(frozen=True)
class AccelerometerConfig(ChannelConfig):
    """Accelerometer on body 2 (thesis fig 4.1 D): a2, m/s^2, down positive."""

    _key: ClassVar[str] = "accelerometer"
    unit: ClassVar[str] = "m/s^2"

    enabled: bool = _f(True, "", "channel present (on the rig: yes)")
    gain: float = _f(1.0, "", "sensitivity error: reading per true value (1 = calibrated)")
    offset: float = _f(0.0, "m/s^2", "bias added to the reading")
    noise_std: float = _f(0.5, "m/s^2", "white noise std per sample (ASSUMED: ~0.05 g broadband)")
    adc_bits: int = _f(16, "", "ADC bits (ASSUMED: dSPACE 16-bit ADC); 0 = ideal")
    adc_range: float = _f(500.0, "m/s^2", "full scale +-, about 50 g (ASSUMED: holds ~300 m/s^2 peaks)")
    max_step: float = _f(500.0, "m/s^2", "largest plausible change of a2 per tick: (a 2 x 200 N reversal "
                         "of the "
                         "drive + 75 N of contact force) / m2 1 kg (DERIVED for the rig at 10 kHz, "
                         "impact_env.control.plausibility); 0 = no jump check")


@dataclass(frozen=True)
class ForceTransducerConfig(ChannelConfig):
    """Force transducer under the pad (thesis fig 4.1 E): T = Phi - m2' a2, N, compression positive."""

    _key: ClassVar[str] = "force"
    unit: ClassVar[str] = "N"

    enabled: bool = _f(True, "", "channel present (on the rig: yes)")
    gain: float = _f(1.0, "", "sensitivity error: reading per true value (1 = calibrated)")
    offset: float = _f(0.0, "N", "bias added to the reading")
    noise_std: float = _f(0.2, "N", "white noise std per sample (ASSUMED)")
    adc_bits: int = _f(16, "", "ADC bits (ASSUMED: dSPACE 16-bit ADC); 0 = ideal")
    adc_range: float = _f(500.0, "N", "full scale +- (ASSUMED: holds ~90 N contact + 200 N shaker)")
    max_step: float = _f(125.0, "N", "largest plausible change of T = Phi - m2' a2 per tick: 75 N of contact "
                         "force + m2' 0.1 kg x 500 m/s^2 (DERIVED for the rig at 10 kHz, "
                         "impact_env.control.plausibility); 0 = off")
    top_mass: float = _f(0.1, "kg", "m2', the part of body 2 above the transducer (ASSUMED: pad + plate, "
                         "0.1 m2 with m2 = 1 kg; thesis eq 4.4 gives no value)")

    def __post_init__(self):
        super().__post_init__()
        check_range("effects.sensors.force.top_mass", self.top_mass, "kg", 0.0, 1e6)


@dataclass(frozen=True)
class PotentiometerConfig(ChannelConfig):
    """Potentiometer on body 2 (thesis fig 4.1 F): x2, m, down positive, 0 at rest."""

    _key: ClassVar[str] = "potentiometer"
    unit: ClassVar[str] = "m"

    enabled: bool = _f(True, "", "channel present (on the rig: yes)")
    gain: float = _f(1.0, "", "sensitivity error: reading per true value (1 = calibrated)")
    offset: float = _f(0.0, "m", "bias added to the reading")
    noise_std: float = _f(1.0e-5, "m", "white noise std per sample (ASSUMED: 10 um)")
    adc_bits: int = _f(16, "", "ADC bits (ASSUMED: dSPACE 16-bit ADC); 0 = ideal")
    adc_range: float = _f(0.01, "m", "full scale +- (ASSUMED: about a small shaker's stroke)")
    max_step: float = _f(3.5e-4, "m", "largest plausible change of x2 per tick at 10 kHz: body 2 "
                         "below 3.5 m/s "
                         "(energy bound, impact_env.control.plausibility) x 0.1 ms; 0 = off")


@dataclass(frozen=True)
class Body1DisplacementConfig(ChannelConfig):
    """Displacement sensor on body 1 (not on the rig; e.g. a laser triangulator): x1, m."""

    _key: ClassVar[str] = "body1_displacement"
    unit: ClassVar[str] = "m"

    enabled: bool = _f(False, "", "channel present (the rig had none: off by default)")
    gain: float = _f(1.0, "", "sensitivity error: reading per true value (1 = calibrated)")
    offset: float = _f(0.0, "m", "bias added to the reading")
    noise_std: float = _f(1.0e-5, "m", "white noise std per sample (ASSUMED: 10 um)")
    adc_bits: int = _f(16, "", "ADC bits (ASSUMED: dSPACE 16-bit ADC); 0 = ideal")
    adc_range: float = _f(0.1, "m", "full scale +- (ASSUMED: holds a 50 mm drop)")
    max_step: float = _f(3.5e-4, "m", "largest plausible change of x1 per tick at 10 kHz: body 1 "
                         "below 3.5 m/s "
                         "x 0.1 ms (as x2's bound); 0 = off")


@dataclass(frozen=True)
class SensorsConfig:
    """All sensor channels, in the order of the sensor vector (see :data:`CHANNELS`)."""

    accelerometer: AccelerometerConfig = field(default_factory=AccelerometerConfig)
    force: ForceTransducerConfig = field(default_factory=ForceTransducerConfig)
    potentiometer: PotentiometerConfig = field(default_factory=PotentiometerConfig)
    body1_displacement: Body1DisplacementConfig = field(default_factory=Body1DisplacementConfig)
    fault_limit_s: float = _f(1.0e-3, "s", "the rig target ends an episode SENSOR_FAULT when implausible "
                              "readings "
                              "last longer than this (ASSUMED: 10 ticks at 10 kHz, a quarter of a contact; "
                              "impact_env.control.plausibility)")

    def __post_init__(self):
        check_range("effects.sensors.fault_limit_s", self.fault_limit_s, "s", 0.0, 10.0, lo_open=True)

    def channels(self) -> tuple[ChannelConfig, ...]:
        return tuple(getattr(self, name) for name in CHANNELS)

    @property
    def enabled_mask(self) -> np.ndarray:
        """bool[N_CHANNELS]: which channels are present."""
        return np.array([ch.enabled for ch in self.channels()], dtype=bool)


def sensor_params(cfg: SensorsConfig) -> np.ndarray:
    """float64[N_CHANNELS, N_PARAM] for :func:`sense`: enabled, gain, offset, noise std,
    ADC step q (0 = none), lowest and highest output value."""
    p = np.zeros((N_CHANNELS, N_PARAM))
    for i, ch in enumerate(cfg.channels()):
        p[i, CP.enabled] = 1.0 if ch.enabled else 0.0
        p[i, CP.gain] = ch.gain
        p[i, CP.offset] = ch.offset
        p[i, CP.noise_std] = ch.noise_std
        if ch.adc_bits:
            q = ch.quantum
            half = 2.0 ** (ch.adc_bits - 1)
            p[i, CP.adc_step] = q
            p[i, CP.lo] = -half * q
            p[i, CP.hi] = (half - 1.0) * q
        else:
            p[i, CP.lo] = -np.inf
            p[i, CP.hi] = np.inf
    return p


def draw_noise(rng: np.random.Generator, n_steps: int | None = None) -> np.ndarray:
    """Standard normals for :func:`sense`: float64[N_CHANNELS], or [n_steps, N_CHANNELS]."""
    shape = (N_CHANNELS,) if n_steps is None else (n_steps, N_CHANNELS)
    return rng.standard_normal(shape)


@jit(inline="always")
def true_readings(x1, x2, a2, phi, top_mass, out):
    """Fill ``out`` (float64[4]) with the true channel values: a2 (m/s^2), transducer force
    ``phi - top_mass * a2`` (N), x2 (m), x1 (m).  phi is the contact force (N, >= 0)."""
    out[ACCEL] = a2
    out[FORCE] = phi - top_mass * a2
    out[POT] = x2
    out[BODY1] = x1


@jit(inline="always")
def _channel(p, j, truth, z):
    """One channel's reading from its parameters ``p[j + CP.*]`` (a flat row): gain, offset and
    noise, then the ADC's rounding and clipping; 0 if the channel is disabled."""
    if p[j + CP.enabled] == 0.0:
        return 0.0
    y = p[j + CP.gain] * truth + p[j + CP.offset] + p[j + CP.noise_std] * z
    q = p[j + CP.adc_step]
    if q > 0.0:
        y = q * np.floor(y / q + 0.5)
        if y < p[j + CP.lo]:
            y = p[j + CP.lo]
        elif y > p[j + CP.hi]:
            y = p[j + CP.hi]
    return y


@jit(inline="always")
def sense(truth, z, params, out):
    """Measure: ``out[i] = ADC(gain*truth[i] + offset + noise_std*z[i])`` per channel; 0 if disabled.

    truth, z, out: float64[N_CHANNELS]; params from :func:`sensor_params`.  Returns ``out``.
    """
    for i in range(truth.shape[0]):
        out[i] = _channel(params[i], 0, truth[i], z[i])
    return out


@jit
def sense_block(truth, z, params, out):
    """:func:`sense` over a block: truth, z, out float64[n_steps, N_CHANNELS].  Returns ``out``."""
    for k in range(truth.shape[0]):
        sense(truth[k], z[k], params, out[k])
    return out


# -- packed block (one env's sensors inside a per-env row; see impact_env.hardware.blocks) -------
# parameters: [top mass m2' (kg, the force transducer's mounting), N_CHANNELS * N_PARAM channel
# parameters of sensor_params]; no state (the noise comes in from outside)

def block_sizes() -> tuple[int, int]:
    """(parameter, state) sizes of the packed sensor block."""
    return 1 + N_CHANNELS * N_PARAM, 0


P_TOP_MASS = 0  # the packed block: [top mass (kg), sensor_params ravelled]


def pack_params(cfg: SensorsConfig, top_mass: float) -> np.ndarray:
    return np.concatenate([[float(top_mass)], sensor_params(cfg).ravel()])


@jit(inline="always")
def read_packed(x1, x2, a2, phi, p, out):
    """The true channel values (:func:`true_readings`) with the packed block's top mass."""
    return true_readings(x1, x2, a2, phi, p[P_TOP_MASS], out)


@jit(inline="always")
def sense_packed(truth, z, p, out):
    """:func:`sense` on a packed block (``truth`` and ``out`` may be the same array)."""
    # (indexed in place: a reshape of the row would cost a call into numba's helper every tick)
    for i in range(truth.shape[0]):
        out[i] = _channel(p, P_TOP_MASS + 1 + i * N_PARAM, truth[i], z[i])
    return out


def _pack(cfg: SensorsConfig, rate: float, on: bool) -> tuple[np.ndarray, int]:
    """Packed even when off: the true readings need the force transducer's top mass."""
    return pack_params(cfg, cfg.force.top_mass), block_sizes()[1]


EFFECT = Effect("sensors", HARDWARE, "sensors", SensorsConfig, "gain, offset, noise, ADC quantisation and "
                "clipping of each channel", readings_only=True, pack=_pack)
