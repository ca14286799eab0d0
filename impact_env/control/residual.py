"""The residual law: a compiled classic law evaluated every tick under the policy's action, on its
own observation frame, the command of a tick being ``clip(action + law, -1, 1)`` (the env's
``residual`` option; the simulator and the rig target run these same kernels).

Parameters and state apart, as named tuples: :class:`ResidualParams` (whether there is a law,
its packed arrays, its observation layout) and :class:`ResidualState` (its memory and
observation buffers, started by :func:`start_residual`).  Without a law both hold arrays of the
same types, so that one compiled kernel serves both cases.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env.control.front_end import ObsParams, ObsState, obs_params, obs_state, observe, start_rows
from impact_env.control.observation import ObservationLayout
from impact_env.control.policy import CompiledPolicy, PolicyArrays, act


class ResidualParams(NamedTuple):
    on: bool  # False: no residual law (the arrays are placeholders)
    law: PolicyArrays  # the law's packed policy (impact_env.control.policy.act)
    obs: ObsParams  # the law's observation layout (history 1)


class ResidualState(NamedTuple):
    memory: np.ndarray  # float64[N, m]: the law's memory, zeroed at an episode start
    obs: ObsState  # the law's observation buffers


def residual_arrays(law: CompiledPolicy | None, layout: ObservationLayout,
                    n: int) -> tuple[ResidualParams, ResidualState]:
    """(params, state) of the residual ``law`` for n envs; with no law, placeholders of the same
    types (on ``layout``, one env)."""
    if law is None:
        return (ResidualParams(False, PolicyArrays(np.zeros(1, np.int64), np.zeros(1)), obs_params(layout)),
                ResidualState(np.zeros((n, 1)), obs_state(layout, 1)))
    pi, pf, m = law.arrays()
    return (ResidualParams(True, PolicyArrays(pi, pf), obs_params(law.layout)),
            ResidualState(np.zeros((n, m)), obs_state(law.layout, n)))


@jit(inline="always")
def add_residual(u, i, p, s):
    """``clip(u + law, -1, 1)``: env i's command with the law's on its last frame."""
    u = u + act(p.law.ints, p.law.floats, s.obs.obs[i], s.memory[i])
    return -1.0 if u < -1.0 else (1.0 if u > 1.0 else u)


@jit(inline="always")
def observe_residual(i, truth, fe, p, s):
    """Rebuild env i's law frame from the front end's conditioned readings (FrontEndState ``fe``)."""
    observe(i, False, 0.0, truth, fe, p.obs, s.obs)


@jit
def start_residual(idx, truth, fe, p, s):
    """Episode start of envs ``idx``: the law's memory cleared, its first frame written from the
    front end's start readings."""
    for m in range(idx.shape[0]):
        s.memory[idx[m]] = 0.0
    start_rows(idx, truth, fe, p.obs, s.obs)
