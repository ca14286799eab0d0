"""The rig-physics stage: one control period (a *tick*) of the hardware, for one env of a batch.

Order (fixed, documented once here)::

    drive command u -> command scaling (amplifier gain, N per unit) -> actuator delay -> shaker
    -> saturation (amplifier limit) -> plant (one period, zero-order hold) -> sensors (gain,
    offset, noise, ADC) -> sensor delay -> raw readings

A stage runs only if its flag is set; a stage that is off is skipped, so a scene with every
effect off integrates exactly the bare plant.  Everything after the raw readings (filters, the
contact detector, the observation frame, the policy) is controller code on the real-time target:
:mod:`impact_env.control`.  The simulator runs this stage and the controller's front end one
after the other; a virtual rig runs this stage alone.

Arguments, as gymnax has them: what is fixed for an episode apart from what changes every tick,
each a :class:`typing.NamedTuple` read by field name (numba compiles them as tuples):

* :class:`HardwareParams` = (``cfg``: :class:`StageConfig`, the scene's constants; ``plant``:
  :class:`PlantParams`, per-env plant parameters and dopri5's error scale; ``effects``:
  :class:`EffectParams`, every effect's per-env parameters, packed, with the offsets of the
  parameter and state blocks, :mod:`impact_env.hardware.blocks`, block order
  :data:`PARAM_BLOCKS`, :data:`STATE_BLOCKS`);
* :class:`HardwareState` = (``plant``: :class:`PlantState`, the plant's state, mode, step size,
  event log and time; ``effects``: float64[N, S], every effect's state, packed; ``noise``:
  :class:`Noise`, pre-drawn standard normals and each env's cursor; ``out``:
  :class:`Readings`, the raw readings and the info columns below).  :func:`reset_env` is the
  one place that starts it at an episode start.

Nothing is allocated: one-element views of ``info`` serve as the delay line's and the
integrator's in/out cells, and the sensor stages work in place.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.effects import registry
from impact_env.effects.delay import delay_packed
from impact_env.effects.saturation import saturate
from impact_env.effects.sensors import read_packed, sense_packed
from impact_env.effects.shaker import shaker_packed
from impact_env.plant.dynamics import coefs, contact_force
from impact_env.plant.integrators import PlantCarry, PlantConsts, advance
from impact_env.plant.layout import STATE

# flag bits (the hardware's effects, as the registry orders them: impact_env.effects.registry)
F_ACT_DELAY = registry.flag("actuator_delay")
F_SHAKER = registry.flag("shaker")
F_SATURATION = registry.flag("saturation")
F_SENSORS = registry.flag("sensors")
F_SENS_DELAY = registry.flag("sensor_delay")
F_BACK_EMF = registry.option_flag("shaker", "back_emf")  # the shaker's back-EMF input, with F_SHAKER

# packed blocks: the stage's own drive block, then every hardware effect's, in registry order
# (sizes from each effect's packer, impact_env.hardware.batch); a block is found by its name,
# ``PB.shaker``: the fields of a NamedTuple made from the registry, numbered by position
PARAM_BLOCKS = ("drive",) + tuple(e.name for e in registry.side(registry.HARDWARE))
STATE_BLOCKS = tuple(e.name for e in registry.side(registry.HARDWARE))
ParamBlocks = NamedTuple("ParamBlocks", [(name, int) for name in PARAM_BLOCKS])  # type: ignore[misc]
StateBlocks = NamedTuple("StateBlocks", [(name, int) for name in STATE_BLOCKS])  # type: ignore[misc]
PB = positions(ParamBlocks)
SB = positions(StateBlocks)


class HardwareInfo(NamedTuple):
    """The columns of the per-env info array (float64[N, N_INFO]), read by name:
    ``info[i, HW_INFO.f_applied]``."""

    f_demand: float  # N, demanded force (command * command scale)
    f_applied: float  # N, force on body 2 after shaker and saturation
    saturated: float  # 1 if saturation changed the force
    contact_force: float  # N, true contact force at the end of the period
    peak_force: float  # N, largest contact force within the period
    a2: float  # m/s^2, true acceleration of body 2 at the end of the period
    status: float  # the plant kernel's status (0 ok)
    catch_integral: float  # J s, the time integral of body 1's catch energy over the period (the plant's)


HW_INFO = positions(HardwareInfo)
N_INFO = len(HW_INFO)
# the same columns as plain ints, for rig/, eval/ and deploy/, which still read them so
(INFO_F_DEMAND, INFO_F_APPLIED, INFO_SATURATED, INFO_CONTACT_FORCE, INFO_PEAK_FORCE, INFO_A2,
 INFO_STATUS, INFO_CATCH_INTEGRAL) = HW_INFO


class StageConfig(NamedTuple):
    """The scene's constants of the stage."""

    flags: np.int64  # the F_* bits of the effects that are on
    method: np.int64  # the integrator (impact_env.hardware.arrays.METHOD_CODES)
    dt: float  # s, the fixed-step methods' step
    rtol: float  # dopri5's relative tolerance
    period: float  # s, the control period


class PlantParams(NamedTuple):
    """Per-env plant parameters (fixed for an episode)."""

    p: np.ndarray  # float64[N, N_PARAM] (impact_env.plant.layout)
    scale: np.ndarray  # float64[N, 6]: dopri5's error scale


class PlantState(NamedTuple):
    """Per-env plant state (changes every tick)."""

    y: np.ndarray  # float64[N, N_STATE]: x1, v1, x2, v2, W_ext, W_diss
    mode: np.ndarray  # int64[N]: the contact mode
    h: np.ndarray  # float64[N, 1]: dopri5's step size
    events: np.ndarray  # float64[N, E, N_EVENT_COLS]: the event log
    n_events: np.ndarray  # int64[N, 1]
    t: np.ndarray  # float64[N]: s since the episode start


class EffectParams(NamedTuple):
    """Every effect's per-env parameters, packed, and the block tables."""

    rows: np.ndarray  # float64[N, Q]: blocks PARAM_BLOCKS
    offsets: np.ndarray  # int64[len(PARAM_BLOCKS) + 1]
    state_offsets: np.ndarray  # int64[len(STATE_BLOCKS) + 1]: blocks STATE_BLOCKS of HardwareState.effects


class Noise(NamedTuple):
    """Pre-drawn standard normals: with the sensors on, env i reads ``z[i, cursor[i]]`` and
    advances its cursor."""

    z: np.ndarray  # float64[N, B, 4]
    cursor: np.ndarray  # int64[N]


class Readings(NamedTuple):
    """What a tick leaves: the raw readings (accelerometer m/s^2, force transducer N,
    potentiometer m, body-1 sensor m) and the info columns."""

    raw: np.ndarray  # float64[N, 4]
    info: np.ndarray  # float64[N, N_INFO]


class HardwareParams(NamedTuple):
    cfg: StageConfig
    plant: PlantParams
    effects: EffectParams


class HardwareState(NamedTuple):
    plant: PlantState
    effects: np.ndarray  # float64[N, S]: every effect's state, packed (EffectParams.state_offsets)
    noise: Noise
    out: Readings


def reset_env(s: HardwareState, i: int, y0: np.ndarray, mode0: int) -> None:
    """Start env i's episode: the plant at ``y0`` in ``mode0``, every effect's state and delay
    line zero, no events, a fresh noise block wanted, the raw readings the true, noise-free
    values at rest (0 m/s^2, 0 N, x2, x1)."""
    ps = s.plant
    ps.y[i] = y0
    ps.mode[i] = mode0
    ps.n_events[i] = 0
    ps.events[i] = 0.0
    ps.h[i] = 0.0
    ps.t[i] = 0.0
    s.effects[i] = 0.0
    s.noise.cursor[i] = s.noise.z.shape[1]
    s.out.info[i] = 0.0
    y = ps.y[i]
    s.out.raw[i] = (0.0, 0.0, y[STATE.x2], y[STATE.x1])


@jit(inline="always")
def block(row, offsets, j):
    """Block ``j`` of a packed row (:mod:`impact_env.hardware.blocks`): a view."""
    return row[offsets[j]:offsets[j + 1]]


@jit(inline="always")
def hardware_tick(i, u, p, s):
    """Advance env i by one control period under the drive command u (1 = the scene's
    command scale newtons upwards, before the drawn amplifier gain); ``p``: HardwareParams,
    ``s``: HardwareState."""
    cfg = p.cfg
    flags = cfg.flags
    ps = s.plant
    po = p.effects.offsets
    so = p.effects.state_offsets
    params = p.effects.rows[i]
    state = s.effects[i]
    info = s.out.info[i]
    f = u * params[po[PB.drive]]
    info[HW_INFO.f_demand] = f
    y = ps.y[i]
    plant_params = p.plant.p[i]
    if flags & F_ACT_DELAY:
        cell = info[HW_INFO.f_applied:HW_INFO.f_applied + 1]
        cell[0] = f
        delay_packed(block(params, po, PB.actuator_delay), block(state, so, SB.actuator_delay), cell, cell)
        f = cell[0]
    if flags & F_SHAKER:
        f = shaker_packed(block(params, po, PB.shaker), block(state, so, SB.shaker), f, y[STATE.v2],
                          (flags & F_BACK_EMF) != 0)
    sat = False
    if flags & F_SATURATION:
        f, sat = saturate(f, block(state, so, SB.saturation), block(params, po, PB.saturation))
    info[HW_INFO.f_applied] = f
    info[HW_INFO.saturated] = 1.0 if sat else 0.0
    peak = info[HW_INFO.peak_force:HW_INFO.peak_force + 1]
    peak[0] = 0.0
    integral = info[HW_INFO.catch_integral:HW_INFO.catch_integral + 1]
    integral[0] = 0.0
    status, mode = advance(ps.mode[i], f, 0.0, cfg.period,
                           PlantConsts(plant_params, p.plant.scale[i], cfg.method, cfg.dt, cfg.rtol),
                           PlantCarry(y, ps.h[i], ps.events[i], ps.n_events[i], peak, integral))
    ps.mode[i] = mode
    info[HW_INFO.status] = status
    # the true contact force and body 2's acceleration at the end of the period, by the same
    # expressions as plant.dynamics.deriv (one contact-force evaluation, not two)
    pc = coefs(plant_params)
    phi, _fe = contact_force(y[STATE.x1] - y[STATE.x2], y[STATE.v1] - y[STATE.v2], mode, pc.c, pc.b)
    a2 = (phi - f - pc.k2 * y[STATE.x2] - pc.c2 * y[STATE.v2]) * pc.im2
    info[HW_INFO.contact_force] = phi
    info[HW_INFO.a2] = a2
    r = s.out.raw[i]
    sens = block(params, po, PB.sensors)
    read_packed(y[STATE.x1], y[STATE.x2], a2, phi, sens, r)
    if flags & F_SENSORS:  # each sensor stage reads channel j before writing it: in place
        z = s.noise.z
        cursor = s.noise.cursor
        c = cursor[i]
        if c >= z.shape[1]:
            raise IndexError("noise block used up: the Hardware refills it before each step")
        sense_packed(r, z[i, c], sens, r)
        cursor[i] = c + 1
    if flags & F_SENS_DELAY:
        delay_packed(block(params, po, PB.sensor_delay), block(state, so, SB.sensor_delay), r, r)
    ps.t[i] += cfg.period


@jit
def tick(i, u, p, s):
    """:func:`hardware_tick` as a called kernel.  numba types and compiles an inlined kernel
    again at each call site; the loops whose speed does not hang on one call per tick (the rig
    target's virtual hardware, the hardware replay, the sensor-fault runs,
    :func:`hardware_step`) call this one copy instead.  The simulator's per-env step
    (:func:`impact_env.sim.step.env_step`) keeps it inlined."""
    hardware_tick(i, u, p, s)


@jit
def hardware_step(u, p, s):
    """One tick of every env i under the drive command u[i] (float64[N])."""
    for i in range(u.shape[0]):
        tick(i, u[i], p, s)


@jit(inline="always")
def state_ok(i, s) -> bool:
    """False once env i's plant kernel failed or its state left the finite range."""
    if s.out.info[i, HW_INFO.status] != 0.0:
        return False
    y = s.plant.y[i]
    for k in range(4):
        if not np.isfinite(y[k]):
            return False
    return True
