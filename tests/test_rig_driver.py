"""The physical rig's path, without a physical rig: ``BlindRig`` (tests/rig_drivers.py) is the
virtual rig behind the DAQ card's boundary only (``virtual = False``, no truth).  The target's
one compiled loop calls its read() and apply() through ctypes callbacks
(impact_env.rig.cdriver.PythonCallbacks), the host gets observations but no reward, and compare --rig
gets its metrics from the log's estimate (thesis eq 4.5), as it would from a real rig.  Loops are
bounded in steps and time; targets run in a thread of this process, or as a process for the CLI."""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager

import numpy as np
import pytest
from rig_drivers import BlindRig
from rig_helpers import start_target, stop

from impact_env.env.catch_env import ImpactCatchEnv
from impact_env.rig.host import RigClient, RigEnv

pytestmark = pytest.mark.slow


@contextmanager
def blind_target(scene="rig", driver=None, **cfg):
    from impact_env.rig.target import Target, TargetConfig

    driver = driver or BlindRig(scene)
    target = Target(driver, config=TargetConfig(lockstep=True, **cfg))
    th = threading.Thread(target=target.serve, daemon=True)
    th.start()
    try:
        yield target, driver
    finally:
        target.stop()
        th.join(10)
        assert not th.is_alive()


def test_host_mode_observations_equal_the_simulator_and_no_reward_is_claimed():
    """Observations bitwise equal to ImpactCatch-v0's for the same seed and actions (the
    simulator's order of read -> front end -> act -> apply); reward 0.0 with
    ``reward_available`` False; no termination (nothing on a physical rig sees the catch), the
    episode runs to the horizon; the driver was only ever read and applied."""
    # The simulator runs first, all of it: its kernels compile on its first reset() and step()
    # (over a minute with a cold numba cache on a loaded 2-core machine), and a lock-step host
    # silent for lockstep_link_timeout_s (60 s) rightly loses its episode (LINK_LOST: the rig
    # then answers step 2 with step 1's observation again).  Nothing of the reference may run
    # between the rig's steps.
    ref = ImpactCatchEnv("rig", horizon=0.02, terminate_on_catch=False)
    o2, _ = ref.reset(seed=11)
    want, actions = [o2.copy()], []  # copies: an env may reuse its observation buffer
    rng = np.random.default_rng(11)
    for _n in range(1, 1000):
        a = rng.uniform(-0.5, 0.5, 1).astype(np.float32)
        o2, _r2, _te2, tr2, _i2 = ref.step(a)
        want.append(o2.copy())
        actions.append(a)
        if tr2:
            break
    assert tr2 and len(actions) == 200
    with blind_target() as (target, driver):
        env = RigEnv(target.address, horizon=0.02, timeout_s=0.2, retries=50)
        try:
            assert env.client.virtual is False
            o1, i1 = env.reset(seed=11)
            assert np.array_equal(o1, want[0]) and i1["reward_available"] is False
            for n, a in enumerate(actions, start=1):
                o1, r1, te1, tr1, i1 = env.step(a)
                assert np.array_equal(o1, want[n]), f"step {n} ({i1.get('end_reason', 'running')})"
                assert r1 == 0.0 and not te1 and not i1["reward_available"]
                if tr1:
                    break
            assert tr1 and n == 200 and i1["end_reason"] == "HORIZON"
        finally:
            env.close()
    assert driver.calls["apply"] >= 200 and driver.calls["read"] >= 200 and driver.calls["idle"] >= 1


def _logged_episode(target, logs, seed=5, steps=1000):
    """One host-mode episode of seeded actions on ``target``, to its end: its log."""
    from impact_env.rig.log import list_episodes, read_episode

    env = RigEnv(target.address, horizon=0.02, timeout_s=0.2, retries=50, hold_ticks=2)
    try:
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        for _ in range(steps):
            _o, _r, te, tr, info = env.step(rng.uniform(-0.5, 0.5, 1).astype(np.float32))
            if te or tr:
                break
    finally:
        env.close()
    deadline = time.monotonic() + 10.0
    while not list_episodes(logs) and time.monotonic() < deadline:
        time.sleep(0.02)
    return read_episode(list_episodes(logs)[0])


def test_a_python_driver_in_the_loop_logs_what_the_virtual_rig_logs_bitwise(tmp_path):
    """The one loop with a Python driver (BlindRig, through callbacks) and with the virtual rig's
    hardware stage compiled into it: the same drop and commands give the same log, bitwise, in
    every column they share (readings, observation, actions, demanded and applied force, status),
    all but the loop's own timing."""
    from impact_env.rig.driver import VirtualRig

    logs = {}
    for name, driver in (("blind", BlindRig("rig")), ("virtual", VirtualRig("rig"))):
        (tmp_path / name).mkdir()
        with blind_target(driver=driver, log_dir=tmp_path / name) as (target, _):
            logs[name] = _logged_episode(target, tmp_path / name)
    blind, virtual = logs["blind"], logs["virtual"]
    assert blind.meta.end_reason == virtual.meta.end_reason and blind.n_ticks > 50
    shared = [c for c in blind.columns if c not in ("lateness_ns", "compute_ns")]
    assert "force_applied_N" in shared and "command" in shared and "status" in shared
    for col in shared:
        assert np.array_equal(blind[col], virtual[col], equal_nan=True), (col, blind[col], virtual[col])
    assert np.array_equal(blind.observation, virtual.observation)


class _FailingRig(BlindRig):
    """BlindRig whose apply() raises at its 30th call."""

    def apply(self, command: float, ticks: int = 1) -> float:
        if self.calls["apply"] == 29:
            raise OSError("DAQ card unplugged")
        return super().apply(command, ticks)


def test_a_python_driver_that_raises_ends_the_episode_fault_and_is_named():
    """An exception in a Python driver's apply() inside the compiled loop: 0 N, the episode ends
    FAULT (the host's env says so), and the target's note names the driver and the error."""
    with blind_target(driver=_FailingRig("rig")) as (target, driver):
        env = RigEnv(target.address, horizon=0.02, timeout_s=0.2, retries=50, hold_ticks=2)
        try:
            env.reset(seed=4)
            for _ in range(100):
                _o, _r, te, tr, info = env.step(np.zeros(1, np.float32))
                if te or tr:
                    break
        finally:
            env.close()
        assert info["end_reason"] == "FAULT"
        assert driver.calls["apply"] == 29  # its 30th raised
        notes = target.notes
        assert any("_FailingRig" in n and "OSError: DAQ card unplugged" in n for n in notes), notes


def test_compare_rig_onboard_estimates_the_metrics_from_the_log():
    """compare --rig against a rig with no body-1 sensor: every metric comes from the log's
    estimate and is finite; the passive drop's catch time agrees with the simulator's exact one.
    Bound: the estimate sees contacts through the 2 N detector threshold (touch late by
    d_th / v, d_th = 0.1 mm, v ~ 0.1 m/s at the last bounces: 1 ms) plus one sample per edge
    (0.1 ms), and the catch is the end of the last flight: 2 ms covers both (docs/rig/logs.md, 'Body
    1's energy from the log', measured 1 ms on the nominal drop)."""
    from impact_env.eval.compare import compare
    from impact_env.eval.rig_compare import rig_compare
    from impact_env.scene import load_scene

    with blind_target() as (target, _driver):
        _scene, runs = rig_compare(target.address, ["passive", "pd-penetration"], episodes=2, seed=3,
                                   progress=False)
    sim = compare(load_scene("rig"), ["passive"], episodes=2, seed=3, workers=1, progress=False)
    for spec in ("passive", "pd-penetration"):
        r = runs[spec]
        assert not r.failures
        for key in ("time_to_catch_s", "energy_integral_ms", "bounces"):
            assert np.all(np.isfinite(r.metrics[key])), (spec, key, r.metrics[key])
    # the blind estimate is of body 1's absolute catch energy (impact_env.rig.flight_energy): the
    # simulation's figure of that definition is time_to_catch_absolute_s (impact_env.sim.metrics)
    got, want = runs["passive"].metrics["time_to_catch_s"], sim["passive"].metrics["time_to_catch_absolute_s"]
    assert np.all(np.abs(got - want) <= 2e-3), (got, want)
    assert runs["passive"].trace_t is None  # no truth: no true traces are made up


def test_cli_serves_a_driver_class_by_module_path():
    """``impact-env rig serve --driver tests.rig_drivers:BlindRig``: the target announces the
    driver, INFO says 'hardware', and SIGTERM leaves it stopped with the shaker at 0 N."""
    proc, addr = start_target("--scene", "rig", "--lockstep", driver="tests.rig_drivers:BlindRig")
    try:
        c = RigClient(addr)
        assert c.virtual is False
        c.close()
    finally:
        assert stop(proc) == 0
    out = proc.stdout.read()
    assert "shaker at 0 N" in out


@pytest.mark.parametrize("spec, words", [
    ("no_colon", ["MODULE:CLASS"]),
    ("no_such_module_xyz:Rig", ["cannot import module 'no_such_module_xyz'"]),
    ("rig_drivers:Missing", ["rig_drivers.Missing", "not a subclass", "RigDriver"]),
    ("rig_drivers:NotADriver", ["rig_drivers.NotADriver", "not a subclass"]),
])
def test_bad_driver_specs_exit_2_naming_the_problem(capsys, spec, words):
    from impact_env.cli.main import main

    assert main(["rig", "serve", "--driver", spec, "--scene", "rig", "--port", "0"]) == 2
    err = capsys.readouterr().err
    for w in words:
        assert w in err, (w, err)


def test_virtual_and_driver_are_exclusive_and_one_is_required(capsys):
    from impact_env.cli.main import main

    for argv in (["rig", "serve"], ["rig", "serve", "--virtual", "--driver", "rig_drivers:BlindRig"]):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2
