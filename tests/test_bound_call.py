"""The simulator's and the task's kernels are called through entry points bound to their
argument types at the first step (``impact_env._jit.bound_call``, skipping numba's per-call
typing): arguments that arrive with other layouts (read-only, strided, lists) must be
converted, not reinterpreted.  Checked bitwise against plain arrays."""

from __future__ import annotations

import numpy as np
from gymnasium.utils import seeding

from impact_env.env.task import TaskConfig, make_catch_task
from impact_env.sim.simulator import Simulator


def _odd(a: np.ndarray, k: int):
    """``a``'s values as a read-only array, a strided view or a list, by turn."""
    ro = a.copy()
    ro.flags.writeable = False
    return (ro, np.repeat(a, 2)[::2], a.tolist())[k % 3]


def test_simulator_odd_argument_layouts_give_the_plain_arrays_results():
    n = 3
    plain, odd = Simulator("rig", n), Simulator("rig", n)
    for s in (plain, odd):
        s.reset([seeding.np_random(10 + i)[0] for i in range(n)])
    rng = np.random.default_rng(0)
    for k in range(60):
        a = rng.uniform(-0.5, 0.5, n)
        mask = np.array([True, k % 2 == 0, True])
        plain.step(a, mask)
        odd.step(_odd(a, k), _odd(mask, k + 1))
        assert np.array_equal(plain.obs, odd.obs) and np.array_equal(plain.Y, odd.Y), k


def test_task_odd_masks_give_the_plain_arrays_results():
    n = 3
    plain, odd = (make_catch_task("rig", n, TaskConfig()) for _ in range(2))
    for t in (plain, odd):
        t.reset([seeding.np_random(20 + i)[0] for i in range(n)])
    rng = np.random.default_rng(1)
    for k in range(60):
        a = rng.uniform(-0.5, 0.5, n)
        mask = np.array([k % 3 != 0, True, k % 2 == 0])
        r1 = [x.copy() for x in plain.step(a, mask)]
        r2 = [x.copy() for x in odd.step(a.copy(), _odd(mask, k))]
        assert all(np.array_equal(x, y) for x, y in zip(r1, r2, strict=True)), k
        assert np.array_equal(plain.rows, odd.rows), k
