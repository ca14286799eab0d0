"""The ``mpc`` law's extended Kalman filter (impact_env.control.estimation) on drops of ``rig``:
convergence on a noise-free drop, covariance against the empirical error on noisy drops, the
lost-track bit and count, the inverse filters, determinism."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from impact_env.control.estimation.ekf import ekf_run
from impact_env.control.estimation.layout import MEMORY, N_STATE
from impact_env.control.estimation.model import constants_vector, ekf_constants, filter_state_space
from impact_env.effects.filters import design_filters, filter_block
from impact_env.scene import load_scene
from impact_env.sim.simulator import Simulator

T = 150  # ticks: the touch at 10, the first contact to about 50, then flight and more contacts
N_DROPS = 12
CHANNELS = ("accelerometer", "force", "potentiometer")
QUIET = {f"effects.sensors.{c}.{k}": v for c in CHANNELS for k, v in (("noise_std", 0.0), ("adc_bits", 0))}


def _demand(t):
    """An open-loop demand (N) that pulls body 2 away in the contact, then pushes: the estimator
    must follow the shaker's force through its replica."""
    return -150.0 if 12 <= t < 30 else (80.0 if 30 <= t < 45 else 0.0)


def _drops(scene, n, seed=0):
    """n drops of ``scene``: the frames' (a2, T, x2) as the policy saw them (SI), the true states."""
    sim = Simulator(scene, n)
    sim.reset([np.random.default_rng(seed + i) for i in range(n)])
    idx = [sim.layout.names.index(c) for c in CHANNELS]
    scales = sim.layout.scales[idx]
    frames, truth = np.zeros((n, T, 3)), np.zeros((n, T, 4))
    demand = np.array([_demand(t) for t in range(T)])
    for t in range(T):
        frames[:, t] = sim.obs[:, idx].astype(np.float64) * scales
        truth[:, t] = sim.plant_state[:, :4]
        sim.step(np.full(n, np.clip(demand[t] / scene.effects.command_scale, -1.0, 1.0)))
    m1 = sim.plant_parameters[:, 0].copy()
    return frames, truth, demand, m1


def _run(k, frames, demand):
    mem = np.zeros(MEMORY)
    ox, st = np.zeros((T, N_STATE)), np.zeros((T, 6 + N_STATE))
    ekf_run(k, mem, frames, demand, ox, st)
    return ox, st


@pytest.fixture(scope="module")
def rig():
    return load_scene("rig")


@pytest.fixture(scope="module")
def noisy(rig):
    return _drops(rig, N_DROPS)


def test_inverse_filter_is_the_filters_state_space(rig):
    """The (A, B, C, D) the estimator inverts run the simulator's own sections: same output."""
    sos = design_filters(rig.effects.filters, rig.control_rate)
    x = np.random.default_rng(3).standard_normal((400, 4))
    out = filter_block(sos, np.zeros((4, sos.shape[1], 2)), x, np.zeros_like(x))
    for c in range(3):
        A, B, C, D = filter_state_space(sos[c][~np.all(sos[c] == [1, 0, 0, 1, 0, 0], axis=1)])
        z = np.zeros(A.shape[0])
        y = np.empty(400)
        for t in range(400):
            y[t] = C @ z + D * x[t, c]
            z = A @ z + B * x[t, c]
        np.testing.assert_allclose(y, out[:, c], rtol=0, atol=1e-12)


def test_noise_free_drop_converges_within_its_own_covariance(rig):
    """Readings without noise or ADC, the filter as ``rig`` has it: once the contact has been
    seen for 8 ticks (tick 18 on; the touch is at tick 10, and the linearisation about a
    near-zero penetration is poorest in those ticks), every plant state's error stays within
    3 standard deviations of the filter's own covariance (the bound the filter derives for
    itself: without noise the error is the prior's and the model's, which that covariance
    holds), and by the end of the first contact body 1's position is known to 20 um and its
    speed to 3 % of the impact speed."""
    frames, truth, demand, m1 = _drops(rig.with_overrides(QUIET), 1, seed=5)
    k = constants_vector(ekf_constants(rig))
    ox, st = _run(k, frames[0], demand)
    err = ox[:, :4] - truth[0]
    sd = np.sqrt(st[:, 3:7])
    assert np.all(np.abs(err[18:]) <= 3.0 * sd[18:] + 1e-12)
    assert abs(err[50, 0]) < 20e-6
    assert abs(err[50, 1]) < 0.03 * rig.impact_speed
    assert st[-1, 1] == 0  # never lost


def test_covariance_matches_the_empirical_error(rig, noisy):
    """NEES of the plant states (x1, v1, x2, v2; each state's squared error over its own
    variance) averaged over the drops and the ticks after the touch is not above the upper
    end of the chi-square interval at 95 % for 4 x N_DROPS degrees of freedom: the filter is
    never overconfident.  It is conservative today (its Q is generous: a mean near 1.4, below
    the interval's lower end 2.6); tightening Q to bring it into the interval is open work."""
    frames, truth, demand, _m1 = noisy
    k = constants_vector(ekf_constants(rig))
    nees = np.zeros((N_DROPS, T))
    for i in range(N_DROPS):
        ox, st = _run(k, frames[i], demand)
        err = ox[:, :4] - truth[i]
        nees[i] = np.sum(err**2 / st[:, 3:7], axis=1)  # (diagonal: the states' own variances)
    lo, hi = chi2.ppf([0.025, 0.975], 4 * N_DROPS) / N_DROPS
    mean = nees[:, 20:].mean()
    assert 0.25 * lo <= mean <= hi, (mean, lo, hi)


def test_lost_track_when_the_model_is_wrong_not_on_clean_drops(rig, noisy):
    frames, _truth, demand, _m1 = noisy
    k = ekf_constants(rig)
    clean = [_run(constants_vector(k), frames[i], demand)[1][-1, 1] for i in range(N_DROPS)]
    assert sum(c > 0 for c in clean) <= 1  # (a false alarm per window has probability 1e-4)
    wrong_c = constants_vector({**k, "c": 4.0 * k["c"]})
    stuck = frames[0].copy()
    stuck[20:, 1] = stuck[20, 1]  # the transducer's reading freezes in the contact
    assert _run(wrong_c, frames[0], demand)[1][-1, 1] > 0
    assert _run(constants_vector(k), stuck, demand)[1][-1, 1] > 0


def test_deterministic(rig, noisy):
    frames, _truth, demand, _m1 = noisy
    k = constants_vector(ekf_constants(rig))
    a, b = _run(k, frames[1], demand), _run(k, frames[1], demand)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_c_text_is_bitwise_the_kernel(rig, noisy, tmp_path):
    """The filter's C text (impact_env.control.estimation.c_text), built in double with the C
    export's flags (-ffp-contract=off), gives bitwise the numba kernel's memory row (estimate,
    covariance, replicas, counters) after every tick of a drop whose transducer reads 30 N too
    much for 60 ticks (lost track: the estimate restarted) and whose potentiometer reads NaN on
    one tick (kept by the inverse filter from then on: a restart every tick), under demands that
    drive the shaker replica and the amplifier's limit."""
    import ctypes
    import subprocess

    from impact_env.control.estimation import c_text
    from impact_env.control.estimation.ekf import ekf_measure, ekf_tick
    from impact_env.control.estimation.layout import EkfMemory
    from impact_env.deploy import parity

    src = tmp_path / "ekf.c"
    src.write_text("#include <math.h>\ntypedef double impact_real;\n" + c_text.ekf_c() + r"""
void run(const double *k, double *mem, const double *frames, const double *forces, int n, int size,
         double *out)
{
    for (int t = 0; t < n; t++) {
        ekf_measure(k, mem, frames + 3 * t);
        ekf_tick(k, mem, frames + 3 * t, forces[t]);
        for (int i = 0; i < size; i++) out[t * size + i] = mem[i];
    }
}
""")
    lib = tmp_path / "libekf.so"
    subprocess.run([parity.find_cc(), *parity.CFLAGS, "-fPIC", "-shared", "-o", str(lib), str(src), "-lm"],
                   check=True)
    frames = np.ascontiguousarray(noisy[0][0].copy())
    frames[60:120, 1] += 30.0  # the transducer reads 30 N too much: lost track
    frames[T - 5, 2] = np.nan  # a potentiometer NaN: a restart every tick on (its inverse filter keeps it)
    demand = np.array([_demand(t) for t in range(T)])
    k = constants_vector(ekf_constants(rig))
    mem = np.zeros(MEMORY)
    want = np.zeros((T, MEMORY))
    for t in range(T):
        ekf_measure(k, mem, frames[t])
        ekf_tick(k, mem, frames[t], demand[t])
        want[t] = mem
    got = np.zeros((T, MEMORY))
    dbl = ctypes.POINTER(ctypes.c_double)
    ctypes.CDLL(str(lib)).run(k.ctypes.data_as(dbl), np.zeros(MEMORY).ctypes.data_as(dbl),
                              frames.ctypes.data_as(dbl), demand.ctypes.data_as(dbl), ctypes.c_int(T),
                              ctypes.c_int(MEMORY), got.ctypes.data_as(dbl))
    assert want[-1, EkfMemory.lost_count] >= want[-1, EkfMemory.resets] >= 1  # the fault was met
    assert np.all(np.isfinite(want[:60, EkfMemory.x:EkfMemory.x + N_STATE]))  # a tracked drop before it
    # bit for bit (-0.0 apart from 0.0), except a NaN's sign and payload, which IEEE 754 leaves open
    # (the faulted ticks' scratch; both builds hold NaN in the same entries)
    same = (got.view(np.uint64) == want.view(np.uint64)) | (np.isnan(got) & np.isnan(want))
    assert np.all(same), np.argwhere(~same)[:5]
