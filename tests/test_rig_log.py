"""Episode logs (impact_env.rig.log): the per-tick arrays, the HDF5 file and its atomic write."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from impact_env._jit import jit
from impact_env.rig import log as tick_log
from impact_env.rig.safety import OVERRUN, WATCHDOG
from impact_env.scene import load_scene

ROOT = Path(__file__).resolve().parent.parent


@jit
def _fill(rows, obs, count, n, hold):
    """What the target's compiled loop does each tick (with made-up readings)."""
    for k in range(n):
        i = tick_log.claim_row(rows, count)
        if i < 0:
            return k
        rows[i, tick_log.COL.tick] = k
        rows[i, tick_log.COL.t_s] = k * 1e-4
        rows[i, tick_log.COL.accelerometer_mps2] = 0.5 * k
        rows[i, tick_log.COL.force_N] = -0.25 * k
        rows[i, tick_log.COL.potentiometer_m] = 1e-6 * k
        rows[i, tick_log.COL.action] = 0.1
        rows[i, tick_log.COL.force_demand_N] = 20.0
        rows[i, tick_log.COL.force_applied_N] = 20.0 if k < 15 else 0.0
        rows[i, tick_log.COL.command_age_ticks] = k % hold if k < 15 else k - 10
        rows[i, tick_log.COL.status] = 0 if k < 15 else WATCHDOG | OVERRUN
        rows[i, tick_log.COL.step] = k // hold
        rows[i, tick_log.COL.contact_detected] = 1.0 if 5 <= k < 9 else 0.0
        rows[i, tick_log.COL.lateness_ns] = 1000 + k
        rows[i, tick_log.COL.compute_ns] = 20_000 + k
        rows[i, tick_log.N_FIXED] = 3.0 * k  # the first extra column
        for j in range(obs.shape[1]):
            obs[i, j] = k + 0.5 * j
    return n


def _meta(**kw):
    scene = load_scene("rig")
    base = dict(scene_toml=scene.to_toml(), mode="onboard", hold_ticks=5, seed=42, control_rate_hz=1e4,
                episode=3, session=0xBEEF, policy="thesis-rig:h01=2.3e6,h11=18",
                policy_sha256=hashlib.sha256(b"policy").hexdigest(),
                obs_names=("accelerometer", "force", "potentiometer", "contact_detected"),
                end_reason="HORIZON", counters={"dropped.corrupt": 2, "watchdog_trips": 1, "overruns": 0})
    base.update(kw)
    return tick_log.EpisodeMeta(**base)


def _filled(n=20, capacity=32):
    log = tick_log.TickLog(capacity, 4, extra=("x1_m",), extra_units={"x1_m": "m"})
    assert _fill(log.rows, log.obs, log.count, n, 5) == n
    return log


def test_ticklog_layout_and_compiled_filling():
    log = _filled()
    assert log.n == 20 and log.capacity == 32
    assert (
        log.names[: tick_log.N_FIXED] == tuple(c[0] for c in tick_log.COLUMNS)
        and log.col("x1_m") == tick_log.N_FIXED
    )
    cols = log.columns()
    assert cols["tick"].dtype == np.int64 and cols["status"].dtype == np.uint32
    assert cols["contact_detected"].dtype == np.uint8 and cols["t_s"].dtype == np.float64
    np.testing.assert_array_equal(cols["tick"], np.arange(20))
    assert cols["status"][15] == WATCHDOG | OVERRUN
    np.testing.assert_array_equal(cols["x1_m"], 3.0 * np.arange(20))
    assert _fill(log.rows, log.obs, log.count, 40, 5) == 12  # full after 32 rows: claim_row says -1
    assert log.n == 32
    with pytest.raises(OverflowError, match="full"):
        log.record(tick=1)
    log.reset()
    assert log.n == 0 and log.record(tick=7, obs=np.ones(4)) == 0 and log.columns()["tick"][0] == 7
    with pytest.raises(KeyError, match="no column 'tock'"):
        log.record(tock=1)


@pytest.mark.parametrize("kw,match", [
    ({"capacity": 0, "obs_size": 1}, "capacity"), ({"capacity": 5, "obs_size": -1}, "obs_size"),
    ({"capacity": 5, "obs_size": 1, "extra": ("tick",)}, "extra column 'tick'"),
    ({"capacity": 5, "obs_size": 1, "extra": ("x-1",)}, "extra column"),
])
def test_ticklog_argument_errors(kw, match):
    with pytest.raises(ValueError, match=match):
        tick_log.TickLog(**kw)


def test_write_read_round_trip(tmp_path):
    log = _filled()
    meta = _meta()
    path = tick_log.write_episode(log, tmp_path / "logs", meta)
    assert path.name == "episode_0000beef_000003.h5"
    back = tick_log.read_episode(path)
    mem = log.to_episode(meta)
    assert back.columns.keys() == mem.columns.keys()
    for k in mem.columns:
        assert back[k].dtype == mem[k].dtype, k
        np.testing.assert_array_equal(back[k], mem[k])
    np.testing.assert_array_equal(back.observation, log.obs[:20])
    assert back.meta == meta and back.units["x1_m"] == "m" and back.units["force_N"] == "N"
    assert back.n_ticks == 20 and back.path == path
    assert back.scene() == load_scene("rig")
    assert set(meta.versions) == {"impact_env", "python", "numpy", "numba", "h5py"}
    assert tick_log.list_episodes(tmp_path / "logs") == [path]


def test_format_3_fields_round_trip_and_an_older_file_reads_as_a_drop(tmp_path):
    import h5py

    phys = load_scene("rig").with_overrides({"plant.c": 2.5e6})
    meta = _meta(kind="shaker", excitation='{"signal": "sweep"}', physics_toml=phys.to_toml())
    path = tick_log.write_episode(_filled(), tmp_path, meta)
    back = tick_log.read_episode(path)
    assert (back.meta.kind, back.meta.excitation) == ("shaker", '{"signal": "sweep"}')
    assert back.physics() == phys and back.scene() == load_scene("rig")
    with h5py.File(path, "a") as f:  # a format-2 file: none of the three attributes
        for k in ("kind", "excitation", "physics_toml"):
            del f.attrs[k]
        f.attrs["format_version"] = 2
    old = tick_log.read_episode(path)
    assert (old.meta.kind, old.meta.excitation, old.meta.physics_toml) == ("drop", "", "")
    assert old.physics() == load_scene("rig")
    with pytest.raises(ValueError, match="kind"):
        _meta(kind="sweep")


def test_write_refuses_bad_names_and_missing_meta(tmp_path):
    with pytest.raises(ValueError, match="needs meta"):
        tick_log.write_episode(_filled(), tmp_path)
    with pytest.raises(ValueError, match="plain name"):
        tick_log.write_episode(_filled(), tmp_path, _meta(), name="../x.h5")


def test_failed_write_leaves_no_file(tmp_path, monkeypatch):
    def boom(fd):
        raise OSError("disk full")

    monkeypatch.setattr(tick_log.os, "fsync", boom)
    with pytest.raises(OSError, match="disk full"):
        tick_log.write_episode(_filled(), tmp_path, _meta())
    assert list(tmp_path.iterdir()) == []


def test_a_crash_mid_write_loses_no_finished_episode(tmp_path):
    """Episode 1 is written; a process writing episode 2 dies (os._exit) just before the rename:
    episode 1 is intact, episode 2's temporary file is ignored by list_episodes."""
    first = tick_log.write_episode(_filled(), tmp_path, _meta(episode=1))
    script = textwrap.dedent(f"""
        import os, sys
        sys.path.insert(0, {str(ROOT)!r})
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_rig_log import _meta
        from impact_env.rig import log as L
        log = L.TickLog(100, 4)
        for k in range(100):
            log.record(tick=k, t_s=k * 1e-4, obs=[k, k, k, k])
        L.os.replace = lambda *a: os._exit(9)  # the crash, after the data are written
        L.write_episode(log, {str(tmp_path)!r}, _meta(episode=2))
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 9, out.stderr[-2000:]
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names[0].startswith(".episode_0000beef_000002.h5.") and names[0].endswith(".tmp")
    assert tick_log.list_episodes(tmp_path) == [first]
    assert tick_log.read_episode(first).meta.episode == 1


def test_missing_h5py_gives_an_install_hint(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "h5py", None)
    with pytest.raises(ImportError, match=r"pip install 'impact-env\[rig\]'"):
        tick_log.write_episode(_filled(), tmp_path, _meta())
    with pytest.raises(ImportError, match="h5py"):
        tick_log.read_episode(tmp_path / "x.h5")


def test_read_refuses_other_files(tmp_path):
    import h5py

    with h5py.File(tmp_path / "other.h5", "w") as f:
        f.attrs["format"] = "something else"
    with pytest.raises(ValueError, match="not a rig episode log"):
        tick_log.read_episode(tmp_path / "other.h5")


@pytest.mark.parametrize("kw,match", [
    ({"mode": "remote"}, "mode"), ({"hold_ticks": -1}, "hold_ticks"),
    ({"control_rate_hz": 0.0}, "control_rate_hz"),
    ({"policy_sha256": "abc"}, "policy_sha256"), ({"counters": {"x": 1.5}}, "counter 'x'"),
])
def test_meta_validation(kw, match):
    with pytest.raises(ValueError, match=match):
        _meta(**kw)
