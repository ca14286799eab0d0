"""A real Dask cluster on loopback, for trying cluster mode on one machine, the tests and
``scripts/bench_cluster.py``: a scheduler
process and worker processes (``python -m dask scheduler`` / ``python -m dask worker``, the
commands a user runs on a real cluster, docs/cluster.md), bound to 127.0.0.1 only, every wait
bounded, every process ended on the way out (and by a watchdog if the caller hangs)."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

START_TIMEOUT_S = 90.0  # scheduler up and every worker joined (a worker imports numpy, numba, ...)


def _stop(proc: subprocess.Popen, timeout: float = 15.0) -> None:
    """End one process this module started (its process group: a worker's nanny and its child)."""
    if proc.poll() is not None:
        return
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout)


@contextlib.contextmanager
def local_cluster(workers: int = 2, threads: int = 1, lifetime_s: float = 600.0) -> Iterator[str]:
    """Yield the scheduler's address (``tcp://127.0.0.1:PORT``) with ``workers`` worker processes
    of ``threads`` threads each joined.  Everything is stopped on exit, or after ``lifetime_s`` s
    by a watchdog (so a hung test cannot leave the cluster running)."""
    from distributed import Client

    root = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))}
    procs: list[subprocess.Popen] = []
    with tempfile.TemporaryDirectory(prefix="impact-env-cluster-") as tmp:
        sched_file = Path(tmp) / "scheduler.json"
        logs = [open(Path(tmp) / "scheduler.log", "w")]  # noqa: SIM115  (closed below)

        def start(args: list[str], log) -> subprocess.Popen:
            p = subprocess.Popen([sys.executable, "-m", "dask", *args], stdout=log, stderr=subprocess.STDOUT,
                                 stdin=subprocess.DEVNULL, env=env, cwd=tmp, start_new_session=True)
            procs.append(p)
            return p

        def stop_all() -> None:
            for p in reversed(procs):
                _stop(p)

        watchdog = threading.Timer(lifetime_s, stop_all)
        watchdog.daemon = True
        watchdog.start()
        try:
            sched = start(["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                           "--scheduler-file", str(sched_file)], logs[0])
            deadline = time.monotonic() + START_TIMEOUT_S
            address = None
            while address is None:  # the file appears before the scheduler has written it whole
                if sched.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError("the Dask scheduler did not start:\n"
                                       + _tail(Path(tmp) / "scheduler.log"))
                time.sleep(0.1)
                try:
                    address = json.loads(sched_file.read_text())["address"]
                except (OSError, ValueError, KeyError):  # absent, empty or half written: wait
                    address = None
            logs.append(open(Path(tmp) / "workers.log", "w"))  # noqa: SIM115
            start(["worker", address, "--nworkers", str(workers), "--nthreads", str(threads),
                   "--host", "127.0.0.1", "--no-dashboard", "--death-timeout", "60",
                   "--local-directory", tmp], logs[1])
            with Client(address, timeout=30, set_as_default=False) as client:
                try:
                    client.wait_for_workers(workers, timeout=max(1.0, deadline - time.monotonic()))
                except TimeoutError:
                    raise RuntimeError(f"{workers} Dask workers did not join within {START_TIMEOUT_S:g} s:\n"
                                       + _tail(Path(tmp) / "workers.log")) from None
            yield address
        finally:
            watchdog.cancel()
            stop_all()
            for log in logs:
                log.close()


def _tail(path: Path, n: int = 3000) -> str:
    try:
        return path.read_text()[-n:]
    except OSError:
        return ""
