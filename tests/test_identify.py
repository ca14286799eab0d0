"""Identification (impact_env.ident, impact-env identify / rig identify): the target's episode
kinds and excitations, the fit's model against the hardware stage (bitwise), the recovery of
rigs nobody tuned for, and the refusals of logs that cannot serve.

Tolerance of the recovery.  On a virtual rig the model is the rig's own hardware stage, so a
fitted value misses the truth only by what the sensors' noise leaves undetermined: for white
Gaussian noise the least-squares estimate is unbiased to first order with the covariance
``s^2 (J^T J)^-1`` the fit reports (``s^2``, the reduced chi-square, near 1 when the model
explains the logs down to the noise), so each identified value lies within Z = 5 of its
standard uncertainties of the truth, but for a chance of 6e-7 per value.  The uncertainties
themselves scale as the noise over the square root of the samples (the plan's episodes and their
length): the test also checks that the plan identifies each parameter it is meant to, to better
than 2 % (so the 5-sigma check is not vacuous), and that the reduced chi-square is near 1."""

from __future__ import annotations

import json
import math
import threading

import numpy as np
import pytest

from impact_env.config import ConfigError
from impact_env.hardware.batch import Hardware
from impact_env.hardware.replay import replay
from impact_env.ident import report
from impact_env.ident.experiments import ExperimentError, load
from impact_env.ident.fit import identify
from impact_env.ident.model import FIELDS, shift, shift_readings
from impact_env.ident.plan import PlanEpisode, default_plan, run_plan
from impact_env.ident.virtual import perturbed_physics
from impact_env.rig import protocol
from impact_env.rig.driver import VirtualRig
from impact_env.rig.excitation import Excitation
from impact_env.rig.host import RigClient
from impact_env.rig.log import read_episode, write_episode
from impact_env.rig.target import Target, TargetConfig
from impact_env.scene import load_scene

Z = 5.0


def _serve(physics=None, scene="rig", log_dir=None):
    target = Target(VirtualRig(scene, physics), config=TargetConfig(lockstep=True, log_dir=log_dir))
    th = threading.Thread(target=target.serve, daemon=True)
    th.start()
    return target, th


def _stop(target, th):
    target.stop()
    th.join(10)


# -- excitations ---------------------------------------------------------------------------------------
def test_excitations_are_what_they_say():
    rate, n = 1e4, 10_000
    sw = Excitation("sweep", 40.0, 50.0, 2000.0, 0.01).samples(rate, n)
    assert sw[0] == 0.0 and sw[-1] == 0.0 and np.max(np.abs(sw)) <= 40.0 + 1e-12
    crossings = lambda x: np.count_nonzero(np.diff(np.signbit(x)))  # noqa: E731
    # a log sweep: the instantaneous frequency grows geometrically: first and last tenth
    f_first = crossings(sw[1000:2000]) / 2 / 0.1
    f_last = crossings(sw[8000:9000]) / 2 / 0.1
    assert 50 < f_first < 120 and 900 < f_last < 2000
    ms = Excitation("multisine", 30.0, 100.0, 1000.0, 0.0).samples(rate, n)
    assert np.max(np.abs(ms)) == pytest.approx(30.0)
    spec = np.abs(np.fft.rfft(ms)) ** 2
    f = np.fft.rfftfreq(n, 1 / rate)
    assert spec[(f >= 100) & (f <= 1000)].sum() > (1 - 1e-9) * spec.sum()  # every line in the band
    pr = Excitation("prbs", 20.0, 1.0, 1000.0, seed=3).samples(rate, 3 * 32767)
    assert set(np.unique(pr)) == {-20.0, 20.0}
    bits = pr[::3][:32767]  # one period of the 15-bit sequence: 2^14 ones, 2^14 - 1 minus ones
    assert np.count_nonzero(bits > 0) == 16384
    assert np.array_equal(
        Excitation.from_json(Excitation("sweep", 4.0, 5.0, 200.0).to_json()).samples(rate, 99),
        Excitation("sweep", 4.0, 5.0, 200.0).samples(rate, 99))


@pytest.mark.parametrize("make, match", [
    (lambda: Excitation("sweep", 250.0).commands(1e4, 100, 200.0), "command_scale"),
    (lambda: Excitation("sweep", 150.0).commands(1e4, 100, 200.0, 100.0), "peak_n"),
    (lambda: Excitation("prbs", 90.0, 1.0, 100.0).commands(1e4, 1000, 200.0, 200.0, 98.0), "continuous"),
    (lambda: Excitation("sweep", 10.0, 10.0, 6000.0).samples(1e4, 100), "Nyquist"),
    (lambda: Excitation("sweep", 10.0, 500.0, 400.0), "f_lo_Hz"),
    (lambda: Excitation("chirp", 10.0), "excitation.signal"),
    (lambda: Excitation("sweep", 0.0), "amplitude_N"),
    (lambda: Excitation.from_json('{"format": "impact-env-excitation", "version": 1, "gain": 2}'), "gain"),
])
def test_bad_excitations_are_refused_naming_the_field(make, match):
    with pytest.raises(ConfigError, match=match):
        make()


# -- the model against the hardware stage ---------------------------------------------------------------
def test_replay_with_shifted_delays_is_the_delay_effects_bitwise():
    """The fit's model drops the delay effects and shifts commands and readings by whole ticks:
    exactly what the delay lines do (zeros until they fill, the release's readings undelayed)."""
    quiet = {f"effects.sensors.{c}.noise_std": 0.0 for c in ("accelerometer", "force", "potentiometer")}
    base = load_scene("rig").with_overrides({**quiet, "randomize.m1": [], "randomize.drop_height": []})
    delayed = base.with_overrides({"effects.active": list(base.effects.active)
                                                     + ["actuator_delay", "sensor_delay"],
                                   "effects.delay.actuator_s": 2e-4, "effects.delay.sensor_s": 3e-4})
    u = Excitation("multisine", 30.0, 50.0, 3000.0).commands(1e4, 800, 200.0)
    for held in (True, False):
        ref, _ = replay(Hardware(delayed, 1), u, held=held)
        got, _ = replay(Hardware(base, 1), shift(u, 2), held=held)
        assert np.array_equal(ref, shift_readings(got, 3))


def test_the_fits_damping_table_delivers_each_restitution_over_its_range():
    """The model's pad damping comes from a table over the fit's restitutions (base / 4 to 1): the
    collision with the table's damping delivers the restitution asked for to within 1e-11, the
    size of the polynomial's error in e(zeta) over solves of rtol 1e-12, and the damping is the
    exact solve's to 1e-10 relative where it is not tiny (near e = 1 the error in zeta is absolute)."""
    from impact_env.ident.model import BOUND, Model
    from impact_env.plant.restitution import restitution_of_zeta, zeta_for_restitution

    model = Model(load_scene("rig"))
    e0 = model.base.plant.restitution
    for e in [*np.linspace(e0 * math.exp(-BOUND), 0.999, 7), 0.9999]:
        zeta = model.zeta(float(e))
        assert abs(restitution_of_zeta(zeta) - e) <= 1e-11, e
        if e <= 0.9:
            exact = zeta_for_restitution(float(e))
            assert abs(zeta - exact) <= 1e-10 * exact, e
    assert model.zeta(1.0) == 0.0


# -- the target's identification episodes --------------------------------------------------------------
def test_the_targets_identification_episodes(tmp_path):
    target, th = _serve(log_dir=tmp_path)
    client = RigClient(target.address)
    try:
        ex = Excitation("sweep", 20.0, 20.0, 2000.0)
        client.arm("onboard", 4, 2000, kind=protocol.EpisodeKind.SHAKER, excitation=ex)
        log = client.fetch_log(client.wait_end(30).episode)
        assert log.meta.kind == "shaker" and json.loads(log.meta.excitation)["signal"] == "sweep"
        # the commands played are the excitation's, tick by tick; body 1 never moved
        assert np.array_equal(log["command"][:-1], ex.commands(1e4, 2000, 200.0))
        # (the last row: no tick)
        assert np.ptp(log["true_x1_m"][:-1]) == 0.0 and np.max(np.abs(log["true_x2_m"])) > 1e-5
        client.arm("onboard", 5, 1000, kind=protocol.EpisodeKind.QUIET)
        log = client.fetch_log(client.wait_end(30).episode)
        assert (log.meta.kind == "quiet" and np.all(log["command"] == 0.0)
                and np.ptp(log["true_x2_m"][:-1]) == 0.0)
        # refused, naming why: a shaker episode in host mode, a quiet one with a signal, a peak over the limit
        for kw, match in ((dict(mode="host", kind=protocol.EpisodeKind.SHAKER, excitation=ex), "onboard"),
                          (dict(kind=protocol.EpisodeKind.QUIET, excitation=ex), "quiet"),
                          (dict(kind=protocol.EpisodeKind.SHAKER, horizon=20000,
                                excitation=Excitation("sweep", 199.0, 10.0, 100.0)), "amplitude_N")):
            mode = kw.pop("mode", "onboard")
            horizon = kw.pop("horizon", 500)
            with pytest.raises(Exception, match=match):
                client.arm(mode, 1, horizon, **kw)
    finally:
        client.close()
        _stop(target, th)


# -- recovery ---------------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("seed, delays", [(11, (0, 0)), (12, (1, 1))], ids=["no-delay", "delays"])
def test_identification_recovers_a_rig_nobody_tuned_for(tmp_path, seed, delays):
    """A virtual rig whose hardware is ``rig``'s moved by up to +-40 % (and, in one, a tick of
    delay on each side), described to the target as ``rig``: the quick plan on loopback, then
    ``impact-env identify``; every identified field within Z standard uncertainties of the truth."""
    physics, truth = perturbed_physics("rig", seed, 0.4, *delays)
    target, th = _serve(physics)
    try:
        from impact_env.cli.main import main

        assert main(["rig", "identify", "--rig", target.address, "--out", str(tmp_path), "--quick"]) == 0
    finally:
        _stop(target, th)
    data = json.loads((tmp_path / "identification.json").read_text())
    assert 0.8 < data["chi2_red"] < 1.2  # the model explains the logs down to the sensors' noise
    assert data["delays_ticks"] == {"actuator": delays[0], "sensor": delays[1]}
    rows = {r["field"]: r for r in data["fields"]}
    checked = []
    for f in FIELDS:
        r = rows[f]
        if r["status"] != "identified":
            continue
        z = math.log(r["value"] / truth[f]) / r["rel_sigma"]
        assert abs(z) <= Z, f"{f}: identified {r['value']:.6g}, true {truth[f]:.6g}, {z:+.1f} sigma"
        checked.append(f)
    # the plan identifies what it is meant to, well (the 5-sigma check is not vacuous)
    for f in ("plant.m1", "plant.m2", "plant.c", "plant.restitution", "plant.suspension_stiffness",
              "plant.suspension_damping", "effects.command_scale", "effects.sensors.force.top_mass",
              "effects.shaker.highpass_hz"):
        assert f in checked and rows[f]["rel_sigma"] < 0.02, (f, rows[f])
    for ch, est in data["sensors"].items():
        off = truth[f"effects.sensors.{ch}.offset"]
        assert abs(est["offset"] - off) <= Z * est["offset_se"]
        assert abs(est["noise_std"] - truth[f"effects.sensors.{ch}.noise_std"]) <= Z * est["noise_se"]
    # the scene file loads, and its hardware is the identified one
    sc = load_scene(tmp_path / "identified.toml")
    assert sc.randomize.c == (rows["plant.c"]["value"],) * 2 and sc.plant.c == 2e6  # controller keeps rig's
    assert sc.plant.restitution == rows["plant.restitution"]["value"]
    drawn = sc.with_draws(sc.randomize.values_at(0.5, sc.control_rate))
    assert drawn.plant.m2 == pytest.approx(rows["plant.m2"]["value"], rel=1e-15)
    assert drawn.effects.command_scale == pytest.approx(rows["effects.command_scale"]["value"], rel=1e-12)
    # the one-point ranges are marked known: the model-based laws plan on them, nothing else changes
    assert set(sc.control.known_hardware) == {"c", "m2", "top_mass", "command_gain"}
    from impact_env.scene.randomize import known_hardware
    assert known_hardware(sc).plant.c == rows["plant.c"]["value"]
    assert ((tmp_path / "report.md").read_text().count("|") > 50
            and (tmp_path / "fit_shaker.png").stat().st_size)


# -- refusals ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def short_logs(tmp_path_factory):
    """A tiny plan's logs (quiet, shaker, two identification drops), a plain drop, and a quiet
    episode of a rig whose accelerometer has another range."""
    d = tmp_path_factory.mktemp("ident-logs")
    plan = [PlanEpisode("quiet", 0.02, ""),
            PlanEpisode("shaker", 0.02, "", Excitation("sweep", 10.0, 100.0, 1000.0)),
            PlanEpisode("ident_drop", 0.02, ""), PlanEpisode("ident_drop", 0.02, "")]
    target, th = _serve()
    client = RigClient(target.address)
    try:
        files = run_plan(client, d / "plan", plan, progress=False)
        from impact_env.control.policy import CompiledPolicy

        client.arm("onboard", 9, 100,
                   policy=CompiledPolicy.from_law("passive", {}, {}, client.scene, "sensors"))
        drop = write_episode(client.fetch_log(client.wait_end(30).episode), d, name="plain_drop.h5")
    finally:
        client.close()
        _stop(target, th)
    other = load_scene("rig").with_overrides({"effects.sensors.accelerometer.adc_range": 300.0})
    target, th = _serve(scene=other)
    client = RigClient(target.address)
    try:
        (o,) = run_plan(client, d / "other", [plan[0]], progress=False)
    finally:
        client.close()
        _stop(target, th)
    return files, drop, o


def test_the_plan_writes_logs_the_loader_takes(short_logs):
    files, _drop, _other = short_logs
    exps = load(files)
    assert [e.kind for e in exps] == ["quiet", "shaker", "ident_drop", "ident_drop"]
    assert all(e.usable[1:].all() for e in exps)


def test_logs_that_cannot_serve_are_refused_naming_the_cause(short_logs, tmp_path):
    files, drop, other = short_logs
    with pytest.raises(ExperimentError, match=r"too few logs.*0 shaker.*1 ident_drop"):
        load([files[0], files[2]])
    with pytest.raises(ExperimentError, match=r"wrong episode kind.*'drop'"):
        load([*files, drop])
    with pytest.raises(ExperimentError, match=r"other sensors.*effects\.sensors\.accelerometer"):
        load([*files, other])
    bad = tmp_path / "corrupt.h5"
    bad.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(200))
    with pytest.raises(ExperimentError, match=r"corrupt\.h5: not a readable rig episode log"):
        load([*files, bad])
    log = read_episode(files[1])
    log.columns["force_N"][5:] = np.nan
    nan = write_episode(log, tmp_path, name="nan.h5")
    with pytest.raises(ExperimentError, match=r"nan\.h5: channel force has \d+ non-finite readings"):
        load([files[0], nan, files[2], files[3]])
    with pytest.raises(ExperimentError, match="no such log"):
        load([tmp_path / "missing.h5"])
    # and the command line says it in one line, exit 2, before fitting anything
    from impact_env.cli.main import main

    assert main(["identify", str(files[0]), "--out", str(tmp_path / "x.toml")]) == 2
    assert not (tmp_path / "x.toml").exists()


def test_the_identified_scene_file_says_where_each_value_came_from(short_logs, tmp_path):
    """A fit on the tiny logs (little data: some fields are not identified, and say so)."""
    files, _drop, _other = short_logs
    exps = load(files)
    fit = identify(exps)
    text = report.scene_text(fit, "rig", ranges_k=2.0)
    assert text.startswith("# rig-identified") and 'base = "rig"' in text
    for f in files:
        assert str(f) in text
    sc = load_scene(_write(tmp_path / "s.toml", text))
    assert sc.randomize.ranged()[:2] == ("m1", "drop_height")  # the benchmark's drops kept
    assert sc.control.known_hardware == ()  # widened by --ranges: not one value, so not known
    for r in report.field_table(fit):
        if r["status"] == "identified" and r["write"] != "report":
            assert f"{r['value']:.6g}" in text or repr(r["value"]) in text


def _write(path, text):
    path.write_text(text)
    return path


def test_default_plan_is_documented_and_inside_the_safety_ratings():
    from impact_env.rig.safety import SafetyConfig

    cfg = SafetyConfig()
    for quick in (False, True):
        plan = default_plan(quick)
        kinds = [p.kind for p in plan]
        assert kinds.count("quiet") == 2 and kinds.count("shaker") >= 2 and kinds.count("ident_drop") >= 3
        for p in plan:
            if p.excitation is not None:
                p.excitation.commands(1e4, int(p.duration_s * 1e4), 200.0, cfg.peak_n, cfg.continuous_n)
