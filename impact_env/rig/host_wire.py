"""The host's side of the wire in compiled code: a policy step's COMMAND sent and the next
OBSERVATION awaited, read, authenticated and decoded in one call that releases the GIL
(:func:`exchange`), so that a host in real time answers the target within the tick the target
waits for it (``rig serve --command-wait``; docs/rig/timing.md).

It is :mod:`impact_env.rig.wire`'s other half, on the same :class:`~impact_env.rig.wire.Wire`:
an OBSERVATION from the target is classified as :class:`impact_env.rig.protocol.DatagramFilter`
would (length, tag, payload, session, the OBSERVATION stream's window) and, if it belongs to the
episode and is of the step awaited or later, its values are copied to ``Wire.out`` (the newest
one wins: a host slower than the target's steps answers the newest); every other datagram (an
EPISODE_END, an ERROR, a stranger's) is queued for Python, which puts it through the filter.
While it waits the call polls the socket for ``spin`` ns, then sleeps in ``poll()``.
"""

from __future__ import annotations

from impact_env._borrow import borrow
from impact_env._jit import jit
from impact_env.rig import protocol as P
from impact_env.rig import wire as WR
from impact_env.rig.cfunc import call_poll, call_recvfrom

# what exchange() returns: the newest OBSERVATION is in Wire.out; Python has a queued datagram to
# look at (none observed yet); the time ran out
OBSERVED, QUEUED, TIMEOUT = 1, 2, 3
OBS_FIXED = 17  # bytes of an OBSERVATION's fixed payload fields (protocol.Observation.FMT)
assert P.Observation.FMT.size == OBS_FIXED and P.Command.FMT.size == 10


@jit
def classify_observation(w, n, episode, min_step):
    """The datagram of ``n`` bytes in ``w.rx`` from ``w.src``, as the host's filter would take it:
    an OBSERVATION of the target's (counted by reason in ``w.c``; one of ``episode`` at ``min_step``
    or later, newer than the one held, copied to ``w.out``) or, anything else, queued."""
    c, d, o = w.c, w.rx, WR.NONCE
    if (n < P.OVERHEAD or not WR.from_peer(w) or d[o + WR.H_TYPE] != WR.T_OBSERVATION
            or d[o + WR.H_MAJOR] != P.VERSION_MAJOR or d[o] != WR.MAGIC[0] or d[o + 1] != WR.MAGIC[1]
            or d[o + 2] != WR.MAGIC[2] or d[o + 3] != WR.MAGIC[3]):
        WR.enqueue(w, n)
        return
    plen = WR.get_uint(d, o + WR.H_PLEN, 2)
    if P.HEADER_SIZE + plen + P.TAG_SIZE != n:
        c.corrupt[0] += 1
        return
    if not WR.tag_checks(w, P.HEADER_SIZE + plen):
        c.unauthenticated[0] += 1
        return
    newer = d[o + WR.H_MINOR] > P.VERSION_MINOR
    pl = o + P.HEADER_SIZE
    if plen < OBS_FIXED:
        c.corrupt[0] += 1
        return
    dtype = d[pl + 12]
    n_obs = WR.get_uint(d, pl + 13, 2)
    m = WR.get_uint(d, pl + 15, 2)
    if (dtype != 4 and dtype != 8) or m > P.MAX_VALUES or n_obs > P.MAX_VALUES:
        c.corrupt[0] += 1
        return
    need = OBS_FIXED + dtype * n_obs + 8 * m
    if plen < need or (not newer and plen != need):
        c.corrupt[0] += 1
        return
    if WR.get_uint(d, o + WR.H_SESSION, 4) != w.session:
        c.wrong_session[0] += 1
        return
    c.authentic[0] += 1
    new = WR.fresh(w, WR.get_uint(d, o + WR.H_SEQ, 4))
    if new == 0:
        c.duplicate[0] += 1
        return
    if new < 0:
        c.out_of_order[0] += 1
        return
    c.accepted[0] += 1
    st = w.st
    step = WR.get_uint(d, pl + 4, 4)
    if WR.get_uint(d, pl, 4) != episode or step < min_step or (st.got[0] and step <= st.out_step[0]):
        return
    q = pl + OBS_FIXED
    out = w.out
    for i in range(n_obs):
        out[i] = WR.get_f32(d, q, w) if dtype == 4 else WR.get_f64(d, q, w)
        q += dtype
    for i in range(m):
        out[n_obs + i] = WR.get_f64(d, q, w)
        q += 8
    st.got[0] = 1
    st.out_step[0] = step
    st.out_status[0] = WR.get_uint(d, pl + 8, 4)
    st.out_dtype[0] = dtype
    st.out_n[0] = n_obs
    st.out_m[0] = m


@jit
def send_command(w, episode, step, action, seq, host_ns):
    """The one-action COMMAND of ``step`` (protocol.command_datagram's bytes), sent to the target."""
    t, o = w.tx, WR.NONCE
    for k in range(4):
        t[o + k] = WR.MAGIC[k]
    t[o + WR.H_MAJOR] = P.VERSION_MAJOR
    t[o + WR.H_MINOR] = P.VERSION_MINOR
    t[o + WR.H_TYPE] = WR.T_COMMAND
    t[o + WR.H_FLAGS] = 0
    WR.put_uint(t, o + WR.H_SESSION, 4, w.session)
    WR.put_uint(t, o + WR.H_SEQ, 4, seq)
    WR.put_uint(t, o + WR.H_TICK, 8, 0)
    WR.put_uint(t, o + WR.H_HOST_NS, 8, host_ns)
    WR.put_uint(t, o + WR.H_TARGET_NS, 8, 0)
    WR.put_uint(t, o + WR.H_PLEN, 2, 18)
    pl = o + P.HEADER_SIZE
    WR.put_uint(t, pl, 4, episode)
    WR.put_uint(t, pl + 4, 4, step)
    WR.put_uint(t, pl + 8, 2, 1)
    WR.put_f64(t, pl + 10, action, w)
    WR.send_frame(w, P.HEADER_SIZE + 18)


@jit(nogil=True)
def exchange(w, send, episode, step, action, seq, min_step, spin_ns, timeout_ns):
    """``send``: the COMMAND of ``step`` first (sequence number ``seq``); then wait, at most
    ``timeout_ns``, for an OBSERVATION of ``episode`` at ``min_step`` or later (polling for
    ``spin_ns``, then asleep in poll()); once one has come, read whatever else is waiting (the
    newest wins).  Returns OBSERVED, QUEUED (a datagram for Python came first) or TIMEOUT."""
    w = borrow(w)
    t0 = WR.now_ns(w)
    if send:
        send_command(w, episode, step, action, seq, t0)
    st = w.st
    st.got[0] = 0
    while True:
        w.srclen[0] = WR.SOCKADDR
        n = call_recvfrom(w.calls.recvfrom, w.fd, w.rx, WR.NONCE, WR.RX_MAX, WR.MSG_DONTWAIT, w.src, w.srclen)
        if n >= 0:
            w.c.received[0] += 1
            h = w.q_head[0]
            classify_observation(w, n, episode, min_step)
            if w.q_head[0] != h and st.got[0] == 0:
                return QUEUED
            continue
        if st.got[0]:
            return OBSERVED
        waited = WR.now_ns(w) - t0
        if waited >= timeout_ns:
            return TIMEOUT
        if waited >= spin_ns:
            call_poll(w.calls.poll, w.pfd, 1, min(5, 1 + (timeout_ns - waited) // 1_000_000))
