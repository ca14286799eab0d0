"""A target on loopback, started from Python: ``impact-env rig serve`` as a child process, waited
for until it listens, and stopped; and a flood of junk datagrams to aim at it.  The rig's
benchmark (scripts/bench_rig.py) starts its targets with exactly the options it names, so its
figures are what ``rig serve`` does with them; the tests wrap :func:`serve` with their own
defaults (tests/rig_helpers.py)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

# a flood at a target (the rig's flood test and benchmark): ``python -c FLOOD HOST PORT
# HELLO_HEX GO_FILE N_MAX MAX_S`` sends, once GO_FILE exists, as fast as it can until N_MAX datagrams
# or MAX_S seconds or until GO_FILE is removed, a quarter each: the host's HELLO replayed, a COMMAND-shaped frame with a bad
# tag, junk (bad magic), truncated frames; it prints "ready", then a JSON line of what it sent
FLOOD = r"""
import json, os, random, socket, sys, time
host, port, hello_hex, go_file, n_max, max_s = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4], \
    int(sys.argv[5]), float(sys.argv[6])
hello = bytes.fromhex(hello_hex)
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.1", 0))
s.setblocking(False)
rng = random.Random(7)
# a COMMAND-shaped frame (valid magic, version, length) under a tag nobody's key makes
frame = bytearray(hello[:42])
frame[6] = 7
frame[40:42] = (18).to_bytes(2, "little")
bad_tag = bytes(frame) + bytes(18) + bytes(16)
kinds = ("replayed_hello", "bad_tag", "malformed", "truncated")
sent = dict.fromkeys(kinds, 0)
not_sent = replies = reply_bytes = 0
print("ready", flush=True)
while not os.path.exists(go_file):
    time.sleep(0.001)
t0 = time.perf_counter()
k = 0
while k < n_max and time.perf_counter() - t0 < max_s:
    kind = kinds[k % 4]
    if kind == "replayed_hello":
        data = hello
    elif kind == "bad_tag":
        data = bad_tag[:-16] + rng.randbytes(16)
    elif kind == "malformed":
        data = b"JUNK" + rng.randbytes(rng.randint(60, 400))
    else:
        data = hello[:rng.randint(0, 57)]
    k += 1
    try:
        s.sendto(data, (host, port))
        sent[kind] += 1
    except BlockingIOError:
        not_sent += 1
    if k % 64 == 0:
        if k % 4096 == 0 and not os.path.exists(go_file):  # told to stop
            break
        while True:
            try:
                reply_bytes += len(s.recv(70000))
                replies += 1
            except BlockingIOError:
                break
elapsed = time.perf_counter() - t0
time.sleep(0.3)
while True:
    try:
        reply_bytes += len(s.recv(70000))
        replies += 1
    except BlockingIOError:
        break
print(json.dumps({"sent": sent, "not_sent": not_sent, "replies": replies, "reply_bytes": reply_bytes,
                  "elapsed_s": elapsed}), flush=True)
"""



def serve(*args: str, timeout_s: float = 300.0, driver: str | None = None, cwd: str | Path | None = None,
          env: dict | None = None) -> tuple[subprocess.Popen, str]:
    """``impact-env rig serve --virtual --port 0 ARGS`` (``--driver DRIVER`` instead of
    ``--virtual`` if given) in this Python; returns (process, ``udp://HOST:PORT``) once it
    listens (a first run may compile the kernels: up to ``timeout_s`` s).  ``env``: the child's
    environment (default: this process's, unbuffered)."""
    which = ["--virtual"] if driver is None else ["--driver", driver]
    cmd = [sys.executable, "-m", "impact_env.cli.main", "rig", "serve", *which, "--port", "0", *args]
    child_env = dict(env if env is not None else os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd,
                            env=child_env)
    out, err = proc.stdout, proc.stderr
    assert out is not None and err is not None  # both are pipes
    deadline = time.monotonic() + timeout_s
    line = ""
    while "listening" not in line:
        if proc.poll() is not None or time.monotonic() > deadline:
            stop(proc)
            raise RuntimeError(f"target did not start: {err.read()[-2000:]}")
        line = out.readline()
    found = re.search(r"udp://\S+", line)
    assert found is not None, line
    return proc, found.group(0)


def stop(proc: subprocess.Popen, sig=signal.SIGTERM, timeout_s: float = 20.0) -> int:
    """Signal ``proc`` (SIGTERM) and wait up to ``timeout_s`` s, then kill it; its exit code."""
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
    return proc.returncode
