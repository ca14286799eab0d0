"""Simulator: N rigs of one scene with their controllers' front ends, stepped one policy step at
a time.

A simulator is the rig's hardware (:class:`impact_env.hardware.batch.Hardware`: actuator delay,
shaker, saturation, plant, sensors, sensor delay) followed by the controller's front end
(:class:`impact_env.control.front_end.FrontEnd`: filters, detector, observation frame): the
same two compiled stages a virtual rig and the real-time target run on either side of the DAQ
card.  One step holds the command for ``hold_ticks`` control periods (the policy rate is the
control rate over ``hold_ticks``) and ends with the observation.  A single environment is a
batch of one.
"""

from __future__ import annotations

import numpy as np

from impact_env._threads import BlockRunner, check_threads, env_blocks, resolve_threads
from impact_env.config import check_hold_ticks
from impact_env.control.front_end import FrontEnd
from impact_env.control.observation import ObservationLayout, make_layout
from impact_env.control.policy import CompiledPolicy
from impact_env.control.residual import residual_arrays, start_residual
from impact_env.hardware.batch import NOISE_BLOCK, Hardware
from impact_env.scene import Scene, load_scene
from impact_env.sim.records import N_PLANT_REC, N_REC
from impact_env.sim.step import SimParams, SimState, sim_step

#: envs per block at least when a step runs in threads (measured: scripts/bench_env.py, section
#: "threads", rig on 2 cores: 2 blocks of 32 envs 0.99x and 1.27x in two runs with a free second
#: core, of 64 envs 1.11x and 1.53x, and 0.82x and 0.90x with the second core busy); a smaller
#: block costs more to hand to a thread (50-90 us) than it saves
MIN_BLOCK_ENVS = 64


class Simulator:
    """N simulated rigs of ``scene`` with the observation ``layout`` (default: the scene's sensor
    channels and detector, history 1).

    ``reset(rngs, mask)`` starts drops (env i's randomness from ``rngs[i]``, see
    :class:`~impact_env.hardware.batch.Hardware`); ``step(actions, active)`` advances the active
    envs by one policy step.  After either: ``obs`` (float32[N, layout.size]), ``readings``
    (float64[N, 4]: the conditioned readings), ``detected``, ``records`` (float64[N, hold_ticks,
    N_REC], :mod:`impact_env.sim.records`) and ``plant_records`` (float64[N, hold_ticks,
    N_PLANT_REC]: the plant's integral and located separations), and the hardware's arrays
    (``plant_state``, ``plant_parameters``, ``t``, ``info``, ``impact_energy``, ``t_touch``,
    ``drawn``) through :attr:`hw`.

    ``residual``: a compiled classic law evaluated every tick on its own observation frame; the
    command of a tick is ``clip(action + law, -1, 1)`` (:mod:`impact_env.sim.step`).

    ``threads``: a step runs its envs in this many threads at once (blocks of at least
    :data:`MIN_BLOCK_ENVS` envs, :class:`~impact_env._threads.BlockRunner`; a smaller batch runs
    serially);
    ``"auto"``: the CPUs this process may use, at most one per :data:`MIN_BLOCK_ENVS` envs;
    None or 1: serially, in the calling thread.  The results do not depend on it, bitwise
    (:mod:`impact_env._threads`).  It may be changed between steps (:attr:`threads`).
    """

    def __init__(self, scene: Scene | str, num_envs: int = 1, layout: ObservationLayout | None = None,
                 hold_ticks: int = 1, residual: CompiledPolicy | None = None, events_per_env: int = 64,
                 threads: int | str | None = None):
        scene = load_scene(scene)
        self.hold = check_hold_ticks(hold_ticks)
        threads = check_threads(threads)
        # a step's noise must fit one block (the stream does not depend on the block's size)
        self.hw = hw = Hardware(scene, num_envs, events_per_env, noise_block=max(NOISE_BLOCK, self.hold))
        self.scene = scene
        self.n = hw.n
        self.period = hw.period
        self.layout = layout if layout is not None else make_layout(scene)
        self.fe = FrontEnd(scene, self.layout, self.n)
        self.records = np.zeros((self.n, self.hold, N_REC))
        self.plant_records = np.zeros((self.n, self.hold, N_PLANT_REC))
        self._all = np.ones(self.n, dtype=bool)
        self._run = BlockRunner(sim_step)  # over the blocks of envs (threads)
        self.residual = residual
        if residual is not None:
            if residual.mlp is not None or residual.history != 1:
                raise ValueError(f"residual: {residual.name!r} must be a classic law (history 1), evaluated "
                                 "every tick; a network cannot be the base of a residual policy")
            residual.check_scene(scene)
        law_p, law_s = residual_arrays(residual, self.layout, self.n)
        fe = self.fe
        #: the compiled step's parameters and state (named tuples over the arrays of hw and fe)
        self.params = SimParams(self.hold, hw.params, fe.params, fe.obs_params, law_p)
        self.state = SimState(hw.state, fe.state, fe.obs_state, law_s, self.records, self.plant_records)
        self._blocks: list[tuple[int, int]] = []
        self.threads = threads

    @property
    def threads(self) -> int:
        """How many threads a step runs its envs in (1: serially; ``"auto"`` resolved:
        :func:`impact_env._threads.resolve_threads`); may be set between steps."""
        return self._threads

    @threads.setter
    def threads(self, threads: int | str | None) -> None:
        self._threads = resolve_threads(check_threads(threads), self.n, MIN_BLOCK_ENVS)
        self._blocks = env_blocks(self.n, self._threads, MIN_BLOCK_ENVS)

    # -- episodes ------------------------------------------------------------------------------
    def reset(self, rngs, mask=None) -> np.ndarray:
        """Start new drops where ``mask`` is true (all if None); returns their indices."""
        idx = self.hw.reset(rngs, mask)
        self.fe.start(idx, self.hw.raw, self.hw.plant_state)
        if self.residual is not None:  # the law's memory and first frame, from the same readings
            start_residual(np.asarray(idx, dtype=np.int64), self.hw.plant_state, self.fe.state,
                           self.params.law,
                           self.state.law)
        self.records[idx] = 0.0
        self.plant_records[idx] = 0.0
        return idx

    def step(self, actions, active=None) -> None:
        """One policy step (``hold_ticks`` ticks) of every env (or of those where ``active`` is
        true: the others are left exactly as they are) under float64[N] commands in [-1, 1]."""
        self._run(self._blocks, self.step_args(actions, active))

    @property
    def blocks(self) -> list[tuple[int, int]]:
        """The blocks of envs a step runs at once (one: the serial call)."""
        return self._blocks

    def step_args(self, actions, active=None) -> tuple:
        """The arguments after ``(i0, i1)`` of :func:`~impact_env.sim.step.sim_step` for one step
        (``actions, active, params, state``), the step's noise drawn: for a caller that runs the
        step inside a kernel of its own, over :attr:`blocks` (the catch task's
        :func:`~impact_env.env.task_kernel.catch_step`)."""
        n = self.n
        # C-contiguous and writeable, as the compiled kernels were compiled for (a copy otherwise)
        a = np.require(actions, np.float64, ("C", "W")).reshape(n)
        act = self._all if active is None else np.require(active, bool, ("C", "W")).reshape(n)
        self.hw.refill_noise(self.hold, None if active is None else act, self._blocks)
        return a, act, self.params, self.state

    # -- what the rest of the project reads ---------------------------------------------------
    @property
    def obs(self) -> np.ndarray:
        return self.fe.obs

    @property
    def readings(self) -> np.ndarray:
        return self.fe.cond

    @property
    def detected(self) -> np.ndarray:
        return self.fe.detected

    @property
    def plant_state(self) -> np.ndarray:
        return self.hw.plant_state

    @property
    def plant_parameters(self) -> np.ndarray:
        return self.hw.plant_parameters

    # the old names of plant_state and plant_parameters (eval/ and rig/ read them)
    @property
    def Y(self) -> np.ndarray:
        return self.hw.plant_state

    @property
    def P(self) -> np.ndarray:
        return self.hw.plant_parameters

    @property
    def t(self) -> np.ndarray:
        return self.hw.t

    @property
    def info(self) -> np.ndarray:
        return self.hw.info

    @property
    def impact_energy(self) -> np.ndarray:
        return self.hw.impact_energy

    @property
    def t_touch(self) -> np.ndarray:
        return self.hw.t_touch

    @property
    def drawn(self) -> list[dict[str, float]]:
        return self.hw.drawn

    def catch_energy(self) -> np.ndarray:
        return self.hw.catch_energy()

    def diverged(self) -> np.ndarray:
        return self.hw.diverged()
