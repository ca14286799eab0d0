"""Per-channel digital filters on the sensor readings: Butterworth band-pass or low-pass.

The thesis bandpassed its sensor signals to the band that carries the control information,
20-1000 Hz (sec 4.3, 5), and notes that the filters' delay limited the controller (sec 4.2).
Its filter order is not given: ``order = 2`` is an **assumption**.

Design: ``scipy.signal.butter(order, band, btype, output="sos", fs=rate)`` at the control rate.
``order`` is butter's N: a band-pass of order N has 2N poles (N second-order sections), a
low-pass ceil(N/2) sections.  For ``kind = "lowpass"`` the cut-off is ``high_hz`` and ``low_hz``
is ignored; ``kind = "none"`` passes the channel through unchanged.

Run: every channel is a cascade of second-order sections in transposed direct form II, the
same recursion as ``scipy.signal.sosfilt`` (so the two agree to rounding), with its state kept
in an explicit float64 array.  Channels with fewer sections are padded with identity sections
(``[1, 0, 0, 1, 0, 0]``), which pass the signal exactly.  The C export's float32 build runs the same
sections as trapezoidal state-variable filters (:func:`tpt_sections`: far less float32 rounding
at cut-offs near DC).

Defaults: accelerometer and force transducer band-pass 20-1000 Hz (thesis); potentiometer and
body-1 displacement low-pass 1000 Hz (**assumption**: a band-pass would remove the static
position the controller needs).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.config import ConfigError, check_choice, check_range, doc_field
from impact_env.effects.effect import CONTROLLER, Effect
from impact_env.effects.sensors import CHANNELS, N_CHANNELS

KINDS = ("bandpass", "lowpass", "none")


class SectionSlots(NamedTuple):
    """One second-order section's coefficients, in scipy's ``sos`` layout (float64[6], a0 = 1)."""

    b0: float  # numerator
    b1: float
    b2: float
    a0: float  # denominator
    a1: float
    a2: float


class DelaySlots(NamedTuple):
    """One section's state (float64[2]): the two delays of the transposed direct form II."""

    z1: float
    z2: float


SECTION = positions(SectionSlots)
DELAY = positions(DelaySlots)
IDENTITY_SECTION = SectionSlots(b0=1.0, b1=0.0, b2=0.0, a0=1.0, a1=0.0, a2=0.0)


_f = doc_field


@dataclass(frozen=True)
class FilterConfig:
    """One channel's filter.  Subclasses fix the channel (config key and default kind)."""

    _key: ClassVar[str] = ""

    kind: str = _f("bandpass", "", "bandpass | lowpass (cut-off high_hz) | none")
    low_hz: float = _f(20.0, "Hz", "lower band edge (-3 dB) of the band-pass (thesis sec 4.3: 20 Hz); "
                       "kind = lowpass ignores it")
    high_hz: float = _f(1000.0, "Hz", "upper band edge / low-pass cut-off (thesis sec 4.3: 1000 Hz)")
    order: int = _f(2, "", "Butterworth order N (band-pass: 2N poles); ASSUMED, thesis gives none")

    @property
    def path(self) -> str:
        return f"effects.filters.{self._key}" if self._key else "effects.filter"

    def __post_init__(self):
        p = self.path
        check_choice(f"{p}.kind", self.kind, KINDS)
        check_range(f"{p}.low_hz", self.low_hz, "Hz", 1e-3, 1e7)
        check_range(f"{p}.high_hz", self.high_hz, "Hz", 1e-3, 1e7)
        if isinstance(self.order, bool) or not isinstance(self.order, int):
            raise ConfigError(f"{p}.order must be an integer (1 to 10), got {self.order!r}")
        check_range(f"{p}.order", self.order, "", 1, 10)
        if self.kind == "bandpass" and self.low_hz >= self.high_hz:
            raise ConfigError(f"{p}.low_hz = {self.low_hz:g} Hz is out of range: must be below "
                              f"{p}.high_hz = {self.high_hz:g} Hz")

    def check_rate(self, rate: float) -> None:
        """Raise ConfigError unless the band lies below the Nyquist frequency ``rate / 2``."""
        if self.kind == "none":
            return
        nyq = 0.5 * rate
        for name in (("low_hz", "high_hz") if self.kind == "bandpass" else ("high_hz",)):
            v = getattr(self, name)
            if v >= nyq:
                raise ConfigError(f"{self.path}.{name} = {v:g} Hz is out of range: must be < {nyq:g} Hz, "
                                  f"the Nyquist frequency at control.rate = {rate:g} Hz")


@dataclass(frozen=True)
class AccelerometerFilter(FilterConfig):
    _key: ClassVar[str] = "accelerometer"


@dataclass(frozen=True)
class ForceFilter(FilterConfig):
    _key: ClassVar[str] = "force"


@dataclass(frozen=True)
class PotentiometerFilter(FilterConfig):
    _key: ClassVar[str] = "potentiometer"
    kind: str = _f("lowpass", "", "bandpass | lowpass (cut-off high_hz) | none; ASSUMED lowpass: keeps DC")


@dataclass(frozen=True)
class Body1DisplacementFilter(FilterConfig):
    _key: ClassVar[str] = "body1_displacement"
    kind: str = _f("lowpass", "", "bandpass | lowpass (cut-off high_hz) | none; ASSUMED lowpass: keeps DC")


@dataclass(frozen=True)
class FiltersConfig:
    """The filter of each sensor channel, in the order of the sensor vector."""

    accelerometer: AccelerometerFilter = field(default_factory=AccelerometerFilter)
    force: ForceFilter = field(default_factory=ForceFilter)
    potentiometer: PotentiometerFilter = field(default_factory=PotentiometerFilter)
    body1_displacement: Body1DisplacementFilter = field(default_factory=Body1DisplacementFilter)

    def channels(self) -> tuple[FilterConfig, ...]:
        return tuple(getattr(self, name) for name in CHANNELS)

    @property
    def active(self) -> bool:
        """False when every channel's kind is ``none`` (the stage can be left out)."""
        return any(ch.kind != "none" for ch in self.channels())

    def check_rate(self, rate: float) -> None:
        for ch in self.channels():
            ch.check_rate(rate)


def design_sos(cfg: FilterConfig, rate: float) -> np.ndarray:
    """Second-order sections float64[n_sections, 6] of one channel's filter at ``rate`` (Hz).

    ``kind = "none"`` gives one identity section.  Raises ConfigError for a band at or above
    the Nyquist frequency.
    """
    from scipy import signal

    check_range("control.rate", rate, "Hz", 0.0, None, lo_open=True)
    cfg.check_rate(rate)
    if cfg.kind == "none":
        return np.array([IDENTITY_SECTION])
    if cfg.kind == "bandpass":
        sos = signal.butter(cfg.order, [cfg.low_hz, cfg.high_hz], btype="bandpass", output="sos", fs=rate)
    else:
        sos = signal.butter(cfg.order, cfg.high_hz, btype="lowpass", output="sos", fs=rate)
    return np.ascontiguousarray(sos, dtype=np.float64)


def design_filters(cfg: FiltersConfig, rate: float) -> np.ndarray:
    """float64[N_CHANNELS, n_sections, 6]: every channel's sections, padded with identity sections."""
    per = [design_sos(ch, rate) for ch in cfg.channels()]
    n = max(s.shape[0] for s in per)
    sos = np.empty((N_CHANNELS, n, 6))
    sos[:] = IDENTITY_SECTION
    for i, s in enumerate(per):
        sos[i, : s.shape[0]] = s
    return sos


def make_filter_state(sos: np.ndarray) -> np.ndarray:
    """Zero state float64[n_channels, n_sections, 2] for the sections ``sos``."""
    return np.zeros((sos.shape[0], sos.shape[1], 2))


def reset_filter_state(state: np.ndarray, sos: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
    """Reset in place: zeros, or (``x0`` given, float64[n_channels]) the steady state for a constant
    input x0 per channel (``scipy.signal.sosfilt_zi`` scaled), so a constant reading passes without
    a start-up transient.  Returns ``state``."""
    if x0 is None:
        state[:] = 0.0
        return state
    from scipy import signal

    x0 = np.asarray(x0, dtype=np.float64)
    for i in range(sos.shape[0]):
        state[i] = signal.sosfilt_zi(sos[i]) * x0[i]
    return state


def tpt_sections(sos: np.ndarray) -> np.ndarray:
    """The sections ``sos`` (float64[..., 6], scipy's layout, a0 = 1) as trapezoidal state-variable
    filters: float64[..., 6] of ``(c1, c2, c3, m0, m1, m2)``, for the C export's float32 build.

    Zavalishin's topology-preserving transform of the SVF ("The Art of VA Filter Design", 2012),
    in Simper's linear trapezoidal form ("Linear Trapezoidal Integrated State Variable Filter",
    Cytomic, 2013), run per sample as::

        v3 = x - s2;  v1 = c1 s1 + c2 v3;  v2 = s2 + c2 s1 + c3 v3
        s1 = 2 v1 - s1;  s2 = 2 v2 - s2;  y = m0 x + m1 v1 + m2 v2

    Any stable section is this filter with g = sqrt(A(1) / A(-1)), g k = 2 (1 - a2) / A(-1)
    (A, B: the section's denominator and numerator in z^-1), c1 = 1 / (1 + g (g + k)),
    c2 = g c1, c3 = g c2, and the output mix m0 = B(-1) / A(-1), m2 = B(1) / A(1) - m0,
    m1 = (b0 - m0) N / g - m2 g with N = 4 / A(-1): the same transfer function, from zero state
    the same response.  Why: the rig's band-pass has a 20 Hz high-pass section at 10 kHz whose
    poles lie 0.009 from z = 1; in direct form its float32 state rounding is amplified by
    about 1 / ((1 - r) theta^2) and its coefficients' rounding moves the poles, while the SVF's
    states are the signal's own band-pass and low-pass parts.  On the readings of the rig's
    drops its float32 output departs from the double filter 70-100x less than transposed direct
    form II's (``tests/test_filters_tpt.py``).  Identity sections map to m0 = 1, the rest 0:
    they pass the signal exactly.  Raises ConfigError for a section with a pole on or outside
    the unit circle.
    """
    sos = np.asarray(sos, dtype=np.float64)
    b0, b1, b2, a0, a1, a2 = (sos[..., i] for i in range(6))
    if np.any(a0 != 1.0):
        raise ConfigError("tpt_sections: every section's a0 must be 1 (scipy's normalised sos)")
    a_p, a_m = 1.0 + a1 + a2, 1.0 - a1 + a2
    if np.any(a_p <= 0.0) or np.any(a_m <= 0.0) or np.any(np.abs(a2) >= 1.0):
        raise ConfigError("tpt_sections: a section has a pole on or outside the unit circle (Jury: "
                          "A(1) > 0, A(-1) > 0 and |a2| < 1 are required): it is not a stable filter")
    g = np.sqrt(a_p / a_m)
    k = 2.0 * (1.0 - a2) / a_m / g
    n = 4.0 / a_m
    m0 = (b0 - b1 + b2) / a_m
    m2 = (b0 + b1 + b2) / a_p - m0
    m1 = (b0 - m0) * n / g - m2 * g
    c1 = 1.0 / (1.0 + g * (g + k))
    return np.stack([c1, g * c1, g * (g * c1), m0, m1, m2], axis=-1)


def group_delay_s(cfg: FilterConfig, rate: float, freq_hz: float | np.ndarray | None = None):
    """Group delay (s) the filter adds at ``freq_hz`` (Hz; default: :func:`passband_centre_hz`).

    Sum of the sections' group delays from ``scipy.signal.group_delay`` (delays of a cascade
    add), divided by the rate.  Returns a float for a scalar frequency, else an array.
    """
    from scipy import signal

    f = passband_centre_hz(cfg) if freq_hz is None else freq_hz
    fa = np.atleast_1d(np.asarray(f, dtype=np.float64))
    total = np.zeros_like(fa)
    for sec in design_sos(cfg, rate):
        _, gd = signal.group_delay((sec[:3], sec[3:]), w=fa, fs=rate)
        total += gd
    total /= rate
    return float(total[0]) if np.ndim(f) == 0 else total


def passband_centre_hz(cfg: FilterConfig) -> float:
    """Band-pass: geometric centre sqrt(low high) (where a Butterworth band-pass has unit gain);
    low-pass and none: 0 Hz (DC)."""
    return float(np.sqrt(cfg.low_hz * cfg.high_hz)) if cfg.kind == "bandpass" else 0.0


@jit(inline="always")
def filter_step(sos, zi, x, out):
    """One sample through every channel's SOS cascade (transposed direct form II, as sosfilt).

    sos: float64[n_ch, n_sec, 6]; zi: float64[n_ch, n_sec, 2], updated in place;
    x, out: float64[n_ch].  Returns ``out``.
    """
    for c in range(sos.shape[0]):
        v = x[c]
        for s in range(sos.shape[1]):
            y = sos[c, s, SECTION.b0] * v + zi[c, s, DELAY.z1]
            zi[c, s, DELAY.z1] = sos[c, s, SECTION.b1] * v - sos[c, s, SECTION.a1] * y + zi[c, s, DELAY.z2]
            zi[c, s, DELAY.z2] = sos[c, s, SECTION.b2] * v - sos[c, s, SECTION.a2] * y
            v = y
        out[c] = v
    return out


@jit
def filter_block(sos, zi, x, out):
    """:func:`filter_step` over a block: x, out float64[n_steps, n_ch].  Returns ``out``."""
    for k in range(x.shape[0]):
        filter_step(sos, zi, x[k], out[k])
    return out


EFFECT = Effect("filters", CONTROLLER, "filters", FiltersConfig, "a Butterworth band- or low-pass per sensor "
                "channel", readings_only=True)
