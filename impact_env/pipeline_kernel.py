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
from impact_env.plant.dynamics import contact_force
from impact_env.plant.integrators import advance
from impact_env.plant.layout import C2, K2, M2, B, C

# flag bits
F_ACT_DELAY = 1
F_SHAKER = 2
F_SATURATION = 4
F_SENSORS = 8
F_FILTERS = 16
F_SENS_DELAY = 32
F_DETECTOR = 64
F_BACK_EMF = 128  # the shaker's back-EMF input (effects.shaker.back_emf), with F_SHAKER

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
                       act_buf, act_len, act_head,
                       sh_A, sh_B, sh_C, sh_D, sh_E, sh_X,
                       sat_params, sat_state,
                       sens_params, top_mass, Z,
                       sos, filt_state,
                       sd_buf, sd_len, sd_head,
                       det_params, det_state,
                       readings, info):
    """Advance every env i (rows of the state arrays) by one control period under actions[i]
    (in [-1, 1]).  Writes the readings (float64[N, 4]: accelerometer, force transducer,
    potentiometer, body-1 sensor, after the enabled sensor stages) and the info columns.

    Every parameter is per env (leading axis N), so envs of one batch may differ (randomised
    scenes): ``command_scale`` float64[N]; the delay lines ``act_buf``/``sd_buf`` are sized for
    the longest delay and env i uses its first ``act_len[i]``/``sd_len[i]`` (int64[N]) slots;
    shaker ``sh_A`` [N, n, n], ``sh_B``/``sh_C``/``sh_E`` [N, n], ``sh_D`` [N] (``sh_E``: the
    back-EMF input, used with ``F_BACK_EMF``); ``sat_params`` [N, 4]; ``sens_params`` [N, 4, 6],
    ``top_mass`` [N]; ``det_params`` [N, 5].  The filters' ``sos`` are shared.
    """
    n = actions.shape[0]
    tmp = np.empty(4)
    tmp1 = np.empty(1)
    out1 = np.empty(1)
    peak = np.zeros(1)
    for i in range(n):
        f = actions[i] * command_scale[i]
        info[i, I_F_DEMAND] = f
        y = Y[i]
        p = P[i]
        if flags & F_ACT_DELAY:
            tmp1[0] = f
            delay_step(act_buf[i, :act_len[i]], act_head[i], tmp1, out1)
            f = out1[0]
        if flags & F_SHAKER:
            f = shaker_step(sh_A[i], sh_B[i], sh_C[i], sh_D[i], sh_X[i], f)
            if flags & F_BACK_EMF:
                v2 = y[3]
                for j in range(sh_X.shape[1]):
                    sh_X[i, j] += sh_E[i, j] * v2
        sat = False
        if flags & F_SATURATION:
            f, sat = saturate(f, sat_state[i], sat_params[i])
        info[i, I_F_APPLIED] = f
        info[i, I_SATURATED] = 1.0 if sat else 0.0
        peak[0] = 0.0
        status, mode = advance(y, modes[i], f, t0, period, p, method, dt, rtol, scale[i], H[i],
                               EV[i], EVN[i], peak)
        modes[i] = mode
        info[i, I_STATUS] = status
        info[i, I_PEAK_FORCE] = peak[0]
        # the true contact force and body 2's acceleration at the end of the period, by the
        # same expressions as plant.dynamics.deriv (one contact-force evaluation, not two)
        phi, _fe = contact_force(y[0] - y[2], y[1] - y[3], mode, p[C], p[B])
        a2 = (phi - f - p[K2] * y[2] - p[C2] * y[3]) * (1.0 / p[M2])
        info[i, I_CONTACT_FORCE] = phi
        info[i, I_A2] = a2
        out = readings[i]
        true_readings(y[0], y[2], a2, phi, top_mass[i], tmp)
        if flags & F_SENSORS:
            sense(tmp, Z[i], sens_params[i], out)
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
            delay_step(sd_buf[i, :sd_len[i]], sd_head[i], tmp, out)
        det = False
        if flags & F_DETECTOR:
            det = detect(out[0], out[1], det_state[i], det_params[i])
        info[i, I_DETECTED] = 1.0 if det else 0.0
