"""Honest rig metrics (issue 25): a log's records on the true time axis (tick / rate, not the row
index), each policy's skipped-tick share in ``compare --rig``, the refusal to report a sim-to-rig
gap above 1 %, and a clear one-line error when no target answers."""

from __future__ import annotations

import socket

import numpy as np
import pytest

from impact_env.rig import log as tick_log
from impact_env.rig.controller import TRUTH_COLUMNS
from impact_env.rig.log_metrics import log_records, skipped_fraction
from impact_env.sim import records as sim_records

RATE = 1.0e4


def _log_with_gap(skip: range) -> tick_log.EpisodeLog:
    """A virtual rig's log of ticks 0..99 without the rows of ``skip`` (an overrun), its truth
    linear in time (x1 = 1e-3 t ticks... m), the command a ramp held over the gap."""
    ticks = np.array([k for k in range(100) if k not in skip])
    log = tick_log.TickLog(101, 1, extra=TRUTH_COLUMNS)
    for k in ticks:
        row = {"tick": k, "t_s": k / RATE, "action": 0.01 * k, "status": 0, "contact_detected": k % 2}
        row |= {c: 0.0 for c in TRUTH_COLUMNS}
        row |= {"true_x1_m": 1e-3 * k, "true_v1_mps": 2.0 - 0.01 * k, "command": 0.01 * k,
                "hw_force_applied_N": 2.0 * k}
        log.record(**row)
    meta = tick_log.EpisodeMeta(scene_toml="", mode="onboard", hold_ticks=1, seed=0, control_rate_hz=RATE)
    return log.to_episode(meta)


def test_records_sit_on_their_ticks_across_skipped_ones():
    log = _log_with_gap(range(40, 50))
    rec = log_records(log)
    assert rec.shape[0] == 100  # ticks 0..99, not the 90 rows
    np.testing.assert_array_equal(rec[:, sim_records.REC.t], (np.arange(100) + 1) / RATE)
    # linear: exact
    np.testing.assert_allclose(rec[:, sim_records.REC.x1], 1e-3 * np.arange(100), rtol=0, atol=1e-15)
    assert np.all(rec[40:50, sim_records.REC.u] == rec[39, sim_records.REC.u])  # the command the DAC held
    assert rec[50, sim_records.REC.u] == 0.5 and rec[39, sim_records.REC.u] == 0.39
    assert skipped_fraction(log) == pytest.approx(0.1)
    full = _log_with_gap(range(0))
    assert skipped_fraction(full) == 0.0
    r = log_records(full)  # without a gap: the rows as they are, bitwise
    assert np.array_equal(r[:, sim_records.REC.x1], full["true_x1_m"][:100]) and r.shape[0] == 100


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_compare_rig_without_a_target_says_so_in_one_line(capsys):
    from impact_env.cli.main import main

    port = _free_udp_port()
    assert main(["compare", "--rig", f"udp://127.0.0.1:{port}", "--policies", "passive", "--episodes", "1",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "no target answered" in err and "rig serve" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


@pytest.fixture(scope="module")
def fake_rig_runs():
    """compare's runs of passive on the rig scene, standing for a rig whose target skipped 30 %
    of its ticks (what a loaded machine did in issue 25: 2688 of 4000)."""
    from impact_env.eval.compare import compare
    from impact_env.scene import load_scene

    scene = load_scene("rig")
    runs = compare(scene, ["passive"], episodes=1, seed=0, workers=1, progress=False)
    runs["passive"].summary["skipped_tick_fraction"] = 0.3
    return scene, runs


@pytest.mark.parametrize("allow", [False, True])
def test_compare_rig_refuses_a_gap_over_one_percent_of_skipped_ticks(allow, fake_rig_runs, monkeypatch,
                                                                    capsys):
    from impact_env.cli.main import main
    from impact_env.eval import rig_compare

    monkeypatch.setattr(rig_compare, "rig_compare", lambda *a, **k: fake_rig_runs)
    argv = ["compare", "--rig", "udp://127.0.0.1:1", "--scene", "rig", "--policies", "passive",
            "--episodes", "1", "--no-progress", "--workers", "1"] + (["--allow-overruns"] if allow else [])
    rc = main(argv)
    out, err = capsys.readouterr()
    assert "skipped ticks" in out and "passive 30 %" in out  # the share is printed either way
    if allow:
        assert rc == 0 and "sim-to-rig gap" in out
    else:
        assert rc == 1 and "sim-to-rig gap" not in out
        assert "'passive' skipped 30 % of its ticks" in err and "lock-step" in err and "idle core" in err


def test_episodes_the_rig_cut_short_count_as_failed_and_are_named():
    """compare --rig in real time: an episode the rig ended OVERRUN, SENSOR_FAULT or LINK_LOST is
    not a whole episode: its metrics are not in the table, it counts as failed (3/3 here, not
    0/3), and each is named in the failures with its end reason."""
    from impact_env.eval import rig_compare
    from impact_env.eval.compare import summarize

    reasons = ("OVERRUN", "SENSOR_FAULT", "LINK_LOST")
    logs = []
    for reason in reasons:
        log = _log_with_gap(range(40, 50))
        log.meta.end_reason = reason
        logs.append(log)
    failures: list = []
    run, skipped = rig_compare._run("passive", logs, failures, 1.0)
    s = summarize(run)
    assert s["episodes"] == 3 and s["failed_episodes"] == 3
    assert [f["episode"] for f in failures] == [0, 1, 2]
    for f, reason in zip(failures, reasons, strict=True):
        assert f"ended the episode {reason} at tick 99" in f["error"] and f["policy"] == "passive"
    assert np.allclose(skipped, 0.1)  # the skipped-tick share is still reported
