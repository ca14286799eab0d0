"""The C export's float32 filter structure (:func:`impact_env.effects.filters.tpt_sections`): the
trapezoidal SVF realises every section's transfer function (oracle: ``scipy.signal.sosfilt`` in
double), and in float32 it departs from the double filter far less than transposed direct form II
on the rig's band-pass (the reason it is used).  The recursion below is the generated C's, line for
line; ``tests/test_c_export.py`` runs the C itself."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from impact_env.config import ConfigError
from impact_env.effects.filters import IDENTITY_SECTION, FilterConfig, design_sos, tpt_sections

RATE = 10_000.0


def tpt_run(sections: np.ndarray, x: np.ndarray, dtype) -> np.ndarray:
    t = np.asarray(tpt_sections(sections), dtype=dtype)
    y = np.asarray(x, dtype=dtype).copy()
    two = dtype(2.0)
    for c1, c2, c3, m0, m1, m2 in t:
        s1 = s2 = dtype(0.0)
        for i, v in enumerate(y):
            v3 = v - s2
            v1 = c1 * s1 + c2 * v3
            v2 = s2 + c2 * s1 + c3 * v3
            s1 = two * v1 - s1
            s2 = two * v2 - s2
            y[i] = m0 * v + m1 * v1 + m2 * v2
    return y


def tdf2_run(sections: np.ndarray, x: np.ndarray, dtype) -> np.ndarray:
    y = np.asarray(x, dtype=dtype).copy()
    for b0, b1, b2, _a0, a1, a2 in np.asarray(sections, dtype=dtype):
        z0 = z1 = dtype(0.0)
        for i, v in enumerate(y):
            o = b0 * v + z0
            z0 = b1 * v - a1 * o + z1
            z1 = b2 * v - a2 * o
            y[i] = o
    return y


def impacts(n: int = 2500, seed: int = 0) -> np.ndarray:
    """An accelerometer-like signal: a DC offset, 1 m/s^2 noise and three impact pulses of a few
    hundred m/s^2 lasting about 0.3 ms."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE
    x = 3.0 + rng.normal(0.0, 1.0, n)
    for t0, amp in ((0.01, 280.0), (0.05, -150.0), (0.12, 90.0)):
        x += amp * np.exp(-0.5 * ((t - t0) / 1e-4) ** 2)
    return x


CASES = {
    "band-pass 20-1000 Hz order 2 (the rig's)": FilterConfig(),
    "band-pass 5-2000 Hz order 3": FilterConfig(low_hz=5.0, high_hz=2000.0, order=3),
    "low-pass 1000 Hz order 3 (a first-order section)": FilterConfig(kind="lowpass", order=3),
    "low-pass 50 Hz order 4": FilterConfig(kind="lowpass", high_hz=50.0, order=4),
}


@pytest.mark.parametrize("name", list(CASES))
def test_tpt_is_the_same_filter_in_double(name):
    sos = design_sos(CASES[name], RATE)
    x = impacts()
    ref = signal.sosfilt(sos, x)
    got = tpt_run(sos, x, np.float64)
    # both are double recursions of the same stable filter: they differ by rounding (~1e-16 of the
    # signal's scale) times the noise gain of the slowest section, at most ~1e4 here
    assert np.max(np.abs(got - ref)) <= 1e-16 * 1e4 * np.max(np.abs(x)) * 10


def test_identity_section_passes_the_signal_exactly():
    x = impacts()
    assert np.array_equal(tpt_run(np.array([IDENTITY_SECTION]), x, np.float32), x.astype(np.float32))
    assert np.array_equal(tpt_run(np.array([IDENTITY_SECTION]), x, np.float64), x)


def test_float32_departs_far_less_than_direct_form_on_the_rigs_band_pass():
    sos = design_sos(FilterConfig(), RATE)
    x = impacts()
    ref = signal.sosfilt(sos, x)
    err_df = np.max(np.abs(tdf2_run(sos, x, np.float32) - ref))
    err_tpt = np.max(np.abs(tpt_run(sos, x, np.float32) - ref))
    # IEEE float32 arithmetic in numpy is exactly rounded, so both figures are the same on every
    # machine; the factor 10 is far below the 40-100x seen on the rig's drops (docs/rig/c-export.md)
    assert err_tpt * 10 < err_df, (err_tpt, err_df)
    # and the SVF's error is of the order of float32's resolution of the signal, times a small gain
    assert err_tpt < 1e3 * np.finfo(np.float32).eps * np.max(np.abs(x)), err_tpt


@pytest.mark.parametrize("a", [(1.0, -2.0, 1.0), (1.0, 2.0, 1.0), (1.0, -2.1, 1.2), (2.0, 0.0, 0.0)])
def test_sections_it_cannot_realise_are_refused(a):
    with pytest.raises(ConfigError, match="tpt_sections"):
        tpt_sections(np.array([[1.0, 0.0, 0.0, *a]]))
