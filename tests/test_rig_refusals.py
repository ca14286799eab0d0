"""Every refusal answered: an ARM or a COMMAND with a field out of range gets an ERROR naming the
field and its range, no larger than the request, within a per-source rate; every ARM field is
bounded (the timeouts by the target's longest episode), and a COMMAND carries exactly the armed
number of actions.  A keyed lock-step target in a thread of this process, on loopback; seeded
fuzzing, every wait bounded."""

from __future__ import annotations

import random
import struct
import threading
import time

import pytest

from impact_env.rig import protocol
from impact_env.rig.driver import VirtualRig
from impact_env.rig.host import RigClient
from impact_env.rig.target import Target, TargetConfig

KEY = bytes(range(50, 82))
ARM_FMT = struct.Struct("<BBBBHQIIII32s")  # protocol.Arm.FMT: mode, observation, history, options, ...


@pytest.fixture(scope="module")
def served():
    target = Target(VirtualRig("rig"), config=TargetConfig(lockstep=True, key=KEY, max_horizon_s=1.0))
    th = threading.Thread(target=target.serve, daemon=True)
    th.start()
    client = RigClient(target.address, key=KEY, timeout_s=0.2, retries=10)
    yield target, client
    client.close()
    target.stop()
    th.join(10)


def _frame(client: RigClient, mtype: int, payload: bytes) -> bytes:
    """A datagram of the client's session, well tagged, whatever its payload holds."""
    link = client.link
    seq, link.seq = link.seq, (link.seq + 1) & protocol.U32
    head = protocol.HEADER.pack(
        protocol.MAGIC,
        protocol.VERSION_MAJOR,
        protocol.VERSION_MINOR,
        mtype,
        0,
        link.session,
        seq,
        0,
        0,
        0,
        len(payload),
    )
    frame = head + payload
    return frame + protocol.tag(KEY, link.filter.nonce, frame)


def _reply(client: RigClient, request: bytes, wait_s: float = 5.0) -> tuple[protocol.Message, int] | None:
    """The reply (ERROR or ARMED) answering ``request`` (by sequence number), and its size."""
    seq = struct.unpack_from("<I", request, 12)[0]
    deadline = time.monotonic() + wait_s
    while (left := deadline - time.monotonic()) > 0:
        got = client.endpoint.recv(left)
        if got is None:
            return None
        data, _ = got
        try:
            msg = protocol.decode(data, KEY, client.link.filter.nonce)
        except protocol.ProtocolError:
            continue
        if (
            msg.type == protocol.MsgType.ERROR and msg.body.ref_seq == seq
        ) or msg.type == protocol.MsgType.ARMED:
            return msg, len(data)
    return None


def _draw_arm(r: random.Random, top: int) -> tuple[tuple, set[str]]:
    """An ARM's fields, each valid or out of range at random, and the names of those out."""
    bad: set[str] = set()

    def pick(name, good, out):
        if r.random() < 0.2:
            bad.add(name)
            return r.choice(out)
        return good

    hold = pick("hold_ticks", r.choice([1, 4, 10]), [0])
    horizon = pick("horizon_ticks", 40 * hold, [0, top + 1, 2**32 - 1, 40 * hold + 1 if hold > 1 else 0])
    fields = (pick("mode", 1, [0, 3, 255]), pick("observation", 0, [3, 7, 255]),
              pick("history", r.choice([1, 2]), [0, 65, 255]), pick("options", r.choice([0, 1]), [8, 255]),
              hold, r.getrandbits(64), horizon,
              pick("first_command_timeout_ticks", r.choice([0, 100]), [top + 1, 2**32 - 1]),
              pick("link_timeout_ms", r.choice([0, 500]), [1001, 2**32 - 1]), 0, bytes(32))
    return fields, bad


def test_arm_field_fuzzing_every_arm_is_answered_armed_or_refused_by_field(served):
    """60 seeded ARMs, each field in or out of its range at random: an ARM with no field out
    is ARMED; every other is answered with an ERROR whose text names one of its fields out of
    range, and its range; no reply is larger than its ARM.  Paced under the refusals' rate."""
    target, client = served
    r = random.Random(36)
    top = target.max_horizon_ticks
    outcomes = {"armed": 0, "refused": 0}
    for _ in range(60):
        fields, bad = _draw_arm(r, top)
        data = _frame(client, protocol.MsgType.ARM, ARM_FMT.pack(*fields))
        client.endpoint.send(data)
        got = _reply(client, data)
        assert got is not None, f"no reply to ARM {fields} (out of range: {bad})"
        msg, size = got
        assert size <= len(data)
        if not bad:
            assert msg.type == protocol.MsgType.ARMED, (fields, msg)
            outcomes["armed"] += 1
        else:
            assert msg.type == protocol.MsgType.ERROR, (fields, bad, msg)
            assert msg.body.code in (protocol.ErrorCode.OUT_OF_RANGE, protocol.ErrorCode.BAD_REQUEST)
            named = msg.body.text.split("=")[0].split(":")[0]
            assert named in bad, (fields, bad, msg.body.text)
            assert "[" in msg.body.text or "%" in msg.body.text, msg.body.text  # its range, or the rule
            outcomes["refused"] += 1
        time.sleep(0.03)
    assert outcomes["armed"] >= 3 and outcomes["refused"] >= 20, outcomes


def test_an_onboard_arm_without_a_policy_and_out_of_range_timeouts_are_refused_by_name(served):
    target, client = served
    top = target.max_horizon_ticks
    for fields, name in [((2, 0, 1, 0, 4, 1, 40, 0, 0, 0, bytes(32)), "policy_size=0"),
                         ((1, 0, 1, 0, 4, 1, 40, 2**32 - 1, 0, 0, bytes(32)),
                          f"first_command_timeout_ticks=4294967295 [0,{top}]"),
                         ((1, 0, 1, 0, 4, 1, 40, 0, 2**32 - 1, 0, bytes(32)),
                          "link_timeout_ms=4294967295 [0,1000]")]:
        data = _frame(client, protocol.MsgType.ARM, ARM_FMT.pack(*fields))
        client.endpoint.send(data)
        msg, size = _reply(client, data)
        assert msg.type == protocol.MsgType.ERROR and msg.body.text.startswith(name) and size <= len(data)
        time.sleep(0.03)


def _command(client: RigClient, step: int, actions: list[float]) -> bytes:
    payload = struct.pack("<IIH", client.episode, step, len(actions))
    payload += struct.pack(f"<{len(actions)}d", *actions)
    return _frame(client, protocol.MsgType.COMMAND, payload)


def test_command_field_fuzzing_only_the_armed_count_acts_and_every_other_is_refused(served):
    """A host-mode episode (lock-step, 40 ticks at hold 4): at each step COMMANDs of 0, 2, 3 or
    4096 actions (each answered by an ERROR naming the count, ``n=K [1,1]`` cut to the request's
    size, which for 0 actions leaves the name) before the step's one valid COMMAND; the log
    counts the valid ones only, and no refused one drove a force (the 2-action ones say 1.0)."""
    target, client = served
    r = random.Random(7)
    client.arm("host", 5, 40, hold_ticks=4)
    refused = 0
    for step in range(10):
        obs = client.observation(step, 2.0)
        assert isinstance(obs, protocol.Observation) and obs.step == step
        for _ in range(2):
            n = r.choice([0, 2, 3, 4096])
            data = _command(client, step, [1.0] * n)
            client.endpoint.send(data)
            msg, size = _reply(client, data)
            assert msg.type == protocol.MsgType.ERROR and msg.body.code == protocol.ErrorCode.OUT_OF_RANGE
            assert f"n={n} [1,1]".startswith(msg.body.text) and msg.body.text.startswith("n=")
            assert size <= len(data)
            refused += 1
        client.command(step, 0.0)
    end = client.wait_end(5.0)
    assert end.reason == protocol.EndReason.HORIZON
    log = client.fetch_log()
    c = log.meta.counters
    assert c["commands_accepted"] == 10 == c["commands_acted"], c
    assert c["dropped_corrupt"] >= refused
    assert float(abs(log["force_demand_N"]).max()) == 0.0


def test_refusals_are_rate_limited_per_source_and_counted(served):
    """100 bad ARMs at once: the first ones (the bucket's 32) are answered, the rest counted
    ``refusals_limited``; answered + limited = 100."""
    target, client = served
    f = target.link.filter
    limited0 = f.refusals_limited
    time.sleep(1.0)  # the bucket refills
    sent = [_frame(client, protocol.MsgType.ARM, ARM_FMT.pack(0, 0, 1, 0, 4, 1, 40, 0, 0, 0, bytes(32)))
            for _ in range(100)]
    for data in sent:
        client.endpoint.send(data)
    answered = 0
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline and answered + f.refusals_limited - limited0 < 100:
        got = client.endpoint.recv(0.2)
        if got is not None:
            answered += protocol.decode(got[0], KEY, client.link.filter.nonce).type == protocol.MsgType.ERROR
    assert answered + f.refusals_limited - limited0 == 100
    assert 32 <= answered < 100
