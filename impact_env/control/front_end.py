"""The controller's front end: the compiled code between the raw readings and the policy.

Per tick, :func:`condition` runs the scene's filters (Butterworth SOS per channel,
:mod:`impact_env.effects.filters`) and the contact detector (thesis eq 4.4,
:mod:`impact_env.effects.detector`) on the raw readings.  Per policy step, :func:`observe` builds
the observation row from the conditioned readings: the layout's channels and detector bit (and,
in simulation only, the true state for privileged observations), each divided by its reference
scale and clipped, stacked with the previous frames and actions when the history is longer than
one (:mod:`impact_env.control.observation`).

The simulator and the real-time target call these same kernels, so a deployed policy sees what
it saw in simulation.  Their arguments are named tuples, parameters (fixed for an episode) apart
from state (changed every tick, started by one reset function each):
:class:`FrontEndParams` / :class:`FrontEndState` (:func:`reset_front_end`) and
:class:`ObsParams` / :class:`ObsState` (:func:`reset_obs`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env.control.observation import OBS_LIMIT, ObservationLayout
from impact_env.effects import registry
from impact_env.effects.detector import detect, detector_params
from impact_env.effects.filters import design_filters, filter_step
from impact_env.effects.sensors import ACCEL, FORCE, N_CHANNELS
from impact_env.scene import Scene

# flag bits (the controller's effects, as the registry orders them: impact_env.effects.registry)
F_FILTERS = registry.flag("filters")
F_DETECTOR = registry.flag("detector")


class FrontEndParams(NamedTuple):
    """The scene's filters and detector (fixed)."""

    flags: np.int64  # F_FILTERS | F_DETECTOR, those the scene has
    sos: np.ndarray  # float64[4, S, 6]: each channel's second-order sections
    detector: np.ndarray  # float64[5]: impact_env.effects.detector.detector_params


class FrontEndState(NamedTuple):
    """Per-env filter memory, detector state and what they give."""

    filt: np.ndarray  # float64[N, 4, S, 2]
    det: np.ndarray  # float64[N, 2]
    cond: np.ndarray  # float64[N, 4]: the conditioned readings
    detected: np.ndarray  # float64[N]: the detector's bit (0 or 1)


class ObsParams(NamedTuple):
    """An observation layout (impact_env.control.observation), for the kernels."""

    channels: np.ndarray  # int64[k]: sensor channels, in frame order
    detector: bool  # the frame holds the detector's bit
    privileged: bool  # the frame holds x1, v1, x2, v2
    scales: np.ndarray  # float64[F]
    limit: float  # |entry| bound


class ObsState(NamedTuple):
    """Per-env observation history and rows."""

    frames: np.ndarray  # float64[N, H, F]: newest first, scaled
    past_actions: np.ndarray  # float64[N, H]
    obs: np.ndarray  # float32[N, size]: the observation rows


@jit(inline="always")
def reset_front_end(s, i):
    """Env i's filters and detector at an episode start (the readings come from the caller)."""
    s.filt[i] = 0.0
    s.det[i] = 0.0
    s.detected[i] = 0.0


@jit(inline="always")
def reset_obs(s, i):
    """Env i's observation history at an episode start."""
    s.frames[i] = 0.0
    s.past_actions[i] = 0.0


@jit(inline="always")
def condition(i, raw, p, s):
    """Filters and detector of env i on its raw readings ``raw[i]`` (float64[4]); ``p``:
    FrontEndParams, ``s``: FrontEndState."""
    c = s.cond[i]
    r = raw[i]
    for j in range(c.shape[0]):
        c[j] = r[j]
    if p.flags & F_FILTERS:
        filter_step(p.sos, s.filt[i], c, c)
    d = False
    if p.flags & F_DETECTOR:
        d = detect(c[ACCEL], c[FORCE], s.det[i], p.detector)
    s.detected[i] = 1.0 if d else 0.0


@jit(inline="always")
def observe(i, push, action, truth, fe, op, os):
    """Env i's observation row after a policy step: push ``action`` into the past actions (when
    ``push``), shift the frames, write the new frame from the conditioned readings of ``fe``
    (FrontEndState; and ``truth`` = x1, v1, x2, v2 for privileged layouts), scaled and clipped.
    ``op``: ObsParams, ``os``: ObsState."""
    cond = fe.cond
    detected = fe.detected
    channels = op.channels
    scales = op.scales
    limit = op.limit
    frames = os.frames
    past_actions = os.past_actions
    obs = os.obs
    history = frames.shape[1]
    frame_size = frames.shape[2]
    if push and history > 1:
        for h in range(history - 1, 0, -1):
            past_actions[i, h] = past_actions[i, h - 1]
        past_actions[i, 0] = action
    for h in range(history - 1, 0, -1):
        for j in range(frame_size):
            frames[i, h, j] = frames[i, h - 1, j]
    j = 0
    for k in range(channels.shape[0]):
        frames[i, 0, j] = cond[i, channels[k]]
        j += 1
    if op.detector:
        frames[i, 0, j] = detected[i]
        j += 1
    if op.privileged:
        for k in range(4):
            frames[i, 0, j + k] = truth[k]
    for j in range(frame_size):
        v = frames[i, 0, j] / scales[j]
        if v > limit:
            v = limit
        elif v < -limit:
            v = -limit
        frames[i, 0, j] = v
    for h in range(history):
        for j in range(frame_size):
            obs[i, h * frame_size + j] = frames[i, h, j]
    if history > 1:
        for h in range(history):
            obs[i, history * frame_size + h] = past_actions[i, h]


@jit
def start_rows(idx, truth, fe, op, os):
    """Episode start for envs ``idx``: the observation history of ``os`` cleared and its first
    row written from the readings already in ``fe.cond`` (the caller's start values)."""
    for m in range(idx.shape[0]):
        i = idx[m]
        reset_obs(os, i)
        observe(i, False, 0.0, truth[i], fe, op, os)


@jit
def start_envs(idx, truth, s, op, os):
    """Episode start for envs ``idx``: the front end's state reset, then :func:`start_rows`."""
    for m in range(idx.shape[0]):
        reset_front_end(s, idx[m])
    start_rows(idx, truth, s, op, os)


def obs_params(layout: ObservationLayout) -> ObsParams:
    """The kernels' view of ``layout``."""
    return ObsParams(layout.sensor_channels, bool(layout.detector), bool(layout.privileged), layout.scales,
                     float(OBS_LIMIT))


def obs_state(layout: ObservationLayout, n: int) -> ObsState:
    """Zeroed observation buffers of ``layout`` for n envs."""
    F, H = layout.frame_size, layout.history
    return ObsState(np.zeros((n, H, F)), np.zeros((n, H)), np.zeros((n, layout.size), dtype=np.float32))


class FrontEnd:
    """The front end of N controllers of one scene, for an observation ``layout``: its compiled
    arguments (:attr:`params`, :attr:`state`, :attr:`obs_params`, :attr:`obs_state`).
    ``cond`` holds the conditioned readings (float64[N, 4]), ``detected`` the detector's bit,
    ``obs`` the observation rows (float32[N, layout.size])."""

    def __init__(self, scene: Scene, layout: ObservationLayout, num_envs: int):
        fx = scene.effects
        rate = scene.control_rate
        n = int(num_envs)
        self.layout = layout
        flags = registry.flags(registry.CONTROLLER, fx)
        sos = design_filters(fx.filters, rate) if fx.on("filters") else np.zeros((N_CHANNELS, 1, 6))
        self.params = FrontEndParams(np.int64(flags), sos, detector_params(fx.detector, rate))
        self.state = FrontEndState(np.zeros((n, N_CHANNELS, sos.shape[1], 2)), np.zeros((n, 2)),
                                   np.zeros((n, N_CHANNELS)), np.zeros(n))
        self.obs_params = obs_params(layout)
        self.obs_state = obs_state(layout, n)

    @property
    def flags(self) -> int:
        return int(self.params.flags)

    @property
    def sos(self) -> np.ndarray:
        return self.params.sos

    @property
    def det_params(self) -> np.ndarray:
        return self.params.detector

    @property
    def cond(self) -> np.ndarray:
        return self.state.cond

    @property
    def detected(self) -> np.ndarray:
        return self.state.detected

    @property
    def obs(self) -> np.ndarray:
        return self.obs_state.obs

    def start(self, idx: np.ndarray, readings: np.ndarray, truth: np.ndarray) -> None:
        """Start envs ``idx`` with the readings ``readings[idx]`` (float64[N, 4]) and the true
        state ``truth`` (float64[N, >=4], for privileged layouts)."""
        self.state.cond[idx] = readings[idx]
        start_envs(np.asarray(idx, dtype=np.int64), truth, self.state, self.obs_params, self.obs_state)
