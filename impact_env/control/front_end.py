"""The controller's front end: the compiled code between the raw readings and the policy.

Per tick, :func:`condition` runs the scene's filters (Butterworth SOS per channel,
:mod:`impact_env.effects.filters`) and the contact detector (thesis eq 4.4,
:mod:`impact_env.effects.detector`) on the raw readings.  Per policy step, :func:`observe` builds
the observation row from the conditioned readings: the layout's channels and detector bit (and,
in simulation only, the true state for privileged observations), each divided by its reference
scale and clipped, stacked with the previous frames and actions when the history is longer than
one (:mod:`impact_env.control.observation`).

The simulator and the real-time target call these same kernels, so a deployed policy sees what
it saw in simulation.  Argument groups (tuples):

* ``fe`` = (flags, sos float64[4, S, 6], filt float64[N, 4, S, 2], det_params float64[5],
  det_state float64[N, 2], cond float64[N, 4], detected float64[N]);
* ``ob`` = (channels int64[k], detector bool, privileged bool, scales float64[F], limit,
  frames float64[N, H, F], past_actions float64[N, H], obs float32[N, size]).
"""

from __future__ import annotations

import numpy as np

from impact_env._jit import jit
from impact_env.control.observation import OBS_LIMIT, ObservationLayout
from impact_env.effects.detector import detect, detector_params
from impact_env.effects.filters import design_filters, filter_step
from impact_env.effects.sensors import N_CHANNELS
from impact_env.scene import Scene

F_FILTERS = 1
F_DETECTOR = 2


@jit(inline="always")
def condition(i, raw, fe):
    """Filters and detector of env i on its raw readings ``raw[i]`` (float64[4])."""
    flags, sos, filt, det_params, det_state, cond, detected = fe
    c = cond[i]
    r = raw[i]
    for j in range(c.shape[0]):
        c[j] = r[j]
    if flags & F_FILTERS:
        filter_step(sos, filt[i], c, c)
    d = False
    if flags & F_DETECTOR:
        d = detect(c[0], c[1], det_state[i], det_params)
    detected[i] = 1.0 if d else 0.0


@jit(inline="always")
def observe(i, push, action, truth, fe, ob):
    """Env i's observation row after a policy step: push ``action`` into the past actions (when
    ``push``), shift the frames, write the new frame from the conditioned readings (and
    ``truth`` = x1, v1, x2, v2 for privileged layouts), scaled and clipped."""
    cond = fe[5]
    detected = fe[6]
    channels, detector, privileged, scales, limit, frames, past_actions, obs = ob
    H = frames.shape[1]
    F = frames.shape[2]
    if push and H > 1:
        for h in range(H - 1, 0, -1):
            past_actions[i, h] = past_actions[i, h - 1]
        past_actions[i, 0] = action
    for h in range(H - 1, 0, -1):
        for j in range(F):
            frames[i, h, j] = frames[i, h - 1, j]
    j = 0
    for k in range(channels.shape[0]):
        frames[i, 0, j] = cond[i, channels[k]]
        j += 1
    if detector:
        frames[i, 0, j] = detected[i]
        j += 1
    if privileged:
        for k in range(4):
            frames[i, 0, j + k] = truth[k]
    for j in range(F):
        v = frames[i, 0, j] / scales[j]
        if v > limit:
            v = limit
        elif v < -limit:
            v = -limit
        frames[i, 0, j] = v
    for h in range(H):
        for j in range(F):
            obs[i, h * F + j] = frames[i, h, j]
    if H > 1:
        for h in range(H):
            obs[i, H * F + h] = past_actions[i, h]


@jit
def start_rows(idx, truth, fe, ob):
    """Episode start for envs ``idx``: clear the front end's state and write the first
    observation from the readings already in ``cond`` (the caller's start values)."""
    filt, det_state, detected = fe[2], fe[4], fe[6]
    frames, past_actions = ob[5], ob[6]
    for m in range(idx.shape[0]):
        i = idx[m]
        filt[i] = 0.0
        det_state[i] = 0.0
        detected[i] = 0.0
        frames[i] = 0.0
        past_actions[i] = 0.0
        observe(i, False, 0.0, truth[i], fe, ob)


def observation_buffers(layout: ObservationLayout, n: int) -> tuple:
    """The ``ob`` argument group of :func:`observe` for ``layout`` and n envs (frames newest
    first, scaled; past actions; the float32 observation rows)."""
    F, H = layout.frame_size, layout.history
    return (layout.sensor_channels, bool(layout.detector), bool(layout.privileged), layout.scales,
            float(OBS_LIMIT), np.zeros((n, H, F)), np.zeros((n, H)),
            np.zeros((n, layout.size), dtype=np.float32))


class FrontEnd:
    """The front end of N controllers of one scene, for an observation ``layout``: its compiled
    arguments (:attr:`fe`, :attr:`ob`) and their arrays.  ``cond`` holds the conditioned
    readings (float64[N, 4]), ``detected`` the detector's bit, ``obs`` the observation rows
    (float32[N, layout.size])."""

    def __init__(self, scene: Scene, layout: ObservationLayout, num_envs: int):
        fx = scene.effects
        rate = scene.control_rate
        n = int(num_envs)
        self.layout = layout
        self.flags = (F_FILTERS if fx.on("filters") else 0) | (F_DETECTOR if fx.on("detector") else 0)
        self.sos = design_filters(fx.filters, rate) if fx.on("filters") else np.zeros((N_CHANNELS, 1, 6))
        self.filt = np.zeros((n, N_CHANNELS, self.sos.shape[1], 2))
        self.det_params = detector_params(fx.detector, rate)
        self.det_state = np.zeros((n, 2))
        self.cond = np.zeros((n, N_CHANNELS))
        self.detected = np.zeros(n)
        self.ob = observation_buffers(layout, n)
        self.frames, self.past_actions, self.obs = self.ob[5], self.ob[6], self.ob[7]
        self.fe = (np.int64(self.flags), self.sos, self.filt, self.det_params, self.det_state, self.cond,
                   self.detected)

    def start(self, idx: np.ndarray, readings: np.ndarray, truth: np.ndarray) -> None:
        """Start envs ``idx`` with the readings ``readings[idx]`` (float64[N, 4]) and the true
        state ``truth`` (float64[N, >=4], for privileged layouts)."""
        self.cond[idx] = readings[idx]
        start_rows(np.asarray(idx, dtype=np.int64), truth, self.fe, self.ob)
