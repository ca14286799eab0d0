"""The step's named tuples bound once (:mod:`impact_env._bind`): the bound call is the kernel's own
call, bitwise, through resets, autoresets and copies; it is really used; and what it cannot bind
is left to the direct call."""

from __future__ import annotations

import copy

import gymnasium as gym
import numpy as np
import pytest

import impact_env  # noqa: F401  (registers ImpactCatch-v0)
from impact_env import _bind
from impact_env.env import task_kernel as TK
from impact_env.env.task import PreparedStep
from impact_env.env.vector import ImpactCatchVectorEnv

pytestmark = pytest.mark.skipif(not _bind.ENABLED, reason="IMPACT_ENV_BIND=0")


def _episodes(env, steps: int, seed: int, unbound: bool) -> list[np.ndarray]:
    runner = env.unwrapped.task._run
    if unbound:
        runner._bound = False  # the direct call, never bound
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    out = [obs.copy()]
    for k in range(steps):
        action = rng.uniform(-1.0, 1.0, size=env.action_space.shape).astype(np.float32)
        if k % 7 == 3:  # outside [-1, 1] (clipped) and as a list: the general path
            action = 1.5 * action if k % 2 else action.tolist()
        obs, r, term, trunc, info = env.step(action)
        out.append(np.concatenate([obs.ravel(), [r, term, trunc], np.asarray(list(info.values())[:-1], float),
                                   info["state"]]))
        if term or trunc:
            obs, _ = env.reset()
            out.append(obs.copy())
    return out


@pytest.mark.parametrize("scene", ["rig", "rig-randomized"])
def test_single_env_bound_is_bitwise_the_direct_call(scene):
    bound_env = gym.make("ImpactCatch-v0", scene=scene, hold_ticks=16)
    direct_env = gym.make("ImpactCatch-v0", scene=scene, hold_ticks=16)
    a = _episodes(bound_env, 600, 3, unbound=False)  # 250 steps of 1.6 ms an episode: two resets
    b = _episodes(direct_env, 600, 3, unbound=True)
    assert isinstance(bound_env.unwrapped.task._run._bound, _bind.Bound)  # the bound call ran
    assert isinstance(bound_env.unwrapped._prepared, PreparedStep)  # and the prepared step
    assert direct_env.unwrapped.task._run._bound is False and direct_env.unwrapped._prepared is False
    assert len(a) == len(b) >= 603  # two resets happened
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x, y, equal_nan=True)


@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_vector_env_bound_is_bitwise_the_direct_call(mode):
    runs = []
    for unbound in (False, True):
        env = ImpactCatchVectorEnv(6, "rig-randomized", hold_ticks=8, autoreset_mode=mode)
        if unbound:
            env.task._run._bound = False
        rng = np.random.default_rng(5)
        obs, _ = env.reset(seed=11)
        rows = [obs.copy()]
        for _ in range(120):
            obs, r, te, tr, info = env.step(rng.uniform(-1.0, 1.0, size=(6, 1)))
            rows += [obs.copy(), r, te, tr, info["t"].copy()]
        assert (env.task._run._bound is False) == unbound
        assert unbound or isinstance(env.task._run._bound, _bind.Bound)
        runs.append(rows)
    for x, y in zip(*runs, strict=True):
        assert np.array_equal(x, y, equal_nan=True)


def test_a_copied_env_binds_its_own_arrays():
    env = gym.make("ImpactCatch-v0", scene="rig")
    env.reset(seed=2)
    zero = np.zeros(env.action_space.shape, np.float32)
    for _ in range(5):
        env.step(zero)
    bound = env.unwrapped.task._run._bound
    assert isinstance(bound, _bind.Bound)
    prepared = env.unwrapped._prepared
    assert isinstance(prepared, PreparedStep)
    twin = copy.deepcopy(env)
    assert twin.unwrapped.task._run._bound is None  # not the original's pointers
    assert twin.unwrapped._prepared is None
    kept = env.unwrapped.task.obs.copy()
    steps = [twin.step(np.full(env.action_space.shape, 0.5, np.float32))[0] for _ in range(20)]
    assert np.array_equal(env.unwrapped.task.obs, kept)  # the original is untouched by the copy's steps
    assert isinstance(twin.unwrapped.task._run._bound, _bind.Bound) and twin.unwrapped.task._run._bound is not bound
    assert isinstance(twin.unwrapped._prepared, PreparedStep) and twin.unwrapped._prepared is not prepared
    again = [env.step(np.full(env.action_space.shape, 0.5, np.float32))[0] for _ in range(20)]
    for x, y in zip(steps, again, strict=True):
        assert np.array_equal(x, y)


def test_the_single_env_steps_through_its_prepared_step_only_with_a_command_in_range(monkeypatch):
    env = gym.make("ImpactCatch-v0", scene="rig")
    env.reset(seed=1)
    inner = env.unwrapped
    task = inner.task
    general = []
    step = task.step
    monkeypatch.setattr(task, "step", lambda *a, **k: general.append(1) or step(*a, **k))
    env.step(np.zeros(1, np.float32))  # the first step: the general path, which prepares the next
    assert len(general) == 1 and isinstance(inner._prepared, PreparedStep)
    for x in (0.3, -1.0, 1.0, 0.0):
        env.step(np.array([x], np.float32))
    assert len(general) == 1  # in range: the prepared step, not the task's
    for action in (np.array([1.5], np.float32), [0.2], np.array([[0.1]])):
        env.step(action)  # clipped, a list, a (1, 1) array: the general path
    assert len(general) == 4
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([np.nan], np.float32))  # NaN fails the range test: the general path's error
    assert len(general) == 4


def test_what_it_cannot_bind_is_left_to_the_direct_call():
    env = gym.make("ImpactCatch-v0", scene="rig")
    env.reset(seed=0)
    task = env.unwrapped.task
    sim = task.sim
    args = (0, 1) + sim.step_args(np.zeros(1), None) + (task.drop, task.params, task.state, task.out, task._no_cols)
    strided = task.out._replace(rewards=np.zeros(4)[::2])  # not contiguous: carray cannot rebuild it
    assert _bind.bind(TK.catch_step, args[:9] + (strided,) + args[10:]) is None
    assert isinstance(_bind.bind(TK.catch_step, args), _bind.Bound)


def test_a_folder_others_may_write_to_is_not_used(tmp_path):
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)  # a shim imported from here could be someone else's code
    assert not _bind._private(shared)
    shared.chmod(0o700)
    assert _bind._private(shared)
