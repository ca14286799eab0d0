"""Hypothesis fuzz over every scene field (see tests/fuzz_scene.py): no traceback, no late
failure, every rejection a ConfigError naming the field.  The suite runs 150 cases; the
figures in the report come from ``python tests/fuzz_scene.py 3000``."""

from __future__ import annotations

import pytest
from fuzz_scene import FIELDS, cases, outcome
from hypothesis import HealthCheck, given, settings


@pytest.mark.slow
@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(case=cases)
def test_scene_fuzz(case):
    kind, detail = outcome(*case)
    assert kind != "FAILED", detail


def test_the_fuzz_covers_every_field():
    keys = {f[0] for f in FIELDS}
    assert {"effects.shaker.fir_taps", "effects.detector.threshold_n", "randomize.c", "integrator.dt",
            "effects.saturation.peak_n", "name"} <= keys
    assert len(keys) == len(FIELDS) > 90


@pytest.mark.parametrize("ov,field", [
    ({"effects.shaker.coil_resistance": 1e300}, "effects.shaker.coil_resistance"),
    ({"effects.shaker.lowpass_hz": 1e300}, "effects.shaker.lowpass_hz"),
    ({"effects.saturation.peak_n": 1e308, "effects.saturation.continuous_n": 1e308}, "effects.saturation"),
    ({"effects.shaker.model": "measured", "effects.shaker.fir_taps": [float("nan")]},
     "effects.shaker.fir_taps[0]"),
    ({"effects.detector.threshold_n": -5.0}, "effects.detector.threshold_n"),
    ({"effects.delay.sensor_s": 0.5, "control.rate": 1e6, "integrator.dt": 1e-6},
     "effects.delay.sensor_s"),
])
def test_the_issue_cases_are_rejected_at_load(ov, field):
    """The extreme-but-finite values that used to crash the env or compare late (or, for the
    NaN tap and the negative threshold, to run) are refused when the scene is built."""
    from impact_env.config import ConfigError
    from impact_env.scene import load_scene

    with pytest.raises(ConfigError, match=field.replace(".", r"\.").replace("[", r"\[").replace("]", r"\]")):
        load_scene("rig", ov)
