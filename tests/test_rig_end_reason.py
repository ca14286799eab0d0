"""One end reason, the same on the host and in the target's log: a host whose task catches body 1
(terminate_on_catch) tells the target so (DISARM reason CAUGHT, acknowledged), and the episode's
log, its EPISODE_END and the host's ``info["end_reason"]`` all say CAUGHT.  A lock-step target in
a thread of this process, on loopback; every wait bounded."""

from __future__ import annotations

import threading

import numpy as np

from impact_env.rig import protocol
from impact_env.rig.driver import VirtualRig
from impact_env.rig.host import RigEnv
from impact_env.rig.target import Target, TargetConfig


def test_a_catch_on_the_host_is_the_logs_end_reason_too(monkeypatch):
    """The host's task kernel says terminated at step 3 (a catch, injected): the host returns
    terminated with end_reason CAUGHT, and the target's log and EPISODE_END say CAUGHT (before,
    the host's plain DISARM made the log say DISARMED)."""
    target = Target(VirtualRig("rig"), config=TargetConfig(lockstep=True))
    th = threading.Thread(target=target.serve, daemon=True)
    th.start()
    real = RigEnv._task_step

    def caught_at_step_3(self, recs, state, out):
        real(self, recs, state, out)
        out.terminated[0] = self._n >= 3

    monkeypatch.setattr(RigEnv, "_task_step", caught_at_step_3)
    env = RigEnv(target.address, hold_ticks=4, horizon=0.01, timeout_s=0.2, retries=25)
    try:
        env.reset(seed=9)
        for _ in range(env.max_steps):
            *_, term, trunc, info = env.step(np.array([0.0], np.float32))
            if term or trunc:
                break
        assert term and not trunc and info["end_reason"] == "CAUGHT" and env._n == 3
        end = env.client.wait_end(10.0)
        assert end.reason == protocol.EndReason.CAUGHT
        log = env.client.fetch_log(end.episode, end.data_sha256)
        assert log.meta.end_reason == "CAUGHT" and log["tick"][-1] < env.max_steps * 4
    finally:
        env.close()
        target.stop()
        th.join(10)
