"""Transport delays: a ring buffer per path that shifts a vector of channels by whole control periods.

Two paths, each given in **seconds** (the thesis does not quantify either; both default to 0):

* ``sensor_s``: from the sensors' readings to the raw readings the controller gets (converter
  latency, bus, ...): the controller's filters see the delayed readings;
* ``actuator_s``: from the force demand (the command times its scale) to the shaker's input
  (computation and output latency).

Rule for turning seconds into samples at the control rate ``rate`` (Hz)::

    k = round(delay_s * rate)          # samples, i.e. control periods
    |delay_s * rate - k| > 1e-6 * max(1, k)   ->  ConfigError ("not representable")

so a delay must be a whole number of control periods (up to rounding).  A delay line of k
samples returns ``y[n] = x[n - k]``; for n < k it returns the fill value of the last reset
(0 by default).  k = 0 passes the input through unchanged.

State: ``buf`` float64[k, n_channels] (the last k inputs) and ``head`` float64[1] (the slot to
read and overwrite next, an integer stored as float64 so that all effect state is float64).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from impact_env._jit import jit
from impact_env.config import ConfigError, check_range, doc_field
from impact_env.effects.effect import HARDWARE, Effect
from impact_env.effects.sensors import N_CHANNELS

REL_TOL = 1e-6
MAX_DELAY_SAMPLES = 100_000  # 10 s at 10 kHz


_f = doc_field


@dataclass(frozen=True)
class DelayConfig:
    """Transport delays of the sensor path and the actuator path (whole control periods)."""

    sensor_s: float = _f(0.0, "s", "sensor readings -> controller (ASSUMED 0: thesis gives no figure)")
    actuator_s: float = _f(0.0, "s", "force demand -> shaker (ASSUMED 0: thesis gives no figure)")

    def __post_init__(self):
        check_range("effects.delay.sensor_s", self.sensor_s, "s", 0.0, 10.0)
        check_range("effects.delay.actuator_s", self.actuator_s, "s", 0.0, 10.0)

    def samples(self, rate: float) -> tuple[int, int]:
        """(sensor, actuator) delays in samples at ``rate``; ConfigError if not representable."""
        return (delay_samples(self.sensor_s, rate, "effects.delay.sensor_s"),
                delay_samples(self.actuator_s, rate, "effects.delay.actuator_s"))


def delay_samples(delay_s: float, rate: float, name: str = "effects.delay") -> int:
    """Whole samples k for a delay of ``delay_s`` seconds at ``rate`` Hz (see the module's rule)."""
    check_range(name, delay_s, "s", 0.0)
    check_range("control.rate", rate, "Hz", 0.0, None, lo_open=True)
    exact = delay_s * rate
    k = int(round(exact))
    if abs(exact - k) > REL_TOL * max(1, k):
        lo, hi = int(np.floor(exact)), int(np.ceil(exact))
        raise ConfigError(
            f"{name} = {delay_s:g} s is not representable at control.rate = {rate:g} Hz: it is "
            f"{exact:g} control periods; use a whole multiple of {1.0 / rate:g} s "
            f"(e.g. {lo / rate:g} s or {hi / rate:g} s)")
    if k > MAX_DELAY_SAMPLES:
        raise ConfigError(f"{name} = {delay_s:g} s is {k} control periods at control.rate = {rate:g} Hz, "
                          f"more than {MAX_DELAY_SAMPLES} (the delay line's memory); shorten the delay")
    return k


def make_delay_state(k: int, n_channels: int, fill: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(buf float64[k, n_channels], head float64[1]) for a delay of k samples."""
    if k < 0 or n_channels < 1:
        raise ValueError(f"delay line needs k >= 0 samples and n_channels >= 1, got k={k}, n={n_channels}")
    buf = np.full((k, n_channels), float(fill))
    return buf, np.zeros(1)


def reset_delay_state(buf: np.ndarray, head: np.ndarray, fill=0.0) -> None:
    """Reset in place: every stored sample = ``fill`` (a float or float64[n_channels])."""
    buf[:] = fill
    head[0] = 0.0


@jit(inline="always")
def delay_step(buf, head, x, out):
    """Push ``x`` (float64[n_ch]) and write the input of k steps ago into ``out``; returns ``out``."""
    return _push(buf.reshape(buf.size), 0, buf.shape[0], head, x, out)  # (a view: buf is contiguous)


@jit(inline="always")
def _push(line, base, k, head, x, out):
    """:func:`delay_step` on a line of k rows held flat, row h at ``line[base + h n]`` (n =
    x's channels): the packed block's row is used as it is, where a reshape would cost a call
    into numba's helper every tick."""
    n = x.shape[0]
    if k == 0:
        for c in range(n):
            out[c] = x[c]
        return out
    h = int(head[0])
    for c in range(n):
        v = x[c]
        out[c] = line[base + h * n + c]
        line[base + h * n + c] = v
    h += 1
    head[0] = 0.0 if h == k else float(h)
    return out


@jit
def delay_block(buf, head, x, out):
    """:func:`delay_step` over a block: x, out float64[n_steps, n_ch].  Returns ``out``."""
    for n in range(x.shape[0]):
        delay_step(buf, head, x[n], out[n])
    return out


# -- packed block (one env's delay line inside a per-env row; see impact_env.hardware.blocks) ----
# parameters: [k, the delay in samples]; state: [head, the buffer's k_max * n_channels samples]

def block_sizes(k_max: int, n_channels: int) -> tuple[int, int]:
    """(parameter, state) sizes of a packed delay line of at most ``k_max`` samples."""
    return 1, 1 + k_max * n_channels


P_K = 0  # the packed block: [k]


def pack_params(k: int) -> np.ndarray:
    return np.array([float(k)])


@jit(inline="always")
def delay_packed(p, st, x, out):
    """:func:`delay_step` on a packed block: ``p`` = [k], ``st`` = [head, buffer]; x, out
    float64[n_ch] (they may be the same array)."""
    return _push(st, 1, int(p[P_K]), st[0:1], x, out)


def _packer(path: int, n_channels: int):
    """The packer of one path's delay line (``path``: 0 sensor, 1 actuator, as
    :meth:`DelayConfig.samples` orders them): [k] and a line of k samples of n_channels; an
    effect that is off gets k = 0 (the delays are checked either way)."""
    def pack(cfg: DelayConfig, rate: float, on: bool) -> tuple[np.ndarray, int]:
        k = cfg.samples(rate)[path]
        if not on:
            k = 0
        return pack_params(k), block_sizes(k, n_channels)[1]
    return pack


ACTUATOR_DELAY = Effect("actuator_delay", HARDWARE, "delay", DelayConfig, "the force command reaches the "
                        "plant whole control periods late", readings_only=False, pack=_packer(1, 1))
SENSOR_DELAY = Effect("sensor_delay", HARDWARE, "delay", DelayConfig, "the raw readings reach the controller "
                      "whole control periods late", readings_only=True, pack=_packer(0, N_CHANNELS))
