"""Set-ups that several tests share, built once per test session.

* ``rig_runs``: a short comparison of three classic laws on ``rig`` (3 episodes of 50 ms), the
  input of the plot tests.
* ``warm_kernels``: the simulator's kernels compiled (or loaded from the cache) in this process
  before a test starts other processes that run them (a CLI in a subprocess, a forked pool, a
  fresh interpreter): on a cold cache (a fresh clone, CI) each of those would compile the same
  kernels itself, several at once on the same cores.
"""

from __future__ import annotations

import pytest

RIG_RUN_SPECS = ("passive", "thesis-rig", "pd-penetration")  # passive: no force, so no spectrum line


@pytest.fixture(scope="session")
def warm_kernels():
    from impact_env.eval.compare import warm_up
    from impact_env.scene import load_scene

    warm_up(load_scene("rig"), 0.01)


@pytest.fixture(scope="session")
def rig_runs(warm_kernels):
    from impact_env.eval.compare import compare
    from impact_env.scene import load_scene

    return compare(load_scene("rig"), list(RIG_RUN_SPECS), episodes=3, seed=0, horizon=0.05, workers=1,
                   progress=False)
