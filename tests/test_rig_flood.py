"""A flood at the target during host-mode episodes (targets as processes, on loopback, bounded).

A second process sends, as fast as it can, a fixed number of datagrams: the host's own HELLO
recorded and replayed, datagrams with a bad tag, malformed bytes (bad magic) and truncated
frames.  Every episode must end at its horizon, the host's log fetch must work, and every
datagram must be accounted for: what the target's filter counted (by reason) plus what the
kernel dropped at the target's socket (``/proc/net/udp``'s drops column, read while the target
runs) equals what the flood and the host sent.

In host mode the target's real-time loop reads the socket itself (:mod:`impact_env.rig.wire`):
it takes the host's COMMANDs and hands everything else to the network thread through a queue;
what a flood puts in a full queue is counted ``queue_full``.  In real time, every COMMAND the host
sent in an episode must be accounted for by that episode's log: it acted, was superseded or came
late, none lost."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rig_helpers import FLOOD, start_target, stop
from test_rig_session import Recorder

from impact_env.rig.auth import write_key
from impact_env.rig.host import RigEnv

pytestmark = [pytest.mark.slow, pytest.mark.skipif(not Path("/proc/net/udp").exists(),
                                                    reason="reads the kernel's UDP drop counter (Linux)")]

N_FLOOD = 20_000  # datagrams; at the rate one Python process sends them, a second or two
MAX_FLOOD_S = 20.0



def _kernel_drops(port: int) -> int:
    """The drops the kernel counted at the UDP sockets bound to 127.0.0.1:``port`` (a full
    receive buffer): the target's socket and its host's lane."""
    drops = [int(f[-1]) for f in map(str.split, Path("/proc/net/udp").read_text().splitlines()[1:])
             if f[1] == f"0100007F:{port:04X}"]
    assert drops, f"no UDP socket on 127.0.0.1:{port} in /proc/net/udp"
    return sum(drops)


def _since_start(text: str) -> dict[str, int]:
    line = text.split("datagrams since start:")[1].splitlines()[0]
    return {k: int(v) for k, v in re.findall(r"(\w+) (\d+)", line)}


def _flood_during_episodes(tmp_path, lockstep: bool):
    key = write_key(tmp_path / "rig.key")
    args = ["--scene", "rig", "--key", str(key)] + (["--lockstep"] if lockstep else [])
    proc, addr = start_target(*args)
    host, port = re.match(r"udp://([^:]+):(\d+)", addr).groups()
    go = tmp_path / "go"
    env = RigEnv(addr, key=key, hold_ticks=4, horizon=0.02, terminate_on_catch=False, timeout_s=0.2,
                 retries=25, first_command_timeout_s=2.0)
    rec = Recorder(env.client.endpoint)
    env.client.hello()
    hello = rec.of(1)[-1]  # the host's HELLO, as a sniffer would have it
    flood = subprocess.Popen([sys.executable, "-c", FLOOD, host, port, hello.hex(), str(go), str(N_FLOOD),
                              str(MAX_FLOOD_S)], stdout=subprocess.PIPE, text=True)
    ends, fetched, out = [], 0, ""
    episode_sent, episode_counters = [], []
    try:
        assert flood.stdout.readline().strip() == "ready"
        deadline = time.monotonic() + 120.0
        k = 0
        while (flood.poll() is None or k < 2) and time.monotonic() < deadline:
            env.reset(seed=k)
            go.touch()  # the flood starts with the first episode and runs through the next ones
            n_sent = 0
            while True:
                *_, te, tr, info = env.step(np.array([0.05], np.float32))
                n_sent += 1
                if te or tr:
                    break
            ends.append(info.get("end_reason", "HORIZON"))
            end = env.client.wait_end(20.0)
            log = env.client.fetch_log(end.episode, end.data_sha256)  # the host's fetch works mid-flood
            fetched += log.meta.end_reason == ends[-1]
            episode_sent.append(n_sent)
            episode_counters.append(log.meta.counters)
            k += 1
        out, _ = flood.communicate(timeout=60)
        time.sleep(0.5)  # the target reads what is left in its buffer
        drops = _kernel_drops(int(port))
        host_sent = env.client.endpoint.sent
    finally:
        if flood.poll() is None:
            flood.kill()
            flood.wait(5)
        env.close()
        host_sent_final = env.client.endpoint.sent
        assert stop(proc) == 0
    counts = _since_start(proc.stdout.read())
    report = json.loads(out)
    sent = report["sent"]
    n_flood = sum(sent.values())
    print(f"flood ({'lock-step' if lockstep else 'real time'}): {report}, episodes {len(ends)} ends "
          f"{set(ends)}, kernel drops {drops}, target counters {counts}")
    assert n_flood + report["not_sent"] == N_FLOOD or report["elapsed_s"] >= MAX_FLOOD_S
    assert set(ends) == {"HORIZON"} and len(ends) >= 2
    assert fetched == len(ends)
    # every datagram accounted for: the target's filter counted each it read, by one reason, and
    # the kernel counted the ones its full buffer dropped; nothing else went missing on loopback
    assert counts["datagrams_received"] == counts["datagrams_accepted"] + sum(
        v for k, v in counts.items() if k.startswith("dropped_") and k != "dropped_kernel")
    assert host_sent <= host_sent_final
    assert counts["datagrams_received"] + drops == n_flood + host_sent_final
    # and by reason: the replayed HELLOs are a stranger's, the bad tags unauthenticated, the rest corrupt
    # (or, read by the real-time loop while the network thread's queue was full, queue_full)
    flood_counted = counts.get("dropped_stranger", 0) + counts.get("dropped_unauthenticated", 0) \
        + counts.get("dropped_corrupt", 0) + counts.get("dropped_queue_full", 0)
    assert n_flood - drops <= flood_counted <= n_flood
    assert counts.get("dropped_stranger", 0) <= sent["replayed_hello"]
    assert counts.get("dropped_unauthenticated", 0) <= sent["bad_tag"]
    assert counts.get("dropped_corrupt", 0) <= sent["malformed"] + sent["truncated"]
    assert counts["datagrams_accepted"] >= 2 * env.max_steps  # the host's own commands got through
    if not lockstep:  # each of the host's commands is in its episode's log: acted, superseded or late
        for n_sent, c in zip(episode_sent, episode_counters):
            # the last step's command answers the horizon's observation: after the episode's end
            assert c["commands_accepted"] + c["commands_late"] >= n_sent - 1, (n_sent, c)
            assert c["commands_accepted"] == (c["commands_acted"] + c["commands_superseded"]
                                              + c["commands_expired"] + c["commands_unused_at_end"]), c
    # what went back to the flood: BUSY for some replayed HELLOs (rate-limited), never more bytes
    assert report["reply_bytes"] <= sent["replayed_hello"] * len(hello)
    return report, counts, drops


def test_flood_during_lockstep_host_episodes(tmp_path):
    _flood_during_episodes(tmp_path, lockstep=True)


def test_flood_during_realtime_host_episodes(tmp_path):
    _flood_during_episodes(tmp_path, lockstep=False)
