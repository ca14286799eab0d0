"""The target (``impact-env rig serve``) on loopback, against a virtual rig: lock-step equals the
simulator bitwise, compare --rig equals compare --scene, faults (loss, bursts, duplicates,
reordering, late commands, a killed host, a killed target, fuzzed datagrams) are survived and
counted, and the shaker ends at zero.  Every loop is bounded in time; targets run as processes,
as they would on a rig."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rig_helpers import LossyProxy, slow_rate_args, start_target, stop, streamed_ticks

from impact_env.env.catch_env import ImpactCatchEnv
from impact_env.rig.host import RigClient, RigEnv
from impact_env.rig.log import read_episode
from impact_env.rig.transport import RigTimeout, parse_address

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def lockstep(tmp_path_factory):
    logs = tmp_path_factory.mktemp("lockstep-logs")
    proc, addr = start_target("--scene", "rig", "--lockstep", "--log-dir", str(logs))
    yield addr, logs
    assert stop(proc) == 0


def run_pair(env, ref, seed, steps, scale=0.5):
    """Step the rig env and the simulated env with the same actions (inside the safety layer's
    envelope: its RMS clamp, which the simulator does not model, never binds at |a| <= 0.5);
    returns the number of steps and of mismatches (observation, reward, flags)."""
    ref.reset(seed=seed)  # the reference's kernels compiled before the rig's episode is armed
    ref.step(np.zeros(1, np.float32))
    o1, _ = env.reset(seed=seed)
    o2, _ = ref.reset(seed=seed)
    bad = int(not np.array_equal(o1, o2))
    rng = np.random.default_rng(seed)
    for n in range(1, steps + 1):  # noqa: B007 (n is returned: the number of steps taken)
        a = rng.uniform(-scale, scale, 1).astype(np.float32)
        o1, r1, te1, tr1, i1 = env.step(a)
        o2, r2, te2, tr2, i2 = ref.step(a)
        bad += (not np.array_equal(o1, o2)) or r1 != r2 or te1 != te2 or tr1 != tr2 or \
            i1["catch_energy"] != i2["catch_energy"]
        if te2 or tr2:
            break
    return n, bad


@pytest.mark.parametrize("kwargs", [{}, {"hold_ticks": 2, "residual": "pd-penetration"}])
def test_lockstep_rig_equals_impactcatch_bitwise(lockstep, kwargs):
    addr, _ = lockstep
    env = RigEnv(addr, horizon=0.05, timeout_s=0.2, retries=50, **kwargs)
    ref = ImpactCatchEnv("rig", horizon=0.05, **kwargs)
    try:
        for seed in (3, 4):
            n, bad = run_pair(env, ref, seed, 10_000)  # to the end: caught (terminated) or the horizon
            assert bad == 0 and n > 100
    finally:
        env.close()


def test_compare_rig_equals_compare_scene(lockstep):
    """Onboard classic and compiled policies give compare's numbers bitwise; an SB3 model in host
    mode to the float32 rounding of torch's batched matmul (the rig evaluates one observation at a
    time, compare a batch)."""
    from impact_env.eval.compare import compare
    from impact_env.eval.rig_compare import rig_compare
    from impact_env.policy.export import export_policy
    from impact_env.scene import load_scene

    addr, _ = lockstep
    scene = load_scene("rig")
    specs = ["passive", "pd-penetration", "thesis-rig:h01=1.8e6", "ppo:agents/models/ppo_rig/model.zip"]
    _, rig = rig_compare(addr, specs, episodes=2, seed=7, horizon=0.03, progress=False)
    paths = {}
    for k, spec in enumerate(specs[:3]):
        paths[spec] = f"compiled:{export_policy(spec, scene).save(Path(lockstep[1]) / f'p{k}.policy.json')}"
    sim = compare(scene, [*paths.values(), specs[3]], episodes=2, seed=7, horizon=0.03, workers=1,
                  progress=False)
    # a rig's log has the ticks' records, not the plant's inside (impact_env.sim.metrics): its
    # energy integral is the tick sum (the simulation's energy_integral_ticks_ms), its exit speed
    # is read at the tick, and it has no horizon for the vibration window
    as_sim = {"energy_integral_ms": "energy_integral_ticks_ms"}
    plant_only = {"exit_speed_ratio", "exit_velocity_ratio", "residual_vibration_mps"}
    for spec in specs:
        a, b = rig[spec].metrics, sim[paths.get(spec, spec)].metrics
        for key in set(a) - plant_only:
            if spec in paths:
                np.testing.assert_array_equal(a[key], b[as_sim.get(key, key)], err_msg=f"{spec} {key}")
            else:
                np.testing.assert_allclose(a[key], b[as_sim.get(key, key)], rtol=1e-6, atol=1e-9,
                                           err_msg=f"{spec} {key}")
    assert rig["pd-penetration"].metrics["peak_force_N"].max() > 100.0


def test_compare_rig_cli_prints_both_tables_the_gap_and_writes_the_outputs(lockstep, tmp_path, capsys):
    """``impact-env compare --rig ADDR --scene rig --out DIR``: the rig's table, the simulation's
    on the same seeds, the gap lines (0 for a law run onboard in lock-step) and the files."""
    from impact_env.cli.main import main

    addr, _ = lockstep
    rc = main(["compare", "--rig", addr, "--scene", "rig", "--policies", "passive,pd-penetration",
               "--episodes", "2", "--horizon", "0.03", "--seed", "7", "--workers", "1",
               "--out", str(tmp_path / "out"), "--no-progress"])
    text = capsys.readouterr().out
    assert rc == 0
    assert "simulation (scene rig)" in text and "sim-to-rig gap" in text
    gaps = [ln for ln in text.splitlines() if ln.startswith("  pd-penetration:")]
    assert gaps and "energy_integral_ms +0" in gaps[-1].replace("-0", "+0")
    assert list((tmp_path / "out").iterdir())


@pytest.mark.parametrize("loss, burst, dup, reorder", [(0.01, 1, 0.0, 0.0), (0.10, 1, 0.05, 0.05),
                                                        (0.50, 1, 0.0, 0.0), (0.10, 5, 0.1, 0.1)])
def test_lossy_link_costs_time_not_the_episode(lockstep, loss, burst, dup, reorder):
    """Through a link that loses, duplicates and reorders datagrams, lock-step host mode still gives
    the simulator's episode bitwise (requests are retried, observations re-sent, stale datagrams
    dropped), and the target counts what it dropped."""
    addr, logs = lockstep
    proxy = LossyProxy(addr, loss=loss, burst=burst, dup=dup, reorder=reorder, seed=int(loss * 100) + burst)
    env = None
    try:
        env = RigEnv(proxy.address, horizon=0.01, timeout_s=0.02, retries=60)
        ref = ImpactCatchEnv("rig", horizon=0.01)
        n, bad = run_pair(env, ref, 11, 10_000)
        assert bad == 0 and n == 100
        ep = env.client.episode
    finally:
        if env is not None:
            env.close()
        proxy.close()
    assert proxy.counts["dropped"] > 0
    log = _wait_log(logs, ep, env.client.link.session)
    c = log.meta.counters
    assert c["datagrams_received"] == (c["datagrams_accepted"]
                                       + sum(v for k, v in c.items() if k.startswith("dropped_")))
    if dup or reorder:
        assert c["dropped_duplicate"] + c["dropped_out_of_order"] + c["dropped_late"] > 0


def _wait_log(logs: Path, episode: int, session: int, timeout_s: float = 20.0):
    from impact_env.rig.log import episode_filename

    path = Path(logs) / episode_filename(episode, session)
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        assert time.monotonic() < deadline, f"no log {path}"
        time.sleep(0.05)
    return read_episode(path)


def test_fuzzed_datagrams_are_all_counted(lockstep):
    """10^5 random and mutated datagrams at a target during an episode (from another socket: the
    well-formed ones are strangers'): it keeps serving, and every datagram it received in the
    episode is accepted or counted under a reason in the episode's log."""
    addr, logs = lockstep
    host, port = parse_address(addr)
    client = RigClient(addr)
    good = __import__("impact_env.rig.protocol", fromlist=["P"])
    rng = np.random.default_rng(0)
    client.arm("host", 1, 100, link_timeout_ms=60_000)  # lock-step: it waits for the first command
    nonce = client.link.filter.nonce  # the fuzz knows the session's nonce (not that it would help)
    seed_msgs = [good.encode(good.Message(b, session=client.link.session, seq=int(rng.integers(1 << 32))),
                             b"", nonce)
                 for b in (good.Command(client.episode, 0, (0.1,)), good.Heartbeat(), good.Fetch(1, 0, 0, 64),
                           good.Disarm(0))]
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for k in range(100_000):
            kind = k % 4
            if kind == 0:
                data = rng.integers(0, 256, int(rng.integers(0, 120)), dtype=np.uint8).tobytes()
            else:
                data = bytearray(seed_msgs[k % len(seed_msgs)])
                for _ in range(int(rng.integers(0, 3))):
                    data[int(rng.integers(len(data)))] = int(rng.integers(256))
                data = bytes(data)
            s.sendto(data, (host, port))
            if k % 200 == 199:
                # flow control: the target answers a HEARTBEAT only after reading every datagram
                # before it, so no socket buffer fills whatever the machine's load (a full buffer
                # is not the test)
                client.link.request(good.Heartbeat(), lambda m: m.type == good.MsgType.HEARTBEAT,
                                    "HEARTBEAT", 1.0, 20)
    finally:
        s.close()
    client.disarm(wait=True)
    end = client.wait_end(timeout_s=20.0)
    assert end.reason == 3  # DISARMED by its host: no stranger's DISARM or COMMAND got in
    log = client.fetch_log(end.episode, end.data_sha256)
    client.close()
    c = log.meta.counters
    counted = c["datagrams_accepted"] + sum(v for k, v in c.items() if k.startswith("dropped_"))
    assert c["datagrams_received"] == counted
    assert c["datagrams_received"] >= 100_000  # every fuzzed datagram reached it (and the host's own)
    assert c["dropped_corrupt"] > 10_000 and c["dropped_unauthenticated"] > 10_000
    assert c["dropped_stranger"] > 1_000  # the unmutated copies: well tagged, from the wrong port
    assert c.get("commands_accepted", 0) == 0


def test_target_killed_host_raises_soon_and_close_does_not_hang():
    proc, addr = start_target("--scene", "rig")
    env = RigEnv(addr, timeout_s=0.05, retries=10)
    env.reset(seed=1)
    stop(proc, signal.SIGKILL)
    with pytest.raises(RigTimeout, match="OBSERVATION") as exc:
        for _ in range(10_000):
            env.step(np.zeros(1, np.float32))
    # the host gave up after its own budget: retries + 1 waits of timeout_s (no wall clock asserted)
    assert exc.value.tries == 11 and exc.value.waited_s == pytest.approx(11 * 0.05)
    sent = env.client.endpoint.sent
    env.close()
    # close() retries its DISARM within its 0.3 s budget: at most 0.3 / 0.05 = 6 datagrams, then gives up
    assert 1 <= env.client.endpoint.sent - sent <= 6 and env.client.endpoint.closed


HOST = r"""
import sys, time, numpy as np
from impact_env.rig.host import RigClient
c = RigClient(sys.argv[1])
c.arm("host", 5, 50_000, hold_ticks=10, link_timeout_ms=2000)
step, applied = 0, 0
while True:  # a host stepping in real time until it is killed
    obs = c.observation(step, 0.05)
    if obs is not None:
        if not hasattr(obs, "obs"):
            print("ended", obs, flush=True)
            break
        step = obs.step
        c.command(step, 0.1)
        step += 1
        applied += obs.telemetry[0] != 0.0  # force demanded: a command of ours is in use
        if applied >= 20:
            print("stepping", flush=True)
"""


def test_host_killed_midway_force_is_zero_within_two_policy_periods(tmp_path):
    """Real time, hold 10 ticks of a 1 kHz target (10 ms steps, which a Python host keeps up with
    whatever the load): the host is SIGKILLed while stepping; the log shows the demanded force at
    0 from 2 policy periods after the last command's first tick, then the link timeout ends the
    episode.  The link timeout is 2 s: with 0.3 s, a host process descheduled that long by a
    loaded machine ends the episode LINK_LOST before the kill.  Once in a CI run the target ended
    the episode before the host was stepping, for a reason the test did not print then (the
    likeliest is that one); the assertion now prints the host's lines."""
    proc, addr = start_target("--scene", "rig", *slow_rate_args(1000), "--log-dir", str(tmp_path))
    host = subprocess.Popen([sys.executable, "-c", HOST, addr], stdout=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        deadline = time.monotonic() + 60
        said = []  # the host's lines: an episode the target ended before the kill says why
        while "stepping" not in (line := host.stdout.readline()):
            said += [line] if line else []
            assert time.monotonic() < deadline and host.poll() is None, said
        host.kill()
        host.wait(5)
        deadline = time.monotonic() + 30
        while not list(tmp_path.glob("episode_*.h5")):
            assert time.monotonic() < deadline
            time.sleep(0.05)
    finally:
        stop(proc)
    log = read_episode(next(tmp_path.glob("episode_*.h5")))
    assert log.meta.end_reason == "LINK_LOST"
    # a loaded machine lets late ticks pass without a row (OVERRUN): work in ticks, not rows
    tick, age = log["tick"].astype(np.int64), log["command_age_ticks"].astype(np.int64)
    last_cmd = int(np.max((tick - age)[age >= 0]))  # the tick the last command took effect
    f = log["force_demand_N"]
    assert np.all(f[tick >= last_cmd + 20] == 0.0) and tick[-1] > last_cmd + 20
    assert np.any(f[tick < last_cmd] != 0.0)


def test_sigterm_mid_episode_leaves_the_shaker_at_zero(tmp_path):
    """SIGTERM while an onboard episode runs in real time: the target stops, idles the driver and
    exits 0 ('shaker at 0 N'); the episode's log ends by DISARMED."""
    from impact_env.rig import protocol
    from impact_env.rig.excitation import Excitation

    proc, addr = start_target("--scene", "rig", "--log-dir", str(tmp_path))
    c = RigClient(addr)
    # the shaker driven (body 1 held) by a sweep far above the suspension's resonance: a force
    # on the shaker when the signal comes, and one that no overrun can turn into a travel trip
    # (a held 20 N moves body 2 by 2 mm; a catching law's 200 N held over skipped ticks can trip
    # the 7 mm limit on a loaded machine, ending the episode before the signal)
    c.arm(
        "onboard",
        3,
        100_000,
        kind=protocol.EpisodeKind.SHAKER,
        excitation=Excitation("sweep", 20.0, 200.0, 2000.0),
    )
    deadline = time.monotonic() + 30.0
    while streamed_ticks(tmp_path) <= 200:  # it runs, the shaker driven
        assert time.monotonic() < deadline
        time.sleep(0.05)
    assert stop(proc, signal.SIGTERM) == 0
    c.close()
    assert "shaker at 0 N" in proc.stdout.read()
    log = read_episode(next(tmp_path.glob("episode_*.h5")))
    assert log.meta.end_reason == "DISARMED" and 100 < log.n_ticks < 100_000
    assert np.any(np.abs(log["force_demand_N"]) > 1.0)  # the shaker was driven when the signal came


def test_rig_log_command_summarises_a_virtual_log(lockstep, tmp_path):

    from impact_env.cli.main import main

    addr, logs = lockstep
    env = RigEnv(addr, horizon=0.03, timeout_s=0.2, retries=50)
    env.reset(seed=2)
    for _ in range(300):
        _o, _r, te, tr, _i = env.step(np.array([0.1], np.float32))
        if te or tr:
            break
    ep, session = env.client.episode, env.client.link.session
    env.close()
    path = _wait_log(logs, ep, session).path
    out = tmp_path / "log.png"
    rc = main(["rig", "log", str(path), "--json", "--plot", str(out)])
    assert rc == 0 and out.stat().st_size > 10_000
