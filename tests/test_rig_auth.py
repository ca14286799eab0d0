"""Authenticated rig sessions (impact_env.rig.auth, the protocol's HMAC tag, the target's session
pinning): the right key works, a wrong or missing key is a clear error at start naming the
option, and a HELLO from another address never takes an open session.  Targets in threads of this
process, lock-step, on loopback."""

from __future__ import annotations

import os
import stat
import threading

import numpy as np
import pytest

from impact_env.rig import protocol
from impact_env.rig.auth import KeyFileError, load_key, write_key
from impact_env.rig.driver import VirtualRig
from impact_env.rig.host import RigClient, RigEnv
from impact_env.rig.target import Target, TargetConfig
from impact_env.rig.transport import RigError


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    d = tmp_path_factory.mktemp("keys")
    return write_key(d / "rig.key"), write_key(d / "other.key")


@pytest.fixture(scope="module")
def keyed(keys):
    target = Target(VirtualRig("rig"), config=TargetConfig(lockstep=True, key=load_key(keys[0])))
    th = threading.Thread(target=target.serve, daemon=True)
    th.start()
    yield target
    target.stop()
    th.join(10)


def _episode(env, seed=1, steps=20):
    env.reset(seed=seed)
    for _ in range(steps):
        env.step(np.array([0.1], np.float32))


def test_key_file_errors_name_the_option(tmp_path, capsys):
    # imported here: importing the submodule impact_env.cli.main at collection would shadow the
    # package's main() that tests/test_scene_cli.py imports (``from impact_env.cli import main``)
    from impact_env.cli.main import main

    with pytest.raises(KeyFileError, match="--key .*no such key file"):
        load_key(tmp_path / "missing.key")
    (tmp_path / "bad.key").write_text("not hex at all\n")
    (tmp_path / "bad.key").chmod(0o600)
    with pytest.raises(KeyFileError, match="--key .*hexadecimal"):
        load_key(tmp_path / "bad.key")
    (tmp_path / "short.key").write_text("00ff" * 4)
    (tmp_path / "short.key").chmod(0o600)
    with pytest.raises(KeyFileError, match="8 B; at least 16 B"):
        load_key(tmp_path / "short.key")
    assert main(["rig", "serve", "--virtual", "--port", "0", "--key", str(tmp_path / "missing.key")]) == 2
    assert "--key" in capsys.readouterr().err
    with pytest.raises(FileExistsError):
        write_key(tmp_path / "bad.key")  # a key file is never overwritten


@pytest.mark.skipif(os.name != "posix", reason="POSIX file modes")
@pytest.mark.parametrize("mode", [0o666, 0o644, 0o640, 0o604, 0o620])
def test_a_key_file_open_to_group_or_others_is_refused_with_the_chmod_to_run(tmp_path, mode):
    """As ssh refuses such a private key: the message gives the command that fixes it, and after
    it the same file loads."""
    path = write_key(tmp_path / "rig.key")
    assert stat.S_IMODE(path.stat().st_mode) == 0o600  # keygen's own mode
    path.chmod(mode)
    with pytest.raises(KeyFileError, match=rf"--key {path}: .*mode {mode:04o}.*chmod 600 {path}"):
        load_key(path)
    path.chmod(0o600)
    assert len(load_key(path)) == 32


def test_rig_keygen_writes_mode_0600_whatever_the_umask(tmp_path):
    from impact_env.cli.main import main

    old = os.umask(0)
    try:
        assert main(["rig", "keygen", str(tmp_path / "k.key")]) == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "k.key").stat().st_mode) == 0o600


def test_the_right_key_runs_an_episode(keyed, keys):
    env = RigEnv(keyed.address, key=keys[0], horizon=0.01, timeout_s=0.2, retries=25)
    try:
        assert env.client.info.keyed
        _episode(env)
    finally:
        env.close()


@pytest.mark.parametrize("which", ["none", "other"])
def test_a_host_without_the_key_is_refused_with_a_clear_error(keyed, keys, which):
    key = None if which == "none" else keys[1]
    with pytest.raises(RigError, match="UNAUTHENTICATED.*--key FILE") as info:
        RigClient(keyed.address, key=key, timeout_s=0.2, retries=5)
    assert ("has no key" if key is None else "has a key") in str(info.value)
    assert keyed.link.filter.counts()["unauthenticated"] > 0


def test_a_keyed_host_at_a_target_without_key_is_told_so(keys):
    target = Target(VirtualRig("rig"), config=TargetConfig(lockstep=True))
    th = threading.Thread(target=target.serve, daemon=True)
    th.start()
    try:
        assert target.link.filter.loopback_only  # no key: loopback peers only
        with pytest.raises(RigError, match="started with another key or without one.*--key FILE"):
            RigClient(target.address, key=keys[0], timeout_s=0.2, retries=5)
    finally:
        target.stop()
        th.join(10)


def test_a_hello_from_elsewhere_never_takes_the_session(keyed, keys):
    """Another process with the key (another port) says HELLO while a session is open, idle and
    during an episode: refused (ERROR BUSY), counted as ``stranger``; the session goes on."""
    env = RigEnv(keyed.address, key=keys[0], horizon=0.01, timeout_s=0.2, retries=25)
    try:
        before = keyed.link.filter.counts()["stranger"]
        with pytest.raises(RigError, match="BUSY"):
            RigClient(keyed.address, key=keys[0], timeout_s=0.2, retries=5)
        env.reset(seed=2)
        with pytest.raises(RigError, match="BUSY"):
            RigClient(keyed.address, key=keys[0], timeout_s=0.2, retries=5)
        for _ in range(env.max_steps):
            _o, _r, te, tr, _i = env.step(np.array([0.1], np.float32))
            if te or tr:
                break
        assert te or tr
        assert keyed.link.filter.counts()["stranger"] >= before + 2
    finally:
        env.close()
    # closed: the next host opens a session at once
    other = RigClient(keyed.address, key=keys[0], timeout_s=0.2, retries=10)
    other.close()


def test_a_replayed_datagram_of_another_session_is_refused(keys):
    """The tag covers the session's nonce: a COMMAND recorded in one session does not check in the
    next, even with the same session id and a fresh sequence number."""
    key = load_key(keys[0])
    msg = protocol.Message(protocol.Command(1, 0, (1.0,)), session=7, seq=9)
    recorded = protocol.encode(msg, key, nonce=1111)
    f = protocol.DatagramFilter("target", session=7, key=key, nonce=2222)
    assert f.accept(recorded) is None and f.last_reason == "unauthenticated"
    f.nonce = 1111
    assert f.accept(recorded) is not None
    assert f.accept(recorded) is None and f.last_reason == "duplicate"


def test_rig_serve_says_at_start_whom_it_answers(tmp_path):
    """``rig serve`` without --key prints, before it listens, that it answers loopback peers only;
    with --key, that every datagram is authenticated (and not the loopback line)."""
    import os
    import select

    from rig_helpers import start_target, stop

    def start_lines(*args: str) -> str:
        proc, _addr = start_target("--scene", "rig", "--lockstep", *args)
        try:  # stderr's lines were flushed before the listening line on stdout: read them now,
            text = ""  # while the target runs (raw reads: a buffered readline would hide the rest)
            fd = proc.stderr.fileno()
            while not ("loopback" in text or "authenticated" in text) and select.select([fd], [], [], 5.0)[0]:
                chunk = os.read(fd, 4096).decode()
                if not chunk:
                    break
                text += chunk
            return text
        finally:
            stop(proc)

    plain = start_lines()
    assert "no --key: answering loopback peers only" in plain and "--key FILE" in plain
    key = write_key(tmp_path / "serve.key")
    keyed_text = start_lines("--key", str(key))
    assert "every datagram is authenticated" in keyed_text and "loopback peers only" not in keyed_text


def test_compare_rig_with_the_key_file(keyed, keys, capsys):
    """``impact-env compare --rig ADDR --key FILE`` runs its episodes on a keyed target (lock-step
    here); without --key the same command fails at once with the error that names the option."""
    from impact_env.cli.main import main

    base = ["compare", "--rig", keyed.address, "--policies", "passive,pd-penetration", "--episodes", "1",
            "--horizon", "0.01", "--seed", "3", "--workers", "1", "--no-progress", "--json"]
    episodes = keyed.counters["episodes"]
    assert main([*base, "--key", str(keys[0])]) == 0
    import json

    out = json.loads(capsys.readouterr().out)
    assert set(out["rig"]) == {"passive", "pd-penetration"}
    assert keyed.counters["episodes"] == episodes + 2  # one episode of each policy ran on the keyed target
    assert main(base) != 0
    assert "--key FILE" in capsys.readouterr().err
