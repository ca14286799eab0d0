"""Effect kernels: sensors, filters, delay, saturation, contact detector (impact_env.effects)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from impact_env.config import ConfigError, from_dict
from impact_env.effects import delay, detector, filters, saturation, sensors

RATE = 1.0e4


# -- filters ----------------------------------------------------------------------------------

@pytest.mark.parametrize("kind,order,low,high", [
    ("bandpass", 2, 20.0, 1000.0), ("bandpass", 1, 50.0, 300.0), ("bandpass", 4, 20.0, 4000.0),
    ("lowpass", 1, 20.0, 1000.0), ("lowpass", 3, 20.0, 200.0), ("none", 2, 20.0, 1000.0),
])
def test_filter_equals_scipy_sosfilt(kind, order, low, high):
    acc = filters.AccelerometerFilter(kind=kind, order=order, low_hz=low, high_hz=high)
    cfg = filters.FiltersConfig(accelerometer=acc)
    sos = filters.design_filters(cfg, RATE)
    zi = filters.make_filter_state(sos)
    x = np.random.default_rng(7).standard_normal((100_000, sensors.N_CHANNELS)) * 50.0
    y = np.empty_like(x)
    filters.filter_block(sos, zi, x[:60_000], y[:60_000])  # two blocks: the state carries over
    filters.filter_block(sos, zi, x[60_000:], y[60_000:])
    for c, ch in enumerate(cfg.channels()):
        ref = signal.sosfilt(filters.design_sos(ch, RATE), x[:, c])
        np.testing.assert_allclose(y[:, c], ref, rtol=0, atol=1e-12)
    if kind == "none":
        np.testing.assert_array_equal(y[:, 0], x[:, 0])


def test_filter_step_matches_block_and_reset_to_steady_state():
    cfg = filters.FiltersConfig()
    sos = filters.design_filters(cfg, RATE)
    x = np.random.default_rng(3).standard_normal((500, sensors.N_CHANNELS))
    zi1, zi2 = filters.make_filter_state(sos), filters.make_filter_state(sos)
    yb = filters.filter_block(sos, zi1, x, np.empty_like(x))
    out = np.empty(sensors.N_CHANNELS)
    for k in range(50):
        np.testing.assert_array_equal(filters.filter_step(sos, zi2, x[k], out), yb[k])
    # steady state for a constant input: the low-passed potentiometer passes 3 mm unchanged,
    # the band-passed channels give 0 (no DC)
    x0 = np.array([5.0, 2.0, 3e-3, 0.0])
    filters.reset_filter_state(zi1, sos, x0)
    y = filters.filter_block(sos, zi1, np.tile(x0, (200, 1)), np.empty((200, sensors.N_CHANNELS)))
    np.testing.assert_allclose(y[:, sensors.POT], 3e-3, rtol=1e-9)
    np.testing.assert_allclose(y[:, sensors.ACCEL], 0.0, atol=1e-9)
    filters.reset_filter_state(zi1, sos)
    assert not zi1.any()


@pytest.mark.parametrize("cfg", [filters.AccelerometerFilter(),
                                 filters.AccelerometerFilter(order=4, low_hz=50, high_hz=500),
                                 filters.PotentiometerFilter()])
def test_group_delay_against_scipy_and_phase_slope(cfg):
    sos = filters.design_sos(cfg, RATE)
    b, a = signal.sos2tf(sos)
    freqs = np.array([30.0, 100.0, 300.0, 800.0])
    ours = filters.group_delay_s(cfg, RATE, freqs)
    if len(a) <= 5:  # sos2tf of higher orders is too ill-conditioned for a reference
        _, ref = signal.group_delay((b, a), w=freqs, fs=RATE)
        np.testing.assert_allclose(ours, ref / RATE, rtol=1e-6)
    # minus the slope of the unwrapped phase, by central differences
    h = 1e-3
    _, hz = signal.sosfreqz(sos, worN=np.concatenate([freqs - h, freqs + h]), fs=RATE)
    ph = np.unwrap(np.angle(hz).reshape(2, -1), axis=0)
    slope = -(ph[1] - ph[0]) / (2 * np.pi * 2 * h)
    np.testing.assert_allclose(ours, slope, rtol=1e-5)
    centre = filters.group_delay_s(cfg, RATE)
    assert isinstance(centre, float) and 0 < centre < 0.01
    if cfg.kind == "bandpass":
        assert filters.passband_centre_hz(cfg) == pytest.approx(math.sqrt(cfg.low_hz * cfg.high_hz))


# -- sensors ----------------------------------------------------------------------------------

def _ideal(noise=0.0, offset=0.0, bits=0, rng_=1.0, gain=1.0, enabled=True):
    ch = sensors.AccelerometerConfig(noise_std=noise, offset=offset, adc_bits=bits, adc_range=rng_,
                               gain=gain, enabled=enabled)
    return sensors.SensorsConfig(accelerometer=ch)


def test_noise_same_seed_same_noise_different_seed_different():
    p = sensors.sensor_params(sensors.SensorsConfig())
    truth = np.tile([10.0, 5.0, 1e-3, 0.02], (1000, 1))

    def run(seed):
        z = sensors.draw_noise(np.random.default_rng(seed), 1000)
        return sensors.sense_block(truth, z, p, np.empty_like(truth))

    a, b, c = run(42), run(42), run(43)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a[:, :3], c[:, :3])
    assert np.all(a[:, sensors.BODY1] == 0.0)  # disabled by default: reads 0


def test_noise_statistics_as_configured():
    n = 200_000
    p = sensors.sensor_params(_ideal(noise=0.5, offset=0.3))
    z = sensors.draw_noise(np.random.default_rng(0), n)
    channels = sensors.N_CHANNELS
    y = sensors.sense_block(np.zeros((n, channels)), z, p, np.empty((n, channels)))[:, sensors.ACCEL]
    assert abs(y.mean() - 0.3) < 5 * 0.5 / math.sqrt(n)
    assert y.std() == pytest.approx(0.5, rel=0.01)
    # gain applies to the true value, not the noise
    p = sensors.sensor_params(_ideal(gain=2.0, offset=-1.0))
    out = sensors.sense(np.array([3.0, 0, 0, 0]), np.zeros(4), p, np.empty(4))
    assert out[sensors.ACCEL] == 5.0


def test_quantisation_step_midtread_and_clipping():
    cfg = _ideal(bits=4, rng_=1.0)
    q = cfg.accelerometer.quantum
    assert q == 0.125
    p = sensors.sensor_params(cfg)
    x = np.linspace(-1.5, 1.5, 3001)
    truth = np.zeros((x.size, 4))
    truth[:, 0] = x
    y = sensors.sense_block(truth, np.zeros_like(truth), p, np.empty_like(truth))[:, 0]
    levels = np.unique(y)
    np.testing.assert_allclose(np.diff(levels), q)
    assert levels.min() == -1.0 and levels.max() == 1.0 - q  # 16 codes, two's complement
    inside = (x > -1.0) & (x < 1.0 - q)
    assert np.max(np.abs(y[inside] - x[inside])) <= q / 2 + 1e-15
    assert np.all(y[np.abs(x) < q / 2 - 1e-12] == 0.0)  # mid-tread: zero is a level
    assert sensors.sensor_params(sensors.SensorsConfig())[sensors.FORCE,
                                                          sensors.CP.adc_step] == 1000.0 / 2**16


def test_true_readings_transducer_force_and_eq_4_4():
    out = np.empty(4)
    m2p, phi, a2 = 0.1, 50.0, 30.0
    sensors.true_readings(0.002, 0.001, a2, phi, m2p, out)
    assert out[sensors.FORCE] == pytest.approx(phi - m2p * a2)
    # eq 4.4 recovers the contact force
    assert m2p * out[sensors.ACCEL] + out[sensors.FORCE] == pytest.approx(phi)
    assert (out[sensors.POT], out[sensors.BODY1]) == (0.001, 0.002)


# -- delay ------------------------------------------------------------------------------------

@pytest.mark.parametrize("k", [0, 1, 3, 17])
def test_delay_shifts_by_exactly_k_samples(k):
    x = np.random.default_rng(k).standard_normal((300, 3))
    buf, head = delay.make_delay_state(k, 3, fill=-7.0)
    y = delay.delay_block(buf, head, x, np.empty_like(x))
    np.testing.assert_array_equal(y[k:], x[: x.shape[0] - k])
    assert np.all(y[:k] == -7.0)
    delay.reset_delay_state(buf, head)
    out = np.empty(3)
    for n in range(k):
        assert np.all(delay.delay_step(buf, head, x[n], out) == 0.0)
    np.testing.assert_array_equal(delay.delay_step(buf, head, x[k], out), x[0])


def test_delay_seconds_to_samples():
    assert delay.delay_samples(3e-4, RATE) == 3
    assert delay.delay_samples(0.0, RATE) == 0
    assert delay.DelayConfig(sensor_s=2e-4, actuator_s=1e-4).samples(RATE) == (2, 1)
    assert delay.delay_samples(0.1 + 1e-13, RATE) == 1000  # rounding noise is tolerated


# -- saturation -------------------------------------------------------------------------------

@settings(deadline=None, max_examples=60)
@given(cmd=st.lists(st.floats(-1e4, 1e4, allow_nan=False), min_size=1, max_size=300),
       peak=st.floats(1.0, 500.0), frac=st.floats(0.0, 1.0), tau=st.floats(1e-4, 1.0),
       slew=st.one_of(st.just(0.0), st.floats(1e3, 1e7)))
def test_saturation_never_exceeded(cmd, peak, frac, tau, slew):
    cfg = saturation.SaturationConfig(peak_n=peak, continuous_n=frac * peak, tau_s=tau, slew_n_per_s=slew)
    p = saturation.saturation_params(cfg, RATE)
    state = saturation.make_saturation_state()
    cmd = np.asarray(cmd)
    f = np.empty_like(cmd)
    flags = np.empty(cmd.size, dtype=bool)
    saturation.saturate_block(cmd, state, p, f, flags)
    assert np.all(np.abs(f) <= peak)
    np.testing.assert_array_equal(flags, f != cmd)
    # the mean-square budget, recomputed outside the kernel
    alpha, ms, r2 = p[saturation.SP.alpha], 0.0, cfg.rms_limit_n**2
    for v in f:
        ms += alpha * (v * v - ms)
        if cfg.continuous_n > 0:
            assert ms <= r2 * (1 + 1e-9)
    if cfg.continuous_n == 0 and slew > 0:  # no budget: the slew limit always holds
        steps = np.abs(np.diff(np.concatenate([[0.0], f])))
        assert np.all(steps <= slew / RATE * (1 + 1e-12))


def test_slew_rate_respected():
    cfg = saturation.SaturationConfig(slew_n_per_s=1e5, continuous_n=0.0)  # 10 N per sample at 10 kHz
    p = saturation.saturation_params(cfg, RATE)
    cmd = np.concatenate([np.full(50, 150.0), np.full(50, -150.0), np.zeros(50)])
    f = saturation.saturate_block(cmd, saturation.make_saturation_state(), p, np.empty_like(cmd),
                                  np.empty(150, bool))
    assert np.max(np.abs(np.diff(np.concatenate([[0.0], f])))) <= 10.0 + 1e-9
    assert f[14] == 150.0 and f[49] == 150.0 and f[99] == -150.0 and f[149] == 0.0
    assert f[0] == 10.0


def test_rms_budget_engages_after_sustained_overrating_command():
    cfg = saturation.SaturationConfig()  # 200 N peak, 98 N sine peak continuous, tau 0.1 s
    p = saturation.saturation_params(cfg, RATE)
    r = cfg.rms_limit_n
    # a short 200 N pulse (longer than a contact) passes untouched
    f = saturation.saturate_block(np.full(40, 200.0), saturation.make_saturation_state(), p, np.empty(40),
                                  np.empty(40, bool))
    assert np.all(f == 200.0)
    # a sustained 150 N command is limited to the RMS rating once the budget is spent:
    # expected after -tau ln(1 - R^2/150^2) = 24 ms
    n = 5000
    flags = np.empty(n, bool)
    f = saturation.saturate_block(np.full(n, 150.0), saturation.make_saturation_state(), p, np.empty(n),
                                  flags)
    first = np.argmax(flags) / RATE
    assert 0.022 < first < 0.026
    assert not flags[: int(0.02 * RATE)].any() and flags[int(0.03 * RATE):].all()
    assert f[-1] == pytest.approx(r, rel=1e-3)
    # a NaN command gives 0 N, flagged
    assert saturation.saturate(float("nan"), saturation.make_saturation_state(), p) == (0.0, True)


# -- detector ---------------------------------------------------------------------------------

def _synthetic_drop(rate=RATE, noise=0.0, seed=0):
    """Three Hertz-like pulses (Phi = F sin^1.5, ~4 ms) under a 50 Hz shaker force, measured
    through true_readings; returns (true contact, a2 reading, transducer reading)."""
    n = int(0.1 * rate)
    t = np.arange(n) / rate
    phi = np.zeros(n)
    for t0, dur, fmax in [(0.010, 0.0037, 90.0), (0.040, 0.0030, 40.0), (0.070, 0.0025, 15.0)]:
        m = (t > t0) & (t < t0 + dur)
        phi[m] = fmax * np.sin(np.pi * (t[m] - t0) / dur) ** 1.5
    f2 = 20.0 * np.sin(2 * np.pi * 50.0 * t)
    m2, m2p = 1.0, 0.1
    a2 = (phi - f2) / m2
    truth = np.zeros((n, 4))
    for k in range(n):
        sensors.true_readings(0.0, 0.0, a2[k], phi[k], m2p, truth[k])
    rng = np.random.default_rng(seed)
    meas = truth + noise * rng.standard_normal(truth.shape)
    return phi > 0, meas[:, sensors.ACCEL], meas[:, sensors.FORCE]


def test_detector_level_mode_on_synthetic_signal():
    true, a2, fm = _synthetic_drop()
    cfg = detector.DetectorConfig()
    det = detector.detect_block(a2, fm, detector.make_detector_state(), detector.detector_params(cfg, RATE),
                          np.empty(a2.size, bool))
    sc = detector.score_detection(true, det, RATE)
    assert sc.n_onsets == 3 and sc.missed_onsets == 0 and sc.missed_releases == 0
    assert sc.false_contact_fraction == 0.0  # 2 N threshold: shaker force alone never triggers
    assert 0.0 <= sc.onset_lateness_mean_s <= sc.onset_lateness_max_s < 6e-4
    assert -6e-4 < sc.release_lateness_mean_s <= 0.0
    assert sc.missed_contact_fraction < 0.25


def test_detector_derivative_latch_on_synthetic_signal():
    true, a2, fm = _synthetic_drop()
    cfg = detector.DetectorConfig(use_derivative=True, derivative_threshold_n_per_s=5e3)
    det = detector.detect_block(a2, fm, detector.make_detector_state(), detector.detector_params(cfg, RATE),
                          np.empty(a2.size, bool))
    sc = detector.score_detection(true, det, RATE)
    assert sc.missed_onsets == 0 and sc.missed_releases == 0
    assert sc.onset_lateness_max_s <= 3.0 / RATE  # steep edge: within a few samples
    assert sc.release_lateness_max_s < 0.0  # releases at the steepest drop, before separation
    assert sc.false_contact_fraction == 0.0


def test_score_detection_known_shift():
    true = np.zeros(60, bool)
    true[10:20] = True
    true[40:50] = True
    det = np.roll(true, 2)
    sc = detector.score_detection(true, det, 1000.0)
    assert sc.onset_lateness_mean_s == sc.onset_lateness_max_s == pytest.approx(0.002)
    assert sc.release_lateness_mean_s == pytest.approx(0.002)
    assert sc.false_contact_fraction == pytest.approx(4 / 40)
    assert sc.missed_contact_fraction == pytest.approx(4 / 20)
    sc = detector.score_detection(true, np.zeros(60, bool), 1000.0)
    assert sc.missed_onsets == 2 and math.isnan(sc.onset_lateness_mean_s)


# -- validation -------------------------------------------------------------------------------

@pytest.mark.parametrize("make,field", [
    (lambda: filters.design_sos(filters.AccelerometerFilter(high_hz=5000.0), RATE),
     "effects.filters.accelerometer.high_hz"),
    (lambda: filters.FiltersConfig(force=filters.ForceFilter(kind="lowpass",
                                                             high_hz=6000.0)).check_rate(RATE),
     "effects.filters.force.high_hz"),
    (lambda: filters.AccelerometerFilter(low_hz=1000.0, high_hz=1000.0),
     "effects.filters.accelerometer.low_hz"),
    (lambda: filters.PotentiometerFilter(kind="band"), "effects.filters.potentiometer.kind"),
    (lambda: filters.ForceFilter(order=0), "effects.filters.force.order"),
    (lambda: sensors.AccelerometerConfig(noise_std=-0.1), "effects.sensors.accelerometer.noise_std"),
    (lambda: sensors.PotentiometerConfig(adc_bits=40), "effects.sensors.potentiometer.adc_bits"),
    (lambda: sensors.ForceTransducerConfig(adc_range=0.0), "effects.sensors.force.adc_range"),
    (lambda: from_dict(sensors.SensorsConfig, {"force": {"noise_std": -1.0}}, "effects.sensors"),
     "effects.sensors.force.noise_std"),
    (lambda: from_dict(sensors.SensorsConfig, {"acelerometer": {}}, "effects.sensors"),
     "effects.sensors.acelerometer"),
    (lambda: sensors.channel_index("forse", "effects.detector.channel"), "effects.detector.channel"),
    (lambda: delay.DelayConfig(sensor_s=-1e-4), "effects.delay.sensor_s"),
    (lambda: delay.DelayConfig(actuator_s=1.5e-4).samples(RATE), "effects.delay.actuator_s"),
    (lambda: delay.delay_samples(5e-5, RATE, "effects.delay.sensor_s"), "effects.delay.sensor_s"),
    (lambda: saturation.SaturationConfig(continuous_n=300.0), "effects.saturation.continuous_n"),
    (lambda: saturation.SaturationConfig(slew_n_per_s=-1.0), "effects.saturation.slew_n_per_s"),
    (lambda: detector.DetectorConfig(derivative_threshold_n_per_s=0.0),
     "effects.detector.derivative_threshold_n_per_s"),
])
def test_bad_inputs_raise_config_error_naming_the_field(make, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        make()


def test_unrepresentable_delay_message_says_why():
    with pytest.raises(ConfigError, match="not representable at control.rate"):
        delay.delay_samples(1.5e-5, RATE, "effects.delay.sensor_s")


def test_nyquist_message_names_rate():
    with pytest.raises(ConfigError, match="Nyquist"):
        filters.AccelerometerFilter().check_rate(1500.0)  # 1000 Hz edge >= 750 Hz


def test_every_list_of_effects_is_derived_from_the_registry():
    """Each effect declares itself once (impact_env.effects.registry); the scene's names and
    sections, both sides' flag words, the hardware stage's blocks and their sizes, and the
    oracle's readings-only list are read from it."""
    import dataclasses

    from impact_env.effects import registry
    from impact_env.eval.oracle import SENSOR_SIDE
    from impact_env.hardware import stage
    from impact_env.hardware.batch import Hardware
    from impact_env.scene import load_scene
    from impact_env.scene.effects import EFFECTS, EffectsConfig

    assert EFFECTS == registry.NAMES and len(set(EFFECTS)) == len(EFFECTS)
    sections = {f.name: f.default_factory for f in dataclasses.fields(EffectsConfig)}
    assert all(sections[e.section] is e.config for e in registry.REGISTRY)
    for which in (registry.HARDWARE, registry.CONTROLLER):
        bits = [registry.flag(e.name) for e in registry.side(which)]
        bits += [registry.option_flag(e.name, o) for e in registry.side(which) for o in e.options]
        assert len(set(bits)) == len(bits) and all(b > 0 and not b & (b - 1) for b in bits), which
    # the bits are fixed numbers (kernels, the C export and rig logs read them): adding an effect moves none
    pinned = {"actuator_delay": 1, "shaker": 2, "saturation": 4, "sensors": 8, "sensor_delay": 16,
              "filters": 1, "detector": 2}
    assert {name: registry.flag(name) for name in pinned} == pinned
    assert registry.option_flag("shaker", "back_emf") == 32
    hw = registry.side(registry.HARDWARE)
    assert stage.PARAM_BLOCKS == ("drive",) + tuple(e.name for e in hw)
    assert stage.STATE_BLOCKS == tuple(e.name for e in hw)
    scene = load_scene("rig-randomized", {"effects.shaker.back_emf": True})
    hard = Hardware(scene, 1)
    assert hard.flags == sum(registry.flag(e.name) for e in hw if scene.effects.on(e.name)) + stage.F_BACK_EMF
    for e in hw:  # each block as big as the effect's packer says (the largest over the ranges)
        assert e.pack is not None
        p, s = e.pack(getattr(scene.effects, e.section), hard.rate, scene.effects.on(e.name))
        assert hard.param_block(e.name).shape[1] == p.size and hard.state_block(e.name).shape[1] >= s
    assert SENSOR_SIDE == registry.READINGS_ONLY


def test_a_flag_bit_given_twice_is_refused(monkeypatch):
    from impact_env.effects import registry

    monkeypatch.setitem(registry._FLAG, "saturation", registry.flag("shaker"))
    with pytest.raises(ValueError, match="distinct powers of two"):
        registry._check()


def test_every_effect_module_is_in_the_registry():
    """A module of impact_env/effects/ that declares an Effect is listed in the registry (a new
    effect's module without its registry line fails here), and the docs' table of effects is the
    one the registry writes (``python scripts/docs_tables.py`` rewrites it)."""
    import importlib
    import pkgutil
    from pathlib import Path

    import impact_env.effects as pkg
    from impact_env.effects import registry
    from impact_env.effects.effect import Effect

    declared = []
    for mod in pkgutil.iter_modules(pkg.__path__):
        m = importlib.import_module(f"impact_env.effects.{mod.name}")
        declared += [
            v for k, v in vars(m).items() if isinstance(v, Effect) and m.__name__ != registry.__name__
        ]
    assert set(declared) == set(registry.REGISTRY)
    docs = (Path(__file__).resolve().parents[1] / "docs" / "scenes.md").read_text()
    assert registry.markdown_table() in docs, "docs/scenes.md: stale effects table (scripts/docs_tables.py)"
