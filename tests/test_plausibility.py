"""Sensor plausibility (impact_env.control.plausibility): the check itself, in the rig target's
compiled tick (the controller, onboard) and in the exported C tick, bit for bit, with NaN, +-inf,
1e30 and a jump injected on each channel of readings recorded from the virtual rig; and an
episode on a target whose driver reports a fault longer than the scene's limit."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest
from rig_drivers import BlindRig

from impact_env.config import ConfigError
from impact_env.control import plausibility
from impact_env.deploy import parity
from impact_env.deploy.c_export import write_c
from impact_env.policy.export import export_policy
from impact_env.rig import safety
from impact_env.scene import load_scene

ROOT = Path(__file__).resolve().parent.parent
AGENT = f"compiled:{ROOT / 'agents/models/best/best.policy.json'}"
CHANNEL_BITS = dict(enumerate(plausibility.CHANNEL_BITS))


# -- the check alone --------------------------------------------------------------------------------------
def _check(p, s, m, raw):
    out = np.zeros(4)
    bits = plausibility.check_readings(m, np.asarray(raw, dtype=np.float64), p, s, out)
    return int(bits), out


def test_range_jump_hold_and_the_limit():
    scene = load_scene("rig")
    p = plausibility.plausibility_params(scene)
    s = plausibility.reset_state(plausibility.make_state())
    limit = int(p.limit_ticks)
    assert limit == 10  # 1 ms at 10 kHz (effects.sensors.fault_limit_s)
    good = [1.0, 2.0, 1e-4, np.nan]  # the body-1 channel is disabled on the rig: NaN is its reading
    assert _check(p, s, 0, good) == (0, pytest.approx([1.0, 2.0, 1e-4, 0.0]))
    for m, bad, ch in ((1, np.nan, 0), (2, np.inf, 1), (3, -np.inf, 2), (4, 1e30, 0), (5, 0.02, 2)):
        raw = list(good)
        raw[ch] = bad
        bits, out = _check(p, s, m, raw)
        assert bits == plausibility.SENSOR_FAULT | CHANNEL_BITS[ch], (m, hex(bits))
        assert out[ch] == good[ch]  # the last plausible reading, held
    # a jump inside the converter's range, beyond what the physics allows in the ticks since the
    # last good reading (0.35 mm a tick, plus 0.11 mm for the noise): the potentiometer's was
    # tick 4's, so tick 6 may be 0.81 mm away, tick 7 0.46 mm from tick 6's
    x = 1e-4 + 0.75e-3
    assert _check(p, s, 6, [1.0, 2.0, x, 0.0])[0] == 0
    assert _check(p, s, 7, [1.0, 2.0, x + 0.6e-3,
                            0.0])[0] == plausibility.SENSOR_FAULT | plausibility.SENSOR_POTENTIOMETER
    assert _check(p, s, 8, [1.0, 2.0, x, 0.0])[0] == 0  # a good tick ends the run of faults
    # limit faulty ticks in a row are allowed; the next one latches SENSOR_TIMEOUT, for good
    # (the good channels' readings move by a few codes, as noisy ones do: a reading repeated
    # exactly for many ticks is a stuck channel, tests/test_sensor_faults.py)
    for k in range(limit + 1):
        bits, _ = _check(p, s, 10 + k, [np.nan, 2.0 + 0.05 * k, x + 1e-6 * k, 0.0])
        assert bool(bits & plausibility.SENSOR_TIMEOUT) == (k == limit), k
    bits, _ = _check(p, s, 30, [1.0, 2.0, x, 0.0])
    assert bits == plausibility.SENSOR_TIMEOUT
    plausibility.reset_state(s)  # the next episode
    assert _check(p, s, 0, good)[0] == 0


def test_an_enabled_body1_channel_is_checked():
    scene = load_scene("rig", {"effects.sensors.body1_displacement.enabled": True})
    p = plausibility.plausibility_params(scene)
    s = plausibility.make_state()
    assert _check(p, s, 0, [0.0, 0.0, 0.0, 0.05])[0] == 0
    assert _check(p, s, 1, [0.0, 0.0, 0.0,
                            np.nan])[0] == plausibility.SENSOR_FAULT | plausibility.SENSOR_BODY1


@pytest.mark.parametrize("key,value,match", [
    ("effects.sensors.potentiometer.max_step", -1e-3,
     r"effects.sensors.potentiometer.max_step = -0.001 m is out"),
    ("effects.sensors.fault_limit_s", 0.0,
     r"effects.sensors.fault_limit_s = 0.0 s is out of range: must be > 0"),
    ("effects.sensors.accelerometer.max_step", float("nan"), r"accelerometer.max_step = nan m/s\^2"),
])
def test_scene_fields_are_validated_with_their_names_and_units(key, value, match):
    with pytest.raises(ConfigError, match=match):
        load_scene("rig", {key: value})


# -- the target's tick and the C tick ---------------------------------------------------------------
@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """pd-penetration on the rig, drop seed 0: the recorded readings, the numba target's clean run and
    the C double build."""
    scene = load_scene("rig")
    pol = export_policy("pd-penetration", scene)
    rec = parity.record(pol, scene, 0, 2500)
    d = tmp_path_factory.mktemp("plaus") / "c"
    write_c(pol, scene, d)
    cp = parity.CPolicy(parity.build_shared(d, d / "lib.so"))
    return scene, pol, rec, cp


def _fault_tick(rec) -> int:
    """A tick in the middle of a catch: the law drives a force, body 2 accelerates hard."""
    busy = np.flatnonzero((np.abs(rec.force) > 20.0) & (np.abs(rec.readings[:, 0]) > 20.0))
    return int(busy[len(busy) // 2])


def _inject(readings, k, ch, kind):
    r = readings.copy()
    prev = r[k - 1, ch]
    if kind == "jump":  # inside the converter's range, beyond the channel's max_step (+ noise) per tick
        r[k, ch] = {0: -499.0 * np.sign(prev), 1: prev + (300.0 if prev < 0 else -300.0),
                    2: prev + (5e-3 if prev < 0 else -5e-3)}[ch]
    else:
        r[k, ch] = {"nan": np.nan, "+inf": np.inf, "-inf": -np.inf, "1e30": 1e30}[kind]
    return r


def _bits_equal(a, b) -> bool:
    return a.shape == b.shape and np.array_equal(a.view(np.uint64), b.view(np.uint64))


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["nan", "+inf", "-inf", "1e30", "jump"])
@pytest.mark.parametrize("ch", [0, 1, 2])
def test_one_bad_sample_never_becomes_a_force(ch, kind, clean):
    """A bad sample on channel ``ch`` at a tick in the middle of a catch: that tick's status has
    SENSOR_FAULT and the channel's bit and its force is 0 N; every other tick is the run in which
    the sample was the channel's previous reading (the filters and the law were fed the held
    reading, not the bad one), so no force exceeds the clean run's; the C file does the same, bit
    for bit."""
    scene, pol, rec, cp = clean
    k = _fault_tick(rec)
    bad = _inject(rec.readings, k, ch, kind)
    want = parity.numba_sequence(pol, scene, [bad], [])[0]
    got = parity.c_sequence(cp, [bad], [])[0]
    assert _bits_equal(got.command, want.command) and _bits_equal(got.force, want.force)
    assert np.array_equal(got.status, want.status)
    # the fault happened, on this tick and this channel only, and drove 0 N
    assert want.status[k] & plausibility.SENSOR_FAULT and want.status[k] & CHANNEL_BITS[ch], \
        hex(want.status[k])
    assert not any(want.status[k] & b for c, b in CHANNEL_BITS.items() if c != ch)
    assert np.flatnonzero(want.status & plausibility.SENSOR_FAULT).tolist() == [k]
    assert want.force[k] == 0.0 and rec.force[k] != 0.0
    held = rec.readings.copy()
    held[k, ch] = rec.readings[k - 1, ch]
    ref = parity.numba_sequence(pol, scene, [held], [])[0]
    assert not np.any(ref.status & safety.CLAMP_RMS)  # (so tick k's 0 N cannot change a later clamp)
    others = np.arange(len(bad)) != k
    assert _bits_equal(want.command[others], ref.command[others])
    assert np.abs(want.force).max() <= np.abs(rec.force).max()


@pytest.mark.slow
@pytest.mark.parametrize("ch", [0, 1, 2])
def test_a_fault_beyond_the_limit_latches_zero_force(ch, clean):
    """NaN on one channel for limit + 5 ticks from a tick in a catch: 0 N from its first tick, the
    (limit + 1)-th faulty tick latches SENSOR_TIMEOUT (the target ends the episode there), and the
    force stays 0 after the readings are good again; C bit for bit."""
    scene, pol, rec, cp = clean
    k = _fault_tick(rec)
    n = int(plausibility.plausibility_params(scene).limit_ticks)
    bad = rec.readings.copy()
    bad[k:k + n + 5, ch] = np.nan
    want = parity.numba_sequence(pol, scene, [bad], [])[0]
    got = parity.c_sequence(cp, [bad], [])[0]
    assert _bits_equal(got.command, want.command) and np.array_equal(got.status, want.status)
    st = want.status
    assert np.all(st[k:k + n + 5] & CHANNEL_BITS[ch])
    timeout = plausibility.SENSOR_TIMEOUT
    assert not np.any(st[:k + n] & timeout) and np.all(st[k + n:] & timeout)
    assert np.all(want.force[k:] == 0.0) and np.any(rec.force[k + n + 5:] != 0.0)


@pytest.mark.slow
def test_a_nan_body1_reading_changes_nothing_when_the_channel_is_off(clean):
    """The rig has no body-1 sensor (the scene's channel is disabled): its driver reports NaN,
    which is neither a fault nor fed to a filter: the same episode, bit for bit, in both ticks."""
    scene, pol, rec, cp = clean
    r = rec.readings.copy()
    r[:, 3] = np.nan
    want = parity.numba_sequence(pol, scene, [r], [])[0]
    got = parity.c_sequence(cp, [r], [])[0]
    assert _bits_equal(want.command, rec.command) and np.array_equal(want.status, rec.status)
    assert _bits_equal(got.command, rec.command)


@pytest.mark.slow
def test_defaults_never_flag_a_real_episode():
    """The defaults' derivation (module doc) against the virtual rig: drops of rig and
    rig-randomized with the classic laws and the shipped agent, no tick flagged, and the largest
    change between two ticks well inside the allowance (pytest -s prints the figures)."""
    for name in ("rig", "rig-randomized"):
        scene = load_scene(name)
        p = plausibility.plausibility_params(scene)
        allowed = p.ch[:, plausibility.CC.max_jump] + p.ch[:, plausibility.CC.tol]
        worst = np.zeros(3)
        for spec in ("passive", "pd-penetration", "thesis-rig", AGENT):
            pol = export_policy(spec, scene)
            for seed in (0, 1):
                rec = parity.record(pol, scene, seed, 4000)
                assert not np.any(rec.status & plausibility.SENSOR_BITS), (name, spec, seed)
                worst = np.maximum(worst, np.abs(np.diff(rec.readings[:, :3], axis=0)).max(axis=0))
        print(f"{name}: largest change per tick {worst.tolist()}, allowed {allowed[:3].tolist()}")
        assert np.all(worst <= 0.5 * allowed[:3]), (name, worst, allowed)


# -- a target's episode -------------------------------------------------------------------------------------
class FaultyRig(BlindRig):
    """The virtual rig seen through its DAQ boundary, whose channel ``ch`` reads NaN on ticks
    ``ticks`` (a range) of every episode."""

    def __init__(self, scene="rig", ch=1, ticks=range(0)):
        super().__init__(scene)
        self.ch, self.ticks, self._reads = ch, ticks, 0

    def release(self) -> None:
        super().release()
        self._reads = 0

    def read(self) -> np.ndarray:
        r = super().read()
        tick = self._reads - 1  # the target reads once at the release, then once per tick
        self._reads += 1
        if tick in self.ticks:
            r[self.ch] = np.nan
        return r


@pytest.mark.slow
@pytest.mark.parametrize("length,end", [(1, "HORIZON"), (40, "SENSOR_FAULT")])
def test_target_episode_with_a_faulty_force_transducer(length, end):
    """An onboard pd-penetration episode on a target (per-tick loop, lock-step) whose force
    transducer reads NaN from tick 1500 (mid-catch) for ``length`` ticks: one tick is 0 N with
    SENSOR_FAULT | SENSOR_FORCE and the episode goes on; 40 ticks end it SENSOR_FAULT on the
    (limit + 1)-th, with 0 N from the fault's first tick; the log holds the raw NaN (the fault
    happened) and the counter."""
    from impact_env.rig.host import RigClient
    from impact_env.rig.target import Target, TargetConfig

    scene = load_scene("rig")
    driver = FaultyRig("rig", ch=1, ticks=range(1500, 1500 + length))
    target = Target(driver, config=TargetConfig(lockstep=True))
    th = threading.Thread(target=target.serve, daemon=True)
    th.start()
    try:
        client = RigClient(target.address, timeout_s=0.5, retries=20)
        try:
            client.arm("onboard", 0, 2500, "sensors", 1, 1, export_policy("pd-penetration", scene))
            ep_end = client.wait_end(timeout_s=120.0)
            log = client.fetch_log(ep_end.episode, ep_end.data_sha256)
        finally:
            client.close()
    finally:
        target.stop()
        th.join(10)
    assert log.meta.end_reason == end
    tick, st, f = log["tick"], log["status"].astype(np.int64), log["force_demand_N"]
    # the fault happened: the log holds the raw NaN from the driver's 1500th read on (whose tick
    # the loop's first read, at the release, may shift by one)
    i0 = int(np.flatnonzero(np.isnan(log["force_N"]))[0])
    assert abs(int(tick[i0]) - 1500) <= 1 and np.count_nonzero(np.isnan(log["force_N"])) == min(length, 11)
    assert st[i0] & plausibility.SENSOR_FAULT and st[i0] & plausibility.SENSOR_FORCE
    assert f[i0] == 0.0 and np.any(f[:i0] != 0.0)
    assert log.meta.counters["sensor_fault_ticks"] == min(length, 11)
    if end == "SENSOR_FAULT":
        limit = int(plausibility.plausibility_params(scene).limit_ticks)
        assert tick[-1] == tick[i0] + limit and st[-1] & plausibility.SENSOR_TIMEOUT
        assert np.all(f[i0:] == 0.0) and ep_end.reason == 8
    else:
        assert np.flatnonzero(st & plausibility.SENSOR_FAULT).tolist() == [i0] and tick[-1] == 2500
