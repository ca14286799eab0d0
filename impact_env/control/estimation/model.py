"""The EKF's constants from a scene: the plant, the shaker and limit replica, each measured
channel's filter and noise, the prior on body 1, the process noise and the lost-track rule.

Noise (R): each channel's raw reading carries white noise of the scene's ``noise_std`` and the
ADC's rounding, uniform over one step q, so ``R = noise_std^2 + q^2 / 12`` (in the channel's
unit squared); a scene without the sensors effect gets a floor of 1e-6 of the ADC range.

Prior (body 1 is invisible to the sensors before the touch): the run starts ``pre_contact_time``
tau before the first touch (:func:`impact_env.hardware.arrays.free_fall_state`), so
``x1 = -(v tau - g tau^2 / 2)`` and ``v1 = v - g tau`` for the impact speed v; over the scene's
``randomize.drop_height`` range (uniform, ``v = sqrt(2 g h)``) or ``randomize.impact_speed``
the mean and covariance of (x1, v1) are those of the drawn values (a 2001-point quadrature),
with ``timing_std`` s of the touch time added to x1's variance (a start that is not exactly
tau before the touch; the covariance along v alone is rank one and would pin the touch
instant).  im1 = 1/m1 gets the mean and variance of 1/m1 over ``randomize.m1`` (uniform), or a
5 % spread around the nominal m1 without a range.

Process noise (Q): a white acceleration on each body, std ``q_a1`` and ``q_a2`` (m/s^2), for
what the model does not hold: RK4's error in a period that straddles the touch or the
separation (the force switches inside the period: up to about ``F(dt v) / m1``, a few m/s^2 at
a 1 m/s touch), and the damping's dependence on m1, which the Jacobian leaves out; and a random
walk on im1 (``q_im1`` 1/kg per tick) so that its variance never collapses to nothing.

Lost track: the normalised innovations squared summed over ``nis_window`` ticks is
chi-square with ``3 nis_window`` degrees of freedom while the model holds; above its
``1 - nis_alpha`` quantile the filter reports lost track.
"""

from __future__ import annotations

import math
import sys

import numpy as np

from impact_env.config import ConfigError
from impact_env.control.estimation.layout import (
    CH_BASE,
    CHANNEL_NAMES,
    CO_A,
    CO_B,
    CO_C,
    CO_D,
    CO_GAIN,
    CO_NZ,
    CO_OFFSET,
    CO_R,
    EK,
    MAX_SHAKER,
    MAX_Z,
    N_CONSTANTS,
    EkfConstants,
)
from impact_env.effects.filters import design_sos
from impact_env.effects.saturation import saturation_params
from impact_env.effects.shaker import discrete_emf_model
from impact_env.effects.shaker import pack_params as pack_shaker
from impact_env.plant.restitution import zeta_for_restitution

#: the EKF's settings and their defaults (see the module doc for their reasons)
SETTINGS = {
    "q_a1": 20.0,  # m/s^2, white acceleration on body 1
    "q_a2": 5.0,  # m/s^2, white acceleration on body 2
    "q_im1": 1e-3,  # 1/kg per tick, random walk on body 1's inverse mass
    # the recovered raw readings' drift (the inverse filters sum the observation's float32
    # rounding): a random walk per tick, in units of each channel's noise std
    "q_bias": 0.03,
    "timing_std": 2e-5,  # s, the touch instant's uncertainty in the prior
    "nis_window": 50.0,  # ticks per lost-track test
    "nis_alpha": 1e-4,  # false-alarm probability per window of a model that holds
    "reset_x": 1e-3,  # m, position std after lost track
    "reset_v": 1.0,  # m/s, speed std after lost track
    "d_floor": 1e-6,  # m, the penetration below which the damping's slope is taken at this value
}
SENSOR_CHANNELS = ("accelerometer", "force", "potentiometer")  # CHANNEL_NAMES, as the scene names them
N_QUAD = 2001


def filter_state_space(sos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(A, B, C, D) of a cascade of second-order sections in transposed direct form II (the
    simulator's :func:`impact_env.effects.filters.filter_step`), with its state in the same
    order (section s: ``z[2 s], z[2 s + 1]``), found by running the recursion on unit inputs."""
    n = 2 * sos.shape[0]

    def step(z, u):
        z = z.copy()
        v = u
        for s in range(sos.shape[0]):
            b0, b1, b2, _a0, a1, a2 = sos[s]
            y = b0 * v + z[2 * s]
            z[2 * s] = b1 * v - a1 * y + z[2 * s + 1]
            z[2 * s + 1] = b2 * v - a2 * y
            v = y
        return z, v

    A = np.zeros((n, n))
    C = np.zeros(n)
    for j in range(n):
        e = np.zeros(n)
        e[j] = 1.0
        A[:, j], C[j] = step(e, 0.0)
    B, D = step(np.zeros(n), 1.0)
    return A, B, C, float(D)


def _uniform_moments(lo: float, hi: float, fn) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of ``fn(u)`` (a vector) for u uniform on [lo, hi] (midpoint rule)."""
    u = lo + (hi - lo) * (np.arange(N_QUAD) + 0.5) / N_QUAD
    vals = np.array([fn(x) for x in u])
    mean = vals.mean(axis=0)
    dev = vals - mean
    return mean, dev.T @ dev / len(u)


def ekf_constants(scene, settings: dict | None = None) -> dict[str, float]:
    """The EKF's constants (by :class:`~impact_env.control.estimation.layout.EkfConstants`
    name) for ``scene``; ``settings`` override :data:`SETTINGS`.  ConfigError for a scene the
    filter does not model: a measured (FIR) shaker, a filter of more than 4 states, a filter
    without feedthrough, or a disabled accelerometer, transducer or potentiometer.

    The model is the hardware the scene knows (:func:`impact_env.scene.randomize.known_hardware`:
    a calibrated scene's identified c, m2, top mass and amplifier gain included); the policy's clip
    is at the scene's own ``effects.command_scale``, which the amplifier's known gain then scales."""
    from impact_env.scene.randomize import known_command_gain, known_hardware

    command_scale, command_gain = scene.effects.command_scale, known_command_gain(scene)
    scene = known_hardware(scene)
    s = dict(SETTINGS)
    s.update(settings or {})
    k: dict[str, float] = dict.fromkeys(EkfConstants._fields, 0.0)
    pl = scene.plant
    rate = float(scene.control_rate)
    k.update(m2=pl.m2, c=pl.c, g=pl.gravity, k2=pl.suspension_stiffness, c2=pl.suspension_damping,
             top_mass=scene.effects.sensors.force.top_mass, dt=1.0 / rate,
             command_scale=command_scale, command_gain=command_gain)
    k["zeta"] = 0.0 if pl.restitution >= 1.0 else zeta_for_restitution(pl.restitution)
    eff = scene.effects
    if eff.on("shaker"):
        cfg = eff.shaker
        if cfg.model != "coil":
            raise ConfigError("the mpc law's estimator models effects.shaker.model = coil only (got "
                              f"{cfg.model!r}): a measured response of {len(cfg.fir_taps)} taps is too long")
        A, B, C, D, E = discrete_emf_model(cfg, rate)
        if A.shape[0] > MAX_SHAKER:
            raise ConfigError(f"effects.shaker: a model of order {A.shape[0]} exceeds the estimator's "
                              f"{MAX_SHAKER}")
        block = pack_shaker(A, B, C, D, E)
        k.update(sh_on=1.0, sh_n=float(A.shape[0]), back_emf=1.0 if cfg.back_emf else 0.0)
        for i, v in enumerate(block):
            k[f"sh_{i}"] = float(v)
    if eff.on("saturation"):
        sp = saturation_params(eff.saturation, rate)
        # (no slew limit is an infinite step there; the largest float acts the same and stays finite)
        k.update(sat_on=1.0, sat_peak=sp[0], sat_rms2=sp[1], sat_alpha=sp[2],
                 sat_slew=min(sp[3], sys.float_info.max))
    sensors_on = eff.on("sensors")
    filters_on = eff.on("filters")
    for ch, key in zip(CHANNEL_NAMES, SENSOR_CHANNELS, strict=True):
        sc = getattr(eff.sensors, key)
        if not sc.enabled:
            raise ConfigError(f"the mpc law's estimator reads effects.sensors.{key}, which the scene "
                              "disables")
        q = sc.quantum
        r = sc.noise_std**2 + q * q / 12.0 if sensors_on else 0.0
        k[f"{ch}_r"] = max(r, (1e-6 * sc.adc_range) ** 2)
        k[f"{ch}_gain"] = sc.gain if sensors_on else 1.0
        k[f"{ch}_offset"] = sc.offset if sensors_on else 0.0
        fc = getattr(eff.filters, key)
        if not filters_on or fc.kind == "none":
            k[f"{ch}_d"] = 1.0
            continue
        Af, Bf, Cf, Df = filter_state_space(design_sos(fc, rate))
        nz = Af.shape[0]
        if nz > MAX_Z:
            raise ConfigError(f"effects.filters.{key}.order = {fc.order}: its {nz} states exceed the "
                              f"estimator's {MAX_Z} (band-pass order <= 2, low-pass order <= 4)")
        if not abs(Df) > 1e-12:
            raise ConfigError(f"effects.filters.{key}: the filter has no feedthrough, so its input "
                              "cannot be recovered")
        k[f"{ch}_d"] = Df
        k[f"{ch}_nz"] = float(nz)
        for a in range(nz):
            k[f"{ch}_b_{a}"] = float(Bf[a])
            k[f"{ch}_c_{a}"] = float(Cf[a])
            for b in range(nz):
                k[f"{ch}_a_{a * MAX_Z + b}"] = float(Af[a, b])
    # the prior on body 1 from the drop's ranges, at the instant the first reading shows: a known
    # sensor delay (whole periods) puts it that much before the episode's start
    g = pl.gravity
    tau = scene.initial.pre_contact_time
    if eff.on("sensor_delay"):
        tau += eff.delay.samples(rate)[0] / rate
    rnd = scene.randomize

    def start(v):
        t = min(tau, v / g) if g > 0 else tau
        return np.array([-(v * t - 0.5 * g * t * t), v - g * t])

    if rnd.drop_height:
        mean, cov = _uniform_moments(rnd.drop_height[0], rnd.drop_height[-1],
                                     lambda h: start(math.sqrt(2.0 * g * h)))
    elif rnd.impact_speed:
        mean, cov = _uniform_moments(rnd.impact_speed[0], rnd.impact_speed[-1], start)
    else:
        mean, cov = start(scene.impact_speed), np.zeros((2, 2))
    cov[0, 0] += (scene.impact_speed * s["timing_std"]) ** 2
    cov[1, 1] += (0.01 * scene.impact_speed) ** 2  # (a floor: a nominal drop is known to 1 %)
    k.update(x1_0=mean[0], v1_0=mean[1], p_x1=cov[0, 0], p_x1v1=cov[0, 1], p_v1=cov[1, 1])
    if rnd.m1:
        im, var = _uniform_moments(rnd.m1[0], rnd.m1[-1], lambda m: np.array([1.0 / m]))
        k.update(im1_0=im[0], p_im1=var[0, 0])
    else:
        k.update(im1_0=1.0 / pl.m1, p_im1=(0.05 / pl.m1) ** 2)
    k.update(p_x2=1e-12, p_v2=1e-8)  # body 2 starts at rest (a hair of variance keeps P definite)
    from scipy.stats import chi2

    k.update(q_a1=s["q_a1"], q_a2=s["q_a2"], q_im1=s["q_im1"], nis_window=float(s["nis_window"]),
             nis_bound=float(chi2.ppf(1.0 - s["nis_alpha"], 3 * int(s["nis_window"]))),
             reset_x=s["reset_x"],
             q_b_acc=s["q_bias"] * math.sqrt(k["acc_r"]), q_b_force=s["q_bias"] * math.sqrt(k["force_r"]),
             q_b_pot=s["q_bias"] * math.sqrt(k["pot_r"]), p_b_acc=1e-6 * k["acc_r"],
             p_b_force=1e-6 * k["force_r"], p_b_pot=1e-6 * k["pot_r"], reset_v=s["reset_v"],
             d_floor=s["d_floor"])
    assert len(k) == N_CONSTANTS and set(k) == set(EkfConstants._fields)
    for name, v in k.items():
        if not math.isfinite(float(v)):
            raise ConfigError(f"the estimator's constant {name} = {v!r} is not finite")
    return {name: float(v) for name, v in k.items()}


def constants_vector(constants: dict[str, float]) -> np.ndarray:
    """float64[N_CONSTANTS]: the constants in :class:`EkfConstants` order (the kernel's ``k``)."""
    names: tuple[str, ...] = EkfConstants._fields
    return np.array([constants[name] for name in names], dtype=np.float64)


__all__ = ["CH_BASE", "CO_A", "CO_B", "CO_C", "CO_D", "CO_GAIN", "CO_NZ", "CO_OFFSET", "CO_R", "EK",
           "SETTINGS", "constants_vector", "ekf_constants", "filter_state_space"]
