"""compare, sweep and robustness on a real Dask cluster (a scheduler and two worker processes on
loopback, started and stopped by the fixture: impact_env/eval/local_cluster.py) give bitwise the local run's
results; bad ``--cluster`` values are refused, naming the option, before anything runs."""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

import impact_env.eval.parallel as parallel
import impact_env.eval.rollout as rollout_module
import impact_env.policy.registry as policy_registry
from impact_env.cli import main  # the function (a top-level import of impact_env.cli.main would shadow it)
from impact_env.config import ConfigError
from impact_env.eval.compare import check_cluster_specs, compare
from impact_env.eval.parallel import Cluster, parse_cluster, run_tasks
from impact_env.eval.robustness import parse_vary, robustness
from impact_env.eval.sweep import sweep
from impact_env.scene import load_scene

if os.environ.get("CI"):  # CI installs [dev], which has [cluster]: a skip there would hide a broken install
    import distributed  # noqa: F401
else:
    pytest.importorskip("distributed")

RIG = load_scene("rig")
SHORT = 0.015  # s: the first contact and the first flight on rig
SPECS = ["passive", "thesis-rig", "pd-penetration", "oracle:generations=2,popsize=4"]


@pytest.fixture(scope="module")
def address():
    from impact_env.eval.local_cluster import local_cluster

    with local_cluster(workers=2, threads=1) as addr:
        yield addr


@pytest.fixture(scope="module")
def cluster(address):
    with Cluster(address) as cl:
        yield cl


@pytest.fixture
def nothing_runs(monkeypatch):
    """A rollout here fails the test: a refusal must come before anything is simulated."""
    import importlib
    import pkgutil

    import impact_env.eval

    def refuse(*args, **kwargs):
        raise AssertionError("a rollout ran before the refusal")

    # every module that binds rollout by name imported first, so that each binding is patched here
    # and restored after: one imported while the patch stands would keep the refusal for later tests
    for info in pkgutil.iter_modules(impact_env.eval.__path__, "impact_env.eval."):
        importlib.import_module(info.name)
    real = rollout_module.rollout
    for module in [m for name, m in sys.modules.items() if name.startswith("impact_env")]:
        if getattr(module, "rollout", None) is real:  # every module that calls it by this name
            monkeypatch.setattr(module, "rollout", refuse)


def _same(a, b, what: str) -> None:
    """Bitwise equality of nested results (arrays, dicts, lists, floats with NaN and inf)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=what)
        assert np.asarray(a).dtype == np.asarray(b).dtype, what
    elif isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), what
        for k in a:
            _same(a[k], b[k], f"{what}.{k}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), what
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{what}[{i}]")
    elif isinstance(a, float) and math.isnan(a):
        assert isinstance(b, float) and math.isnan(b), what
    else:
        assert a == b, f"{what}: {a!r} != {b!r}"


TIMINGS = {"wall_time_s", "wall_time_total_s", "oracle_seconds_per_drop", "cpu_seconds", "seconds"}  # clocks


def _runs_equal(local, remote) -> None:
    assert list(local) == list(remote)
    for spec in local:
        a, b = local[spec], remote[spec]
        for name in ("episodes", "metrics", "failures", "trace_t", "trace0", "t_touch0", "impact_energy0",
                     "energy_t", "energy_ratio", "control_period", "commands"):
            _same(getattr(a, name), getattr(b, name), f"{spec}.{name}")
        _same({k: v for k, v in a.stats.items() if k not in TIMINGS},
              {k: v for k, v in b.stats.items() if k not in TIMINGS}, f"{spec}.stats")
        _same({k: v for k, v in a.summary.items() if k not in TIMINGS},
              {k: v for k, v in b.summary.items() if k not in TIMINGS}, f"{spec}.summary")


# -- refusals: no cluster needed ------------------------------------------------------------------
BAD = [("ray://127.0.0.1:10001", "Ray is not the engine"), ("127.0.0.1:8786", "expected tcp://HOST:PORT"),
       ("tcp://127.0.0.1", "expected tcp://HOST:PORT"), ("tcp://127.0.0.1:99999", "1..65535"),
       ("tcp://127.0.0.1:port", "1..65535"), ("http://127.0.0.1:8786", "scheme 'http://'"),
       ("tcp://127.0.0.1:8786/x", "expected tcp://HOST:PORT"), ("tcp://:8786", "expected tcp://HOST:PORT")]
COMMANDS = {"compare": ["compare", "--policies", "passive", "--episodes", "1", "--no-progress"],
            "sweep": ["sweep", "--h01", "1e5:1e6:2", "--h11", "1:10:2", "--no-progress"],
            "robustness": ["robustness", "--policies", "passive", "--vary", "c=1e6:2e6:2", "--episodes", "1",
                           "--no-progress"]}


@pytest.mark.parametrize("command", list(COMMANDS))
@pytest.mark.parametrize("value,why", BAD)
def test_a_bad_cluster_address_is_refused_naming_the_option(command, value, why, capsys, tmp_path,
                                                            nothing_runs):
    assert main([*COMMANDS[command], "--out", str(tmp_path / "out"), "--cluster", value]) == 2
    err = capsys.readouterr().err
    assert f"impact-env {command}: error: --cluster {value!r}" in err and why in err, err
    assert "Traceback" not in err


def test_an_address_is_normalised():
    assert parse_cluster(" tcp://127.0.0.1:8786 ") == "tcp://127.0.0.1:8786"
    assert parse_cluster("tcp://[::1]:8786/") == "tcp://[::1]:8786"
    assert parse_cluster("TCP://sched.example:8786") == "tcp://sched.example:8786"


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_no_scheduler_answering_is_refused_before_anything_runs(capsys, monkeypatch, nothing_runs):
    """Refused, not hung: Dask's connection gives up after CONNECT_TIMEOUT_S (set to 1 s here and
    checked to be what Dask was given; no wall clock is read)."""
    import distributed

    monkeypatch.setattr(parallel, "CONNECT_TIMEOUT_S", 1.0)
    timeouts = []
    real_client = distributed.Client

    def client(*args, **kwargs):
        timeouts.append(kwargs.get("timeout"))
        return real_client(*args, **kwargs)

    monkeypatch.setattr(distributed, "Client", client)
    addr = f"tcp://127.0.0.1:{_closed_port()}"
    assert main([*COMMANDS["compare"], "--cluster", addr]) == 2
    err = capsys.readouterr().err
    assert f"error: --cluster {addr}: no Dask scheduler answered" in err and "Traceback" not in err, err
    assert timeouts == [1.0]


def test_a_scheduler_without_workers_is_refused(tmp_path):
    sched_file = tmp_path / "scheduler.json"
    proc = subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0",
                             "--no-dashboard", "--scheduler-file", str(sched_file)], cwd=tmp_path,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not sched_file.exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.1)
        addr = json.loads(sched_file.read_text())["address"]
        with pytest.raises(ConfigError, match=r"--cluster tcp://127\.0\.0\.1:\d+: the scheduler answered but "
                                              r"has no worker after 1 s"):
            Cluster(addr, timeout=1.0)
    finally:
        proc.terminate()
        proc.wait(30)


def test_without_dask_the_option_gives_the_install_hint(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    with pytest.raises(ConfigError,
                       match=r"--cluster needs Dask distributed.*pip install 'impact-env\[cluster\]'"):
        Cluster("tcp://127.0.0.1:8786")


def test_what_the_workers_cannot_find_is_refused(monkeypatch):
    with pytest.raises(ConfigError, match="relative path"):
        check_cluster_specs(["passive", "compiled:agents/models/best/best.policy.json"])
    with pytest.raises(ConfigError, match="relative path"):
        check_cluster_specs(["ppo:runs/a.zip"])
    check_cluster_specs(["passive", "compiled:/abs/best.policy.json", "ppo:/abs/a.zip"])  # absolute: fine

    class Mine(policy_registry.policy_class("passive")):
        name = "mine"

    monkeypatch.setitem(policy_registry.REGISTERED, "mine", Mine)
    with pytest.raises(ConfigError, match="'mine' is registered in this process only"):
        check_cluster_specs(["mine:gain=1"])


def test_rig_and_cluster_do_not_go_together(capsys):
    assert main(["compare", "--rig", "udp://127.0.0.1:9", "--cluster", "tcp://127.0.0.1:8786"]) == 2
    assert "--cluster runs simulations; it does not go with --rig" in capsys.readouterr().err


# -- on the cluster --------------------------------------------------------------------------------
def test_tasks_come_back_in_task_order_and_errors_propagate(cluster):
    assert cluster.workers == 2
    tasks = [float(x * x) for x in range(12)]
    assert run_tasks(math.sqrt, tasks, 2, total=12, desc="t", progress=False, cluster=cluster) == \
        [float(x) for x in range(12)]
    with pytest.raises(ValueError, match="math domain error"):
        run_tasks(math.sqrt, [4.0, -1.0, 9.0], 2, total=3, desc="t", progress=False, cluster=cluster)


def test_the_progress_bar_reaches_its_total_as_tasks_finish(cluster, monkeypatch):
    seen: list[int] = []

    class Recorded(parallel.Progress):
        def update(self, n: int) -> None:
            seen.append(n)
            super().update(n)

    monkeypatch.setattr(parallel, "Progress", Recorded)
    run_tasks(math.sqrt, [1.0] * 7, 2, total=100, desc="t", progress=False, cluster=cluster)
    assert len(seen) == 7 and sum(seen) == 100 and min(seen) >= 14


@pytest.mark.slow
def test_compare_with_the_oracle_on_the_cluster_is_bitwise_the_local_run(cluster):
    local = compare(RIG, SPECS, episodes=3, seed=7, horizon=SHORT, workers=2, progress=False)
    remote = compare(RIG, SPECS, episodes=3, seed=7, horizon=SHORT, progress=False, cluster=cluster)
    _runs_equal(local, remote)
    assert remote[SPECS[-1]].summary["gap_to_oracle_min_ms"] >= 0.0  # the oracle ran, with warm starts
    assert remote[SPECS[-1]].stats["evaluations"].shape == (3,)


@pytest.mark.slow
def test_the_cli_on_the_cluster_prints_the_local_table(address, capsys, tmp_path):
    argv = ["compare", "--scene", "rig", "--policies", "passive,pd-penetration", "--episodes", "3",
            "--horizon", str(SHORT), "--seed", "3", "--json", "--workers", "2"]
    assert main(argv) == 0
    local = json.loads(capsys.readouterr().out)
    assert main([*argv, "--cluster", address]) == 0  # an address: compare connects and disconnects itself
    remote = json.loads(capsys.readouterr().out)
    for js in (local, remote):
        for row in js.values():
            row.pop("wall_time_s"), row.pop("wall_time_total_s")
    assert local == remote and set(local) == {"passive", "pd-penetration"}


@pytest.mark.slow
def test_sweep_on_the_cluster_is_bitwise_the_local_run(cluster):
    axes = (("h01", np.geomspace(1e5, 5e6, 4)), ("h11", np.geomspace(1, 1000, 3)))
    local = sweep(RIG, "thesis-rig", axes, seed=2, t_end=0.02, limit="scene", workers=2,
                  progress=False)
    remote = sweep(RIG, "thesis-rig", axes, seed=2, t_end=0.02, limit="scene", progress=False,
                   cluster=cluster)
    _same(local.metrics, remote.metrics, "metrics")
    _same(local.within_limit, remote.within_limit, "within_limit")
    _same(local.best, remote.best, "best")
    _same(local.failures, remote.failures, "failures")
    assert local.best is not None and local.metrics["peak_force_N"].shape == (4, 3)


@pytest.mark.slow
def test_robustness_on_the_cluster_is_bitwise_the_local_run(cluster):
    scene = load_scene("rig", {"episode.horizon": "0.03"})
    axes = [parse_vary("c=1e6:4e6:3", scene.control_rate)]
    specs = ["passive", "pd-penetration"]
    local = robustness(scene, specs, axes, episodes=3, seed=4, workers=2, progress=False)
    remote = robustness(scene, specs, axes, episodes=3, seed=4, progress=False, cluster=cluster)
    _same(local.points, remote.points, "points")
    strip = lambda rows: [{s: {k: v for k, v in d.items() if k not in TIMINGS} for s, d in r.items()}
                          for r in rows]
    _same(strip(local.summaries), strip(remote.summaries), "summaries")
    assert len(remote.summaries) == 3 and remote.summaries[0]["passive"]["episodes"] == 3
