"""Native vector env: N rigs stepped in one numba call (the single env's task, batched).

``gymnasium.make_vec("ImpactCatch-v0", num_envs=N, vectorization_mode="vector_entry_point",
scene="rig")`` returns :class:`ImpactCatchVectorEnv`.  Its env i behaves exactly like
``gymnasium.make("ImpactCatch-v0", ...)`` reset with ``seed + i`` (Gymnasium's convention for
vector seeding), bitwise: both run :class:`~impact_env.env.task.CatchTask` on the same kernel.

Autoreset (``metadata["autoreset_mode"]``, chosen with ``autoreset_mode=``):

* ``NEXT_STEP`` (default, Gymnasium's): the step after an env ended resets it, ignores its action
  and returns its first observation with reward 0 and both flags false.
* ``SAME_STEP``: an env that ends is reset within the same step; the returned observation is the
  new episode's first, and the last one is in ``info["final_obs"]`` (with ``info["final_info"]``).
  The SB3 adapter (:mod:`impact_env.env.sb3_vecenv`) uses this mode.
* ``DISABLED``: nothing is reset; call ``reset(options={"reset_mask": mask})``.  Stepping an env
  that ended goes on simulating it (used by ``impact-env compare`` with fixed-length episodes).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from impact_env._threads import check_threads
from impact_env.control.observation import OBS_LIMIT
from impact_env.env import task_kernel
from impact_env.env.task import REWARD_TIME_UNIT, TaskConfig, make_catch_task
from impact_env.scene import Scene


class ImpactCatchVectorEnv(VectorEnv):
    """N copies of ``ImpactCatch-v0`` stepped in one call; arguments as the single env's
    (:class:`~impact_env.env.catch_env.ImpactCatchEnv`: the task's options are
    :class:`~impact_env.env.task.TaskConfig`'s fields) plus ``num_envs``, ``autoreset_mode`` and
    ``threads``: the simulator steps its envs in this many threads at once, in blocks of at
    least :data:`~impact_env.sim.simulator.MIN_BLOCK_ENVS` envs (None or 1: serially;
    ``"auto"``: the CPUs this process may use, at most one per block); the results do not depend
    on it, bitwise (docs/env.md, "Threads")."""

    def __init__(self, num_envs: int = 1, scene: Scene | str | dict = "rig", overrides: dict | None = None, *,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 render_mode: str | None = None, threads: int | str | None = None, **task: Any):
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs = {num_envs!r} must be an integer >= 1")
        threads = check_threads(threads)  # (an int, or "auto": the simulator resolves it for N)
        mode = AutoresetMode(autoreset_mode) if isinstance(autoreset_mode, str) else autoreset_mode
        if not isinstance(mode, AutoresetMode):
            raise ValueError(f"autoreset_mode = {autoreset_mode!r}; expected one of "
                             f"{[m.value for m in AutoresetMode]}")
        cfg = TaskConfig.from_options(task, type(self).__init__)
        self.task = make_catch_task(scene, int(num_envs), cfg, overrides, threads=threads)
        self.scene = self.task.scene
        self.layout = self.task.layout
        self.num_envs = int(num_envs)
        self.metadata = {"autoreset_mode": mode, "render_modes": ["rgb_array"], "render_fps": 30}
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode = {render_mode!r}; the vector env renders 'rgb_array' or None")
        self.render_mode = render_mode
        self.single_action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.single_observation_space = spaces.Box(-OBS_LIMIT, OBS_LIMIT, (self.layout.size,), np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.reward_time_unit = REWARD_TIME_UNIT
        self._rngs: list[np.random.Generator] | None = None
        self._done = np.zeros(self.num_envs, dtype=bool)
        self._started = False

    # -- seeding ---------------------------------------------------------------------------------
    def _seed(self, seed) -> None:
        seeds: list[int | None]
        if seed is None:
            seeds = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed has {len(seeds)} entries; expected one per env ({self.num_envs})")
        self._rngs = [seeding.np_random(s)[0] for s in seeds]
        self._np_random, self._np_random_seed = seeding.np_random(seeds[0])

    def reset(self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None):
        """Reset every env (or those in ``options["reset_mask"]``); ``seed`` int: env i gets
        ``seed + i``; a list: one seed per env."""
        if seed is not None or self._rngs is None:
            self._seed(seed)
        mask = None
        if options and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"], dtype=bool)
            if mask.shape != (self.num_envs,):
                raise ValueError(f"options['reset_mask'] has shape {mask.shape}; expected ({self.num_envs},)")
        self.task.reset(self._rngs, mask)
        if mask is None:
            self._done[:] = False
        else:
            self._done[mask] = False
        self._started = True
        return self.task.obs.copy(), self._infos()

    # -- stepping ---------------------------------------------------------------------------------
    def step(self, actions):
        return self.step_arrays(actions, infos=True)

    def step_arrays(self, actions, infos: bool = True):
        """:meth:`step`; with ``infos=False`` the info dict is left empty except, in SAME_STEP
        mode, ``final_obs`` and ``final_info`` of the envs that ended (what SB3 needs: building
        every info array each step would cost more than the rest of a small batch's step)."""
        if not self._started:
            raise RuntimeError("call reset() before step()")
        task = self.task
        a = task.check_actions(actions)
        mode = self.metadata["autoreset_mode"]
        active = None
        if mode == AutoresetMode.NEXT_STEP and self._done.any():
            # the envs that ended last step are reset and report their first observation: they
            # sit this step out (their action is ignored, reward 0, no flags)
            task.reset(self._rngs, self._done)
            active = ~self._done
        # the step writes the info rows as columns too: the info arrays without a transposing copy
        cols = np.empty((task_kernel.N_COL,
                         self.num_envs)) if infos or mode == AutoresetMode.SAME_STEP else None
        rewards, terminated, truncated = (x.copy() for x in task.step(a, active, cols))
        ended = terminated | truncated
        out: dict[str, Any] = {}
        if mode == AutoresetMode.SAME_STEP and ended.any():
            final_obs = np.full(self.num_envs, None, dtype=object)
            for i in np.nonzero(ended)[0]:
                final_obs[i] = task.obs[i].copy()
            final_info = self._infos(cols)
            task.reset(self._rngs, ended)
            if infos:
                out = self._infos()  # the new episodes' first infos where envs were reset
            out["final_obs"] = final_obs
            out["_final_obs"] = ended.copy()
            out["final_info"] = final_info
            out["_final_info"] = ended.copy()
        elif infos:
            out = self._infos(cols)
        self._done = ended
        return task.obs.copy(), rewards, terminated, truncated, out

    def _infos(self, cols: np.ndarray | None = None) -> dict[str, Any]:
        infos: dict[str, Any] = {}
        every = np.ones(self.num_envs, dtype=bool)
        for k, v in self.task.info_arrays(cols).items():
            infos[k] = v
            infos["_" + k] = every
        return infos

    def render(self):
        if self.render_mode is None:
            return None
        from impact_env.env.render import draw_frame  # matplotlib loads only to render

        return tuple(draw_frame(self.task, i) for i in range(self.num_envs))
