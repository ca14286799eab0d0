"""The filter's estimate beside a DAgger student's observation (``agents.distill
--student-observation estimate``): the student reads ``[observation row, features]``, the
features made by the same compiled code that runs before the network in its compiled policy
(:mod:`impact_env.control.estimation.features`), so the trained network meets the same inputs
in ``compare``, on the rig and in the C export."""

from __future__ import annotations

import numpy as np

from impact_env.control.estimation import features as estimate
from impact_env.control.estimation.layout import MEMORY


class StudentEstimator:
    """The filter of ``n`` envs of ``scene`` whose observation frames are named ``frame_names``
    (values divided by ``frame_scales``): :meth:`read` gives the features of this tick,
    :meth:`applied` tells the filter the commands the envs applied, :meth:`start` clears it."""

    def __init__(self, scene, frame_names, frame_scales, n: int):
        self.k = estimate.estimator_constants(scene)
        self.memory = np.zeros((n, MEMORY))
        self.columns = np.array([list(frame_names).index(r) for r in estimate.READS], dtype=np.int64)
        self.scales = np.asarray(frame_scales, dtype=np.float64)[self.columns]
        self.command_scale = float(scene.effects.command_scale)
        self.frames = np.zeros((n, len(estimate.READS)))
        self.out = np.zeros((n, estimate.N_FEATURES))

    def start(self, rows=slice(None)) -> None:
        self.memory[rows] = 0.0

    def read(self, obs: np.ndarray) -> np.ndarray:
        """float32[n, N_FEATURES]: the filter's estimate after this tick's readings (the newest
        frame of ``obs``, scaled as the env gives it: the compiled policy reads the same float32
        entries times the same scales)."""
        self.frames[:] = obs[:, self.columns].astype(np.float64) * self.scales
        estimate.features_batch(self.k, self.memory, self.frames, self.out)
        return self.out.astype(np.float32)

    def applied(self, commands: np.ndarray) -> None:
        """The commands (float[n, 1], fractions of the command scale) applied after :meth:`read`."""
        forces = np.ascontiguousarray(np.asarray(commands, dtype=np.float64)[:, 0] * self.command_scale)
        estimate.applied_batch(self.k, self.memory, self.frames, forces)
