"""The control-step kernel: one control period of the whole signal path for a batch of rigs.

Order (fixed, documented once here):
``action -> command scaling -> actuator delay -> shaker -> saturation -> plant -> sensors
(gain, offset, noise, ADC) -> filters -> sensor delay -> contact detector -> readings``.
A stage runs only if its flag is set; a stage that is off is not evaluated (its branch is
skipped), so a scene with every effect off integrates exactly the bare plant.

Arguments are packed: every per-env parameter of the effects sits in one row of ``PR``
(float64[N, Q]) and every per-env effect state in one row of ``ST`` (float64[N, S]), at the
offsets below (:func:`row_layout` names them; the Simulator exposes each piece as a view).
Passing a few arrays instead of thirty-odd is what makes a call cheap: each array argument
costs tens of ns inside compiled code and about 0.3 us from Python.
"""

from __future__ import annotations

from impact_env._jit import jit
from impact_env.effects.delay import delay_step
from impact_env.effects.detector import detect
from impact_env.effects.filters import filter_step
from impact_env.effects.saturation import saturate
from impact_env.effects.sensors import N_CHANNELS as N_CH
from impact_env.effects.sensors import N_PARAM as SENS_NP
from impact_env.effects.sensors import sense, true_readings
from impact_env.effects.shaker import shaker_step_into
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

# parameter row PR[i]: fixed part, then the shaker matrices A (ns*ns), B, C, E (ns each)
R_CMD = 0  # N per unit action (command scale, times a drawn gain)
R_TOP = 1  # kg, m2' above the force transducer
R_ACT_LEN = 2  # actuator delay, samples (a whole number stored as float64)
R_SD_LEN = 3  # sensor delay, samples
R_SH_D = 4  # shaker feed-through D
R_SCALE = 5  # 6 entries: dopri5's per-component error scale
R_SAT = 11  # 4 entries: saturation params (effects.saturation)
R_DET = 15  # 5 entries: detector params (effects.detector)
R_SENS = 20  # N_CH x SENS_NP (4 x 7) entries: sensor params (effects.sensors)
R_SH = R_SENS + N_CH * SENS_NP  # shaker A, B, C, E

# state row ST[i]: fixed part, then shaker state and scratch (ns each), filter state
# (N_CH * nsec * 2), actuator delay line (ka), sensor delay line (ks * N_CH)
S_H = 0  # dopri5's step size
S_ACT_HEAD = 1
S_SD_HEAD = 2
S_SAT = 3  # 2 entries: saturation state
S_DET = 5  # 2 entries: detector state
S_SHX = 7


@jit(inline="always")
def _offsets(ns, nsec, ka):
    """Offsets of the variable-size pieces: (shaker B, C, E in PR; shaker scratch, filter state,
    actuator delay line, sensor delay line in ST) for shaker order ns, nsec filter sections and
    an actuator delay line of ka samples."""
    o_b = R_SH + ns * ns
    o_c = o_b + ns
    o_e = o_c + ns
    o_scr = S_SHX + ns
    o_filt = o_scr + ns
    o_act = o_filt + N_CH * nsec * 2
    o_sd = o_act + ka
    return o_b, o_c, o_e, o_scr, o_filt, o_act, o_sd


def row_layout(ns: int, nsec: int, ka: int, ks: int):
    """``(pr, Q, st, S)``: name -> (offset, shape) of every piece of a parameter row (Q floats)
    and of a state row (S floats), for shaker order ns, nsec filter sections and delay lines of
    ka (actuator) and ks (sensor) samples."""
    o_b, o_c, o_e, o_scr, o_filt, o_act, o_sd = _offsets.py_func(ns, nsec, ka)
    pr = {"command_scale": (R_CMD, ()), "top_mass": (R_TOP, ()), "act_len": (R_ACT_LEN, ()),
          "sd_len": (R_SD_LEN, ()), "sh_D": (R_SH_D, ()), "scale": (R_SCALE, (6,)),
          "sat_params": (R_SAT, (4,)), "det_params": (R_DET, (5,)), "sens_params": (R_SENS, (N_CH, SENS_NP)),
          "sh_A": (R_SH, (ns, ns)),
          "sh_B": (o_b, (ns,)), "sh_C": (o_c, (ns,)), "sh_E": (o_e, (ns,))}
    st = {"H": (S_H, (1,)), "act_head": (S_ACT_HEAD, (1,)), "sd_head": (S_SD_HEAD, (1,)),
          "sat_state": (S_SAT, (2,)), "det_state": (S_DET, (2,)), "sh_X": (S_SHX, (ns,)),
          "sh_scratch": (o_scr, (ns,)), "filt_state": (o_filt, (N_CH, nsec, 2)), "act_buf": (o_act, (ka, 1)),
          "sd_buf": (o_sd, (ks, N_CH))}
    return pr, o_e + ns, st, o_sd + ks * N_CH


@jit
def control_step_batch(actions, t0, period, flags, method, dt, rtol, dims,
                       Y, modes, P, EV, EVN, PR, ST, sos, noise, cursor, t, readings, info):
    """Advance every env i by one control period under actions[i] (in [-1, 1]).

    Y (float64[N, 6]), modes (int64[N]), P (float64[N, 7]), EV/EVN: the plant's state, mode,
    parameters and event log per env (:mod:`impact_env.plant`).  PR, ST: per-env effect
    parameters and state, laid out as documented above for ``dims`` = int64[4] (shaker order,
    filter sections, actuator and sensor delay-line lengths); env i's delay lines use their
    first ``PR[i, R_ACT_LEN]`` / ``PR[i, R_SD_LEN]`` samples (randomised delays).  sos: the
    filters' sections, shared.  noise (float64[N, B, 4]) and cursor (int64[N]): pre-drawn
    standard normals; with the sensors on, env i reads ``noise[i, cursor[i]]`` and advances
    its cursor.  t (float64[N]) advances by ``period``.  Writes the readings (float64[N, 4]:
    accelerometer, force transducer, potentiometer, body-1 sensor, after the enabled sensor
    stages) and the info columns.  Nothing is allocated: one-element views of info serve as
    the delay line's and the integrator's in/out cells, and the sensor stages work in place.
    """
    n = actions.shape[0]
    ns = dims[0]
    nsec = dims[1]
    o_b, o_c, o_e, o_scr, o_filt, o_act, o_sd = _offsets(ns, nsec, dims[2])
    for i in range(n):
        pr = PR[i]
        st = ST[i]
        f = actions[i] * pr[R_CMD]
        info[i, I_F_DEMAND] = f
        y = Y[i]
        p = P[i]
        if flags & F_ACT_DELAY:
            k = int(pr[R_ACT_LEN])
            cell = info[i, I_F_APPLIED:I_F_APPLIED + 1]
            cell[0] = f
            delay_step(st[o_act:o_act + k].reshape((k, 1)), st[S_ACT_HEAD:S_ACT_HEAD + 1], cell, cell)
            f = cell[0]
        if flags & F_SHAKER:
            x = st[S_SHX:S_SHX + ns]
            f = shaker_step_into(pr[R_SH:o_b].reshape((ns, ns)), pr[o_b:o_c], pr[o_c:o_e], pr[R_SH_D], x, f,
                                 st[o_scr:o_scr + ns])
            if flags & F_BACK_EMF:
                v2 = y[3]
                for j in range(ns):
                    x[j] += pr[o_e + j] * v2
        sat = False
        if flags & F_SATURATION:
            f, sat = saturate(f, st[S_SAT:S_SAT + 2], pr[R_SAT:R_SAT + 4])
        info[i, I_F_APPLIED] = f
        info[i, I_SATURATED] = 1.0 if sat else 0.0
        peak = info[i, I_PEAK_FORCE:I_PEAK_FORCE + 1]
        peak[0] = 0.0
        status, mode = advance(y, modes[i], f, t0, period, p, method, dt, rtol, pr[R_SCALE:R_SCALE + 6],
                               st[S_H:S_H + 1], EV[i], EVN[i], peak)
        modes[i] = mode
        info[i, I_STATUS] = status
        # the true contact force and body 2's acceleration at the end of the period, by the
        # same expressions as plant.dynamics.deriv (one contact-force evaluation, not two)
        phi, _fe = contact_force(y[0] - y[2], y[1] - y[3], mode, p[C], p[B])
        a2 = (phi - f - p[K2] * y[2] - p[C2] * y[3]) * (1.0 / p[M2])
        info[i, I_CONTACT_FORCE] = phi
        info[i, I_A2] = a2
        out = readings[i]
        true_readings(y[0], y[2], a2, phi, pr[R_TOP], out)
        if flags & F_SENSORS:  # each sensor stage reads channel j before writing it: in place
            c = cursor[i]
            if c >= noise.shape[1]:
                raise IndexError("noise block used up: the Simulator refills it before each step")
            sense(out, noise[i, c], pr[R_SENS:R_SH].reshape((N_CH, SENS_NP)), out)
            cursor[i] = c + 1
        if flags & F_FILTERS:
            filter_step(sos, st[o_filt:o_filt + N_CH * nsec * 2].reshape((N_CH, nsec, 2)), out, out)
        if flags & F_SENS_DELAY:
            k = int(pr[R_SD_LEN])
            delay_step(st[o_sd:o_sd + k * N_CH].reshape((k, N_CH)), st[S_SD_HEAD:S_SD_HEAD + 1], out, out)
        det = False
        if flags & F_DETECTOR:
            det = detect(out[0], out[1], st[S_DET:S_DET + 2], pr[R_DET:R_DET + 5])
        info[i, I_DETECTED] = 1.0 if det else 0.0
        t[i] += period
