"""The control-step kernel: one control period of the whole signal path for a batch of rigs.

Order (fixed, documented once here):
``action -> command scaling -> actuator delay -> shaker -> saturation -> plant -> sensors
(gain, offset, noise, ADC) -> filters -> sensor delay -> contact detector -> readings``.
A stage runs only if its flag is set; a stage that is off is not evaluated (its branch is
skipped), so a scene with every effect off integrates exactly the bare plant.
"""

from __future__ import annotations

import numpy as np

from impact_env._jit import jit
from impact_env.effects.delay import delay_step
from impact_env.effects.detector import detect
from impact_env.effects.filters import filter_step
from impact_env.effects.saturation import saturate
from impact_env.effects.sensors import sense, true_readings
from impact_env.effects.shaker import shaker_step
from impact_env.plant.dynamics import contact_force, deriv
from impact_env.plant.integrators import advance
from impact_env.plant.layout import AUTO, C2, K2, M1, M2, B, C, G

# flag bits
F_ACT_DELAY = 1
F_SHAKER = 2
F_SATURATION = 4
F_SENSORS = 8
F_FILTERS = 16
F_SENS_DELAY = 32
F_DETECTOR = 64

# columns of the per-env info array
I_F_DEMAND = 0  # N, demanded force (action * command_scale)
I_F_APPLIED = 1  # N, force on body 2 after shaker and saturation
I_SATURATED = 2  # 1 if saturation changed the force
I_CONTACT_FORCE = 3  # N, true contact force at the end of the period
I_PEAK_FORCE = 4  # N, largest contact force within the period
I_DETECTED = 5  # 1 if the detector reports contact
I_A2 = 6  # m/s^2, true acceleration of body 2 at the end of the period
I_STATUS = 7  # kernel status (0 ok)
N_INFO = 8


@jit
def control_step_batch(actions, t0, period, flags, command_scale,
                       Y, modes, P, H, method, dt, rtol, scale, EV, EVN,
                       act_buf, act_head,
                       sh_A, sh_B, sh_C, sh_D, sh_X,
                       sat_params, sat_state,
                       sens_params, top_mass, Z,
                       sos, filt_state,
                       sd_buf, sd_head,
                       det_params, det_state,
                       readings, info):
    """Advance every env i (rows of the state arrays) by one control period under actions[i]
    (in [-1, 1]).  Writes the readings (float64[N, 4]: accelerometer, force transducer,
    potentiometer, body-1 sensor, after the enabled sensor stages) and the info columns.
    """
    n = actions.shape[0]
    tmp = np.empty(4)
    tmp1 = np.empty(1)
    out1 = np.empty(1)
    peak = np.zeros(1)
    for i in range(n):
        f = actions[i] * command_scale
        info[i, I_F_DEMAND] = f
        if flags & F_ACT_DELAY:
            tmp1[0] = f
            delay_step(act_buf[i], act_head[i], tmp1, out1)
            f = out1[0]
        if flags & F_SHAKER:
            f = shaker_step(sh_A, sh_B, sh_C, sh_D, sh_X[i], f)
        sat = False
        if flags & F_SATURATION:
            f, sat = saturate(f, sat_state[i], sat_params)
        info[i, I_F_APPLIED] = f
        info[i, I_SATURATED] = 1.0 if sat else 0.0
        peak[0] = 0.0
        y = Y[i]
        p = P[i]
        status, mode = advance(y, modes[i], f, t0, period, p, method, dt, rtol, scale[i], H[i],
                               EV[i], EVN[i], peak)
        modes[i] = mode
        info[i, I_STATUS] = status
        info[i, I_PEAK_FORCE] = peak[0]
        d = y[0] - y[2]
        dd = y[1] - y[3]
        phi, _fe = contact_force(d, dd, AUTO if mode == AUTO else mode, p[C], p[B])
        r = deriv(y[0], y[1], y[2], y[3], mode, f, 1.0 / p[M1], 1.0 / p[M2], p[C], p[B], p[G], p[K2], p[C2])
        a2 = r[3]
        info[i, I_CONTACT_FORCE] = phi
        info[i, I_A2] = a2
        out = readings[i]
        true_readings(y[0], y[2], a2, phi, top_mass, tmp)
        if flags & F_SENSORS:
            sense(tmp, Z[i], sens_params, out)
        else:
            for j in range(4):
                out[j] = tmp[j]
        if flags & F_FILTERS:
            for j in range(4):
                tmp[j] = out[j]
            filter_step(sos, filt_state[i], tmp, out)
        if flags & F_SENS_DELAY:
            for j in range(4):
                tmp[j] = out[j]
            delay_step(sd_buf[i], sd_head[i], tmp, out)
        det = False
        if flags & F_DETECTOR:
            det = detect(out[0], out[1], det_state[i], det_params)
        info[i, I_DETECTED] = 1.0 if det else 0.0
