"""Simulator: a batch of N rigs of one scene, stepped one control period at a time.

The Python layer validates, builds every array the kernel needs from the scene (only the
stages the scene names are switched on) and draws all randomness from numpy Generators that
the caller owns; :func:`impact_env.sim.pipeline_kernel.control_step_batch` does the work.
A single environment is a batch of one.
"""

from __future__ import annotations

import numpy as np

from impact_env.effects.delay import delay_samples
from impact_env.effects.detector import detector_params
from impact_env.effects.filters import design_filters
from impact_env.effects.saturation import saturation_params
from impact_env.effects.sensors import N_CHANNELS, sensor_params
from impact_env.effects.shaker import discrete_emf_model
from impact_env.plant import layout as L
from impact_env.plant.dynamics import event_value
from impact_env.plant.energy import catch_energy
from impact_env.plant.restitution import zeta_table
from impact_env.scene import Scene, load_scene
from impact_env.sim import pipeline_kernel as K
from impact_env.sim.arrays import METHOD_CODES, check_stability, error_scale, initial_state, plant_params

NOISE_BLOCK = 256  # control steps of noise drawn at once per env


class Simulator:
    """N copies of a scene's rig.  ``reset(rngs, mask)`` starts drops, ``step(actions)`` advances.

    Attributes after each step (arrays over envs): ``readings`` (float64[N, 4]: accelerometer
    m/s^2, force transducer N, potentiometer m, body-1 sensor m), ``info`` (float64[N, N_INFO],
    columns in :mod:`impact_env.sim.pipeline_kernel`), ``Y`` (true state rows x1, v1, x2, v2,
    W_ext, W_diss), ``t`` (s since the episode start).

    Randomised scenes (``scene.randomize``): at each reset env i draws its values from
    ``rngs[i]`` (the seed policy of :mod:`impact_env.scene.randomize`) and gets exactly the arrays of
    the fixed scene ``scene.with_draws(values)`` (``drawn[i]`` holds the values): its plant row
    ``P[i]`` (the pad damping of a drawn restitution from a :class:`ZetaTable`, equal to the exact
    solve to about 1e-10), initial state, impact energy, command scale, noise levels, shaker
    model and delay lengths.  Envs of one batch thus differ; the kernel is the same.

    The effects' per-env parameters and state live packed in ``PR`` and ``ST`` (one row per env,
    layout :func:`impact_env.sim.pipeline_kernel.row_layout`, sizes ``dims``); their pieces are
    readable and writable as views over envs by name: ``command_scale``, ``sh_A`` .. ``sh_E``,
    ``sat_params``, ``sens_params``, ``top_mass``, ``det_params``, ``act_len``, ``sd_len``,
    ``scale``, and the state ``sh_X``, ``sat_state``, ``filt_state``, ``act_buf``, ``sd_buf``,
    ``det_state``, ``H``, ...
    """

    def __init__(self, scene: Scene | str, num_envs: int = 1, events_per_env: int = 64):
        scene = load_scene(scene)
        if int(num_envs) < 1:
            raise ValueError(f"num_envs = {num_envs!r} must be >= 1")
        check_stability(scene)
        self.scene = scene
        self.n = n = int(num_envs)
        fx = scene.effects
        self.period = scene.control_period
        self.rate = rate = 1.0 / self.period
        self.method = METHOD_CODES[scene.integrator.method]
        self.flags = 0
        for name, bit in (("actuator_delay", K.F_ACT_DELAY), ("shaker", K.F_SHAKER),
                          ("saturation", K.F_SATURATION), ("sensors", K.F_SENSORS),
                          ("filters", K.F_FILTERS), ("sensor_delay", K.F_SENS_DELAY),
                          ("detector", K.F_DETECTOR)):
            if fx.on(name):
                self.flags |= bit
        if fx.on("shaker") and fx.shaker.back_emf:
            self.flags |= K.F_BACK_EMF
        rz = scene.randomize
        self.randomized = rz.any()
        self._zeta = None
        if self.randomized:
            check_stability(scene.with_draws(rz.stiffest()))  # the stiffest drop the ranges allow
            if "restitution" in rz.ranged():
                lo, hi = rz.restitution
                self._zeta = zeta_table(lo, hi)
        self.drawn: list[dict[str, float]] = [{} for _ in range(n)]
        self.Y = np.zeros((n, L.N_STATE))
        self.modes = np.zeros(n, dtype=np.int64)
        self.EV = np.zeros((n, events_per_env, L.N_EVENT_COLS))
        self.EVN = np.zeros((n, 1), dtype=np.int64)
        self.sos = design_filters(fx.filters, rate) if fx.on("filters") else np.zeros((N_CHANNELS, 1, 6))
        # per-env effect parameters and state, packed into one row each (pipeline_kernel's layout);
        # delay lines sized for the longest delay the scene (or its ranges) can ask for
        base = self._env_arrays(scene, exact=True)
        k_sens, k_act = fx.delay.samples(rate)
        k_sens_max = max([k_sens] + [delay_samples(v, rate) for v in rz.sensor_delay_s])
        k_act_max = max([k_act] + [delay_samples(v, rate) for v in rz.actuator_delay_s])
        self.dims = np.array([base["sh_A"].shape[0], self.sos.shape[1],
                              k_act_max if fx.on("actuator_delay") else 0,
                              k_sens_max if fx.on("sensor_delay") else 0], dtype=np.int64)
        pr, q, st, s = K.row_layout(*(int(v) for v in self.dims))
        self.PR = np.zeros((n, q))
        self.ST = np.zeros((n, s))
        # name -> (packed array, offset, shape); views are made on access (so copies and pickles
        # of a Simulator stay consistent)
        self._pieces = {name: ("PR", off, shape) for name, (off, shape) in pr.items()}
        self._pieces.update({name: ("ST", off, shape) for name, (off, shape) in st.items()})
        self._base = base
        for name, value in base.items():
            if name in self._pieces:
                getattr(self, name)[:] = value
            else:
                setattr(self, name, np.repeat(np.asarray(value)[None], n, axis=0))
        self.readings = np.zeros((n, N_CHANNELS))
        self.info = np.zeros((n, K.N_INFO))
        self.t = np.zeros(n)
        self._noise = np.zeros((n, NOISE_BLOCK, N_CHANNELS))
        self._cursor = np.full(n, NOISE_BLOCK, dtype=np.int64)
        self._refill_in = 0  # steps until some env's noise block runs out
        self._rngs: list[np.random.Generator | None] = [None] * n

    def __getattr__(self, name):
        """The named pieces of the packed rows (``sh_A``, ``sens_params``, ``filt_state``, ...:
        see :func:`impact_env.sim.pipeline_kernel.row_layout`) as views over envs."""
        pieces = self.__dict__.get("_pieces")
        if pieces is not None and name in pieces:
            rows, off, shape = pieces[name]
            return _column_view(self.__dict__[rows], off, shape)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def _env_arrays(self, scene: Scene, exact: bool = False) -> dict[str, np.ndarray]:
        """One env's parameter rows and start values for the fixed ``scene`` (attribute -> row)."""
        fx = scene.effects
        rate = self.rate
        p = plant_params(scene, None if exact or self._zeta is None else self._zeta)
        y0, t_touch = initial_state(scene)
        mode0 = L.AUTO
        if scene.integrator.event_location or scene.integrator.method == "dopri5":
            mode0 = L.CONTACT if event_value(y0[0], y0[1], y0[2], y0[3], p[L.C], p[L.B]) > 0 else L.FREE
            if not scene.integrator.event_location:
                mode0 = L.AUTO
        e0 = float(catch_energy(y0[0], y0[1], y0[2], p[L.M1], p[L.C], p[L.G]))
        if fx.on("shaker"):
            A, B, C, D, E = discrete_emf_model(fx.shaker, rate)
        else:
            A, B, C, D, E = np.zeros((1, 1)), np.zeros(1), np.zeros(1), 0.0, np.zeros(1)
        k_sens, k_act = fx.delay.samples(rate)
        return {
            "P": p, "scale": error_scale(scene, p), "command_scale": fx.command_scale,
            "y0": y0, "t_touch": t_touch, "mode0": mode0, "impact_energy": max(e0, 1e-300),
            "sh_A": A, "sh_B": B, "sh_C": C, "sh_D": D, "sh_E": E,
            "sat_params": saturation_params(fx.saturation, rate),
            "sens_params": sensor_params(fx.sensors), "top_mass": fx.sensors.force.top_mass,
            "det_params": detector_params(fx.detector, rate),
            "act_len": float(k_act if fx.on("actuator_delay") else 0),
            "sd_len": float(k_sens if fx.on("sensor_delay") else 0),
        }

    # -- episodes --------------------------------------------------------------------------
    def reset(self, rngs, mask=None) -> None:
        """Start a new drop in the envs where ``mask`` is true (all if None); ``rngs[i]`` is env
        i's Generator: a randomised scene first draws env i's values from it, then the sensor
        noise comes from it as the episode runs (see :mod:`impact_env.scene.randomize`)."""
        idx = range(self.n) if mask is None else np.nonzero(mask)[0]
        for i in idx:
            rng = rngs[i]
            self._rngs[i] = rng
            if self.randomized:  # (a fixed scene's rows were filled once, in __init__)
                self.drawn[i] = values = self.scene.draw(rng)
                for name, value in self._env_arrays(self.scene.with_draws(values)).items():
                    getattr(self, name)[i] = value
            self.Y[i] = self.y0[i]
            self.modes[i] = self.mode0[i]
            self.EVN[i] = 0
            self.EV[i] = 0.0
            self.ST[i] = 0.0  # every effect's state, the delay lines and dopri5's step size
            self.t[i] = 0.0
            self._cursor[i] = NOISE_BLOCK
            self._refill_in = 0
            self.info[i] = 0.0
        self._refresh_readings(idx)

    def _refresh_readings(self, idx) -> None:
        """Readings at the reset state: the true values passed through a zero-action step's
        sensor stages would advance time; instead report the true, noise-free values."""
        for i in idx:
            y = self.Y[i]
            self.readings[i] = (0.0, 0.0, y[L.X2], y[L.X1])

    def _refill_noise(self) -> None:
        """Refill the noise block of every env that has used its block up (the kernel reads
        ``_noise[i, _cursor[i]]`` and advances the cursor)."""
        if self.flags & K.F_SENSORS:
            if self._refill_in <= 0:  # some env has used up its block (or was just reset)
                for i in np.nonzero(self._cursor >= NOISE_BLOCK)[0]:
                    self._noise[i] = self._rngs[i].standard_normal((NOISE_BLOCK, N_CHANNELS))
                    self._cursor[i] = 0
                self._refill_in = NOISE_BLOCK - int(self._cursor.max())
            self._refill_in -= 1

    def step(self, actions: np.ndarray) -> None:
        """Advance every env by one control period; ``actions`` float64[N] in [-1, 1]."""
        a = actions if (type(actions) is np.ndarray and actions.dtype == np.float64 and actions.ndim == 1
                        and actions.shape[0] == self.n and actions.flags.c_contiguous) \
            else np.ascontiguousarray(actions, dtype=np.float64).reshape(self.n)
        self._refill_noise()
        integ = self.scene.integrator
        K.control_step_batch(a, 0.0, self.period, self.flags, self.method, integ.dt, integ.rtol, self.dims,
                             self.Y, self.modes, self.P, self.EV, self.EVN, self.PR, self.ST, self.sos,
                             self._noise, self._cursor, self.t, self.readings, self.info)

    # -- derived readings ---------------------------------------------------------------------
    def catch_energy(self) -> np.ndarray:
        """Body 1's catch energy per env (J)."""
        P = self.P
        Y = self.Y
        return catch_energy(Y[:, L.X1], Y[:, L.V1], Y[:, L.X2], P[:, L.M1], P[:, L.C], P[:, L.G])

    def diverged(self) -> np.ndarray:
        return (self.info[:, K.I_STATUS] != L.OK) | ~np.all(np.isfinite(self.Y), axis=1)


def _column_view(rows: np.ndarray, off: int, shape: tuple) -> np.ndarray:
    """The columns ``off .. off + prod(shape)`` of every row, as a view of shape (n, *shape)."""
    size = int(np.prod(shape)) if shape else 1
    v = rows[:, off] if not shape else rows[:, off:off + size].reshape((rows.shape[0],) + tuple(shape))
    assert np.shares_memory(v, rows) or v.size == 0
    return v
