"""Force saturation of the amplifier + shaker: peak limit, RMS (thermal) budget, slew-rate limit.

Sources: the LDS V406 / PA 100E is rated 98 N sine peak (continuous; thesis sec 4.1), and gave
"approximately 200 N" for short pulses (sec 4.3).  So two limits:

* **peak**: ``|f| <= peak_n`` always (default 200 N, thesis sec 4.3);
* **RMS budget**: a first-order tracker of the mean square force,
  ``ms[n+1] = ms[n] + alpha (f[n]^2 - ms[n])``, ``alpha = 1 - exp(-1/(rate tau_s))``, may not
  exceed ``R^2`` with ``R = continuous_n / sqrt(2)`` (the RMS of a 98 N-peak sine, 69.3 N).
  The allowed force this step is therefore ``sqrt(ms + (R^2 - ms) / alpha)``: large while the
  budget is unspent (short pulses get the full peak), falling to R under a sustained
  over-rated command.  ``tau_s = 0.1 s`` is an **assumption** (the thesis gives no thermal or
  protection time constant): with it a 200 N command is held for about 13 ms before the
  budget engages, longer than a contact (about 4 ms).  ``continuous_n = 0`` turns the budget off.
* **slew rate** (optional, ``slew_n_per_s = 0`` = off): ``|f[n] - f[n-1]| <= slew_n_per_s / rate``.

Order: slew limit first, then the amplitude limit (peak and RMS budget).  The amplitude limit
is hard: the applied force never exceeds it.  The slew limit holds except when the RMS budget
forces a faster decrease (a force at the budget's limit must drop to R at once).
A non-finite command (NaN) is treated as 0 N, and reported as saturated.

State: float64[2] = (mean-square force ms in N^2, previous applied force in N); ms is tracked
even with the budget off (sqrt(ms) is the running RMS of the applied force).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.config import ConfigError, check_range, doc_field
from impact_env.effects.effect import HARDWARE, Effect


class SaturationState(NamedTuple):
    """The state array's entries (float64[N_STATE], zero at the start)."""

    mean_square: float  # N^2, the tracked mean-square force
    prev: float  # N, the previous applied force


class SaturationParams(NamedTuple):
    """The parameter array's entries (float64[N_PARAM], :func:`saturation_params`)."""

    peak: float  # N, the peak limit
    rms2: float  # N^2, the RMS budget squared (< 0: no budget)
    alpha: float  # the mean-square tracker's factor per period
    slew_step: float  # N, the largest change per period (inf: no slew limit)


ST = positions(SaturationState)
SP = positions(SaturationParams)
N_STATE = len(ST)
N_PARAM = len(SP)


_f = doc_field


@dataclass(frozen=True)
class SaturationConfig:
    """Force limits of amplifier and shaker, on the force reaching body 2."""

    peak_n: float = _f(200.0, "N", "peak limit |f| (thesis sec 4.3: about 200 N for short pulses)")
    continuous_n: float = _f(98.0, "N", "continuous rating as a sine peak (thesis: 98 N); budget RMS = "
                             "continuous_n/sqrt(2); 0 = no RMS budget")
    tau_s: float = _f(0.1, "s", "time constant of the mean-square tracker (ASSUMED)")
    slew_n_per_s: float = _f(0.0, "N/s", "slew-rate limit; 0 = off")

    def __post_init__(self):
        # bounds: up to 10 MN and 1e12 N/s (far beyond any shaker; the mean square of 1e7 N
        # stays finite), a time constant from 1 us
        check_range("effects.saturation.peak_n", self.peak_n, "N", 0.0, 1e7, lo_open=True)
        check_range("effects.saturation.continuous_n", self.continuous_n, "N", 0.0, 1e7)
        if self.continuous_n > self.peak_n:
            raise ConfigError(f"effects.saturation.continuous_n = {self.continuous_n:g} N is out of range: "
                              f"must be <= effects.saturation.peak_n = {self.peak_n:g} N")
        check_range("effects.saturation.tau_s", self.tau_s, "s", 1e-6, 1e4)
        check_range("effects.saturation.slew_n_per_s", self.slew_n_per_s, "N/s", 0.0, 1e12)

    @property
    def rms_limit_n(self) -> float:
        """RMS force the budget allows in the long run, N (0: no budget)."""
        return self.continuous_n / math.sqrt(2.0)


def saturation_params(cfg: SaturationConfig, rate: float) -> np.ndarray:
    """float64[N_PARAM] (:class:`SaturationParams`) for :func:`saturate` at the control rate
    ``rate`` (Hz)."""
    check_range("control.rate", rate, "Hz", 0.0, None, lo_open=True)
    p = np.empty(N_PARAM)
    p[SP.peak] = cfg.peak_n
    p[SP.rms2] = cfg.rms_limit_n**2 if cfg.continuous_n > 0 else -1.0
    p[SP.alpha] = -math.expm1(-1.0 / (rate * cfg.tau_s))
    p[SP.slew_step] = cfg.slew_n_per_s / rate if cfg.slew_n_per_s > 0 else np.inf
    return p


def make_saturation_state() -> np.ndarray:
    """State float64[2]: (mean-square force N^2, previous force N), both 0."""
    return np.zeros(N_STATE)


@jit(inline="always")
def saturate(f_cmd, state, params):
    """Apply the limits to the command ``f_cmd`` (N); update ``state``.

    Returns ``(f, saturated)``: the applied force (N) and whether any limit changed the command.
    """
    f = f_cmd
    if not np.isfinite(f):
        f = 0.0
    prev = state[ST.prev]
    step = params[SP.slew_step]
    if f > prev + step:
        f = prev + step
    elif f < prev - step:
        f = prev - step
    lim = params[SP.peak]
    rms2 = params[SP.rms2]
    if rms2 >= 0.0:
        ms = state[ST.mean_square]
        room = ms + (rms2 - ms) / params[SP.alpha]
        if room < 0.0:
            room = 0.0
        r = np.sqrt(room)
        if r < lim:
            lim = r
    if f > lim:
        f = lim
    elif f < -lim:
        f = -lim
    state[ST.mean_square] += params[SP.alpha] * (f * f - state[ST.mean_square])
    state[ST.prev] = f
    return f, f != f_cmd


@jit
def saturate_block(f_cmd, state, params, out, flags):
    """:func:`saturate` over a block of commands (float64[n]); fills ``out`` (float64[n]) and
    ``flags`` (bool[n]).  Returns ``out``."""
    for n in range(f_cmd.shape[0]):
        out[n], flags[n] = saturate(f_cmd[n], state, params)
    return out


# -- packed block: the parameters and state above, as they are (float64[4], float64[2]) ----------

def block_sizes() -> tuple[int, int]:
    """(parameter, state) sizes of the packed saturation block."""
    return N_PARAM, N_STATE


def _pack(cfg: SaturationConfig, rate: float, on: bool) -> tuple[np.ndarray, int]:
    return saturation_params(cfg, rate), block_sizes()[1]


EFFECT = Effect("saturation", HARDWARE, "saturation", SaturationConfig, "the amplifier's peak limit, RMS "
                "(thermal) budget and slew rate", readings_only=False, pack=_pack)
