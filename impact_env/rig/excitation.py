"""Excitations of the drive command for identification episodes (``impact-env rig identify``).

An identification episode of kind *shaker* holds body 1 on the electromagnet and drives the
shaker with an open-loop signal; *quiet* drives it with 0 N (the sensors' offsets and noise).
The host describes the signal in a small JSON file (:meth:`Excitation.to_json`), uploaded like a
policy file and hashed into the ARM; the target generates the samples from it
(:meth:`Excitation.samples`) and plays them through its safety layer, one per tick.  The log
keeps both the file (attribute ``excitation``) and the command the driver was given each tick
(column ``command``), which is what a fit replays.

Signals (``amplitude_N`` the peak force demanded, N; band ``f_lo_Hz`` .. ``f_hi_Hz``, Hz):

* ``sweep``: a logarithmic (exponential) sine sweep, ``A w(t) sin(2 pi f_lo T/L (e^{L t/T} - 1))``
  with ``L = ln(f_hi/f_lo)`` over the episode's T seconds: equal time per octave, so the
  suspension's low resonance and the coil's high poles get the same share;
* ``multisine``: the sum of cosines at up to 64 log-spaced lines of the record's frequency
  grid (1/T) inside the band, with Schroeder's phases (low crest factor), scaled to the peak;
* ``prbs``: a maximum-length pseudo-random binary sequence (15-bit LFSR, its start state from
  ``seed``), each bit held ``round(rate / (3 f_hi))`` ticks (the spectrum is flat to within
  about 1.3 dB up to a third of the bit rate, i.e. to f_hi); ``f_lo_Hz`` is not used;
* ``zero``: 0 N throughout (a quiet episode).

``w(t)`` is a raised-cosine fade over ``taper_s`` at both ends (sweep and multisine), so the
signal starts and ends at 0 N: no step into the shaker's band-pass and suspension.

Limits (checked before anything moves, naming the field): the peak within the safety layer's
``peak_n`` and the scene's ``command_scale`` (|command| <= 1), the RMS within the continuous
rating ``continuous_n / sqrt(2)``, ``0 < f_lo < f_hi <= rate / 2``.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass

import numpy as np

from impact_env.config import ConfigError, check_choice, check_range
from impact_env.control.policy import sequence_arrays

FORMAT = "impact-env-excitation"
VERSION = 1
SIGNALS = ("sweep", "multisine", "prbs", "zero")
MAX_LINES = 64
PRBS_BITS = 15
PRBS_TAPS = (15, 14)  # x^15 + x^14 + 1: a maximum-length feedback polynomial


@dataclass(frozen=True)
class Excitation:
    """One identification signal (see the module doc; SI units)."""

    signal: str = "zero"
    amplitude_N: float = 0.0
    f_lo_Hz: float = 10.0
    f_hi_Hz: float = 1000.0
    taper_s: float = 0.01
    seed: int = 0

    def __post_init__(self):
        check_choice("excitation.signal", self.signal, SIGNALS)
        check_range("excitation.amplitude_N", self.amplitude_N, "N", 0.0, 1e7)
        check_range("excitation.f_lo_Hz", self.f_lo_Hz, "Hz", 0.0, 1e7, lo_open=True)
        check_range("excitation.f_hi_Hz", self.f_hi_Hz, "Hz", 0.0, 1e7, lo_open=True)
        check_range("excitation.taper_s", self.taper_s, "s", 0.0, 10.0)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**63:
            raise ConfigError(f"excitation.seed = {self.seed!r} must be an integer in [0, 2^63)")
        if self.signal != "zero" and self.amplitude_N <= 0:
            raise ConfigError(f"excitation.amplitude_N = {self.amplitude_N!r} N must be > 0 N for a "
                              f"{self.signal} (signal 'zero' is the quiet episode)")
        if self.signal in ("sweep", "multisine") and self.f_lo_Hz >= self.f_hi_Hz:
            raise ConfigError(f"excitation.f_lo_Hz = {self.f_lo_Hz:g} Hz must be below excitation.f_hi_Hz = "
                              f"{self.f_hi_Hz:g} Hz")

    # -- the samples ---------------------------------------------------------------------------
    def samples(self, rate: float, n: int) -> np.ndarray:
        """The force demanded at ticks 0 .. n-1 (float64[n], N, up positive) at ``rate`` Hz."""
        check_range("control.rate", rate, "Hz", 0.0, 1e8, lo_open=True)
        if self.signal != "zero" and self.f_hi_Hz > rate / 2 * (1 + 1e-12):
            raise ConfigError(f"excitation.f_hi_Hz = {self.f_hi_Hz:g} Hz is above the Nyquist frequency "
                              f"{rate / 2:g} Hz of the control rate {rate:g} Hz")
        n = int(n)
        if n < 1:
            raise ConfigError(f"an excitation needs at least one tick, got {n}")
        t = np.arange(n) / rate
        T = n / rate
        if self.signal == "zero":
            return np.zeros(n)
        if self.signal == "sweep":
            L = math.log(self.f_hi_Hz / self.f_lo_Hz)
            x = np.sin(2 * np.pi * self.f_lo_Hz * T / L * np.expm1(L * t / T))
        elif self.signal == "multisine":
            x = _multisine(t, T, self.f_lo_Hz, self.f_hi_Hz)
        else:
            x = _prbs(n, max(1, int(round(rate / (3.0 * self.f_hi_Hz)))), self.seed)
        if self.signal != "prbs":
            x = x * _taper(t, t[-1], self.taper_s)  # (0 at the first and the last tick)
        return self.amplitude_N * x

    def commands(self, rate: float, n: int, command_scale: float, peak_n: float | None = None,
                 continuous_n: float | None = None) -> np.ndarray:
        """The dimensionless commands (1 = ``command_scale`` N up) of :meth:`samples`, refused
        (ConfigError naming the field) if they leave [-1, 1], the peak ``peak_n`` (N) or the RMS
        ``continuous_n / sqrt(2)`` (N) of the safety layer, so that it never has to cut them."""
        f = self.samples(rate, n)
        peak = float(np.max(np.abs(f))) if n else 0.0
        if peak > command_scale * (1 + 1e-12):
            raise ConfigError(f"excitation.amplitude_N = {self.amplitude_N:g} N asks for a peak of "
                              f"{peak:.4g} N, more than the scene's effects.command_scale = "
                              f"{command_scale:g} N (command 1)")
        if peak_n is not None and peak > peak_n:
            raise ConfigError(f"excitation.amplitude_N = {self.amplitude_N:g} N: peak {peak:.4g} N above the "
                              f"safety layer's peak_n = {peak_n:g} N")
        if continuous_n is not None and continuous_n > 0:
            rms = float(np.sqrt(np.mean(f * f)))
            if rms > continuous_n / math.sqrt(2):
                raise ConfigError(f"excitation.amplitude_N = {self.amplitude_N:g} N: RMS {rms:.4g} N above "
                                  f"the safety layer's continuous rating {continuous_n / math.sqrt(2):.4g} "
                                  f"N RMS (continuous_n = {continuous_n:g} N peak)")
        return f / command_scale

    # -- the file --------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {"format": FORMAT, "version": VERSION, **asdict(self)}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, d, where: str = "excitation") -> Excitation:
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise ConfigError(f"{where} is not an {FORMAT} file (no 'format': {FORMAT!r})")
        if d.get("version") != VERSION:
            raise ConfigError(f"{where} has version {d.get('version')!r}; this impact_env reads {VERSION}")
        keys = {k: v for k, v in d.items() if k not in ("format", "version")}
        unknown = sorted(set(keys) - set(cls.__dataclass_fields__))
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}")
        try:
            return cls(**keys)
        except TypeError as exc:
            raise ConfigError(f"{where}: {exc}") from None

    @classmethod
    def from_json(cls, text: str | bytes, where: str = "excitation") -> Excitation:
        try:
            d = json.loads(text)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{where} is not JSON: {exc}") from None
        return cls.from_dict(d, where)

    def describe(self) -> str:
        if self.signal == "zero":
            return "0 N (quiet)"
        band = (f"up to {self.f_hi_Hz:g} Hz" if self.signal == "prbs"
                else f"{self.f_lo_Hz:g}-{self.f_hi_Hz:g} Hz")
        return f"{self.signal} {band}, {self.amplitude_N:g} N peak"


def is_excitation(data: bytes) -> bool:
    """Whether an uploaded file is an excitation (not a policy file)."""
    try:
        d = json.loads(data)
    except (json.JSONDecodeError, UnicodeDecodeError):
        return False
    return isinstance(d, dict) and d.get("format") == FORMAT


def _taper(t: np.ndarray, T: float, taper_s: float) -> np.ndarray:
    w = np.ones_like(t)
    tau = min(taper_s, T / 2)
    if tau <= 0:
        return w
    up = t < tau
    w[up] = 0.5 - 0.5 * np.cos(np.pi * t[up] / tau)
    down = t > T - tau
    w[down] = 0.5 - 0.5 * np.cos(np.pi * (T - t[down]) / tau)
    return w


def _multisine(t: np.ndarray, T: float, f_lo: float, f_hi: float) -> np.ndarray:
    df = 1.0 / T
    k_lo, k_hi = max(1, int(math.ceil(f_lo / df))), int(math.floor(f_hi / df))
    if k_hi < k_lo:
        raise ConfigError(f"excitation: the band {f_lo:g}-{f_hi:g} Hz holds no line of the record's "
                          f"{df:g} Hz grid (lengthen the episode or widen the band)")
    ks = np.unique(np.round(np.geomspace(k_lo, k_hi, MAX_LINES)).astype(int))
    K = len(ks)
    phase = -np.pi * np.arange(K) * (np.arange(K) - 1) / K  # Schroeder
    x = np.zeros_like(t)
    for k, ph in zip(ks, phase, strict=True):
        x += np.cos(2 * np.pi * k * df * t + ph)
    return x / np.max(np.abs(x))


def _prbs(n: int, hold: int, seed: int) -> np.ndarray:
    state = (int(seed) % (2**PRBS_BITS - 1)) + 1  # any nonzero start state
    a, b = PRBS_TAPS
    bits = np.empty((n + hold - 1) // hold)
    for i in range(len(bits)):
        bit = ((state >> (a - 1)) ^ (state >> (b - 1))) & 1
        state = ((state << 1) | bit) & (2**PRBS_BITS - 1)
        bits[i] = 1.0 if bit else -1.0
    return np.repeat(bits, hold)[:n]


class ExcitationPolicy:
    """The excitation as the target's onboard "policy": an open-loop sequence of commands for
    :func:`impact_env.control.policy.act` (it reads no observation)."""

    observation = "sensors"
    history = 1
    hold_ticks = 1

    def __init__(self, excitation: Excitation, commands: np.ndarray, obs_size: int, command_scale: float):
        self.excitation = excitation
        self.name = f"excitation: {excitation.describe()}"
        self._arrays = sequence_arrays(commands, obs_size, command_scale)

    def arrays(self):
        return self._arrays

    def residual_policy(self):
        return None
