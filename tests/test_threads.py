"""Threads over blocks of envs (impact_env._threads): the vector env, rollouts and compare give
bitwise the same results with any thread count as with the serial call (the env's blocks in
Python threads; compare's compiled loop in one compiled parallel region, its named tuples
flattened through its shim), a block that raises is reported, and a bad thread count is refused
by name.

The blocks' minimum size (the measured threshold below which a batch runs serially) is set to
1 here, so that a handful of envs really runs in 2 and 3 threads."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest
from numba import prange

import impact_env._threads as threads_module
import impact_env.eval.rollout as rollout_module
import impact_env.sim.simulator as simulator_module
from impact_env._jit import jit
from impact_env._threads import (
    check_threads,
    env_blocks,
    flatten,
    machine_threads,
    python_threads,
    resolve_threads,
    unflatten,
)
from impact_env.cli import main
from impact_env.env.vector import ImpactCatchVectorEnv
from impact_env.eval.compare import compare
from impact_env.eval.rollout import rollout
from impact_env.policy.export import export_policy
from impact_env.policy.registry import make_policy
from impact_env.scene import load_scene
from impact_env.sim.simulator import Simulator

RIG = load_scene("rig")
THREADS = (1, 2, 3)  # 3: more threads than the test machine's cores is fine


@pytest.fixture
def small_blocks(monkeypatch):
    monkeypatch.setattr(simulator_module, "MIN_BLOCK_ENVS", 1)
    monkeypatch.setattr(rollout_module, "MIN_BLOCK_EPISODES", 1)


def compiled_region_only(monkeypatch):
    """Blocks must run in the compiled parallel region: the Python-thread fallback fails."""
    def refuse(*args, **kwargs):
        raise AssertionError("the blocks ran in Python threads, not in the compiled parallel region")

    monkeypatch.setattr(threads_module, "python_threads", refuse)


# -- the thread count -------------------------------------------------------------------------------
@pytest.mark.parametrize("bad", [0, -1, 1.5, "2", True])
def test_a_bad_thread_count_is_refused_naming_the_parameter(bad):
    with pytest.raises(ValueError, match=r"threads = .* must be an integer >= 1"):
        check_threads(bad)
    with pytest.raises(ValueError, match="threads"):
        Simulator(RIG, 2, threads=bad)
    with pytest.raises(ValueError, match="threads"):
        ImpactCatchVectorEnv(2, "rig", threads=bad)
    with pytest.raises(ValueError, match="threads"):
        rollout(RIG, make_policy("passive", RIG), [0], horizon=1e-3, threads=bad)
    with pytest.raises(ValueError, match="threads"):
        compare(RIG, ["passive"], episodes=1, horizon=1e-3, workers=1, progress=False, threads=bad)
    sim = Simulator(RIG, 2)
    with pytest.raises(ValueError, match="threads"):
        sim.threads = bad


def test_cli_compare_bad_threads_exits_2(capsys):
    assert main(["compare", "--no-progress", "--threads", "0"]) == 2
    assert "--threads 0 must be an integer >= 1 or 'auto'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:
        main(["compare", "--no-progress", "--threads", "many"])
    assert exit_.value.code == 2
    assert "'many' is neither an integer nor 'auto'" in capsys.readouterr().err


def test_env_blocks_cover_the_envs_and_respect_the_minimum():
    assert check_threads(None) == 1
    assert env_blocks(10, 1, 1) == [(0, 10)]
    assert env_blocks(10, 3, 1) == [(0, 3), (3, 7), (7, 10)]
    assert env_blocks(10, 3, 4) == [(0, 5), (5, 10)]  # blocks of 4 envs at least
    assert env_blocks(10, 3, 64) == [(0, 10)]  # too small a batch: serial
    assert env_blocks(2, 8, 1) == [(0, 1), (1, 2)]
    for n, k, m in ((1, 1, 1), (1000, 7, 3), (65, 2, 64), (128, 2, 64)):
        b = env_blocks(n, k, m)
        assert b[0][0] == 0 and b[-1][1] == n and all(b[j][1] == b[j + 1][0] for j in range(len(b) - 1))
        assert len(b) == 1 or min(i1 - i0 for i0, i1 in b) >= m


def test_auto_picks_the_machines_cpus_at_most_one_per_block():
    cpus = machine_threads()
    assert cpus == len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else cpus >= 1
    assert check_threads("auto") == "auto" and check_threads(" AUTO ") == "auto"
    assert resolve_threads("auto", 10**6, 64) == cpus
    assert resolve_threads("auto", 100, 64) == 1  # one block of 64 envs at most: serial
    assert resolve_threads("auto", 128, 64) == min(cpus, 2)
    assert resolve_threads(3, 10, 64) == 3  # an explicit count is kept (env_blocks applies the minimum)
    sim = Simulator(RIG, 8, threads="auto")
    assert sim.threads == 1  # 8 envs: fewer than one block of MIN_BLOCK_ENVS per thread


def test_flatten_and_unflatten_walk_the_named_tuples_in_field_order():
    from impact_env.sim.step import SimParams, SimState

    sim = Simulator(RIG, 3)
    for value, cls in ((sim.params, SimParams), (sim.state, SimState)):
        flat = flatten(value)
        assert all(not (isinstance(x, tuple) and hasattr(x, "_fields")) for x in flat)
        back = unflatten(flat, cls)
        assert type(back) is cls and type(back[1]) is type(value[1])
        assert all(a is b for a, b in zip(flatten(back), flat, strict=True))


def test_a_block_that_raises_is_reported(small_blocks):
    """A block's kernel that raises: in threads and serially, its own message."""
    sim = Simulator(RIG, 4, threads=2)
    sim.reset([np.random.default_rng(i) for i in range(4)])
    sim.step(np.zeros(4))
    for threads in (2, 1):
        sim.threads = threads
        sim.hw.cursor[2] = sim.hw.noise.shape[1]  # env 2's noise used up, the refill skipped
        with pytest.raises(IndexError, match="noise block used up"):
            sim._run(sim._blocks, (np.zeros(4), sim._all, sim.params, sim.state))


@jit(nogil=True)
def _negative_raises(i0, i1, arr):
    for i in range(i0, i1):
        if arr[i] < 0.0:
            raise ValueError("negative")
        arr[i] += 1.0


@jit(nogil=True)
def _guarded(i0, i1, arr):
    try:
        _negative_raises(i0, i1, arr)
    except Exception:  # noqa: BLE001 - reported by BlockRunner
        return False
    return True


@jit(nogil=True, parallel=True)
def _negative_blocks(bounds, ok, arr):
    for b in prange(bounds.shape[0] - 1):
        ok[b] = _guarded(bounds[b], bounds[b + 1], arr)


def test_a_shim_block_that_raises_is_reported():
    """numba loses an exception raised inside a parallel loop: the shim's guard reports it."""
    run = threads_module.BlockRunner(_negative_raises, _negative_blocks)
    arr = np.zeros(6)
    run(env_blocks(6, 2, 1), (arr,))
    assert (arr == 1.0).all()
    arr[4] = -1.0
    if threads_module.parallel_available():
        with pytest.raises(RuntimeError, match="envs 3 .. 5: the compiled kernel _negative_raises raised"):
            run(env_blocks(6, 2, 1), (arr,))


def _sim_run(threads, n=6, steps=40):
    sim = Simulator(RIG, n, threads=threads)
    sim.reset([np.random.default_rng(100 + i) for i in range(n)])
    rng = np.random.default_rng(5)
    for _ in range(steps):
        sim.step(rng.uniform(-1.0, 1.0, n))
    return [sim.plant_state.copy(), sim.records.copy(), sim.obs.copy(), sim.readings.copy(),
            sim.hw.effect_state.copy()]


def test_the_simulator_step_in_threads_is_bitwise_the_serial_one(small_blocks):
    ref = _sim_run(1)
    for threads in (2, 3, "auto"):
        got = _sim_run(threads)
        for j, (a, b) in enumerate(zip(ref, got, strict=True)):
            assert np.array_equal(a, b, equal_nan=True), f"threads {threads}, #{j}"


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform")
def test_a_child_forked_after_a_threaded_step_still_steps_in_threads(small_blocks):
    """A child forked after a threaded step (compare's process pool) runs its blocks in threads
    of its own, with the same results."""
    ref = _sim_run(1)
    _sim_run(2)  # this process has its pool of threads now
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: exit 0 only if its threaded run equals the serial one
        code = 1
        try:
            os.close(r)
            got = _sim_run(2)
            same = all(np.array_equal(a, b, equal_nan=True) for a, b in zip(ref, got, strict=True))
            code = 0 if same else 3
        finally:
            os._exit(code)
    os.close(w)
    _, status = os.waitpid(pid, 0)
    os.close(r)
    assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0, status


def test_python_threads_runs_every_block_and_raises_after_all_ended():
    out = np.zeros(10)

    def kernel(i0, i1, arr, boom):
        arr[i0:i1] = i0
        if boom and i0 > 0:
            raise RuntimeError(f"block {i0}")

    python_threads(kernel, env_blocks(10, 3, 1), (out, False))
    np.testing.assert_array_equal(out, [0, 0, 0, 3, 3, 3, 3, 7, 7, 7])
    out[:] = -1.0
    with pytest.raises(RuntimeError, match="block 3"):  # the first failing block, in block order
        python_threads(kernel, env_blocks(10, 3, 1), (out, True))
    assert (out >= 0).all()  # every block ran to its end


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform")
def test_a_forked_child_gets_its_own_threads():
    """compare's process pool forks: a child must not wait on its parent's pool threads (which
    it does not have)."""
    out = np.zeros(4)

    def kernel(i0, i1, arr):
        arr[i0:i1] = 1.0

    python_threads(kernel, env_blocks(4, 2, 1), (out,))  # the parent's pool exists now
    pid = os.fork()
    if pid == 0:  # the child: exit 0 only if its blocks ran
        code = 1
        try:
            arr = np.zeros(4)
            done = threading.Event()
            t = threading.Thread(daemon=True, target=lambda: (
                python_threads(kernel, env_blocks(4, 2, 1), (arr,)), done.set()))
            t.start()
            code = 0 if done.wait(20.0) and arr.all() else 1
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0


# -- bitwise: vector env ----------------------------------------------------------------------------
def _vector_run(threads, scene, mode, task):
    n = 5
    env = ImpactCatchVectorEnv(n, scene, autoreset_mode=mode, threads=threads, horizon=2e-3, **task)
    assert len(env.task.sim._blocks) == min(threads, n)
    obs, info = env.reset(seed=11)
    rng = np.random.default_rng(4)
    out = [obs, *info.values()]
    for _ in range(30):  # horizon 2 ms: every env ends (truncated) and is reset on the way
        o, r, te, tr, inf = env.step(rng.uniform(-1.0, 1.0, (n, 1)).astype(np.float32))
        out += [o, r, te, tr]
        for key, v in sorted(inf.items()):
            if key in ("final_obs", "final_info"):
                out += [x for x in v if x is not None] if key == "final_obs" else list(v.values())
            else:
                out.append(v)
    sim = env.task.sim
    out += [sim.plant_state, sim.records, sim.readings, sim.hw.effect_state, sim.fe.state.filt]
    return out


@pytest.mark.parametrize("scene,mode,task", [
    ("rig", "NextStep", {}),
    ("rig-randomized", "SameStep", {"hold_ticks": 2, "residual": "pd-penetration", "history": 2}),
])
def test_vector_env_steps_do_not_depend_on_the_thread_count(small_blocks, scene, mode, task):
    ref = _vector_run(1, scene, mode, task)
    for threads in THREADS[1:]:
        got = _vector_run(threads, scene, mode, task)
        assert len(got) == len(ref)
        for j, (a, b) in enumerate(zip(ref, got, strict=True)):
            assert np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True), f"threads {threads}, #{j}"


# -- bitwise: rollouts and compare ------------------------------------------------------------------
def _same_rollouts(a, b):
    assert a.metrics.keys() == b.metrics.keys()
    for key in a.metrics:
        assert np.array_equal(a.metrics[key], b.metrics[key], equal_nan=True), key
    for key in a.traces:
        assert np.array_equal(a.traces[key], b.traces[key], equal_nan=True), key
    assert np.array_equal(a.t_touch, b.t_touch) and np.array_equal(a.impact_energy, b.impact_energy)
    assert a.failures == b.failures


@pytest.mark.parametrize("spec", ["passive", "pd-penetration", "compiled pd-penetration"])
def test_a_rollout_does_not_depend_on_the_thread_count(small_blocks, monkeypatch, spec):
    """passive and pd-penetration: the Python loop (threads in the simulator's step); the
    compiled policy: the compiled loop (one compiled parallel region over blocks of episodes,
    whole chunks)."""
    if spec.startswith("compiled"):
        compiled_region_only(monkeypatch)

    def run(threads):
        name = spec.split()[-1]
        policy = export_policy(name, RIG) if spec.startswith("compiled") else make_policy(name, RIG)
        return rollout(RIG, policy, [3, 4, 5, 6, 7], horizon=0.012, threads=threads, record_commands=False)

    ref = run(1)
    for threads in THREADS[1:]:
        _same_rollouts(ref, run(threads))


def test_compare_does_not_depend_on_the_thread_count(small_blocks):
    specs = ["passive", "pd-penetration"]
    a = compare(RIG, specs, episodes=4, seed=2, horizon=0.01, workers=1, progress=False, threads=1)
    b = compare(RIG, specs, episodes=4, seed=2, horizon=0.01, workers=1, progress=False, threads=2)
    for spec in specs:
        for key, v in a[spec].metrics.items():
            assert np.array_equal(v, b[spec].metrics[key], equal_nan=True), f"{spec} {key}"
        assert np.array_equal(a[spec].energy_ratio, b[spec].energy_ratio)


def _tbb_installed() -> bool:
    from importlib.metadata import PackageNotFoundError, distribution

    try:
        distribution("tbb")
    except PackageNotFoundError:
        return False
    return True


@pytest.mark.skipif(not _tbb_installed(), reason="TBB not installed (pip install 'impact-env[tbb]'); "
                    ".ci/run runs tests/tbb_layer_check.py in its core venv with the extra")
def test_pips_tbb_is_the_layer_and_gives_the_serial_results():
    """With pip's TBB in the environment (whose libtbb the loader does not find by itself:
    impact_env._threads._pip_tbb loads it), the blocks run on numba's TBB layer, bitwise the
    serial step (tests/tbb_layer_check.py, in a fresh process: the layer is chosen once per
    process)."""
    import subprocess
    import sys
    from pathlib import Path

    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_THREADING_LAYER", "LD_LIBRARY_PATH")}
    proc = subprocess.run([sys.executable, str(Path(__file__).with_name("tbb_layer_check.py"))],
                          capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("OK"), proc.stderr[-2000:]
