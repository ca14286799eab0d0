"""Where the EKF keeps its constants and its memory: named positions in the two float64 vectors.

Constants (one vector per scene, :func:`impact_env.control.estimation.model.ekf_constants`): the
plant, the shaker and limit replica, each filtered channel's model, the noises, the prior and the
lost-track rule.  Memory (one row per env, zeroed at the episode start): flags and counters, the
state estimate, its covariance and scratch.

The state is ``[x1, v1, x2, v2, im1, b_acc, b_force, b_pot]``: body 1's and body 2's position
(m, down) and speed (m/s), body 1's inverse mass im1 = 1/m1 (1/kg, drawn per drop, so
estimated), and the drift of each recovered raw reading (m/s^2, N, m): a steady part and
one that alternates in sign every tick (the inverse filters' poles at z = 1 and z = -1).  Each
measured channel's filter (at most :data:`MAX_Z` states) is inverted to recover its raw reading
(:mod:`impact_env.control.estimation.ekf` says why that is exact).
"""

from __future__ import annotations

from collections import namedtuple

from impact_env._packed import positions

N_PLANT = 5  # x1, v1, x2, v2, im1
X1, V1, X2, V2, IM1 = range(N_PLANT)
BIAS = N_PLANT  # then each channel's drift of the recovered raw reading (see ekf's module doc),
#                a steady part, then one that alternates in sign every tick
CHANNEL_NAMES = ("acc", "force", "pot")  # the measured channels, in the state's order
N_MEAS = len(CHANNEL_NAMES)
MAX_Z = 4  # filter states per channel (a band-pass of order 2, a low-pass of order 4)
BIAS_ALT = BIAS + N_MEAS
N_STATE = N_PLANT + 2 * N_MEAS
MAX_SHAKER = 4  # shaker model order (the coil model's 3, plus the inverse pre-filter's 1)
SHAKER_BLOCK = 1 + MAX_SHAKER * MAX_SHAKER + 3 * MAX_SHAKER  # the shaker's packed parameter block


def _fields() -> list[str]:
    f = ["m2", "c", "zeta", "g", "k2", "c2", "top_mass", "dt", "command_scale", "command_gain",
         "sh_on", "sh_n", "back_emf"]
    f += [f"sh_{i}" for i in range(SHAKER_BLOCK)]
    f += ["sat_on", "sat_peak", "sat_rms2", "sat_alpha", "sat_slew"]
    for ch in CHANNEL_NAMES:
        f += [f"{ch}_gain", f"{ch}_offset", f"{ch}_r", f"{ch}_d", f"{ch}_nz"]
        f += [f"{ch}_a_{i}" for i in range(MAX_Z * MAX_Z)]
        for name in ("b", "c"):
            f += [f"{ch}_{name}_{i}" for i in range(MAX_Z)]
    f += ["q_a1", "q_a2", "q_im1", "q_b_acc", "q_b_force", "q_b_pot", "p_b_acc", "p_b_force", "p_b_pot"]
    f += ["x1_0", "v1_0", "p_x1", "p_x1v1", "p_v1", "im1_0", "p_im1", "p_x2", "p_v2"]
    f += ["nis_window", "nis_bound", "reset_x", "reset_v", "d_floor"]
    return f


#: the EKF's constants vector, by name (every field a float; arrays as numbered fields)
EkfConstants = namedtuple("EkfConstants", _fields())  # type: ignore[misc]  # (generated fields)
EK = positions(EkfConstants)
N_CONSTANTS = len(EK)
#: where each channel's block starts in the constants (its gain), in CHANNEL_NAMES order
CH_BASE = tuple(getattr(EK, f"{ch}_gain") for ch in CHANNEL_NAMES)
CH_STRIDE = CH_BASE[1] - CH_BASE[0]
# offsets inside a channel's block
CO_GAIN, CO_OFFSET, CO_R, CO_D, CO_NZ = range(5)
CO_A = 5
CO_B = CO_A + MAX_Z * MAX_Z
CO_C = CO_B + MAX_Z


class _Memory:
    """Positions in the EKF's memory row (all float64; zeroed at the episode start)."""

    started = 0  # 0 until the first tick has set the prior
    lost = 1  # 1 while the filter reports it has lost track (the status bit)
    lost_count = 2  # how many times it has lost track this episode
    nis_sum = 3  # normalised innovations squared, summed over the current window
    nis_ticks = 4  # ticks in the current window
    f_applied = 5  # N, the force the replica says was applied over the last period (up)
    resets = 6  # non-finite or indefinite covariances met (each also counts as lost)
    nis_last = 7  # the last tick's normalised innovation squared
    shaker = 8  # the shaker replica's packed state (its n states, then n of scratch)
    sat = shaker + 2 * MAX_SHAKER  # the limit replica's state (mean square N^2, previous force N)
    filt = sat + 2  # each channel's filter state, run on the recovered raw readings, N_MEAS x MAX_Z
    raw = filt + N_MEAS * MAX_Z  # this tick's recovered raw readings, N_MEAS
    x = raw + N_MEAS  # the state estimate, N_STATE floats
    p = x + N_STATE  # its covariance, N_STATE x N_STATE row-major
    scratch = p + N_STATE * N_STATE  # (Phi P), N_STATE x N_STATE
    phi = scratch + N_STATE * N_STATE  # the transition, N_STATE x N_STATE
    hx = phi + N_STATE * N_STATE  # each raw reading's gradient in the state, N_MEAS x N_STATE
    hy = hx + N_MEAS * N_STATE  # the predicted raw readings, N_MEAS
    ph = hy + N_MEAS  # P h', N_STATE
    x_prior = ph + N_STATE  # the estimate before this tick's update, N_STATE
    innov = x_prior + N_STATE  # each channel's innovation against the prior, N_MEAS
    size = innov + N_MEAS


_MEM_FIELDS = [f for f in vars(_Memory) if not f.startswith("_")]
#: the memory row's positions by name (a namedtuple instance: numba reads it as constants)
EkfMemory = namedtuple("EkfMemory", _MEM_FIELDS)(*(getattr(_Memory, f) for f in _MEM_FIELDS))  # type: ignore[misc]
MEMORY = _Memory.size
#: where the replicas' region of the memory row (the shaker's, then the limit's) ends
REPLICAS_END = _Memory.sat + 2
