"""The first episode of a fresh target is like any other: its kernels compiled, h5py started and
the episode's memory written before it says it listens and before it answers the first ARM, and
the link's watch started with the loop, so that a first episode does not end at its first steps
(FIRST_COMMAND_TIMEOUT, OVERRUN, LINK_LOST) with the host's step-0 command counted after its end.
Fresh target processes on loopback, in lock-step and in real time with a host delayed by a fixed
time (a 1 kHz target at hold 10: 10 ms steps, the host answering 2 ms after each observation);
every wait bounded."""

from __future__ import annotations

import re
import time

import numpy as np
import pytest
from rig_helpers import slow_rate_args, start_target, stop

from impact_env.rig.host import RigEnv

pytestmark = pytest.mark.slow
N_TARGETS = 2  # fresh processes per mode


@pytest.mark.parametrize("lockstep", [True, False], ids=["lockstep", "realtime"])
def test_each_fresh_targets_first_episode_reaches_its_horizon(lockstep):
    for k in range(N_TARGETS):
        args = ["--scene", "rig", *slow_rate_args(1000)] + (["--lockstep"] if lockstep else [])
        proc, addr = start_target(*args)
        env = None
        try:
            env = RigEnv(addr, hold_ticks=10, horizon=0.2, terminate_on_catch=False, timeout_s=0.2,
                         retries=25, spin_s=0.0)
            env.reset(seed=100 + k)
            steps = 0
            while True:
                if not lockstep:
                    time.sleep(0.002)  # the delayed host: 2 ms of its 10 ms step
                *_, term, trunc, info = env.step(np.array([0.05], np.float32))
                steps += 1
                if term or trunc:
                    break
            assert info["end_reason"] == "HORIZON", (k, steps, info)
            log = env.client.fetch_log()
            c = log.meta.counters
            assert log.meta.end_reason == "HORIZON" and c["commands_acted"] >= 1, c
            assert int(log["command_step"].max()) >= 0  # a command of the host's drove the shaker
        finally:
            if env is not None:
                env.close()
            stop(proc)
        out, err = proc.stdout.read(), proc.stderr.read()
        after = re.search(r"commands_after_end (\d+)", out)
        assert after is None or int(after.group(1)) <= 1, out  # at most the last step's, never step 0's
        # what the target applied of its placement, and what not, is said at start (real time: with
        # its cost, measured as the loop runs)
        assert re.search(r"impact-env rig: (not )?applied: ", err), err[-2000:]
        assert lockstep or "paced as the loop" in err, err[-2000:]
