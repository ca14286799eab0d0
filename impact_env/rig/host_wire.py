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

:func:`run_policy` is a whole host-mode episode in one call: a compiled policy
(:func:`impact_env.control.policy.act`) answers each OBSERVATION as it comes, so that nothing of
Python's stands between an observation and its COMMAND (``RigClient.run_policy``).
"""

from __future__ import annotations

from impact_env._borrow import borrow
from impact_env._jit import jit
from impact_env.control.policy import act
from impact_env.rig import protocol, wire
from impact_env.rig.cfunc import call_poll, call_recvfrom

# what exchange() returns: the newest OBSERVATION is in Wire.out; Python has a queued datagram to
# look at (none observed yet); the time ran out; (run_policy) the episode's last OBSERVATION came
OBSERVED, QUEUED, TIMEOUT, LAST = 1, 2, 3, 4


@jit
def classify_observation(w, n, episode, min_step):
    """The datagram of ``n`` bytes in ``w.rx`` from ``w.src``, as the host's filter would take it:
    an OBSERVATION of the target's (counted by reason in ``w.c``; one of ``episode`` at ``min_step``
    or later, newer than the one held, copied to ``w.out``) or, anything else, queued."""
    c, d, o = w.c, w.rx, wire.NONCE
    if (
        n < protocol.OVERHEAD
        or not wire.from_peer(w)
        or d[o + wire.H_TYPE] != wire.T_OBSERVATION
        or d[o + wire.H_MAJOR] != protocol.VERSION_MAJOR
        or d[o] != wire.MAGIC[0]
        or d[o + 1] != wire.MAGIC[1]
        or d[o + 2] != wire.MAGIC[2]
        or d[o + 3] != wire.MAGIC[3]
    ):
        wire.enqueue(w, n)
        return
    plen = wire.get_uint(d, o + wire.H_PLEN, 2)
    if protocol.HEADER_SIZE + plen + protocol.TAG_SIZE != n:
        c.corrupt[0] += 1
        return
    if not wire.tag_checks(w, protocol.HEADER_SIZE + plen):
        c.unauthenticated[0] += 1
        return
    newer = d[o + wire.H_MINOR] > protocol.VERSION_MINOR
    pl = o + protocol.HEADER_SIZE
    if plen < wire.O_FIXED:
        c.corrupt[0] += 1
        return
    dtype = d[pl + wire.O_DTYPE]
    n_obs = wire.get_uint(d, pl + wire.O_COUNT, 2)
    m = wire.get_uint(d, pl + wire.O_TELEMETRY, 2)
    if (dtype != 4 and dtype != 8) or m > protocol.MAX_VALUES or n_obs > protocol.MAX_VALUES:
        c.corrupt[0] += 1
        return
    need = wire.O_FIXED + dtype * n_obs + 8 * m
    if plen < need or (not newer and plen != need):
        c.corrupt[0] += 1
        return
    if wire.get_uint(d, o + wire.H_SESSION, 4) != w.session:
        c.wrong_session[0] += 1
        return
    c.authentic[0] += 1
    new = wire.fresh(w, wire.get_uint(d, o + wire.H_SEQ, 4))
    if new == 0:
        c.duplicate[0] += 1
        return
    if new < 0:
        c.out_of_order[0] += 1
        return
    c.accepted[0] += 1
    st = w.st
    step = wire.get_uint(d, pl + wire.O_STEP, 4)
    ep = wire.get_uint(d, pl + wire.O_EPISODE, 4)
    if ep != episode or step < min_step or (st.got[0] and step <= st.out_step[0]):
        return
    q = pl + wire.O_FIXED
    out = w.out
    for i in range(n_obs):
        out[i] = wire.get_f32(d, q, w) if dtype == 4 else wire.get_f64(d, q, w)
        q += dtype
    for i in range(m):
        out[n_obs + i] = wire.get_f64(d, q, w)
        q += 8
    st.got[0] = 1
    st.out_step[0] = step
    st.out_status[0] = wire.get_uint(d, pl + wire.O_STATUS, 4)
    st.out_dtype[0] = dtype
    st.out_n[0] = n_obs
    st.out_m[0] = m


@jit
def send_command(w, episode, step, action, seq, host_ns):
    """The one-action COMMAND of ``step`` (protocol.command_datagram's bytes), sent to the target."""
    t, o = w.tx, wire.NONCE
    for k in range(4):
        t[o + k] = wire.MAGIC[k]
    t[o + wire.H_MAJOR] = protocol.VERSION_MAJOR
    t[o + wire.H_MINOR] = protocol.VERSION_MINOR
    t[o + wire.H_TYPE] = wire.T_COMMAND
    t[o + wire.H_FLAGS] = 0
    wire.put_uint(t, o + wire.H_SESSION, 4, w.session)
    wire.put_uint(t, o + wire.H_SEQ, 4, seq)
    wire.put_uint(t, o + wire.H_TICK, 8, 0)
    wire.put_uint(t, o + wire.H_HOST_NS, 8, host_ns)
    wire.put_uint(t, o + wire.H_TARGET_NS, 8, 0)
    wire.put_uint(t, o + wire.H_PLEN, 2, wire.C_FIXED + 8)
    pl = o + protocol.HEADER_SIZE
    wire.put_uint(t, pl + wire.C_EPISODE, 4, episode)
    wire.put_uint(t, pl + wire.C_STEP, 4, step)
    wire.put_uint(t, pl + wire.C_COUNT, 2, 1)
    wire.put_f64(t, pl + wire.C_FIXED, action, w)
    wire.send_frame(w, protocol.HEADER_SIZE + wire.C_FIXED + 8)


@jit(nogil=True)
def exchange(w, send, episode, step, action, seq, min_step, spin_ns, timeout_ns):
    """``send``: the COMMAND of ``step`` first (sequence number ``seq``); then wait, at most
    ``timeout_ns``, for an OBSERVATION of ``episode`` at ``min_step`` or later (polling for
    ``spin_ns``, then asleep in poll()); once one has come, read whatever else is waiting (the
    newest wins).  Returns OBSERVED, QUEUED (a datagram for Python came first) or TIMEOUT."""
    w = borrow(w)
    t0 = wire.now_ns(w)
    if send:
        send_command(w, episode, step, action, seq, t0)
    st = w.st
    st.got[0] = 0
    while True:
        w.srclen[0] = wire.SOCKADDR
        n = call_recvfrom(
            w.calls.recvfrom, w.fd, w.rx, wire.NONCE, wire.RX_MAX, wire.MSG_DONTWAIT, w.src, w.srclen
        )
        if n >= 0:
            w.c.received[0] += 1
            h = w.q_head[0]
            classify_observation(w, n, episode, min_step)
            if w.q_head[0] != h and st.got[0] == 0:
                return QUEUED
            continue
        if st.got[0]:
            return OBSERVED
        waited = wire.now_ns(w) - t0
        if waited >= timeout_ns:
            return TIMEOUT
        if waited >= spin_ns:
            call_poll(w.calls.poll, w.pfd, 1, min(5, 1 + (timeout_ns - waited) // 1_000_000))


@jit(nogil=True)
def run_policy(w, pi, pf, mem, episode, step, send, last_step, seq, spin_ns, timeout_ns, actions):
    """Host mode with the policy compiled here: the OBSERVATION of ``step`` is in ``w.out``; act
    on it (the packed policy ``pi``, ``pf``, its memory ``mem``), send that COMMAND (sequence
    number ``seq``, then the next ones), await the next OBSERVATION (:func:`exchange`) and answer
    it the same way, until the OBSERVATION of ``last_step`` has come (LAST), or :func:`exchange`
    returns QUEUED or TIMEOUT for Python to look at.  ``send`` False: the COMMAND of ``step`` was
    sent already (its action in ``actions[step]``); only wait.  Each answered step's command goes
    to ``actions[step]``.  Returns (code, the step of the newest OBSERVATION, the next sequence
    number)."""
    st = w.st
    while True:
        if send:
            a = act(pi, pf, w.out[:st.out_n[0]], mem)
            actions[step] = a
        else:
            a = actions[step]
        code = exchange(w, send, episode, step, a, seq, step + 1, spin_ns, timeout_ns)
        if send:
            seq = (seq + 1) & protocol.U32
        send = True
        if code != OBSERVED:
            return code, step, seq
        step = st.out_step[0]
        if step >= last_step:
            return LAST, step, seq
