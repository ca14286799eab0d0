"""The hardware of N rigs of one scene: every array the rig-physics stage needs, built from the
scene, and the per-env randomness.

:class:`Hardware` validates, builds the plant's and the effects' per-env arrays (only the stages
the scene names are switched on), draws every random number from numpy Generators that the
caller owns, and hands :func:`impact_env.hardware.stage.hardware_tick` its parameters and state
(:attr:`Hardware.params`, :attr:`Hardware.state`: named tuples over the arrays below).  The
simulator (:class:`impact_env.sim.simulator.Simulator`) puts the
controller's front end after it; a virtual rig uses it alone.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Callable

import numpy as np

from impact_env._threads import python_threads
from impact_env.effects import registry, sensors
from impact_env.hardware import stage
from impact_env.hardware.arrays import (
    METHOD_CODES,
    check_stability,
    error_scale,
    initial_mode,
    initial_state,
    plant_params,
)
from impact_env.hardware.blocks import Blocks
from impact_env.plant.energy import catch_energy
from impact_env.plant.layout import AUTO, FREE, N_EVENT_COLS, N_PARAM, N_STATE, OK, PARAM, STATE
from impact_env.plant.restitution import zeta_table
from impact_env.scene import Scene, load_scene

NOISE_BLOCK = 256  # control ticks of noise drawn at once per env (at least; see Hardware)


def _replace_dotted(config, key: str, value):
    """The frozen dataclass ``config`` with its (dotted) field ``key`` set to ``value``."""
    head, _, rest = key.partition(".")
    return dataclasses.replace(config, **{head: _replace_dotted(getattr(config, head), rest, value)
                                          if rest else value})


class Hardware:
    """N copies of a scene's rig hardware.  ``reset(rngs, mask)`` starts drops; the stage kernel
    advances them (:attr:`params` and :attr:`state` are its two arguments).

    Arrays over envs (SI): ``plant_state`` (float64[N, N_STATE]: x1, v1, x2, v2, W_ext, W_diss,
    :data:`~impact_env.plant.layout.STATE`), ``modes``, ``plant_parameters`` (float64[N, N_PARAM],
    :data:`~impact_env.plant.layout.PARAM`), ``step_size`` (dopri5's, s), ``events`` and
    ``event_count`` (the plant's event log), ``t`` (s since the episode start), ``raw``
    (float64[N, 4]: the raw readings),
    ``info`` (float64[N, N_INFO], columns in :mod:`impact_env.hardware.stage`), ``y0``,
    ``mode0``, ``t_touch`` (s, the first touch after the start), ``impact_energy`` (J),
    ``impact_speed`` (m/s, from the free fall),
    ``drawn`` (each env's randomised values).  ``effect_params``/``effect_state`` hold the
    effects' packed parameters and state (:meth:`param_block` / :meth:`state_block` give a named
    block as a view over envs).  ``Y``, ``P``, ``EV`` and ``EVN`` are the old names of
    ``plant_state``, ``plant_parameters``, ``events`` and ``event_count`` (read by rig/, eval/
    and deploy/, which move to the new ones with their own rework).

    Randomised scenes (``scene.randomize``): at each reset env i draws its values from
    ``rngs[i]`` (the seed policy of :mod:`impact_env.scene.randomize`) and gets exactly the
    arrays of the fixed scene ``scene.with_draws(values)``: its plant row (the pad damping of a
    drawn restitution from a :class:`~impact_env.plant.restitution.ZetaTable`, equal to the
    exact solve to about 1e-10), initial state, impact energy, command scale, noise levels,
    shaker model and delay lengths.  Envs of one batch thus differ; the kernel is the same.
    """

    def __init__(self, scene: Scene | str, num_envs: int = 1, events_per_env: int = 64,
                 noise_block: int = NOISE_BLOCK):
        scene = load_scene(scene)
        if isinstance(num_envs, bool) or int(num_envs) < 1:
            raise ValueError(f"num_envs = {num_envs!r} must be an integer >= 1")
        check_stability(scene)
        self.scene = scene
        self.n = n = int(num_envs)
        fx = scene.effects
        self.period = scene.control_period
        self.rate = 1.0 / self.period
        self.method = METHOD_CODES[scene.integrator.method]
        self.flags = registry.flags(registry.HARDWARE, fx)
        rz = scene.randomize
        self.randomized = rz.any()
        self._zeta = None
        if self.randomized:
            check_stability(scene.with_draws(rz.stiffest()))  # the stiffest drop the ranges allow
            if "restitution" in rz.ranged():
                lo, hi = rz.restitution
                self._zeta = zeta_table(lo, hi)
        base = self._env_arrays(scene, exact=True)
        params = {name: block.size for name, block in base["params"].items()}
        self.param_blocks = Blocks(stage.PARAM_BLOCKS, tuple(params[b] for b in stage.PARAM_BLOCKS))
        self.state_blocks = Blocks(stage.STATE_BLOCKS,
                                   tuple(self._state_size(scene, b) for b in stage.STATE_BLOCKS))
        self.effect_params = np.zeros((n, self.param_blocks.size))
        self.effect_state = np.zeros((n, self.state_blocks.size))
        self.plant_state = np.zeros((n, N_STATE))
        self.modes = np.zeros(n, dtype=np.int64)
        self.plant_parameters = np.zeros((n, N_PARAM))
        self.scale = np.zeros((n, 6))
        self.step_size = np.zeros((n, 1))
        self.events = np.zeros((n, events_per_env, N_EVENT_COLS))
        self.event_count = np.zeros((n, 1), dtype=np.int64)
        self.t = np.zeros(n)
        self.y0 = np.zeros((n, N_STATE))
        self.mode0 = np.zeros(n, dtype=np.int64)
        self.t_touch = np.zeros(n)
        self.impact_energy = np.zeros(n)
        self.impact_speed = np.zeros(n)  # m/s, body 1 relative to body 2 at the first touch
        self.raw = np.zeros((n, sensors.N_CHANNELS))
        self.info = np.zeros((n, stage.N_INFO))
        self.noise_block = nb = max(int(noise_block), 1)
        self.noise = np.zeros((n, nb, sensors.N_CHANNELS))
        self.cursor = np.full(n, nb, dtype=np.int64)
        self._refill_in = 0  # ticks that every env can still run on its noise block
        self.drawn: list[dict[str, float]] = [{} for _ in range(n)]
        self.rngs: list[np.random.Generator | None] = [None] * n
        self._gravity = np.zeros(n)  # each env's gravity on body 1 (a held body 1 has none)
        for i in range(n):
            self._set_env(i, base)
        self._cfg = stage.StageConfig(np.int64(self.flags), np.int64(self.method), float(scene.integrator.dt),
                                   float(scene.integrator.rtol), float(self.period))

    # -- arrays from a scene ----------------------------------------------------------------
    def _env_arrays(self, scene: Scene, exact: bool = False,
                    zeta_of: Callable[[float], float] | None = None) -> dict:
        """One env's parameter blocks and start values for the fixed ``scene`` (the pad's damping:
        by ``zeta_of`` if given, else the exact solve if ``exact`` or the batch has no table)."""
        fx = scene.effects
        if zeta_of is None and not exact:
            zeta_of = self._zeta
        p = plant_params(scene, zeta_of)
        y0, t_touch = initial_state(scene)
        e0 = float(catch_energy(y0[STATE.x1], y0[STATE.v1], y0[STATE.x2], p[PARAM.m1], p[PARAM.c],
                                p[PARAM.g]))
        params = {"drive": np.array([fx.command_scale])}
        params.update((e.name, self._pack(scene, e)[0]) for e in registry.side(registry.HARDWARE))
        return {
            "P": p, "scale": error_scale(scene, p), "y0": y0, "t_touch": t_touch,
            "mode0": initial_mode(scene, y0, p), "impact_energy": max(e0, 1e-300), "params": params,
        }

    def _pack(self, scene: Scene, effect, section=None) -> tuple[np.ndarray, int]:
        """``effect``'s parameter block and state size for the fixed ``scene`` (or for its
        config ``section`` in that scene)."""
        assert effect.pack is not None  # (every hardware effect has one: Effect checks it)
        if section is None:
            section = getattr(scene.effects, effect.section)
        return effect.pack(section, self.rate, scene.effects.on(effect.name))

    def _state_size(self, scene: Scene, name: str) -> int:
        """The state block of effect ``name`` as the scene or any end of a range that varies its
        section needs it (the longest delay line a randomised delay can ask for)."""
        effect = registry.BY_NAME[name]
        section = getattr(scene.effects, effect.section)
        size = self._pack(scene, effect)[1]
        rz = scene.randomize
        head = f"effects.{effect.section}."
        for field in rz.ranged():
            if rz.target(field).startswith(head):
                for end in getattr(rz, field):
                    at_end = _replace_dotted(section, rz.target(field)[len(head):], end)
                    size = max(size, self._pack(scene, effect, at_end)[1])
        return size

    def _set_env(self, i: int, arrays: dict) -> None:
        for name in stage.PARAM_BLOCKS:
            block = self.param_block(name)[i]
            value = arrays["params"][name]
            if value.shape != block.shape:
                raise ValueError(f"the {name} block of env {i} changed size ({value.shape} -> "
                                 f"{block.shape}): a randomised range changes the shaker's model order")
            block[:] = value
        self.plant_parameters[i] = arrays["P"]
        self._gravity[i] = arrays["P"][PARAM.g]
        self.scale[i] = arrays["scale"]
        self.y0[i] = arrays["y0"]
        self.t_touch[i] = arrays["t_touch"]
        self.mode0[i] = arrays["mode0"]
        self.impact_energy[i] = arrays["impact_energy"]

    def set_scene(self, i: int, scene: Scene, zeta_of: Callable[[float], float] | None = None) -> None:
        """Give env i the fixed ``scene``'s hardware (its plant row, drop, command scale, shaker,
        sensors, delays), as a randomised draw would: the scene must keep the effects, the shaker's
        model order and delay lengths this batch was built for.  Kept until the next draw (a
        randomised scene draws anew at each reset; a fixed one keeps it).  ``zeta_of``: the pad's
        scaled damping for the scene's restitution (default: the exact solve; the identification
        passes a :class:`~impact_env.plant.restitution.ZetaTable` over its range)."""
        self._set_env(int(i), self._env_arrays(scene, exact=zeta_of is None, zeta_of=zeta_of))

    def param_block(self, name: str) -> np.ndarray:
        """The parameter block ``name`` of every env (a view: float64[N, size])."""
        return self.param_blocks.view(self.effect_params, name)

    def state_block(self, name: str) -> np.ndarray:
        """The state block ``name`` of every env (a view: float64[N, size])."""
        return self.state_blocks.view(self.effect_state, name)

    # the old names (module doc)
    Y = property(lambda self: self.plant_state)
    P = property(lambda self: self.plant_parameters)
    EV = property(lambda self: self.events)
    EVN = property(lambda self: self.event_count)

    @property
    def command_scale(self) -> np.ndarray:
        """N per unit command, per env (the scene's, times a drawn amplifier gain)."""
        return self.param_block("drive")[:, 0]

    # -- episodes ---------------------------------------------------------------------------
    def reset(self, rngs, mask=None) -> np.ndarray:
        """Start a new drop in the envs where ``mask`` is true (all if None); ``rngs[i]`` is env
        i's Generator: a randomised scene first draws env i's values from it, then the sensor
        noise comes from it as the episode runs (see :mod:`impact_env.scene.randomize`).
        The raw readings at the start are the true, noise-free values.  Returns the indices."""
        idx = np.arange(self.n) if mask is None else np.nonzero(mask)[0]
        state = self.state
        for i in idx:
            rng = rngs[i]
            self.rngs[i] = rng
            if self.randomized:  # (a fixed scene's rows were filled once, in __init__)
                self.drawn[i] = values = self.scene.draw(rng)
                self._set_env(int(i), self._env_arrays(self.scene.with_draws(values)))
            self.plant_parameters[i, PARAM.g] = self._gravity[i]  # (after a held episode)
            stage.reset_env(state, int(i), self.y0[i], self.mode0[i])
        y = self.plant_state[idx]
        gap = np.maximum(y[:, STATE.x2] - y[:, STATE.x1], 0.0)
        self.impact_speed[idx] = np.sqrt(np.maximum(y[:, STATE.v1] - y[:, STATE.v2], 0.0) ** 2
                                         + 2.0 * self.plant_parameters[idx, PARAM.g] * gap)
        self._refill_in = 0
        return idx

    def hold_body1(self, idx) -> None:
        """Keep body 1 on the electromagnet in envs ``idx`` (after :meth:`reset`): at its release
        height above body 2 (the scene's drop height; 0.05 m for a scene given by impact speed),
        at rest, gravity on it cancelled by the magnet, so body 2, its shaker and sensors run
        alone (the identification episodes of kind shaker and quiet).  Body 2 starts at rest."""
        h = self.scene.initial.drop_height
        gap = float(h) if h else 0.05
        for i in np.atleast_1d(idx):
            d = self.drawn[i].get("drop_height", gap)
            y = self.plant_state[i]
            y[:] = 0.0
            y[STATE.x1] = -max(float(d), 0.01)
            self.plant_parameters[i, PARAM.g] = 0.0
            self.modes[i] = AUTO if self.modes[i] == AUTO else FREE
            self.raw[i] = (0.0, 0.0, y[STATE.x2], y[STATE.x1])

    def set_noise_block(self, ticks: int) -> None:
        """Hold ``ticks`` ticks of noise per env (e.g. a whole episode, drawn before it starts);
        the unread samples are kept, so the noise stream is unchanged."""
        nb = max(int(ticks), 1)
        if nb == self.noise_block:
            return
        left = [self.noise[i, self.cursor[i]:self.noise_block].copy() for i in range(self.n)]
        if max(len(x) for x in left) > nb:
            raise ValueError(f"the new noise block ({nb} ticks) cannot hold the unread samples")
        self.noise = np.zeros((self.n, nb, sensors.N_CHANNELS))
        for i, x in enumerate(left):
            self.noise[i, nb - len(x):] = x
            self.cursor[i] = nb - len(x)
        self.noise_block = nb
        self._refill_in = 0

    def refill_noise(self, ticks: int, active=None, blocks: list[tuple[int, int]] | None = None) -> None:
        """Make sure every (active) env has ``ticks`` unread noise samples: an env short of them
        keeps its unread ones and tops its block up from its Generator.  Drawing in pieces gives
        the same stream as drawing at once, so the noise an env meets does not depend on how
        many ticks a step holds.  ``blocks`` (the caller's blocks of envs, several: it steps in
        threads): the blocks' envs are topped up in as many Python threads at once (numpy's
        Generators release the GIL while they draw; each env draws from its own), the same
        numbers as in one thread."""
        if not self.flags & stage.F_SENSORS:
            return
        if self._refill_in >= ticks:
            self._refill_in -= ticks
            return
        nb = self.noise_block
        if ticks > nb:
            raise ValueError(f"{ticks} ticks of noise asked for at once; the noise block holds {nb}")
        short = self.cursor > nb - ticks
        if active is not None:
            short &= active
        idx = np.nonzero(short)[0]
        if blocks is not None and len(blocks) > 1 and len(idx) >= 2 * len(blocks):
            cut = np.searchsorted(idx, [b[0] for b in blocks[1:]])
            parts = np.split(idx, cut)
            python_threads(lambda b0, b1: self._top_up(parts[b0]), [(b, b + 1) for b in range(len(parts))],
                           ())
        else:
            self._top_up(idx)
        # inactive envs were not topped up: check every env again at the next step
        self._refill_in = 0 if active is not None else int(nb - self.cursor.max()) - ticks

    def _top_up(self, idx) -> None:
        """Envs ``idx``: unread noise samples moved to the front, the rest of the block drawn."""
        nb = self.noise_block
        for i in idx:
            c = self.cursor[i]
            left = nb - c
            if left:
                self.noise[i, :left] = self.noise[i, c:]
            # every env is reset (seeded) before it steps; drawn in place (the same numbers)
            rng = typing.cast(np.random.Generator, self.rngs[i])
            rng.standard_normal(out=self.noise[i, left:])
            self.cursor[i] = 0

    @property
    def params(self) -> stage.HardwareParams:
        """The stage kernel's parameters (views of this batch's arrays)."""
        fx = stage.EffectParams(self.effect_params, self.param_blocks.offsets, self.state_blocks.offsets)
        return stage.HardwareParams(self._cfg, stage.PlantParams(self.plant_parameters, self.scale), fx)

    @property
    def state(self) -> stage.HardwareState:
        """The stage kernel's state (views of this batch's arrays; the noise block is the current
        one: take it again after :meth:`set_noise_block`)."""
        plant = stage.PlantState(self.plant_state, self.modes, self.step_size, self.events, self.event_count,
                                 self.t)
        return stage.HardwareState(plant, self.effect_state,
                                stage.Noise(self.noise, self.cursor), stage.Readings(self.raw, self.info))

    def step(self, commands) -> None:
        """One tick of every env under float64[N] drive commands (what a virtual rig does)."""
        u = np.ascontiguousarray(commands, dtype=np.float64).reshape(self.n)
        self.refill_noise(1)
        stage.hardware_step(u, self.params, self.state)

    # -- derived readings -----------------------------------------------------------------------
    def catch_energy(self) -> np.ndarray:
        """Body 1's catch energy per env (J)."""
        P, Y = self.plant_parameters, self.plant_state
        return catch_energy(Y[:, STATE.x1], Y[:, STATE.v1], Y[:, STATE.x2], P[:, PARAM.m1], P[:, PARAM.c],
                            P[:, PARAM.g])

    def diverged(self) -> np.ndarray:
        return (self.info[:, stage.HW_INFO.status] != OK) | ~np.all(np.isfinite(self.plant_state), axis=1)
