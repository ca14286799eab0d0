"""Contact detection from the sensors (thesis eq 4.4), and a scorer for any detector's output.

The rig decided contact from the accelerometer (a2) and the force transducer (T) with eq 4.4,
``m2' a2 + T > 0``: by Newton for the part of body 2 above the transducer the sum is the contact
force Phi (see :mod:`impact_env.effects.sensors` for the frame and signs).  Here the signal is

    s = top_mass * a2_meas + f_meas          (N; top_mass = the detector's value of m2')

and two modes are offered:

* ``level`` (default): contact while ``s > threshold_n``.  With the default 2 N, above body 1's
  weight (about 1 N for m1 = 0.1 kg), body 1 resting on the pad reads "no contact", as on the
  rig (sec 4.2); the value is otherwise an **assumption** (a few times the filtered force noise).
* ``derivative`` (``use_derivative = true``; the thesis: "the derivative ... made the edge ...
  very steep"): ``ds = (s[n] - s[n-1]) * rate`` (N/s, backward difference at the control rate)
  drives a latch: ``ds > derivative_threshold_n_per_s`` switches contact on, ``ds < -threshold``
  switches it off, anything between keeps the state.  Its release fires at the steepest drop of
  the force, before the true separation (the score reports it as negative lateness).  The
  default threshold 5e3 N/s is an **assumption** (impact slopes are about 5e4 N/s at 1 m/s).

State: float64[2] = (s at the previous sample N, latched contact 0/1).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.config import ConfigError, check_range, doc_field
from impact_env.effects.effect import CONTROLLER, Effect


class DetectorState(NamedTuple):
    """The state array's entries (float64[N_STATE])."""

    prev_signal: float  # N, the signal m2' a2 + f at the previous sample
    latch: float  # 1 while contact is detected, else 0


class DetectorParams(NamedTuple):
    """The parameter array's entries (float64[N_PARAM], :func:`detector_params`)."""

    top_mass: float  # kg, m2'
    threshold: float  # N, the level mode's threshold
    use_derivative: float  # 1: the derivative mode, 0: the level mode
    derivative_threshold: float  # N/s, the derivative mode's edge
    rate: float  # Hz, the control rate


DS = positions(DetectorState)
DP = positions(DetectorParams)
N_STATE = len(DS)
N_PARAM = len(DP)


_f = doc_field


@dataclass(frozen=True)
class DetectorConfig:
    """Contact detector on the (filtered, delayed) sensor readings."""

    top_mass: float = _f(0.1, "kg", "m2' used by the detector (ASSUMED, = effects.sensors.force.top_mass)")
    threshold_n: float = _f(2.0, "N", "level mode: contact while m2' a2 + f > threshold (ASSUMED)")
    use_derivative: bool = _f(False, "", "latch on the time derivative instead of the level")
    derivative_threshold_n_per_s: float = _f(5.0e3, "N/s", "derivative mode: edge threshold (ASSUMED)")

    def __post_init__(self):
        for name in ("use_derivative",):
            if not isinstance(getattr(self, name), bool):
                v = getattr(self, name)
                raise ConfigError(f"effects.detector.{name} must be true or false, got {v!r}")
        check_range("effects.detector.top_mass", self.top_mass, "kg", 0.0, 1e6)
        # a contact force is >= 0: a threshold below 0 would report contact with nothing touching
        check_range("effects.detector.threshold_n", self.threshold_n, "N", 0.0, 1e7)
        check_range("effects.detector.derivative_threshold_n_per_s", self.derivative_threshold_n_per_s,
                    "N/s", 0.0, 1e12, lo_open=True)


def detector_params(cfg: DetectorConfig, rate: float) -> np.ndarray:
    """float64[N_PARAM] (:class:`DetectorParams`) for :func:`detect`."""
    check_range("control.rate", rate, "Hz", 0.0, None, lo_open=True)
    return np.array(DetectorParams(top_mass=cfg.top_mass, threshold=cfg.threshold_n,
                                   use_derivative=1.0 if cfg.use_derivative else 0.0,
                                   derivative_threshold=cfg.derivative_threshold_n_per_s, rate=rate),
                    dtype=np.float64)


def make_detector_state(s0: float = 0.0) -> np.ndarray:
    """State float64[N_STATE] (:class:`DetectorState`): previous signal s0 (N), no contact."""
    return np.array(DetectorState(prev_signal=s0, latch=0.0), dtype=np.float64)


@jit(inline="always")
def detect(a2_meas, f_meas, state, params):
    """One sample: returns True while contact is detected; updates ``state``.

    a2_meas: measured acceleration of body 2 (m/s^2, down positive); f_meas: transducer reading
    (N, compression positive).
    """
    s = params[DP.top_mass] * a2_meas + f_meas
    if params[DP.use_derivative] == 0.0:
        on = s > params[DP.threshold]
        state[DS.latch] = 1.0 if on else 0.0
    else:
        ds = (s - state[DS.prev_signal]) * params[DP.rate]
        if ds > params[DP.derivative_threshold]:
            state[DS.latch] = 1.0
        elif ds < -params[DP.derivative_threshold]:
            state[DS.latch] = 0.0
    state[DS.prev_signal] = s
    return state[DS.latch] != 0.0


@jit
def detect_block(a2_meas, f_meas, state, params, out):
    """:func:`detect` over a block (float64[n] each); fills ``out`` (bool[n]).  Returns ``out``."""
    for n in range(a2_meas.shape[0]):
        out[n] = detect(a2_meas[n], f_meas[n], state, params)
    return out


@dataclass(frozen=True)
class DetectionScore:
    """How a detector's output compares with the true contact.  Times in s; lateness is
    detected edge time minus true edge time (negative = early); NaN where nothing to average."""

    false_contact_fraction: float  # of the samples without true contact, share detected as contact
    missed_contact_fraction: float  # of the samples with true contact, share detected as free
    onset_lateness_mean_s: float
    onset_lateness_max_s: float
    release_lateness_mean_s: float
    release_lateness_max_s: float
    n_onsets: int  # true onsets (rising edges)
    n_releases: int  # true releases (falling edges)
    missed_onsets: int  # true onsets with no detected onset in their window
    missed_releases: int
    false_onsets: int = 0  # detected onsets matched with no true onset (spurious detections)
    n_detected_onsets: int = 0


def _edges(x: np.ndarray, rising: bool) -> np.ndarray:
    d = np.diff(x.astype(np.int8))
    return np.flatnonzero(d == (1 if rising else -1)) + 1


def _lateness(true_edges, det_edges, all_true_edges, n):
    """Match each true edge with the nearest detected edge of the same kind lying strictly
    between the neighbouring true edges (of either kind); returns (lateness in samples, misses,
    number of detected edges matched with no true edge)."""
    late, missed, matched = [], 0, set()
    for i in true_edges:
        j = np.searchsorted(all_true_edges, i)
        lo = all_true_edges[j - 1] if j > 0 else -1
        hi = all_true_edges[j + 1] if j + 1 < len(all_true_edges) else n
        cand = det_edges[(det_edges > lo) & (det_edges < hi)]
        if cand.size == 0:
            missed += 1
            continue
        best = cand[np.argmin(np.abs(cand - i))]
        matched.add(int(best))
        late.append(best - i)
    return np.asarray(late, dtype=np.float64), missed, int(det_edges.size - len(matched))


def score_detection(true_contact, detected, rate: float) -> DetectionScore:
    """Score ``detected`` (bool[n]) against ``true_contact`` (bool[n]), both sampled at ``rate`` Hz.

    An edge at index i means the value changed between samples i-1 and i.  Each true onset
    (release) is matched with the nearest detected onset (release) between the true edges
    before and after it; an unmatched true edge counts as missed, an unmatched detected onset
    as a false one.
    """
    t = np.asarray(true_contact, dtype=bool)
    d = np.asarray(detected, dtype=bool)
    if t.shape != d.shape or t.ndim != 1:
        raise ValueError("true_contact and detected must be 1-d and of equal length, "
                         f"got {t.shape} and {d.shape}")
    check_range("rate", rate, "Hz", 0.0, None, lo_open=True)
    n_free, n_contact = int(np.sum(~t)), int(np.sum(t))
    fc = float(np.sum(d & ~t) / n_free) if n_free else float("nan")
    mc = float(np.sum(~d & t) / n_contact) if n_contact else float("nan")
    t_on, t_off = _edges(t, True), _edges(t, False)
    all_t = np.sort(np.concatenate([t_on, t_off]))
    d_on = _edges(d, True)
    on_late, on_miss, on_false = _lateness(t_on, d_on, all_t, t.size)
    off_late, off_miss, _off_false = _lateness(t_off, _edges(d, False), all_t, t.size)

    def stats(x):
        return (float(np.mean(x)) / rate, float(np.max(x)) / rate) if x.size else (float("nan"),) * 2

    on_mean, on_max = stats(on_late)
    off_mean, off_max = stats(off_late)
    return DetectionScore(fc, mc, on_mean, on_max, off_mean, off_max,
                          int(t_on.size), int(t_off.size), on_miss, off_miss, on_false, int(d_on.size))


# -- packed block: the parameters and state above, as they are (float64[5], float64[2]) ----------

def block_sizes() -> tuple[int, int]:
    """(parameter, state) sizes of the packed detector block."""
    return N_PARAM, N_STATE


EFFECT = Effect("detector", CONTROLLER, "detector", DetectorConfig,
                "contact from the sensors (thesis eq 4.4)", readings_only=True)
