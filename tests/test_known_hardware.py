"""A model-based law on a calibrated scene: its model is the hardware the scene knows.

A calibrated scene file (``impact-env identify``) keeps the fields a controller reads (c, m2,
the transducer's top mass, the command scale) at the base's values and writes their identified
values as one-point ``[randomize]`` ranges, and lists them in ``control.known_hardware``: the
simulated hardware is the identified one.  :func:`impact_env.scene.randomize.known_hardware`
folds the listed ranges into the fields, and ``mpc``, ``mpc-state`` and the filter before a
network take their model from it.  Without the list (the same hardware, as ``impact-env
robustness`` moves it: a rig the controller is not told about) the filter's model is the base
rig's, its innovations exceed the hand-over gate before the touch, and ``mpc`` hands over.

The identified delays (``effects.delay``, whole control periods) are the other half: ``mpc``'s
filter then runs that many periods behind, told the demands that act over its period, and the
plan starts from its estimate moved on to the tick the new demand acts
(:func:`impact_env.control.estimation.ekf.ekf_ahead`)."""

from __future__ import annotations

import numpy as np
import pytest

from impact_env.control.estimation.layout import EkfMemory
from impact_env.control.laws import mpc
from impact_env.control.policy import act_batch
from impact_env.policy.export import export_policy
from impact_env.scene import load_scene
from impact_env.scene.randomize import known_hardware
from impact_env.sim.simulator import Simulator

SPEC = "mpc:horizon=8"  # the same code as the default horizon, cheaper
# a rig calibrated far from the base: every controller-read field moved, as identify writes them
UNKNOWN = {"randomize.c": [2.4e6, 2.4e6], "randomize.m2": [0.85, 0.85], "randomize.top_mass": [0.13, 0.13],
           "randomize.command_gain": [1.15, 1.15]}
# the same hardware, told to the controller
CALIBRATED = {**UNKNOWN, "control.known_hardware": ["c", "m2", "top_mass", "command_gain"]}
TICKS = 50  # the touch at tick 10, the first contact, up to the filter's first windowed test
N_DROPS = 4


def test_known_hardware_folds_one_point_hardware_ranges_only():
    base = load_scene("rig")
    assert known_hardware(base) is base  # nothing known beyond the fields: the scene itself
    assert known_hardware(load_scene("rig-randomized")) is not None
    wide = load_scene("rig-randomized")
    assert known_hardware(wide) is wide  # every hardware range there is wide, and none is known
    untold = load_scene("rig", UNKNOWN)
    assert known_hardware(untold) is untold  # one-point, but not listed: the controller is not told
    from impact_env.eval.robustness import point_scene

    moved = point_scene(base, {"c": 2.4e6, "actuator_delay_s": 1e-4})  # the mismatch map's rigs
    assert known_hardware(moved) is moved and mpc.known_lag(moved) == 0
    scene = load_scene("rig", {**CALIBRATED, "randomize.m1": [0.1, 0.1]})
    hw = known_hardware(scene)
    assert hw.plant.c == 2.4e6 and hw.plant.m2 == 0.85 and hw.effects.sensors.force.top_mass == 0.13
    assert hw.effects.command_scale == pytest.approx(1.15 * base.effects.command_scale, rel=1e-15)
    # the drop's own ranges stay ranges, a one-point m1 among them (the filter estimates m1 per drop)
    assert hw.randomize.ranged() == ("m1", "drop_height")
    assert hw.randomize.m1 == (0.1, 0.1) and hw.randomize.drop_height == base.randomize.drop_height
    # the description the controller reads is unchanged
    assert scene.plant.c == base.plant.c and scene.effects.command_scale == base.effects.command_scale
    assert hw.control.known_hardware == ()  # folded: nothing left to fold


def test_a_known_field_must_be_one_point_hardware():
    from impact_env.config import ConfigError

    with pytest.raises(ConfigError, match=r"control.known_hardware lists 'c', but randomize.c = \[2400000.0, "
                                          r"2500000.0\] is not one point"):
        load_scene("rig", {"randomize.c": [2.4e6, 2.5e6], "control.known_hardware": ["c"]})
    with pytest.raises(ConfigError, match="lists 'm1': not a hardware field"):
        load_scene("rig", {"randomize.m1": [0.1, 0.1], "control.known_hardware": ["m1"]})


DELAYS = {"effects.active": ["shaker", "saturation", "sensors", "filters", "detector", "sensor_delay",
                              "actuator_delay"],
          "effects.delay.sensor_s": 2e-4, "effects.delay.actuator_s": 1e-4}  # 2 and 1 periods


def _nis_and_hand_over(overrides: dict, spec: str = SPEC):
    """``spec`` on N_DROPS drops of rig with ``overrides``: the largest one-tick NIS before the
    touch per drop, and whether it handed over."""
    scene = load_scene("rig", overrides)
    law = export_policy(spec, scene)
    sim = Simulator(scene, N_DROPS, layout=law.layout)
    sim.reset([np.random.default_rng(4000 + i) for i in range(N_DROPS)])
    arrays, params, m = law.arrays()
    mem = np.zeros((N_DROPS, m))
    nis = np.zeros((TICKS, N_DROPS))
    touched = np.full(N_DROPS, TICKS)
    for t in range(TICKS):
        u = act_batch(arrays, params, np.ascontiguousarray(sim.obs), mem, np.empty(N_DROPS))
        nis[t] = mem[:, mpc.EKF_MEMORY_START + EkfMemory.nis_last]
        d = sim.plant_state[:, 0] - sim.plant_state[:, 2]
        touched = np.where((touched == TICKS) & (d > 0), t, touched)
        sim.step(u)
    before = np.array([nis[:touched[i], i].max() for i in range(N_DROPS)])
    return before, mem[:, mpc.FALLBACK_ON] > 0


def test_on_a_calibrated_rig_the_filter_holds_and_mpc_plans():
    before, handed_over = _nis_and_hand_over(CALIBRATED)
    # a consistent 3-channel filter: chi-square 3, whose 1 - 1e-9 quantile is 44
    assert before.max() < 44.0, before
    assert not handed_over.any()
    # the same hardware, not told, and the base rig's model taken as exact: the gate sees it and
    # hands over
    before_exact, handed_over_exact = _nis_and_hand_over(UNKNOWN, SPEC + ",untold_error=0")
    assert before_exact.min() > mpc.PARAMS["nis_gate"].default, before_exact
    assert handed_over_exact.all()
    # not told, with the model's error allowed for (the default where hardware is untold): the
    # filter's innovations are within its predicted variance and the plan drives
    before_unknown, handed_over_unknown = _nis_and_hand_over(UNKNOWN)
    assert before_unknown.max() < 44.0, before_unknown
    assert not handed_over_unknown.any()


def test_with_known_delays_the_filter_runs_behind_and_mpc_plans():
    before, handed_over = _nis_and_hand_over({**CALIBRATED, **DELAYS})
    assert before.max() < 44.0, before
    assert not handed_over.any()
    assert mpc.known_lag(load_scene("rig", DELAYS)) == 3 and mpc.known_lag(load_scene("rig")) == 0
    # the delays of rig-randomized are drawn, not known: the law keeps no lag there
    assert mpc.known_lag(load_scene("rig-randomized")) == 0


def test_the_ahead_model_of_mpc_is_the_filters_own():
    """With no readings between, the look-ahead over ``lag`` periods is the filter's own prediction
    over those periods, bit for bit (the same model, applied force and RK4 step, on copies)."""
    from impact_env.control.estimation.ekf import AHEAD_SCRATCH, ekf_ahead, ekf_measure, ekf_tick
    from impact_env.control.estimation.layout import MEMORY, N_STATE, REPLICAS_END
    from impact_env.control.estimation.model import constants_vector, ekf_constants

    scene = load_scene("rig", CALIBRATED)
    k = constants_vector(ekf_constants(scene))
    mem = np.zeros(MEMORY)
    ekf_measure(k, mem, np.array([0.0, 0.0, 0.0]))  # the prior
    demands = np.array([40.0, -120.0, 200.0, 15.0])
    scratch = np.zeros(AHEAD_SCRATCH)
    start = mem.copy()
    ekf_ahead(k, mem, demands, len(demands), scratch)
    np.testing.assert_array_equal(mem, start)  # the filter itself is not moved
    moved = scratch[REPLICAS_END:REPLICAS_END + N_STATE].copy()
    for f in demands:
        ekf_tick(k, mem, None, f)
    np.testing.assert_array_equal(moved[:4], mem[EkfMemory.x:EkfMemory.x + 4])
    assert np.abs(moved[:4] - start[EkfMemory.x:EkfMemory.x + 4]).max() > 0.0  # it did move the state


def test_more_delay_than_mpc_models_is_refused_naming_it():
    from impact_env.config import ConfigError

    with pytest.raises(ConfigError, match=r"at most 8 control periods.*effects.delay gives 9 \(0.0009 s\)"):
        export_policy("mpc", load_scene("rig", {**DELAYS, "effects.delay.sensor_s": 9e-4,
                                                "effects.delay.actuator_s": 0.0}))


@pytest.mark.slow
@pytest.mark.parametrize("delays", [False, True], ids=["calibrated", "calibrated-with-delays"])
def test_the_c_export_of_mpc_on_a_calibrated_rig_replays_bitwise(tmp_path, delays):
    """The amplifier's known gain reaches the C file (the filter's replica and the demand over the
    gain): the double build replays the target bit for bit on the calibrated rig."""
    from impact_env.deploy import parity
    from impact_env.deploy.c_export import write_c

    scene = load_scene("rig", {**CALIBRATED, **(DELAYS if delays else {})})
    policy = export_policy(SPEC, scene)
    write_c(policy, scene, tmp_path / "c")
    cp = parity.CPolicy(parity.build_shared(tmp_path / "c", tmp_path / "lib.so"), False)
    rec = parity.record(policy, scene, 0, 400)
    assert rec.memory[mpc.FALLBACK_ON] == 0.0, "it handed over: the plan would not be compared"
    got = parity.replay(cp, rec)
    np.testing.assert_array_equal(got.command, rec.command)
    np.testing.assert_array_equal(got.status, rec.status)


@pytest.mark.slow
def test_a_target_serving_the_calibrated_scene_runs_mpc_with_the_rigs_numbers():
    """The deployment path: a virtual rig whose hardware is the calibrated one (its delays
    included), served by a target in lock-step.  Serving the calibrated scene, ``mpc`` onboard
    is built from it and plans; serving ``rig`` (the same hardware and drops) it plans on the
    nominal rig and hands over.  The energy integral over the first 50 ms tells them apart."""
    import threading

    from impact_env.eval.rig_compare import rig_compare
    from impact_env.rig.driver import VirtualRig
    from impact_env.rig.target import Target, TargetConfig

    physics = load_scene("rig", {**UNKNOWN, **DELAYS})
    energy = {}
    calibrated = load_scene("rig", {**CALIBRATED, **DELAYS})
    for name, served in (("calibrated", calibrated), ("rig", load_scene("rig"))):
        target = Target(VirtualRig(served, physics), config=TargetConfig(lockstep=True))
        th = threading.Thread(target=target.serve, daemon=True)
        th.start()
        try:
            _scene, runs = rig_compare(target.address, ["mpc"], episodes=3, seed=1000, horizon=0.05,
                                       progress=False)
        finally:
            target.stop()
            th.join(10)
        assert not runs["mpc"].failures
        energy[name] = np.asarray(runs["mpc"].metrics["energy_integral_ms"])
    assert np.all(energy["calibrated"] < 0.6 * energy["rig"]), energy
