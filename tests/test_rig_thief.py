"""A process on the target's machine, running as the target's user, cannot take the host's
datagrams, and when a host's datagrams stop arriving both sides say so by name.

The target binds its address without ``SO_REUSEPORT`` and gives each session a socket of its own
(:meth:`impact_env.rig.transport.Endpoint.open_session`, also without it, connected to the host),
whose port INFO names under the session's key: a thief that asks for ``SO_REUSEPORT`` (or
``SO_REUSEADDR``) is refused the bind, before and during a session, and the host's commands all
act.  Targets in threads of this process, on loopback; every wait bounded."""

from __future__ import annotations

import socket
import threading
import warnings

import numpy as np
import pytest
from rig_helpers import LossyProxy

from impact_env.rig.driver import VirtualRig
from impact_env.rig.host import RigCommandsUnheard, RigEnv
from impact_env.rig.target import Target, TargetConfig

KEY = bytes(range(7, 39))


def _serve(**cfg) -> tuple[Target, threading.Thread]:
    target = Target(VirtualRig("rig"), config=TargetConfig(key=KEY, **cfg))
    th = threading.Thread(target=target.serve, daemon=True)
    th.start()
    return target, th


def _thief_binds(port: int, host: str = "127.0.0.1") -> str | None:
    """A same-user thief's bind of ``host:port`` with SO_REUSEPORT and SO_REUSEADDR: None if it
    got the port, else the kernel's refusal."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind((host, port))
    except OSError as exc:
        return str(exc)
    finally:
        s.close()
    return None


def test_a_thief_with_so_reuseport_cannot_bind_the_targets_ports_and_every_command_acts():
    """Before the session, the target's port; during it, that port and the session's (on
    127.0.0.1 and on the wildcard address): every bind is refused.  The episode runs to its
    horizon with every one of the host's commands acted, none unheard on either side."""
    target, th = _serve(lockstep=True)
    env = None
    try:
        port = target.endpoint.local[1]
        assert _thief_binds(port) and _thief_binds(port, "0.0.0.0")
        env = RigEnv(target.address, key=KEY, hold_ticks=4, horizon=0.01, terminate_on_catch=False,
                     timeout_s=0.2, retries=25)
        session_port = env.client.endpoint.peer[1]
        assert session_port not in (0, port) and session_port == target.endpoint.session_port
        env.reset(seed=3)
        n = 0
        while True:
            for p in (port, session_port):
                assert _thief_binds(p) and _thief_binds(p, "0.0.0.0"), f"a thief bound port {p}"
            *_, term, trunc, info = env.step(np.array([0.1], np.float32))
            n += 1
            if term or trunc:
                break
        assert info["end_reason"] == "HORIZON" and info["commands_unheard_steps"] == 0
        log = env.client.fetch_log()
        c = log.meta.counters
        assert c["commands_acted"] == n == c["commands_accepted"], c
        assert c["host_silent_steps"] == 0 and c["host_silent_from_step"] == -1
    finally:
        if env is not None:
            env.close()
        target.stop()
        th.join(10)


def test_a_target_whose_port_a_thief_holds_refuses_to_start_naming_it():
    """A thief that bound the port first (SO_REUSEPORT) keeps it: the target does not share it,
    and says which address it cannot bind."""
    thief = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    thief.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    thief.bind(("127.0.0.1", 0))
    try:
        addr = f"udp://127.0.0.1:{thief.getsockname()[1]}"
        with pytest.raises(OSError, match=f"cannot bind {addr}"):
            Target(VirtualRig("rig"), bind=addr, config=TargetConfig(lockstep=True))
    finally:
        thief.close()


def test_when_the_hosts_datagrams_stop_arriving_the_loop_and_the_host_say_so():
    """Real time: once the host has seen step 5, a relay drops everything the host sends (as a
    thief would take it).  The target's loop counts every later step HOST_SILENT (its log's
    ``host_silent_steps``, ``host_silent_from_step``, and a note naming it); the host counts the
    steps whose OBSERVATION says none of its commands acted (``info["commands_unheard_steps"]``)
    and warns once (RigCommandsUnheard).  Whatever this machine's load, no command arrives after
    the cut, so those counts have a floor; before it a relayed command may be late as well."""
    target, th = _serve(max_gap_s=10.0, link_timeout_s=30.0)
    proxy = LossyProxy(target.address)
    env = None
    try:
        env = RigEnv(proxy.address, key=KEY, hold_ticks=4, horizon=0.2, terminate_on_catch=False,
                     timeout_s=0.2, retries=25, first_command_timeout_s=1.0)
        env.reset(seed=4)
        cut_step = -1
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            while True:
                *_, term, trunc, info = env.step(np.array([0.1], np.float32))
                if term or trunc:
                    break
                if cut_step < 0 and info["step"] >= 5:
                    proxy.cut, cut_step = True, info["step"]
        assert cut_step >= 5 and proxy.counts["cut"] >= 1  # the fault happened
        unheard = [w for w in caught if issubclass(w.category, RigCommandsUnheard)]
        assert len(unheard) == 1 and "acted on none of this host's COMMANDs" in str(unheard[0].message)
        assert info["commands_unheard_steps"] >= 3
        proxy.cut = False
        log = env.client.fetch_log()
        c = log.meta.counters
        steps = round(0.2 * target.rate) // 4  # the horizon's policy steps
        assert log.meta.end_reason == "HORIZON"
        assert c["host_silent_steps"] >= steps - cut_step - 3, (c, cut_step)
        assert 0 <= c["host_silent_from_step"] <= cut_step + 1
        assert any("HOST_SILENT" in note for note in target.notes)
    finally:
        if env is not None:
            env.close()
        proxy.close()
        target.stop()
        th.join(10)
