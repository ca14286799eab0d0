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
import os
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


# IMPACT_ENV_COMPILE_LOG=FILE: every numba compile of a project kernel in this run, one JSON line
# each (the test that caused it, the kernel, its argument types, wall and CPU seconds (numba
# compiles in the calling thread, so its CPU time moves little with the machine's load), nesting
# depth, the worker's pid), for finding where a cold-cache suite spends its time (.ci/compile_report.py)
_COMPILE_LOG = os.environ.get("IMPACT_ENV_COMPILE_LOG")
_CURRENT_TEST = {"nodeid": "(collection)"}


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    _CURRENT_TEST["nodeid"] = item.nodeid
    if not _COMPILE_LOG:
        yield
        return
    import json
    import resource

    def cpu():  # this process and the children it has waited for
        own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime

    t0, cpu0 = time.perf_counter(), cpu()
    yield
    row = {"test": item.nodeid, "kind": "test", "s": round(time.perf_counter() - t0, 3),
           "cpu_s": round(cpu() - cpu0, 3), "pid": os.getpid()}
    with open(_COMPILE_LOG, "a") as log:
        log.write(json.dumps(row) + "\n")


if _COMPILE_LOG:
    import json

    from numba.core import event

    from impact_env import _jit

    class _CompileLog(event.Listener):
        def __init__(self):
            self.started: list[tuple[float, float]] = []

        def on_start(self, ev):
            self.started.append((time.perf_counter(), time.thread_time()))

        def on_end(self, ev):
            t0, cpu0 = self.started.pop()
            dispatcher = ev.data.get("dispatcher")
            func = getattr(dispatcher, "py_func", None)
            if func is None or id(func) not in _jit._KERNELS:
                return
            row = {"test": _CURRENT_TEST["nodeid"], "kind": "compile", "kernel": _jit._kernel_name(func),
                   "args": str(ev.data.get("args")), "s": round(time.perf_counter() - t0, 3),
                   "cpu_s": round(time.thread_time() - cpu0, 3),
                   "depth": len(self.started), "pid": os.getpid()}
            with open(_COMPILE_LOG, "a") as log:
                log.write(json.dumps(row) + "\n")

    event.register("numba:compile", _CompileLog())
