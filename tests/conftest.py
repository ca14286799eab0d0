"""Fixtures that several tests share (where each module is tested: tests/MAP.md).

* ``root``: the repository's root folder.
* ``scene``: a preset scene by name, built once per session (``scene("rig")``).
* ``wait_until``: a hang guard for a test that waits on another thread or process; its limit is
  far above what the awaited operation takes (a guard against waiting forever, not a check of
  speed: a loaded 2-core machine may be many times slower than an idle one).
* ``rig_runs``: a short comparison of three classic laws on ``rig`` (3 episodes of 50 ms), the
  input of the plot tests.
* ``warm_kernels``: the simulator's kernels compiled (or loaded from the cache) in this process
  before a test starts other processes that run them (a CLI in a subprocess, a forked pool, a
  fresh interpreter): on a cold cache (a fresh clone, CI) each of those would compile the same
  kernels itself, several at once on the same cores.

Shared modules (reference solutions, error budgets, the golden cases) sit beside this file and
import by name (``pythonpath`` in pyproject.toml).
"""

from __future__ import annotations

import functools
import time
from pathlib import Path

import pytest

from impact_env.eval.compare import compare, warm_up
from impact_env.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
RIG_RUN_SPECS = ("passive", "thesis-rig", "pd-penetration")  # passive: no force, so no spectrum line


@pytest.fixture(scope="session")
def root() -> Path:
    return ROOT


@pytest.fixture(scope="session")
def scene():
    """``scene(name)``: the preset ``name``, built once per session (scenes are frozen)."""
    return functools.cache(load_scene)


@pytest.fixture(scope="session")
def wait_until():
    """``wait_until(condition, what, limit_s)``: poll ``condition()`` until it is true; fail
    naming ``what`` after ``limit_s`` seconds (a hang guard: see the module doc)."""
    def wait(condition, what: str, limit_s: float) -> None:
        deadline = time.monotonic() + limit_s
        while not condition():
            if time.monotonic() > deadline:
                pytest.fail(f"{what} did not happen within {limit_s:g} s")
            time.sleep(0.05)
    return wait


@pytest.fixture(scope="session")
def warm_kernels():
    warm_up(load_scene("rig"), 0.01)


@pytest.fixture(scope="session")
def rig_runs(warm_kernels):
    return compare(load_scene("rig"), list(RIG_RUN_SPECS), episodes=3, seed=0, horizon=0.05, workers=1,
                   progress=False)
