"""Lock-free rings between the target's Python threads and its compiled real-time loop
(:mod:`impact_env.rig.rtloop`), after robot_interfaces' time series: one writer per ring, each
entry stamped with a sequence number, the head (entries written) stored after the entry it
announces, and a reader that takes the newest entry by sequence number and checks it was not
overwritten while it read.  The arrays are plain numpy arrays shared by the threads of one
process (the compiled loop runs with the GIL released).

* the observation ring (writer: the loop; reader: the target's Python side): at each step
  boundary of host mode, the step's observation and telemetry, as the loop sent it to the host
  (:mod:`impact_env.rig.wire`: the loop sends and receives host mode's datagrams itself; the
  datagrams it does not take reach the network thread through the wire's queue).
* ``shared``: single-word values the loop publishes (the tick it is at, rows of the log
  complete, its end) and the stop word the Python side sets (a DISARM, a signal, a lost link).
* the command state ``cs`` and counts ``cc``: what the loop did with the host's commands, read
  by Python at the episode's end.

Ordering: the loop fences (:func:`impact_env.rig.cfunc.fence`) between an entry and its head;
on the Python side the stores of one thread reach memory in program order on x86-64 (TSO), which
is what the writer relies on (an arm64 target would need a fence there too).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from impact_env._packed import positions

N_OBS = 16  # observation slots


class Shared(NamedTuple):
    """The shared int64 words: what the loop publishes, and the stop word Python sets."""

    tick: int  # the tick the loop is at
    rows: int  # log rows complete
    obs_head: int  # observations published
    stop: int  # set by Python: 0 N, the loop ends
    done: int  # set by the loop at its end


SH = positions(Shared)
N_SHARED = len(SH)


class ObsMeta(NamedTuple):
    """An observation slot's metadata (float64 columns)."""

    step: int
    tick: int
    status: int
    demand: int  # N
    applied: int  # N
    age: int  # ticks since the command in use first acted (-1: none)


OM = positions(ObsMeta)
N_OM = len(OM)


class CommandState(NamedTuple):
    """The loop's command state (float64, kept in an array so Python reads it at the end)."""

    next_step: int  # the newest accepted command not yet in use: its step (-1: none)
    next_val: int
    cur_step: int  # the command in use (-1: none)
    cur_val: int
    cur_id: int
    cur_acted: int  # 1 once it has acted on a tick
    n_cmd: int  # commands taken into use
    heard_step: int  # the latest step an accepted command was for (-1: none yet)
    late_heard: int  # 1 once a COMMAND of this episode came after its step was over


CS = positions(CommandState)
N_CS = len(CS)


class CommandCounts(NamedTuple):
    """What became of the commands (int64, written by the loop)."""

    acted: int
    superseded: int
    expired: int
    # steps at whose end no command of the host's had been accepted for it (or a later step):
    # the host's datagrams stopped arriving in time (lost, late, or taken)
    silent_steps: int
    silent_from: int  # the first such step (-1: none)


CC = positions(CommandCounts)
N_CC = len(CC)


class HostLink(NamedTuple):
    """The arrays the compiled loop shares with the target's Python threads."""

    obs: np.ndarray  # float64[N_OBS, obs size]
    obs_meta: np.ndarray  # float64[N_OBS, N_OM]
    shared: np.ndarray  # int64[N_SHARED]
    cs: np.ndarray  # float64[N_CS]
    cc: np.ndarray  # int64[N_CC]
    wake: np.ndarray  # int64[3]: libc write's address, the pipe's write end (-1: none), usleep's address
    byte: np.ndarray  # uint8[1]: what is written to the pipe
    telem: np.ndarray  # float64[3]: the telemetry of the OBSERVATION being made (TELEMETRY_FIELDS)


def host_link(obs_size: int, write_addr: int = 0, wake_fd: int = -1, usleep_addr: int = 0) -> HostLink:
    link = HostLink(np.zeros((N_OBS, max(1, obs_size))), np.zeros((N_OBS, N_OM)),
                    np.zeros(N_SHARED, np.int64), np.zeros(N_CS), np.zeros(N_CC, np.int64),
                    np.array([write_addr, wake_fd, usleep_addr], np.int64), np.ones(1, np.uint8), np.zeros(3))
    reset(link)
    return link


def reset(link: HostLink) -> None:
    link.shared[:] = 0
    link.cs[:] = 0.0
    link.cs[CS.next_step] = -1.0
    link.cs[CS.cur_step] = -1.0
    link.cs[CS.cur_id] = -1.0
    link.cs[CS.cur_acted] = 1.0
    link.cs[CS.heard_step] = -1.0
    link.cc[:] = 0
    link.cc[CC.silent_from] = -1


def newest_observation(link: HostLink, after: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The newest observation published after the ``after``-th one (its metadata row and the
    observation, copies), or None; None too if the loop overwrote it while it was read."""
    head = int(link.shared[SH.obs_head])
    if head <= after:
        return None
    j = (head - 1) % N_OBS
    meta = link.obs_meta[j].copy()
    obs = link.obs[j].copy()
    if int(link.shared[SH.obs_head]) - head >= N_OBS - 1:  # lapped while copying: a newer one comes
        return None
    return meta, obs
