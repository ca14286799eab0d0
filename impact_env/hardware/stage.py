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

Arguments are grouped by role, as tuples (numba takes them as one argument each):

* ``cfg`` = (flags, method code, dt s, rtol, period s): the scene's constants;
* ``plant`` = (Y float64[N, 6], modes int64[N], P float64[N, 7], scale float64[N, 6],
  H float64[N, 1], EV float64[N, E, 6], EVN int64[N, 1], t float64[N]): the plant's state,
  mode, parameters, dopri5's error scale and step size, event log, and time since the episode
  start (:mod:`impact_env.plant.layout`);
* ``fx`` = (PR float64[N, Q], ST float64[N, S], po int64[7], so int64[5]): every effect's
  per-env parameters and state, packed (:mod:`impact_env.hardware.blocks`; block order
  :data:`PARAM_BLOCKS`, :data:`STATE_BLOCKS`);
* ``noise`` = (z float64[N, B, 4], cursor int64[N]): pre-drawn standard normals; with the
  sensors on, env i reads ``z[i, cursor[i]]`` and advances its cursor;
* ``out`` = (raw float64[N, 4], info float64[N, N_INFO]): the raw readings (accelerometer
  m/s^2, force transducer N, potentiometer m, body-1 sensor m) and the info columns below.

Nothing is allocated: one-element views of ``info`` serve as the delay line's and the
integrator's in/out cells, and the sensor stages work in place.
"""

from __future__ import annotations

import numpy as np

from impact_env._jit import jit
from impact_env.effects.delay import delay_packed
from impact_env.effects.saturation import saturate
from impact_env.effects.sensors import read_packed, sense_packed
from impact_env.effects.shaker import shaker_packed
from impact_env.plant.dynamics import contact_force
from impact_env.plant.integrators import advance
from impact_env.plant.layout import C2, K2, M2, B, C

# flag bits (the hardware's effects)
F_ACT_DELAY = 1
F_SHAKER = 2
F_SATURATION = 4
F_SENSORS = 8
F_SENS_DELAY = 16
F_BACK_EMF = 32  # the shaker's back-EMF input (effects.shaker.back_emf), with F_SHAKER

# packed blocks, in signal order (sizes from the effect modules)
PARAM_BLOCKS = ("drive", "actuator_delay", "shaker", "saturation", "sensors", "sensor_delay")
STATE_BLOCKS = ("actuator_delay", "shaker", "saturation", "sensor_delay")
PB_DRIVE, PB_ACT_DELAY, PB_SHAKER, PB_SATURATION, PB_SENSORS, PB_SENS_DELAY = range(len(PARAM_BLOCKS))
SB_ACT_DELAY, SB_SHAKER, SB_SATURATION, SB_SENS_DELAY = range(len(STATE_BLOCKS))

# columns of the per-env info array
INFO_F_DEMAND = 0  # N, demanded force (command * command scale)
INFO_F_APPLIED = 1  # N, force on body 2 after shaker and saturation
INFO_SATURATED = 2  # 1 if saturation changed the force
INFO_CONTACT_FORCE = 3  # N, true contact force at the end of the period
INFO_PEAK_FORCE = 4  # N, largest contact force within the period
INFO_A2 = 5  # m/s^2, true acceleration of body 2 at the end of the period
INFO_STATUS = 6  # the plant kernel's status (0 ok)
N_INFO = 7


@jit(inline="always")
def hardware_tick(i, u, cfg, plant, fx, noise, out):
    """Advance env i by one control period under the drive command u (1 = the scene's
    command scale newtons upwards, before the drawn amplifier gain)."""
    flags, method, dt, rtol, period = cfg
    Y, modes, P, scale, H, EV, EVN, t = plant
    PR, ST, po, so = fx
    z, cursor = noise
    raw, info = out
    pr = PR[i]
    st = ST[i]
    inf = info[i]
    f = u * pr[po[PB_DRIVE]]
    inf[INFO_F_DEMAND] = f
    y = Y[i]
    p = P[i]
    if flags & F_ACT_DELAY:
        cell = inf[INFO_F_APPLIED:INFO_F_APPLIED + 1]
        cell[0] = f
        delay_packed(pr[po[PB_ACT_DELAY]:po[PB_ACT_DELAY + 1]], st[so[SB_ACT_DELAY]:so[SB_ACT_DELAY + 1]],
                     cell, cell)
        f = cell[0]
    if flags & F_SHAKER:
        f = shaker_packed(pr[po[PB_SHAKER]:po[PB_SHAKER + 1]], st[so[SB_SHAKER]:so[SB_SHAKER + 1]], f, y[3],
                          (flags & F_BACK_EMF) != 0)
    sat = False
    if flags & F_SATURATION:
        f, sat = saturate(f, st[so[SB_SATURATION]:so[SB_SATURATION + 1]],
                          pr[po[PB_SATURATION]:po[PB_SATURATION + 1]])
    inf[INFO_F_APPLIED] = f
    inf[INFO_SATURATED] = 1.0 if sat else 0.0
    peak = inf[INFO_PEAK_FORCE:INFO_PEAK_FORCE + 1]
    peak[0] = 0.0
    status, mode = advance(y, modes[i], f, 0.0, period, p, method, dt, rtol, scale[i], H[i], EV[i], EVN[i],
                           peak)
    modes[i] = mode
    inf[INFO_STATUS] = status
    # the true contact force and body 2's acceleration at the end of the period, by the same
    # expressions as plant.dynamics.deriv (one contact-force evaluation, not two)
    phi, _fe = contact_force(y[0] - y[2], y[1] - y[3], mode, p[C], p[B])
    a2 = (phi - f - p[K2] * y[2] - p[C2] * y[3]) * (1.0 / p[M2])
    inf[INFO_CONTACT_FORCE] = phi
    inf[INFO_A2] = a2
    r = raw[i]
    sens = pr[po[PB_SENSORS]:po[PB_SENSORS + 1]]
    read_packed(y[0], y[2], a2, phi, sens, r)
    if flags & F_SENSORS:  # each sensor stage reads channel j before writing it: in place
        c = cursor[i]
        if c >= z.shape[1]:
            raise IndexError("noise block used up: the Hardware refills it before each step")
        sense_packed(r, z[i, c], sens, r)
        cursor[i] = c + 1
    if flags & F_SENS_DELAY:
        delay_packed(pr[po[PB_SENS_DELAY]:po[PB_SENS_DELAY + 1]], st[so[SB_SENS_DELAY]:so[SB_SENS_DELAY + 1]],
                     r, r)
    t[i] += period


@jit
def hardware_step(u, cfg, plant, fx, noise, out):
    """One tick of every env i under the drive command u[i] (float64[N])."""
    for i in range(u.shape[0]):
        hardware_tick(i, u[i], cfg, plant, fx, noise, out)


@jit(inline="always")
def state_ok(i, plant, info) -> bool:
    """False once env i's plant kernel failed or its state left the finite range."""
    if info[i, INFO_STATUS] != 0.0:
        return False
    y = plant[0][i]
    for k in range(4):
        if not np.isfinite(y[k]):
            return False
    return True
