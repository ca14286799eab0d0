"""The generated C file (impact_env.deploy): built with gcc -Wall -Wextra -Werror
-ffp-contract=off, loaded with ctypes and driven tick by tick with readings recorded from the
virtual rig beside the numba target's tick (impact_env.rig.controller, onboard): the double
build bitwise equal for every classic law, the shipped agent and a SAC network (same libm as
numba's), the float32 build within the bound of docs/rig/c-export.md, the closed loop with the virtual
rig; the real-time example, the Cortex-M7 cross-build and the refusals."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from impact_env.config import ConfigError
from impact_env.control import laws
from impact_env.deploy import parity
from impact_env.deploy.c_export import generate_c, write_c
from impact_env.policy.export import export_policy
from impact_env.rig import safety
from impact_env.scene import load_scene

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parent.parent
AGENT = f"compiled:{ROOT / 'agents/models/best/best.policy.json'}"
TICKS = 2500  # 0.25 s at 10 kHz: the drop, the first contacts and the catch of most drops
C_LAWS = [law.name for law in laws.REGISTRY if law.c_body is not None]  # every law that exports to C
ACTING_C_LAWS = [name for name in C_LAWS if laws.BY_NAME[name].required()]  # ... and reads something
F32_C_LAWS = [name for name in ACTING_C_LAWS if not laws.BY_NAME[name].c_double_only]  # ... in float32 too
# float32 build (docs/rig/c-export.md, "Deploying to real-time hardware"): on ticks where both builds
# make the same discrete decisions (status bits and the contact detector), |command difference|
# <= F32_BOUND of full scale; the ticks where they decide differently (an RMS clamp or a detector
# threshold met one tick apart) at most F32_FLIP_FRACTION of all (impact_env.deploy.parity).
F32_BOUND = parity.F32_BOUND
F32_FLIP_FRACTION = parity.F32_FLIP_FRACTION


# a core install (no torch, no stable-baselines3, no onnxruntime) runs every test of the classic
# laws and the compiled agent; the cases that need an extra say so and are skipped there
def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ImportError:
        return False


NEEDS_SB3 = pytest.mark.skipif(not _installed("stable_baselines3"),
                               reason="an SB3 model needs the extra: pip install 'impact-env[sb3]'")
NEEDS_ONNX = pytest.mark.skipif(not _installed("onnxruntime"),
                                reason="ONNX needs the extra: pip install 'impact-env[onnx]'")
SAC = pytest.param("sac", marks=NEEDS_SB3)


@pytest.fixture(scope="module")
def sac_spec(tmp_path_factory):
    """An untrained SAC actor of the shape agents.train makes (tanh-squashed, ReLU); asked for
    only by the "sac" cases (:func:`_spec`)."""
    sb3 = pytest.importorskip("stable_baselines3")

    from impact_env.env.sb3_vecenv import make_sb3_vec_env

    venv = make_sb3_vec_env("rig", num_envs=1, history=2)
    model = sb3.SAC("MlpPolicy", venv, policy_kwargs={"net_arch": [16, 16]}, seed=1, device="cpu")
    path = tmp_path_factory.mktemp("sac") / "m.zip"
    model.save(path)
    return f"sac:{path}:observation=sensors,history=2,hold_ticks=1,residual=none"


def _spec(spec: str, request) -> str:
    """The spec to export: the SAC actor's (built by the fixture) for "sac"."""
    return request.getfixturevalue("sac_spec") if spec == "sac" else spec


def _build(pol, scene, tmp_path, float32=False):
    d = tmp_path / ("c32" if float32 else "c64")
    if not (d / "impact_policy.c").exists():
        write_c(pol, scene, d, force=True)
    return parity.CPolicy(parity.build_shared(d, d / "lib.so", float32), float32)


@pytest.mark.parametrize("scene_name,seed", [("rig", 0), ("rig-randomized", 7)])
@pytest.mark.parametrize("spec", [*C_LAWS, "thesis-rig:h01=3e6,h11=25", "pd-penetration:kp=3e5", AGENT, SAC])
def test_double_build_is_bitwise_the_numba_target(spec, scene_name, seed, request, tmp_path):
    scene = load_scene(scene_name)
    pol = export_policy(_spec(spec, request), scene)
    cp = _build(pol, scene, tmp_path)
    rec = parity.record(pol, scene, seed, TICKS)
    got = parity.replay(cp, rec)
    assert np.array_equal(got.command, rec.command), parity.compare_runs(rec, got)
    assert np.array_equal(got.force, rec.force)
    assert np.array_equal(got.status, rec.status)
    assert np.any(rec.command != 0.0) or spec == "passive"  # the policy did act: not a vacuous match


def _bitwise(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal bit for bit (so -0.0 != 0.0 and NaN payloads count), not only as numbers."""
    return a.shape == b.shape and np.array_equal(a.view(np.uint64), b.view(np.uint64))


def _sequences_agree(pol, scene, cp, episodes, idle) -> list[parity.Recording]:
    """The C build and the numba target over the same consecutive episodes: every command,
    force and status word of every tick bit for bit; returns the numba target's runs."""
    want = parity.numba_sequence(pol, scene, episodes, idle)
    got = parity.c_sequence(cp, episodes, idle)
    for k, (w, g) in enumerate(zip(want, got, strict=True)):
        assert _bitwise(g.command, w.command), (k, parity.compare_runs(w, g))
        assert _bitwise(g.force, w.force), k
        assert np.array_equal(g.status, w.status), (k, parity.compare_runs(w, g))
    return want


def _hot(readings: np.ndarray, start: int = 200) -> np.ndarray:
    """Readings of repeated hard contacts: a contact force of up to 300 N for 80 of every 100
    ticks from ``start``, rising and falling over 10 ticks, added as the plant's equations have
    it (body 2, 1 kg, accelerates by Phi / m2, the transducer under the 0.1 kg top part carries
    0.9 Phi: the plausibility check's cross-channel checks see a consistent contact; 30 N and
    30 m/s^2 a tick are inside its jump bounds, 300 m/s^2 inside the converter's 500).  The sensor-fed laws answer each with a saturated command, so the applied
    force's RMS reaches the continuous rating within a fraction of the window and the RMS clamp
    cuts from then on (a physical rig would never see this; the safety layer must still act the
    same in both builds)."""
    r = readings.copy()
    p = np.arange(start, len(r)) % 100
    phi = 300.0 * np.clip(np.minimum(p, 80 - p) / 10.0, 0.0, 1.0)
    r[start:, 0] += phi / 1.0
    r[start:, 1] += 0.9 * phi
    return r


# seeds per scene of the long runs (drops the virtual rig plays back to back, as a target does)
LONG_SEEDS = {"rig": (0, 4, 9), "rig-randomized": (3, 7, 11)}
LONG_TICKS = 4000  # per recorded episode: 3 x 4000 + the hot one's 3000 > the 10 000-tick window


@pytest.mark.parametrize("scene_name", sorted(LONG_SEEDS))
@pytest.mark.parametrize("spec", ["pd-penetration", AGENT])
def test_consecutive_episodes_wrap_the_rms_window_bitwise(spec, scene_name, tmp_path):
    """Several episodes of one power-on, idle time between them (``impact_idle`` against
    ``Controller.drain``, ``impact_reset`` against ``Controller.start``), more ticks than the RMS
    window holds so its ring wraps; the last episode is a hot one whose RMS clamp depends on every
    square the ring kept from the recorded drops before it (each tick's clamp level is the
    budget minus the other n - 1 squares)."""
    scene = load_scene(scene_name)
    pol = export_policy(spec, scene)
    cp = _build(pol, scene, tmp_path)
    recs = [parity.record(pol, scene, s, LONG_TICKS).readings for s in LONG_SEEDS[scene_name]]
    # the hot one on a drop nobody acted on: a recorded drive's changes would be in its readings
    # but not in the replayed law's demands, which the plausibility check's armature check compares
    passive = parity.record(export_policy("passive", scene), scene, LONG_SEEDS[scene_name][0], 3000).readings
    episodes = [*recs, _hot(passive, start=100)]
    idle = [1500, 700, 300][:len(episodes) - 1]  # shorter than the window: the heat carries over
    window = int(round(safety.SafetyConfig().rms_window_s * scene.control_rate))
    assert sum(len(e) for e in episodes) > window  # the ring wraps on the episodes' own ticks
    want = _sequences_agree(pol, scene, cp, episodes, idle)
    assert all(np.any(w.command != 0.0) for w in want[:-1])  # the policy did act in every drop
    # the wrapped ring's sum decided the last episode's force
    assert np.any(want[-1].status & safety.CLAMP_RMS)


# the drive command's scale of the safety-branch test: a law's command is clipped to [-1, 1], so at the
# preset's 200 N (= the peak rating) the peak clamp cannot cut; an amplifier giving 300 N per unit can
HOT_SCALE_N = 300.0


# policies that demand the peak on hard contacts (a law's gains decide that, so not every law:
# this list is chosen, not derived)
@pytest.mark.parametrize("spec", ["pd-penetration", "thesis-rig", AGENT, SAC])
def test_safety_branches_bitwise(spec, request, tmp_path):
    """Synthetic readings that drive every branch of the safety layer, as consecutive episodes of
    one power-on: hard contacts at a 300 N command scale (CLAMP_PEAK on every saturated tick, then
    CLAMP_RMS; twice, with less idle time than the window between, so the second starts hot and
    the ring wraps while it clamps), a NaN accelerometer reading (the plausibility check holds the
    last good one: SENSOR_FAULT and SENSOR_ACCELEROMETER for that tick, 0 N, the network never
    sees the NaN), a NaN potentiometer reading (the same, its own bit), |x2| beyond the 7 mm
    travel limit for three ticks (TRAVEL, latched), an infinite force reading, and a potentiometer
    NaN for 30 ticks (beyond the 10-tick fault limit: SENSOR_TIMEOUT latched); the C double build
    against the numba target, bit for bit."""
    scene = load_scene("rig", {"effects.command_scale": HOT_SCALE_N})
    pol = export_policy(_spec(spec, request), scene)
    cp = _build(pol, scene, tmp_path)
    base = parity.record(export_policy("passive", scene), scene, 0, 6000).readings  # a drop nobody acts on
    limit = safety.SafetyConfig().travel_limit_m
    nan_acc, nan_pot, beyond, inf_force, long_fault = (base[:2000].copy() for _ in range(5))
    nan_acc[500, 0] = np.nan
    nan_pot[300, 2] = np.nan
    # a physical excursion (0.2 mm a tick, inside the plausibility check's 0.35 mm): a jump to it
    # would be an implausible reading instead
    beyond[360:400, 2] = np.linspace(beyond[360, 2], 1.15 * limit, 40)
    beyond[400:403, 2] = 1.15 * limit
    inf_force[600, 1] = np.inf
    long_fault[700:730, 2] = np.nan
    episodes = [_hot(base), _hot(base), nan_acc, nan_pot, beyond, inf_force, long_fault]
    idle = [3000, 100, 100, 100, 100, 100]
    want = _sequences_agree(pol, scene, cp, episodes, idle)
    bits = [int(np.bitwise_or.reduce(w.status)) for w in want]
    for k, (tick, chan) in {2: (500, safety.SENSOR_ACCELEROMETER), 3: (300, safety.SENSOR_POTENTIOMETER),
                            5: (600, safety.SENSOR_FORCE)}.items():
        st = want[k].status
        assert st[tick] & safety.SENSOR_FAULT and st[tick] & chan and want[k].force[tick] == 0.0, k
        assert np.count_nonzero(st & safety.SENSOR_FAULT) == 1, k  # that tick alone: not latched
        assert not bits[k] & (safety.NONFINITE | safety.SENSOR_TIMEOUT), k  # the bad sample reached no policy
    trip = int(np.argmax(want[4].status & safety.TRAVEL))
    assert bits[4] & safety.TRAVEL and 360 < trip < 400 and np.all(want[4].status[trip:] & safety.TRAVEL)
    # the excursion was plausible (its end is not)
    assert not np.any(want[4].status[:403] & safety.SENSOR_FAULT)
    assert np.all(want[4].force[trip:] == 0.0)
    lf = want[6].status
    n_lim = int(PA_limit(scene))
    assert not np.any(lf[: 700 + n_lim] & safety.SENSOR_TIMEOUT) and np.all(
        lf[700 + n_lim :] & safety.SENSOR_TIMEOUT
    )
    assert np.all(want[6].force[700:] == 0.0)
    if pol.law is not None:
        rms = [np.flatnonzero(w.status & safety.CLAMP_RMS) for w in want[:2]]
        assert bits[0] & safety.CLAMP_PEAK and rms[0].size and rms[1].size
        assert rms[1][0] < rms[0][0]  # the second hot episode started with the first one's heat


def PA_limit(scene) -> float:
    """The faulty ticks in a row the scene allows (effects.sensors.fault_limit_s in ticks)."""
    from impact_env.control.plausibility import plausibility_params

    return plausibility_params(scene).limit_ticks


@pytest.mark.parametrize("spec", [*F32_C_LAWS, AGENT])
def test_float32_build_within_its_bound(spec, tmp_path):
    scene = load_scene("rig-randomized")
    pol = export_policy(spec, scene)
    cp = _build(pol, scene, tmp_path, float32=True)
    for seed in (0, 5):
        rec = parity.record(pol, scene, seed, TICKS)
        got = parity.replay(cp, rec)
        flip = parity.decisions_differ(rec, got, pol.hold_ticks)
        du = np.abs(got.command - rec.command)
        assert du[~flip].max() <= F32_BOUND, (seed, du[~flip].max())
        assert np.count_nonzero(flip) <= F32_FLIP_FRACTION * TICKS
        rep = parity.compare_runs(rec, got, pol.hold_ticks)
        assert rep.verdict(True)[0] and rep.flipped == np.count_nonzero(flip)  # what --check prints
        assert np.any(du > 0.0) or spec == "thesis-rig"  # float32 is really in use (thesis-rig: saturated)



@pytest.mark.parametrize("without", ["filters", "detector"])
def test_a_scene_without_a_front_end_effect(without, tmp_path):
    """A scene without the filters (or the detector) exports and builds (no table left unused
    under -Werror), the double build bitwise the numba target, the float32 build within its bound."""
    base = load_scene("rig")
    scene = load_scene("rig", {"effects.active": [e for e in base.effects.active if e != without]})
    pol = export_policy("pd-penetration", scene)
    rec = parity.record(pol, scene, 0, 1500)
    for f32 in (False, True):
        got = parity.replay(_build(pol, scene, tmp_path, float32=f32), rec)
        du = np.abs(got.command - rec.command)
        assert (du.max() == 0.0) if not f32 else (du.max() <= F32_BOUND), (f32, du.max())

MPC_SPEC = "mpc:horizon=8"  # a short horizon: the same code as the default 40, cheaper to record


def test_mpc_check_passes_in_double_and_has_no_float32_build(tmp_path, capsys):
    """``impact-env export mpc --scene rig --c DIR --check``: the sensor-fed MPC law (its
    extended Kalman filter and its iLQR solver as the file's static functions) replays bitwise in
    the double build; the float32 build is refused, with its reason, by the check, by the header
    (#error) and by parity.check (its command jumps by full scale where its plan switches, so no
    per-tick bound of docs/rig/c-export.md can hold)."""
    from impact_env.cli.main import main

    out = tmp_path / "mpc"
    assert main(["export", MPC_SPEC, "--scene", "rig", "--c", str(out), "--check"]) == 0
    text = capsys.readouterr().out
    assert text.count("PASS: 0 of 2000 commands and 0 status words differ (bound: 0, bitwise)") == 2
    assert "check float32 build: none (mpc has no float32 build" in text and "PASS: the double build" in text
    src = (out / "impact_policy.c").read_text()
    assert "static impact_real mpc_tick(" in src and "static void ekf_measure(" in src
    with pytest.raises(ConfigError, match="#error.*mpc has no float32 build"):
        parity.build_shared(out, tmp_path / "f32.so", float32=True)
    scene = load_scene("rig")
    with pytest.raises(ConfigError, match="mpc has no float32 build"):
        parity.check(export_policy(MPC_SPEC, scene), scene, out, seeds=(0,), ticks=10, float32=True)


@pytest.mark.parametrize("seed", [3, 8])
@pytest.mark.parametrize("spec", ["pd-penetration", AGENT])
def test_closed_loop_with_the_virtual_rig(spec, seed, tmp_path):
    """The C step in place of the numba tick, the virtual rig's hardware stage as the plant, over
    the scene's whole horizon.  The double build gives the very same episode (readings,
    commands) as the numba target.  The float32 build gives compare's metrics (energy integral,
    time to catch, peak force) within the bound its command error implies
    (:func:`impact_env.deploy.parity.closed_loop_check`: float32 changes each tick's command by
    at most F32_BOUND of full scale where the builds decide alike, test_float32_build_within_its_bound,
    and the bound is how far the metrics move when the double loop's commands carry random errors
    of that size)."""
    scene = load_scene("rig")
    ticks = int(round(scene.episode.horizon * scene.control_rate))
    pol = export_policy(spec, scene)
    rec = parity.record(pol, scene, seed, ticks)
    c64 = _build(pol, scene, tmp_path)
    d64 = parity.closed_loop(c64, scene, seed, ticks)
    assert np.array_equal(d64.readings, rec.readings) and np.array_equal(d64.command, rec.command)
    c32 = _build(pol, scene, tmp_path, float32=True)
    d32 = parity.closed_loop(c32, scene, seed, ticks)
    assert np.any(d32.command != d64.command)  # float32 is in use: not a vacuous comparison
    checked = parity.closed_loop_check(c64, c32, scene, seed, ticks)
    for k, metric in checked.items():
        assert metric.within, (k, metric)
    m64 = {k: metric.double for k, metric in checked.items()}
    assert np.isfinite(m64["energy_integral_ms"]) and m64["peak_force_N"] > 0.0  # a real episode


def test_realtime_example_runs_and_replays_bitwise(tmp_path):
    scene = load_scene("rig")
    pol = export_policy("pd-penetration", scene)
    d = tmp_path / "c"
    write_c(pol, scene, d)
    exe = parity.build_rt_example(d, tmp_path / "impact_rt")
    rec = parity.record(pol, scene, 2, 2000)
    rec.readings.astype("<f8").tofile(tmp_path / "r.f64")
    out = subprocess.run([str(exe), str(tmp_path / "r.f64"), str(tmp_path / "c.f64"), "--no-sleep"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert np.array_equal(np.fromfile(tmp_path / "c.f64"), rec.command)
    paced = subprocess.run([str(exe), str(tmp_path / "r.f64"), str(tmp_path / "c.f64")],
                           capture_output=True, text=True, timeout=60)  # 0.2 s of real time
    assert paced.returncode == 0 and "lateness us p50" in paced.stdout and "overruns" in paced.stdout
    cmd = np.fromfile(tmp_path / "c.f64")
    skipped = int(paced.stdout.split(" skipped")[0].split()[-1])
    assert np.count_nonzero(np.isnan(cmd)) == skipped  # every skipped tick is accounted for
    first = int(np.argmax(np.isnan(cmd))) if skipped else cmd.size
    assert np.array_equal(cmd[:first], rec.command[:first])  # until an overrun, the replayed episode


@pytest.mark.skipif(shutil.which("arm-none-eabi-gcc") is None,
                    reason="Debian's gcc-arm-none-eabi is not installed (.ci/run installs it)")
@pytest.mark.parametrize("float32", [False, True])
def test_cortex_m7_cross_build(float32, tmp_path):
    scene = load_scene("rig")
    pol = export_policy(AGENT, scene)
    write_c(pol, scene, tmp_path / "c")
    size = parity.build_arm(tmp_path / "c", tmp_path / "p.o", float32)
    n_weights = sum(np.asarray(ly["weight"]).size + len(ly["bias"]) for ly in pol.mlp["layers"])
    assert size["text"] >= n_weights * (4 if float32 else 8)  # the weights are in flash, as constants
    assert size["data"] == 0 and size["bss"] == 0  # no globals: all state is the caller's


@pytest.mark.skipif(shutil.which("arm-none-eabi-gcc") is None,
                    reason="Debian's gcc-arm-none-eabi is not installed (.ci/run installs it)")
def test_cortex_m7_cross_build_of_mpc(tmp_path):
    """mpc (filter and solver included) cross-builds for a Cortex-M7 in double, with no globals;
    its float32 build stops at the header's #error."""
    scene = load_scene("rig")
    write_c(export_policy("mpc", scene), scene, tmp_path / "c")
    size = parity.build_arm(tmp_path / "c", tmp_path / "p.o")
    assert size["data"] == 0 and size["bss"] == 0
    with pytest.raises(ConfigError, match="mpc has no float32 build"):
        parity.build_arm(tmp_path / "c", tmp_path / "p32.o", float32=True)


def _libm_bound(pol) -> float:
    """The largest |command difference| two libms can cause whose ``tanh`` are each within 2 ulp
    (glibc's documented bound on x86_64 and on armhf, its libm-test-ulps): at |y| < 1 two such
    results differ by at most 4 ulp = 4 * 2^-53; a layer passes its inputs' differences on
    through |W| (tanh is 1-Lipschitz) and adds its own; the squash scales by (high - low) / 2;
    the residual law (no libm difference: pow agrees bitwise, measured) and the final clip do not
    grow it.  Doubled for the sums' roundings, which move with their inputs."""
    delta = 4 * 2.0**-53
    m = pol.mlp
    d = np.zeros(pol.layout.size)
    for ly in m["layers"]:
        d = np.abs(np.asarray(ly["weight"], dtype=np.float64)) @ d
        if ly.get("activation", "identity") in ("tanh", "elu"):
            d = d + delta
    out = float(d[0])
    if m["output"] == "squash":
        out = 0.5 * (float(m["high"]) - float(m["low"])) * (out + delta)
    return 2.0 * out


@pytest.mark.skipif(shutil.which("qemu-arm") is None or shutil.which(parity.ARM_LINUX_CC) is None,
                    reason="Debian's qemu-user and gcc-arm-linux-gnueabihf are not installed "
                           "(.ci/run installs them)")
@pytest.mark.parametrize("spec", [*ACTING_C_LAWS, AGENT])
def test_parity_of_an_arm_linux_build_under_qemu_arm(spec, tmp_path):
    """The real-time example cross-built for 32-bit ARM Linux (arm-linux-gnueabihf-gcc -static,
    the same CFLAGS) and run by qemu-arm in user mode, --no-sleep, on readings recorded from the
    virtual rig: another instruction set, another glibc build.  The double build is bitwise the
    numba target's for the classic laws (IEEE arithmetic, no fused multiply-adds, and ARM's pow
    gives the same bits); for the network within :func:`_libm_bound` (ARM's tanh may differ in
    the last place: the shipped student's commands differ on 188 of 3000 ticks, by at most 5.6e-17,
    the bound 6e-14); the float32
    build bitwise the x86-64 float32 build's."""
    scene = load_scene("rig")
    pol = export_policy(spec, scene)
    d = tmp_path / "c"
    write_c(pol, scene, d)
    rec = parity.record(pol, scene, 2, 3000)
    rec.readings.astype("<f8").tofile(tmp_path / "r.f64")
    got = {}
    builds = (False, True) if spec in F32_C_LAWS or spec == AGENT else (False,)  # mpc: double only
    for f32 in builds:
        arm = parity.build_rt_example(d, tmp_path / f"arm{int(f32)}", f32, cc=parity.ARM_LINUX_CC, extra=("-static",))
        file = tmp_path / f"arm{int(f32)}.f64"
        r = subprocess.run(["qemu-arm", str(arm), str(tmp_path / "r.f64"), str(file), "--no-sleep"],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        got[f32] = np.fromfile(file)
    if pol.mlp is None:
        assert _bitwise(got[False], rec.command)
    else:
        # the size of the difference is bounded; how many policy steps differ is how often the two
        # libms' tanh disagree in the last place on this network's inputs (the first PPO agent: 2 of
        # 750 steps; the distilled student: 47 of 750, each at most 8 ulp of its command)
        assert np.abs(got[False] - rec.command).max() <= _libm_bound(pol)
    if True not in got:
        return
    x86 = parity.build_rt_example(d, tmp_path / "x86_f32", True)
    r = subprocess.run([str(x86), str(tmp_path / "r.f64"), str(tmp_path / "x86.f64"), "--no-sleep"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert _bitwise(got[True], np.fromfile(tmp_path / "x86.f64"))
    assert np.any(got[True] != rec.command) or spec == "thesis-rig"  # float32 in use (thesis-rig: saturated)


def test_generated_code_reads_like_code_and_carries_its_sources():
    scene = load_scene("rig")
    pol = export_policy("pd-penetration:kp=3e5", scene)
    art = generate_c(pol, scene, spec="pd-penetration:kp=3e5")
    assert art.scene_sha256 in art.source and art.policy_sha256 in art.header
    assert "eq 4.4" in art.source and "MAIN_KP = 300000.0" in art.source
    for forbidden in ("malloc", "printf", "static impact_state", "stdio.h"):
        assert forbidden not in art.source
    # the numbers are the kernels' own arrays: every SOS coefficient appears with repr's digits
    from impact_env.control.front_end import FrontEnd

    for x in FrontEnd(scene, pol.layout, 1).sos.ravel():
        assert repr(float(x)) in art.source or f"{float(x)!r}.0" in art.source or x in (0.0, 1.0)


def test_refusals(tmp_path, capsys):
    from impact_env.cli.main import main

    scene = load_scene("rig")
    with pytest.raises(ConfigError, match="privileged"):
        generate_c(export_policy("thesis-ideal", scene), scene)
    with pytest.raises(ConfigError, match="'mpc-state' reads a privileged observation"):
        generate_c(export_policy("mpc-state", scene), scene)
    (tmp_path / "exists").mkdir()
    assert main(["export", "pd-penetration", "--scene", "rig", "--c", str(tmp_path / "exists")]) == 2
    assert "--force" in capsys.readouterr().err
    assert main(["export", "no-such-law", "--scene", "rig", "--c", str(tmp_path / "new")]) == 2
    assert not (tmp_path / "new").exists()
    assert main(["export", "pd-penetration", "--scene", "rig", "--c", str(tmp_path / "ok"), "--check"]) == 0
    out = capsys.readouterr().out
    assert out.count("double  build") == 2 and out.count("float32 build") == 2  # a verdict per build
    assert "PASS: 0 of 2000 commands and 0 status words differ (bound: 0, bitwise)" in out
    assert "FAIL" not in out and "PASS: both builds" in out


@NEEDS_ONNX
def test_onnx_carries_its_meaning(tmp_path):
    import json

    import onnxruntime as ort

    from impact_env.policy.export import write_onnx

    scene = load_scene("rig")
    pol = export_policy(AGENT, scene)
    path = write_onnx(pol, tmp_path / "p.onnx")
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    meta = sess.get_modelmeta().custom_metadata_map
    names = json.loads(meta["impact_env.observation_names"])
    assert len(names) == pol.layout.size and names[0] == pol.layout.names[0]
    assert json.loads(meta["impact_env.frame_scales"]) == [float(x) for x in pol.layout.scales]
    assert int(meta["impact_env.hold_ticks"]) == pol.hold_ticks
    assert int(meta["impact_env.history"]) == pol.history
    assert float(meta["impact_env.command_scale_n"]) == pol.command_scale
    assert json.loads(meta["impact_env.residual_law"])["name"] == pol.residual_policy().law["name"]
    assert meta["impact_env.policy_sha256"] == pol.sha256()


@NEEDS_SB3
def test_export_c_of_a_ppo_zip(tmp_path, capsys):
    """``impact-env export ppo:agents/models/best/model.zip --scene rig --c DIR --check``: the SB3
    zip itself (its model.json beside it gives observation, hold and residual) becomes the C
    file; the double build replays bitwise, and its network is the shipped compiled policy's, the
    same numbers printed the same way (that file was made from this zip)."""
    import re

    from impact_env.cli.main import main

    spec = f"ppo:{ROOT / 'agents/models/best/model.zip'}"
    out = tmp_path / "ppo"
    assert main(["export", spec, "--scene", "rig", "--c", str(out), "--check"]) == 0
    text = capsys.readouterr().out
    assert text.count("PASS: 0 of 2000 commands") == 2  # both drops of the double build, bitwise
    src = (out / "impact_policy.c").read_text()
    assert "MLP 64 x 64 x 1" in src and "residual law pd-penetration" in src and spec in src

    def network(c: str) -> list[str]:
        return re.findall(r"static const impact_real [WB]\d+\[[^;]*;", c, flags=re.S)

    shipped = generate_c(export_policy(AGENT, load_scene("rig")), load_scene("rig")).source
    assert network(src) and network(src) == network(shipped)


def test_the_check_counts_flipped_decisions_apart_from_its_bound():
    """What ``export --c --check`` judges: a tick whose contact-detector bit differs (a law's force
    gated a tick apart: 0.102 of full scale, as seen for pd-penetration's float32 build) counts as
    a flipped decision, not against the 1e-4 bound, and so do the held ticks of a policy step whose
    first tick flipped; the same difference on a tick with the same decisions is a FAIL; the
    double build passes only bitwise."""
    n = 100
    a = parity.Recording(np.zeros((n, 4)), np.zeros(n), np.zeros(n), np.zeros(n, np.int64),
                         detected=np.zeros(n, np.int64))
    b = parity.Recording(a.readings, a.command.copy(), a.force.copy(), a.status.copy(),
                         detected=a.detected.copy())
    b.command[40:44] = 0.102
    b.detected[40] = 1
    rep = parity.compare_runs(a, b, hold=4)
    assert rep.flipped == 4 and rep.max_abs_same == 0.0 and rep.max_abs == 0.102
    assert rep.verdict(True)[0] and not rep.verdict(False)[0]
    assert "PASS" in rep.verdict(True)[1] and "4 ticks (4.00 %) decide differently" in rep.verdict(True)[1]
    rep1 = parity.compare_runs(a, b, hold=1)  # without the hold, ticks 41-43 decided alike: over the bound
    assert rep1.flipped == 1 and not rep1.verdict(True)[0] and "FAIL" in rep1.verdict(True)[1]
    b.command[40:44] = 0.0
    b.command[60] = 0.5 * F32_BOUND
    assert parity.compare_runs(a, b).verdict(True)[0] and not parity.compare_runs(a, b).verdict(False)[0]
