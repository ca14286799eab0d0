"""``ImpactCatch-v0``: catch a falling body with a shaker so that it does not bounce."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from impact_env.control.observation import OBS_LIMIT
from impact_env.env.task import (
    REWARD_FORMULA,
    REWARD_TIME_UNIT,
    TaskConfig,
    info_from_row,
    make_catch_task,
    options_doc,
)
from impact_env.scene import Scene


class ImpactCatchEnv(gym.Env):
    """
    ## Description

    Body 1 (mass ``m1``) falls onto body 2 (``m2``: a shaker's armature, a pad and a fixture)
    through a Hertzian pad, contact force ``c d^1.5`` (``d`` the penetration, m).  The agent
    commands the shaker's force on body 2 and must take body 1's energy out as fast as possible:
    catch it without bounces.  The physics, effects (shaker response, saturation, sensor noise,
    filters, delays, contact detector) and numbers come from a *scene*
    (:mod:`impact_env.scene.presets`: ``ideal``, ``rig``, ...), after E. Nyström, *Controlling a one
    degree of motion impact* (Chalmers, 2013).

    ## Action Space

    ``Box(-1, 1, (1,), float32)``: the shaker command; ``+1`` demands ``effects.command_scale``
    newtons **upwards** on body 2 (200 N on ``rig``).  The demand then passes through the scene's
    actuator delay, shaker response and saturation.  Values outside [-1, 1] are clipped
    (``action_bounds="clip"``, default) or rejected (``"raise"``); NaN, inf or a wrong shape raise
    ``ValueError``.

    ## Observation Space

    ``Box(-1e4, 1e4, (k,), float32)`` (entries clipped to it), layout in
    ``env.unwrapped.layout.describe()``.  With the default ``observation="sensors"``: the
    scene's enabled sensor channels as its controller would read them after noise,
    quantisation, filters and delay (thesis frame: x down)

    | name               | unit  | scale (divides the value)                   |
    |--------------------|-------|---------------------------------------------|
    | accelerometer      | m/s^2 | F_ref / m2                                  |
    | force              | N     | F_ref = c d_ref^1.5                         |
    | potentiometer      | m     | d_ref = (5 m v0^2 / 4c)^(2/5)               |
    | body1_displacement | m     | d_ref (only if the scene enables it)        |
    | contact_detected   | -     | 1 (only with the scene's ``detector``)      |

    ``observation="privileged"`` gives the true ``x1, v1, x2, v2`` (m, m/s; scales d_ref, v0)
    instead, ``"both"`` appends them to the sensors.  ``history=k`` stacks the last k frames and
    k actions (for delayed scenes).  See :mod:`impact_env.control.observation`.

    ## Rewards

    ``REWARD_FORMULA_DOC``

    per step, E body 1's catch energy (kinetic + gravitational relative to resting on body 2 +
    elastic pad energy, J), E0 its value at the start, F_cmd the scene's command scale (N), T the
    control period, t_unit = 1 ms: the return is minus the time integral of the normalised
    energy in ms (rate independent).  Weights default to 0.

    ## Starting State

    Body 1 falls towards body 2 at rest, ``initial.pre_contact_time`` (1 ms) before the first
    touch, with the impact speed given by the scene (drawn from its ranges on randomised scenes).

    ## Episode End

    *Terminated* when the catch energy stays below ``catch_threshold`` (1 %) of E0 for
    ``catch_hold`` (10 ms), or when the simulation diverges (``info["diverged"]``, observation kept
    finite).  *Truncated* at ``horizon`` (the scene's ``episode.horizon``; 0.3 s on ``ideal``, 0.4 s
    on ``rig``).  One step is one control period (100 us on ``rig``; 1 us on ``ideal``, which
    samples at every integration step: give ``overrides={"control.rate": 1e4}`` for RL).

    ## Arguments

    ``gymnasium.make("ImpactCatch-v0", scene="rig", overrides=None, render_mode=None, **options)``,
    the options being the task's (the fields of :class:`~impact_env.env.task.TaskConfig`, one
    definition shared with the vector env and ``ImpactCatchRig-v0``; this list is written from
    them):

TASK_OPTIONS_DOC

    ``scene``: a preset name, a :class:`~impact_env.scene.Scene`, a dict or a TOML path;
    ``overrides``: dotted keys (``{"plant.m1": 0.05}``).  ``hold_ticks``: control periods per
    policy step (the action is held, rewards summed, the observation is the last period's; an
    episode ending inside a hold ends the step there).  ``residual``: a classic law's name
    (``"pd-penetration"``, ...), evaluated every control period on its own copy of the sensor frame
    by the compiled policy code; the action adds to its command (clipped to [-1, 1]).

    ``info`` holds (SI): ``t``, ``catch_energy``, ``catch_energy_ratio``, ``impact_energy``,
    ``impact_speed``, ``contact`` (true contact), ``contact_force``, ``force_demand``,
    ``force_applied``, ``saturated``, ``detected``, ``state`` (x1, v1, x2, v2), ``diverged``,
    ``caught``, ``t_touch`` (time of the first touch after the episode start, from the free fall).

    ## Version History

    * v0: first release.
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 30}

    def __init__(self, scene: Scene | str | dict = "rig", overrides: dict | None = None, *,
                 render_mode: str | None = None, **task: Any):
        # the task's options (impact_env.env.task.TaskConfig); an unknown name lists this env's own too
        cfg = TaskConfig.from_options(task, type(self).__init__)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode = {render_mode!r}; expected one of "
                             f"{self.metadata['render_modes']} or None")
        self.task = make_catch_task(scene, 1, cfg, overrides)
        self.scene = self.task.scene
        self.layout = self.task.layout
        self.render_mode = render_mode
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.observation_space = spaces.Box(-OBS_LIMIT, OBS_LIMIT, (self.layout.size,), np.float32)
        self.reward_time_unit = REWARD_TIME_UNIT
        self._started = False
        self._viewer = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self.task.reset([self.np_random])
        self._started = True
        return self.task.obs[0].copy(), self._info()

    def step(self, action):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        task = self.task
        rewards, terminated, truncated = task.step(task.check_actions(action))
        return (task.obs[0].copy(), float(rewards[0]), bool(terminated[0]), bool(truncated[0]),
                info_from_row(task.rows[0]))

    def _info(self) -> dict[str, Any]:
        return info_from_row(self.task.rows[0])

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        from impact_env.env.render import draw_frame, show_frame  # matplotlib loads only to render

        frame = draw_frame(self.task, 0)
        if self.render_mode == "rgb_array":
            return frame
        self._viewer = show_frame(frame, self._viewer, self.metadata["render_fps"])
        return None

    def close(self):
        if self._viewer is not None:
            from impact_env.env.render import close_viewer  # (a viewer exists: render is loaded)

            close_viewer(self._viewer)
            self._viewer = None


ImpactCatchEnv.__doc__ = ((ImpactCatchEnv.__doc__ or "").replace("TASK_OPTIONS_DOC", options_doc("    "))
                          .replace("REWARD_FORMULA_DOC", REWARD_FORMULA))
