"""The target's safety layer (impact_env.rig.safety): each rule and its boundaries, against a
plain-Python reference for the RMS window."""

from __future__ import annotations

import math
from collections import deque

import numpy as np
import pytest

from impact_env.config import ConfigError
from impact_env.rig import safety

RATE = 1.0e4
SCALE = 200.0


def layer(hold=1, mode="host", **cfg):
    return safety.SafetyLayer(
        safety.SafetyConfig(**cfg), command_scale=SCALE, rate=RATE, hold_ticks=hold, mode=mode
    )


# -- watchdog and first command -----------------------------------------------------------------------
@pytest.mark.parametrize("hold", [1, 3, 10])
def test_watchdog_holds_repeats_once_then_zeroes_at_exactly_two_periods(hold):
    s = layer(hold)
    for age in range(0, 3 * hold + 2):
        f, st = s.step(0.25, age, age, 0.0)
        if age < hold:
            assert (f, st) == (50.0, 0), age
        elif age < 2 * hold:
            assert (f, st) == (50.0, safety.REPEATED), age
        else:
            assert (f, st) == (0.0, safety.WATCHDOG), age
    assert s.counters()["watchdog_trips"] == 1
    assert s.step(0.25, 0, 99, 0.0) == (50.0, 0)  # a fresh command restores the force (not latched)
    s.step(0.25, 2 * hold, 99, 0.0)
    assert s.counters()["watchdog_trips"] == 2


def test_force_is_zero_within_two_policy_periods_of_the_last_command():
    """A host that stops after a random number of steps: from the tick 2 H after its last
    command's first tick on, the force is exactly 0 (the target loop ages the command by one per
    tick and resets the age when a new command is taken)."""
    rng = np.random.default_rng(4)
    for hold in (1, 2, 7, 10):
        s = layer(hold)
        last_step = int(rng.integers(1, 20))
        age, t_last = -1, None
        for tick in range(0, (last_step + 5) * hold):
            if tick % hold == 0 and tick // hold <= last_step:
                age, t_last = 0, tick  # the command of this policy step arrives on time
            f, st = s.step(float(rng.uniform(0.1, 1.0)), age, tick, 0.0)
            if tick >= t_last + 2 * hold:
                assert f == 0.0 and st & safety.WATCHDOG, (hold, tick)
            else:
                assert f > 0.0
            age += 1


def test_first_command_timeout_boundary():
    s = layer(hold=10)
    limit = math.ceil(s.cfg.first_command_timeout_s * RATE)
    assert limit == 1000
    assert s.step(0.5, -1, limit - 1, 0.0) == (0.0, safety.NO_COMMAND)
    assert s.step(0.5, -1, limit, 0.0) == (0.0, safety.NO_COMMAND | safety.FIRST_COMMAND_TIMEOUT)
    assert s.step(0.5, 0, limit + 1, 0.0) == (100.0, 0)  # a command after it still counts: the loop disarms
    short = layer(first_command_timeout_s=2.5e-4)  # 2.5 ticks -> 3
    assert short.step(0.0, -1, 2, 0.0)[1] == safety.NO_COMMAND
    assert short.step(0.0, -1, 3, 0.0)[1] & safety.FIRST_COMMAND_TIMEOUT


def test_onboard_mode_has_no_watchdog():
    s = layer(hold=2, mode="onboard")
    assert s.step(0.5, -1, 10**6, 0.0) == (100.0, 0)
    assert s.step(0.5, 10**6, 10**6, 0.0) == (100.0, 0)


# -- non-finite commands --------------------------------------------------------------------------------
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1e308])
def test_nonfinite_demand_is_zeroed_and_marked_not_latched(bad):
    s = layer()
    assert s.step(bad, 0, 0, 0.0) == (0.0, safety.NONFINITE)
    assert s.step(0.1, 0, 1, 0.0) == (20.0, 0)
    assert s.counters()["nonfinite_ticks"] == 1


def test_nonfinite_stale_command_is_not_counted_when_the_watchdog_zeroes_it():
    s = layer(hold=1)
    assert s.step(math.nan, 2, 2, 0.0) == (0.0, safety.WATCHDOG)


# -- travel limit ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_travel_limit_latches_until_a_new_episode(sign):
    s = layer()
    lim = s.cfg.travel_limit_m
    assert lim == 7.0e-3
    assert s.step(0.5, 0, 0, sign * lim) == (100.0, 0)  # at the limit: allowed
    assert s.step(0.5, 0, 1, sign * np.nextafter(lim, 1.0)) == (0.0, safety.TRAVEL)
    assert s.step(0.5, 0, 2, 0.0) == (0.0, safety.TRAVEL)  # back inside: still off
    assert s.step(-0.5, 0, 3, -sign * 0.5 * lim) == (0.0, safety.TRAVEL)  # a restoring command too
    assert s.counters()["travel_trips"] == 1 and s.latched == safety.TRAVEL
    s.new_episode()
    assert s.step(0.5, 0, 0, 0.0) == (100.0, 0) and s.counters()["travel_trips"] == 0


def test_nonfinite_potentiometer_is_a_sensor_fault_for_its_tick():
    """A caller without the plausibility check (impact_env.control.plausibility) hands a NaN x2
    straight in: 0 N and the potentiometer's fault bits for that tick, not latched (the check's
    SENSOR_TIMEOUT is what ends an episode); the travel limit still latches."""
    s = layer()
    bad = safety.SENSOR_FAULT | safety.SENSOR_POTENTIOMETER
    assert s.step(0.5, 0, 0, math.nan) == (0.0, bad)
    assert s.step(0.5, 0, 1, 0.0) == (100.0, 0)
    f, st = s.step(0.5, 0, 2, 1.0)
    assert f == 0.0 and st == safety.TRAVEL
    assert s.counters()["sensor_fault_ticks"] == 1


@pytest.mark.parametrize(
    "bits",
    [
        safety.SENSOR_FAULT | safety.SENSOR_FORCE,
        safety.SENSOR_FAULT | safety.SENSOR_TIMEOUT | safety.SENSOR_ACCELEROMETER,
    ],
)
def test_sensor_bits_zero_the_tick_before_the_clamps(bits):
    """The plausibility check's bits: 0 N on that tick (the RMS ledger gets a 0), the bits
    reported; the next clean tick acts again."""
    s = layer(rms_window_s=0.001)
    assert s.step(1.0, 0, 0, 0.0, bits) == (0.0, bits)
    assert s.window_rms_n == 0.0
    assert s.step(0.25, 0, 1, 0.0) == (50.0, 0)


# -- force clamps ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("demand,force,bits", [
    (1.0, 200.0, 0), (-1.0, -200.0, 0), (1.5, 200.0, safety.CLAMP_PEAK), (-7.0, -200.0, safety.CLAMP_PEAK),
    (0.0, 0.0, 0)])
def test_peak_clamp(demand, force, bits):
    assert layer().step(demand, 0, 0, 0.0) == (force, bits)


def test_peak_below_command_scale():
    s = layer(peak_n=150.0, continuous_n=98.0)
    assert s.step(0.9, 0, 0, 0.0) == (150.0, safety.CLAMP_PEAK)


def naive_rms_clamp(forces, n, rms2):
    """Reference: f_k^2 <= n R^2 - (sum of the n-1 applied squares before it), plain floats."""
    hist: deque[float] = deque(maxlen=n - 1) if n > 1 else deque(maxlen=0)
    out = []
    for f in forces:
        room = max(n * rms2 - math.fsum(hist), 0.0)
        g = f if f * f <= room else math.copysign(math.sqrt(room), f)
        out.append(g)
        if n > 1:
            hist.append(g * g)
    return np.array(out)


@pytest.mark.parametrize("window_s", [1e-4, 0.01, 0.0537])
def test_rms_clamp_equals_reference(window_s):
    rng = np.random.default_rng(11)
    n = max(1, round(window_s * RATE))
    s = layer(rms_window_s=window_s, peak_n=200.0, continuous_n=98.0)
    # bursts of full-scale demand between quiet stretches, and noise
    demand = np.concatenate([np.full(3 * n, 1.0), rng.uniform(-1, 1, 4 * n), np.zeros(n),
                             np.full(2 * n, -1.0)])
    out = np.array([s.step(d, 0, k, 0.0)[0] for k, d in enumerate(demand)])
    ref = naive_rms_clamp(demand * SCALE, n, safety.SafetyConfig().rms_limit_n ** 2)
    q = s.params[safety.PARAM.quantum]
    np.testing.assert_array_less(np.abs(out**2 - ref**2), (n + 2) * q)  # squares kept to a quantum each
    # the RMS over every window of n ticks respects the rating (to the quanta)
    sq = np.concatenate([np.zeros(n - 1), out**2])
    win = np.convolve(sq, np.ones(n), mode="valid") / n
    assert win.max() <= safety.SafetyConfig().rms_limit_n ** 2 + (n + 2) * q / n
    assert s.counters()["clamp_rms_ticks"] > 0


def test_full_scale_command_lasts_its_budget_then_the_window_rms_stays_at_the_rating():
    window_s = 0.05  # 500 ticks: a 200 N command fits for floor(500 * 69.3^2 / 200^2) = 60 ticks
    s = layer(rms_window_s=window_s)
    n = 500
    out = [s.step(1.0, 0, k, 0.0) for k in range(3 * n)]
    forces = np.array([f for f, _ in out])
    full = int(np.sum(forces[:n] == 200.0))
    # a boxcar budget: the pulse comes back when its first ticks leave the window
    assert int(np.sum(forces == 200.0)) == 3 * full
    assert full == math.floor(n * safety.SafetyConfig().rms_limit_n ** 2 / 200.0**2) == 60
    assert out[full][1] == safety.CLAMP_RMS and out[full - 1][1] == 0
    assert s.window_rms_n == pytest.approx(safety.SafetyConfig().rms_limit_n, rel=1e-6)
    s.drain(n)  # a window's worth of idle ticks: cool again
    assert s.window_rms_n == 0.0
    assert s.step(1.0, 0, 0, 0.0) == (200.0, 0)


def test_new_episode_keeps_the_window():
    s = layer(rms_window_s=0.01)
    for k in range(200):
        s.step(1.0, 0, k, 0.0)
    rms = s.window_rms_n
    s.new_episode()
    assert s.window_rms_n == rms > 0 and s.counters() == dict.fromkeys(safety.COUNTERS, 0)


def test_continuous_zero_turns_the_rms_clamp_off():
    s = layer(continuous_n=0.0, rms_window_s=0.001)
    assert all(s.step(1.0, 0, k, 0.0) == (200.0, 0) for k in range(100))


# -- config, params, helpers ----------------------------------------------------------------------------
@pytest.mark.parametrize("kw,match", [
    ({"peak_n": 0.0}, r"safety.peak_n = 0.0 N is out of range: must be > 0 N"),
    ({"continuous_n": 250.0}, r"safety.continuous_n = 250.0 N is out of range: must be >= 0 N and <= 200 N"),
    ({"rms_window_s": -1.0}, "safety.rms_window_s"),
    ({"travel_limit_m": math.nan}, "safety.travel_limit_m"),
    ({"first_command_timeout_s": 0.0}, "safety.first_command_timeout_s"),
])
def test_config_errors_name_the_field_and_unit(kw, match):
    with pytest.raises(ConfigError, match=match):
        safety.SafetyConfig(**kw)


@pytest.mark.parametrize("args,match", [
    ((0.0, RATE, 1, "host"), "effects.command_scale"),
    ((SCALE, 0.0, 1, "host"), "control.rate"),
    ((SCALE, RATE, 0, "host"), "hold_ticks = 0"),
    ((SCALE, RATE, 2.0, "host"), "hold_ticks = 2.0"),
    ((SCALE, RATE, 1, "remote"), "mode = 'remote'"),
    ((SCALE, 1e8, 1, "host"), "at most"),
])
def test_params_errors(args, match):
    cfg = safety.SafetyConfig(rms_window_s=600.0) if args[1] == 1e8 else safety.SafetyConfig()
    with pytest.raises(ConfigError, match=match):
        safety.safety_params(cfg, *args)


def test_quantum_keeps_the_sum_exact_in_float64():
    p = safety.safety_params(safety.SafetyConfig(rms_window_s=600.0), SCALE, 1e4, 1)
    assert p[safety.PARAM.window] * safety.SafetyConfig().peak_n ** 2 / p[safety.PARAM.quantum] <= 2.0**50
    assert safety.safety_params(safety.SafetyConfig(), SCALE, RATE, 1)[safety.PARAM.quantum] == 1e-6


def test_describe_status():
    assert safety.describe_status(safety.WATCHDOG | safety.OVERRUN | (1 << 20)) == [
        "WATCHDOG",
        "OVERRUN",
        "bit20",
    ]
    assert safety.describe_status(0) == []
    assert len(set(safety.STATUS_BITS.values())) == len(safety.STATUS_BITS)
