"""The rig's wire protocol (impact_env.rig.protocol): golden bytes, round trips, the datagram filter
and a fuzz run of 10^5 datagrams."""

from __future__ import annotations

import hashlib
import hmac
import random
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from impact_env.rig import protocol

SHA_SCENE = hashlib.sha256(b"scene").digest()  # 4f48f7207cebf926...
SHA_POLICY = hashlib.sha256(b"policy").digest()  # 823412d1eacb6795...
HEAD = dict(session=0x01020304, seq=5, tick=10000, host_ns=1_000_000_007, target_ns=2_000_000_011)

# Header bytes common to every golden message, then per message: type byte, payload length,
# payload, tag (HMAC-SHA256 under GOLDEN_KEY with the session nonce GOLDEN_NONCE, 16 bytes).
# Header: magic "IMPR" | major 04 | minor 00 | type | flags 00 | session 04030201 |
# seq 05000000 | tick 1027000000000000 (10000) | host_ns 07ca9a3b00000000 (1000000007) |
# target_ns 0b94357700000000 (2000000011) | payload length (u16).
MAGIC_VER = "494d5052" "04" "00"
GOLDEN_KEY = bytes(range(32))
GOLDEN_NONCE = 0x0123456789ABCDEF
HOST_NONCE = bytes.fromhex("00112233445566778899aabbccddeeff")
TARGET_NONCE = bytes.fromhex("ffeeddccbbaa99887766554433221100")
AFTER_TYPE = "00" "04030201" "05000000" "1027000000000000" "07ca9a3b00000000" "0b94357700000000"

GOLDEN = [
    # nonce | 64 zero bytes of padding
    (protocol.Hello(nonce=HOST_NONCE), "01", "5000", HOST_NONCE.hex() + "00" * 64,
     "87f1f837ab21b7b69f3b8af5190e68ab"),
    (protocol.Challenge(nonce=HOST_NONCE, target_nonce=TARGET_NONCE), "0f", "2000",
     HOST_NONCE.hex() + TARGET_NONCE.hex(), "5e4cdbc2ba886214f0b12d5045d42024"),
    # nonce | target nonce | 48 zero bytes of padding
    (protocol.Response(nonce=HOST_NONCE, target_nonce=TARGET_NONCE), "10", "5000",
     HOST_NONCE.hex() + TARGET_NONCE.hex() + "00" * 48, "d504be07cf70e619815a5f31bd5b7826"),
    (protocol.Info(nonce=HOST_NONCE, control_rate_hz=1e4, state=protocol.TargetState.IDLE, driver=0,
                   lockstep=True, scene_size=2345, scene_sha256=SHA_SCENE, session_nonce=0x1122334455667788,
                   keyed=True, session_port=5601),
     "02", "4a00",
     # nonce (16 B) | rate 1e4 (f64) | state 00 | driver 00 | lockstep 01 | scene_size 2345 | sha256 |
     # session_nonce (u64) | keyed 01 | session_port 5601
     HOST_NONCE.hex() + "000000000088c340" "00" "00" "01" "29090000" + SHA_SCENE.hex() + "8877665544332211"
     "01" "e115",
     "b37854aadca05fcf0bb3ffe8c296a76b"),
    (protocol.Arm(mode="onboard", observation="sensors", history=2, options=protocol.ARM_TERMINATE_ON_CATCH,
                  hold_ticks=10, seed=42, horizon_ticks=4000, first_command_timeout_ticks=1000,
                  link_timeout_ms=500, policy_size=100000, policy_sha256=SHA_POLICY), "03", "3e00",
     # mode 02 | obs 00 | history 02 | options 01 | hold 10 | seed 42 | horizon 4000 | timeout 1000 |
     # link 500 ms | size 100000 | sha256
     "02" "00" "02" "01" "0a00" "2a00000000000000" "a00f0000" "e8030000" "f4010000" "a0860100"
     + SHA_POLICY.hex(), "16816c4c44f0f8d855cc9d4a42b4c953"),
    (protocol.Armed(episode=3, start_tick=123456, obs_size=10, action_size=1, obs_dtype=4, telemetry_size=2,
                    hold_ticks=10, control_rate_hz=1e4, scene_sha256=SHA_SCENE), "04", "3c00",
     "03000000" "40e2010000000000" "0a00" "0100" "04" "02" "0a00" "000000000088c340" + SHA_SCENE.hex(),
     "e57a56f03fbd17c599ae963272f00b78"),
    (protocol.PolicyChunk(upload_id=0x0807060504030201, total=100000, offset=2048, data=b"\x00\x01\x02\xff"),
     "05", "1600", "0102030405060708" "a0860100" "00080000" "0400" "000102ff",
     "86d5bcd0e49a1c5b39fdeab9db222823"),
    (protocol.Ack(acked_type=protocol.MsgType.POLICY_CHUNK, code=0, acked_seq=77, value=2052), "06", "0e00",
     "05" "00" "4d000000" "0408000000000000", "4e7b34abc9208b49e0b99381f6efe752"),
    (protocol.Command(episode=3, step=7, action=(0.25,)), "07", "1200",
     "03000000" "07000000" "0100" "000000000000d03f", "b36d56ffab122079cedc5d2f91c98f12"),
    (protocol.Observation(episode=3, step=7, status=0x10002, dtype=4, obs=(1.5, -0.25, 0.0),
                          telemetry=(12.5,)),
     "08", "2500",
     # episode | step | status | dtype 04 | n 3 | m 1 (u16) | 1.5f -0.25f 0.0f | 12.5 (f64)
     "03000000" "07000000" "02000100" "04" "0300" "0100" "0000c03f" "000080be" "00000000" "0000000000002940",
     "1877325e8daa95c5c8bf1eaafbe5f6a4"),
    (protocol.EpisodeEnd(episode=3, reason=protocol.EndReason.HORIZON, status=0x4, n_ticks=4000, n_steps=400,
                         data_size=65536, data_sha256=SHA_POLICY), "09", "3900",
     "03000000" "01" "04000000" "a00f000000000000" "90010000" "00000100" + SHA_POLICY.hex(),
     "00691bb4b18483ad71f1fdffea97141d"),
    (protocol.Fetch(resource=protocol.Resource.EPISODE, item=3, offset=1024, max_len=1024), "0a", "0b00",
     "02" "03000000" "00040000" "0004", "1f3c42c8a38bed940d3bd8eb903b17bf"),
    (protocol.Chunk(resource=protocol.Resource.EPISODE, item=3, total=65536, offset=1024, data=b"HDF"),
     "0b", "1200",
     "02" "03000000" "00000100" "00040000" "0300" "484446", "792b7fb1f1dd2d170402fc9be4d7a9b9"),
    (protocol.Disarm(reason=1), "0c", "0100", "01", "22eb6bf5015f35de95eb29a602b50352"),
    (protocol.Heartbeat(state=protocol.TargetState.RUNNING, episode=3, step=7, peer_seq=99), "0d", "0d00",
     "02" "03000000" "07000000" "63000000", "1c7b2a88dd1d5c4fce925cc1b2cfbf17"),
    (protocol.Error(code=protocol.ErrorCode.BUSY, ref_seq=5, text="busy: session 0x1"), "0e", "1900",
     "0200" "05000000" "1100" + b"busy: session 0x1".hex(), "45133ef79e7f45222dc9a3566bfc9689"),
]


def test_golden_cover_every_type():
    assert {type(b) for b, *_ in GOLDEN} == set(protocol.BODIES.values())


@pytest.mark.parametrize("body,mtype,plen,payload,tag", GOLDEN, ids=[type(g[0]).__name__ for g in GOLDEN])
def test_golden_bytes(body, mtype, plen, payload, tag):
    expected = bytes.fromhex(MAGIC_VER + mtype + AFTER_TYPE + plen + payload + tag)
    msg = protocol.Message(body, **HEAD)
    assert protocol.encode(msg, GOLDEN_KEY, GOLDEN_NONCE) == expected
    assert protocol.decode(expected, GOLDEN_KEY, GOLDEN_NONCE) == msg
    # the trailer is the standard library's HMAC-SHA256 of the nonce (0 for the handshake's types
    # and ERROR, sent before both sides know it) and everything before it, cut to 16 bytes
    nonce = (
        0
        if msg.type
        in (
            protocol.MsgType.HELLO,
            protocol.MsgType.CHALLENGE,
            protocol.MsgType.RESPONSE,
            protocol.MsgType.INFO,
            protocol.MsgType.ERROR,
        )
        else GOLDEN_NONCE
    )
    mac = hmac.new(GOLDEN_KEY, nonce.to_bytes(8, "little") + expected[:-16], hashlib.sha256).digest()[:16]
    assert expected[-16:] == mac
    assert len(expected) == protocol.OVERHEAD + len(payload) // 2
    # another key, no key, or (but for the open types) another session nonce: refused
    with pytest.raises(protocol.Unauthenticated):
        protocol.decode(expected, bytes(32), GOLDEN_NONCE)
    with pytest.raises(protocol.Unauthenticated):
        protocol.decode(expected)
    if nonce:
        with pytest.raises(protocol.Unauthenticated):
            protocol.decode(expected, GOLDEN_KEY, GOLDEN_NONCE + 1)


# -- round trips -------------------------------------------------------------------------------------
u8, u16, u32, u64 = (st.integers(0, m) for m in (protocol.U8, protocol.U16, protocol.U32, protocol.U64))
sha = st.binary(min_size=32, max_size=32)
rate = st.floats(min_value=1e-3, max_value=1e9)
f64 = st.floats(allow_nan=False)
f32 = st.floats(width=32, allow_nan=False)


@st.composite
def chunk_like(draw, cls, head):
    data = draw(st.binary(max_size=protocol.CHUNK_DATA))
    total = draw(st.integers(len(data), protocol.MAX_TRANSFER))
    offset = draw(st.integers(0, total - len(data)))
    return cls(*head(draw), total, offset, data)


nonce16 = st.binary(min_size=protocol.NONCE_SIZE, max_size=protocol.NONCE_SIZE)
BODY_STRATEGIES = st.one_of(
    st.builds(protocol.Hello, nonce16),
    st.builds(protocol.Challenge, nonce16, nonce16),
    st.builds(protocol.Response, nonce16, nonce16),
    st.builds(
        protocol.Info,
        nonce16,
        rate,
        st.integers(0, 3),
        st.integers(0, 1),
        st.booleans(),
        u32,
        sha,
        u64,
        st.booleans(),
    ),
    st.builds(
        protocol.Arm,
        st.sampled_from(list(protocol.MODES)),
        st.sampled_from(list(protocol.OBSERVATIONS)),
        st.integers(1, 64),
        u8,
        st.integers(1, protocol.U16),
        u64,
        st.integers(1, protocol.U32),
        u32,
        u32,
        u32,
        sha,
    ),
    st.builds(
        protocol.Armed,
        u32,
        u64,
        st.integers(0, protocol.MAX_VALUES),
        st.integers(0, protocol.MAX_VALUES),
        st.sampled_from([4, 8]),
        st.integers(0, len(protocol.TELEMETRY_FIELDS)),
        st.integers(1, protocol.U16),
        rate,
        sha,
    ),
    chunk_like(protocol.PolicyChunk, lambda d: (d(u64),)),
    st.builds(protocol.Ack, u8, u8, u32, u64),
    st.builds(protocol.Command, u32, u32, st.lists(f64, min_size=1, max_size=8).map(tuple)),
    st.builds(
        protocol.Observation,
        u32,
        u32,
        u32,
        st.just(4),
        st.lists(f32, max_size=40).map(tuple),
        st.lists(f64, max_size=len(protocol.TELEMETRY_FIELDS)).map(tuple),
    ),
    st.builds(
        protocol.Observation,
        u32,
        u32,
        u32,
        st.just(8),
        st.lists(f64, max_size=40).map(tuple),
        st.lists(f64, max_size=len(protocol.TELEMETRY_FIELDS)).map(tuple),
    ),
    st.builds(protocol.EpisodeEnd, u32, u8, u32, u64, u32, u32, sha),
    st.builds(protocol.Fetch, u8, u32, u32, st.integers(1, protocol.U16)),
    chunk_like(protocol.Chunk, lambda d: (d(u8), d(u32))),
    st.builds(protocol.Disarm, st.integers(0, protocol.DISARM_CAUGHT)),
    st.builds(protocol.Heartbeat, u8, u32, u32, u32),
    st.builds(protocol.Error, u16, u32, st.text(max_size=200)),
)


@settings(max_examples=600, deadline=None)
@given(body=BODY_STRATEGIES, session=u32, seq=u32, tick=u64, hns=u64, tns=u64, flags=u8)
def test_round_trip(body, session, seq, tick, hns, tns, flags):
    msg = protocol.Message(body, session, seq, tick, hns, tns, flags)
    data = protocol.encode(msg)
    assert protocol.decode(data) == msg
    assert protocol.encode(protocol.decode(data)) == data
    assert len(data) <= protocol.MAX_DATAGRAM


def test_nan_values_keep_their_bits():
    nan = struct.unpack("<d", bytes.fromhex("010000000000f87f"))[0]  # a quiet NaN with a payload
    data = protocol.encode(protocol.Message(protocol.Command(0, 0, (nan, -0.0, float("inf")))))
    back = protocol.decode(data).body.action
    assert struct.pack("<3d", *back) == struct.pack("<3d", nan, -0.0, float("inf"))
    assert protocol.encode(protocol.decode(data)) == data


def test_float32_observations_are_rounded_on_encode():
    msg = protocol.Message(protocol.Observation(obs=(0.1, 1e-50), dtype=4))
    back = protocol.decode(protocol.encode(msg)).body.obs
    assert back == (struct.unpack("<f", struct.pack("<f", 0.1))[0], 0.0)
    with pytest.raises(ValueError, match="overflows float32"):
        protocol.Observation(obs=(1e39,), dtype=4)


@pytest.mark.parametrize("make,match", [
    (lambda: protocol.Command(0, 0, ()), "action must be a tuple of 1"),
    (lambda: protocol.Command(0, -1, (0.0,)), "step = -1"),
    (lambda: protocol.Command(0, 0, [0.0]), "action must be a tuple"),
    (lambda: protocol.Command(0, 0, (1,)), "Python floats"),
    (lambda: protocol.Arm(mode="remote"), "mode = 'remote'"),
    (lambda: protocol.Arm(hold_ticks=0), r"hold_ticks = 0 must be an integer in \[1, 65535\]"),
    (lambda: protocol.Arm(history=65), "history"),
    (lambda: protocol.Arm(policy_sha256=b"short"), "32 bytes"),
    (lambda: protocol.Info(control_rate_hz=0.0), "control_rate_hz"),
    (lambda: protocol.Chunk(total=10, offset=8, data=b"abc"), "runs past the total"),
    (lambda: protocol.Error(text="x" * 2000), "at most 1024"),
    (lambda: protocol.Message(protocol.Hello(), session=2**32), "session"),
    (lambda: protocol.Hello(nonce=1234), "nonce must be 16 bytes"),
    (lambda: protocol.Response(target_nonce=bytes(8)), "target_nonce must be 16 bytes"),
    (lambda: protocol.Message("hello"), "body must be one of"),
])
def test_invalid_fields_are_refused_with_their_name(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_error_shorten_cuts_at_a_character_boundary():
    e = protocol.Error.shorten(protocol.ErrorCode.BAD_REQUEST, 1, "é" * 1000)  # 2 bytes each
    assert len(e.text.encode()) <= protocol.MAX_TEXT and set(e.text) == {"é"}
    assert protocol.decode(protocol.encode(protocol.Message(e))).body == e


# -- decoding errors ---------------------------------------------------------------------------------
def _with_crc(frame: bytes) -> bytes:
    """``frame`` with the tag of a side without a key (nonce 0)."""
    return frame + protocol.tag(b"", 0, frame)


def _frame(mtype=protocol.MsgType.HELLO, payload=bytes(protocol.Hello.FMT.size), major=protocol.VERSION_MAJOR,
           minor=protocol.VERSION_MINOR, magic=protocol.MAGIC, plen=None, session=1, seq=1):
    head = protocol.HEADER.pack(magic, major, minor, mtype, 0, session, seq, 0, 0, 0,
                                len(payload) if plen is None else plen)
    return _with_crc(head + payload)


@pytest.mark.parametrize(
    "data,exc,detail",
    [
        (b"", protocol.CorruptDatagram, "truncated"),
        (b"IMPR" + bytes(50), protocol.CorruptDatagram, "truncated"),
        (_frame(magic=b"XXXX"), protocol.CorruptDatagram, "magic"),
        (_frame(major=1), protocol.WrongVersion, "major"),
        (_frame(plen=3), protocol.CorruptDatagram, "length"),
        (_frame()[:-1] + b"\0", protocol.Unauthenticated, "HELLO"),
        (_frame(mtype=99), protocol.UnknownType, "type"),
        (_frame(payload=bytes(79)), protocol.CorruptDatagram, "payload"),  # HELLO needs 80 bytes
        (_frame(payload=bytes(81)), protocol.CorruptDatagram, "payload"),  # and exactly 80 at minor 0
        (
            _frame(protocol.MsgType.COMMAND, struct.pack("<IIH", 0, 0, 2) + bytes(8)),
            protocol.CorruptDatagram,
            "payload",
        ),
        # no action, mode 0: authenticated (no key here) fields out of range, which the sender is told
        (_frame(protocol.MsgType.COMMAND, struct.pack("<IIH", 0, 0, 0)), protocol.FieldOutOfRange, "field"),
        (_frame(protocol.MsgType.ARM, bytes(62)), protocol.FieldOutOfRange, "field"),
        (
            _frame(protocol.MsgType.ERROR, struct.pack("<HIH", 1, 0, 2) + b"\xff\xfe"),
            protocol.CorruptDatagram,
            "payload",
        ),
        (
            _frame(
                protocol.MsgType.INFO,
                struct.pack("<16sdBBBI32sQBH", bytes(16), float("nan"), 0, 0, 0, 0, bytes(32), 1, 0, 0),
            ),
            protocol.CorruptDatagram,
            "payload",
        ),
        (
            _frame(protocol.MsgType.CHUNK, struct.pack("<BIIIH", 2, 0, 2, 0, 3) + b"abc"),
            protocol.CorruptDatagram,
            "payload",
        ),
    ],
)
def test_decode_errors(data, exc, detail):
    with pytest.raises(exc) as info:
        protocol.decode(data)
    assert info.value.detail == detail


def test_newer_minor_may_append_fields():
    body = struct.pack("<IIH", 1, 2, 1) + struct.pack("<d", 0.5) + b"appended"
    msg = protocol.decode(_frame(protocol.MsgType.COMMAND, body, minor=protocol.VERSION_MINOR + 1))
    assert msg.body == protocol.Command(1, 2, (0.5,))
    with pytest.raises(protocol.CorruptDatagram):
        protocol.decode(_frame(protocol.MsgType.COMMAND, body))  # the same bytes at our own minor: too long
    with pytest.raises(protocol.UnknownType):
        protocol.decode(_frame(50, b"", minor=protocol.VERSION_MINOR + 1))


# -- the filter ---------------------------------------------------------------------------------------
def _cmd(seq, episode=0, step=0, session=7):
    return protocol.encode(
        protocol.Message(protocol.Command(episode, step, (0.1,)), session=session, seq=seq)
    )


def test_filter_sequence_window():
    f = protocol.DatagramFilter("target", session=7)
    assert f.accept(_cmd(10)) is not None
    assert f.accept(_cmd(10)) is None and f.last_reason == "duplicate"
    assert f.accept(_cmd(12)) is not None
    assert f.accept(_cmd(11)) is None and f.last_reason == "out_of_order"  # never seen, but older
    assert f.accept(_cmd(10)) is None and f.last_reason == "duplicate"  # still in the window
    assert f.accept(_cmd(12 + 63)) is not None
    assert f.accept(_cmd(12)) is None and f.last_reason == "duplicate"  # 63 back: the window's edge
    assert f.accept(_cmd(12 + 64)) is not None
    assert f.accept(_cmd(12)) is None and f.last_reason == "out_of_order"  # left the window
    assert f.counts() == {"accepted": 4, "corrupt": 0, "wrong_version": 0, "unauthenticated": 0,
                          "not_loopback": 0, "stranger": 0, "wrong_session": 0,
                          "unexpected": 0, "duplicate": 3, "out_of_order": 2, "late": 0, "rate_limited": 0,
                          "no_challenge": 0, "queue_full": 0}


def test_filter_sequence_numbers_wrap():
    f = protocol.DatagramFilter("target", session=7)
    assert f.accept(_cmd(protocol.U32 - 1)) is not None
    assert f.accept(_cmd(protocol.U32)) is not None
    assert f.accept(_cmd(0)) is not None  # 2^32 - 1 -> 0 is one step newer
    assert f.accept(_cmd(protocol.U32)) is None and f.last_reason == "duplicate"
    assert f.accept(_cmd(2**31 + 1)) is None and f.last_reason == "out_of_order"  # half a cycle: older


def test_filter_streams_are_per_type():
    f = protocol.DatagramFilter("target", session=7)
    assert f.accept(_cmd(10)) is not None
    # older seq, other type: its own stream
    hb = protocol.encode(protocol.Message(protocol.Heartbeat(), session=7, seq=5))
    assert f.accept(hb) is not None


def test_filter_sessions_and_directions():
    f = protocol.DatagramFilter("target")
    assert f.accept(_cmd(1)) is None and f.last_reason == "wrong_session"  # no session open yet
    hello = protocol.encode(protocol.Message(protocol.Hello(), session=7, seq=0))
    assert f.accept(hello) is not None  # HELLO opens one, whatever the session
    f.session = 7
    assert f.accept(_cmd(1)) is not None
    assert f.accept(_cmd(2, session=8)) is None and f.last_reason == "wrong_session"
    obs = protocol.encode(protocol.Message(protocol.Observation(), session=7, seq=3))
    assert f.accept(obs) is None and f.last_reason == "unexpected"  # target->host type at the target
    h = protocol.DatagramFilter("host", session=7)
    assert h.accept(obs) is not None
    assert h.accept(_cmd(4)) is None and h.last_reason == "unexpected"
    f.session = 7  # setting the session forgets the streams: seq 1 is new again
    assert f.accept(_cmd(1)) is not None
    with pytest.raises(ValueError, match="role"):
        protocol.DatagramFilter("client")


def test_filter_hello_flood_does_not_evict_the_open_session():
    f = protocol.DatagramFilter("target", session=7)
    assert f.accept(_cmd(100)) is not None
    for k in range(3 * protocol.DatagramFilter.MAX_STREAMS):
        hello = protocol.encode(protocol.Message(protocol.Hello(), session=1000 + k, seq=0))
        assert f.accept(hello, sender=("127.0.0.1", 2000 + k)) is not None  # a source each: no rate limit
    assert f.accept(_cmd(50)) is None and f.last_reason == "out_of_order"  # the stream is still known


@pytest.mark.parametrize("cmd_ep,cmd_step,ep,step,ok", [
    (2, 5, 2, 5, True), (2, 6, 2, 5, True), (2, 4, 2, 5, False), (1, 9, 2, 0, False), (3, 0, 2, 9, True)])
def test_filter_late_commands(cmd_ep, cmd_step, ep, step, ok):
    f = protocol.DatagramFilter("target", session=7)
    got = f.accept(_cmd(1, cmd_ep, cmd_step), episode=ep, step=step)
    assert (got is not None) == ok
    assert f.counts()["late"] == (0 if ok else 1)


# -- fuzz ---------------------------------------------------------------------------------------------
N_FUZZ = 100_000


_RANDOM_BODIES = {
    protocol.MsgType.HELLO: lambda r: protocol.Hello(r.randbytes(16)),
    protocol.MsgType.RESPONSE: lambda r: protocol.Response(r.randbytes(16), r.randbytes(16)),
    protocol.MsgType.CHALLENGE: lambda r: protocol.Challenge(r.randbytes(16), r.randbytes(16)),
    protocol.MsgType.ARM: lambda r: protocol.Arm(
        r.choice(list(protocol.MODES)),
        r.choice(list(protocol.OBSERVATIONS)),
        r.randint(1, 64),
        0,
        r.randint(1, 100),
        r.getrandbits(64),
        r.randint(1, 10**6),
        r.randint(0, 10**4),
        0,
        0,
        r.randbytes(32),
    ),
    protocol.MsgType.POLICY_CHUNK: lambda r: protocol.PolicyChunk(
        r.getrandbits(64), 5000, 1000, r.randbytes(r.randint(0, 64))
    ),
    protocol.MsgType.COMMAND: lambda r: protocol.Command(
        0, 0, tuple(r.uniform(-1, 1) for _ in range(r.randint(1, 3)))
    ),
    protocol.MsgType.FETCH: lambda r: protocol.Fetch(
        r.randint(1, 2), r.randint(0, 9), r.randint(0, 10**5), 1024
    ),
    protocol.MsgType.DISARM: lambda r: protocol.Disarm(r.randint(0, 2)),
    protocol.MsgType.ACK: lambda r: protocol.Ack(r.randint(1, 14), 0, r.getrandbits(32), r.getrandbits(64)),
    protocol.MsgType.HEARTBEAT: lambda r: protocol.Heartbeat(
        r.randint(0, 3), 1, r.getrandbits(16), r.getrandbits(32)
    ),
    protocol.MsgType.ERROR: lambda r: protocol.Error(
        r.randint(0, 7), r.getrandbits(32), "e" * r.randint(0, 30)
    ),
    protocol.MsgType.OBSERVATION: lambda r: protocol.Observation(1, 2, 3, 4, (0.5, 0.25)),
    protocol.MsgType.INFO: lambda r: protocol.Info(r.randbytes(16), 1e4, 0, 0, False, 10, r.randbytes(32)),
    protocol.MsgType.CHUNK: lambda r: protocol.Chunk(2, 1, 100, 0, b"x"),
    protocol.MsgType.ARMED: lambda r: protocol.Armed(1, 0, 3, 1, 4, 0, 10, 1e4, r.randbytes(32)),
    protocol.MsgType.EPISODE_END: lambda r: protocol.EpisodeEnd(1, 1, 0, 10, 1, 0, r.randbytes(32)),
}


def _random_body(r: random.Random, t: protocol.MsgType):
    return _RANDOM_BODIES[t](r)


def test_fuzz_every_datagram_is_accepted_or_counted():
    """10^5 seeded datagrams (valid, random, bit-flipped, truncated, re-framed with a good CRC but a
    wrong version, type, length, session or payload, replayed, reordered, late) through the
    target's filter: no exception escapes, each lands in an outcome it may land in, and the
    counters add up to the number of datagrams."""
    r = random.Random(20240611)
    session = 0x5EED
    home, elsewhere = ("127.0.0.1", 5600), ("127.0.0.1", 5601)
    now = [0.0]  # the rate limiter's clock: 1 ms a datagram, so its verdicts are the seed's alone
    f = protocol.DatagramFilter("target", session=session, peer=home, loopback_only=True,
                                limiter=protocol.handshake.RateLimiter(clock=lambda: now[0]))
    seq = 0
    episode, step = 1, 0
    sent: dict[int, list[bytes]] = {}  # type -> accepted datagrams, newest last
    newest: dict[int, int] = {}
    h2t = sorted(protocol.HOST_TO_TARGET - protocol.HANDSHAKE_TYPES)
    t2h_only = sorted(protocol.TARGET_TO_HOST - protocol.HOST_TO_TARGET)
    outcome_counts: dict[str, int] = {}

    def fresh(t, body=None):
        nonlocal seq
        seq += 2  # odd numbers are never sent: they serve as never-seen older numbers
        if body is None:
            body = _random_body(r, t)
            if t == protocol.MsgType.COMMAND:
                body = protocol.Command(episode, step + r.randint(0, 2), body.action)
        return protocol.Message(body, session=session, seq=seq, tick=r.getrandbits(40))

    def feed(data, allowed, sender=home):
        now[0] += 1e-3
        before = f.total
        msg = f.accept(data, episode, step, sender)
        assert f.total == before + 1, (i, kind)  # one counter moved, by one
        outcome = "accepted" if msg is not None else f.last_reason
        assert outcome in allowed, (i, kind, outcome, f.last_error)
        outcome_counts[outcome] = outcome_counts.get(outcome, 0) + 1
        if outcome in ("accepted", "late"):  # both passed the sequence check: the stream moved on
            (mtype,) = struct.unpack_from("<B", data, 6)
            (mseq,) = struct.unpack_from("<I", data, 12)
            (msession,) = struct.unpack_from("<I", data, 8)
            if msession == session:
                newest[mtype] = mseq
                if msg is not None:
                    sent.setdefault(mtype, []).append(data)
                    del sent[mtype][:-100]

    i = 0
    while f.total < N_FUZZ:  # every datagram fed counts, the first copy of a repeated one too
        i += 1
        if i % 50 == 0:
            step += 1
            if step > 400:
                episode, step = episode + 1, 0
        kind = r.randrange(16)
        if kind in (11, 15) and f.total >= N_FUZZ - 1:
            kind = 0
        t = r.choice(h2t)
        sender = home
        base = protocol.encode(fresh(t))
        if kind == 0:  # a valid, fresh datagram
            data, allowed = base, {"accepted"}
        elif kind == 1:  # random bytes
            data = r.randbytes(r.choice([r.randint(0, 60), r.randint(0, 2000)]))
            allowed = set(protocol.DatagramFilter.REASONS)
        elif kind == 2:  # 1-3 flipped bits (the tag detects them; magic/version/length flips count as such)
            b = bytearray(base)
            for bit in r.sample(range(8 * len(b)), r.randint(1, 3)):  # distinct bits
                b[bit // 8] ^= 1 << (bit % 8)
            data, allowed = bytes(b), {"corrupt", "wrong_version", "unauthenticated"}
        elif kind == 3:  # truncated or extended
            cut = r.randint(0, len(base) - 1)
            data = base[:cut] if r.random() < 0.5 else base + r.randbytes(r.randint(1, 20))
            allowed = {"corrupt"}
        elif kind == 4:  # a valid frame (good CRC) around a bad header field or payload
            b = bytearray(base[:-protocol.TAG_SIZE])
            what = r.randrange(5)
            if what == 0:
                b[4] = r.choice([0, 1, 2, 255])  # any major but ours (3)
                allowed = {"wrong_version"}
            elif what == 1:
                b[6] = r.choice([0, 17, 200, 255])
                allowed = {"unexpected"}
            elif what == 2:
                b[40:42] = struct.pack("<H", r.randint(0, 65535))
                allowed = {"corrupt", "accepted"} if b[40:42] == base[40:42] else {"corrupt"}
            elif what == 3:
                b[8:12] = struct.pack("<I", session ^ r.randint(1, protocol.U32))
                allowed = {"wrong_session"}
            else:
                b[protocol.HEADER_SIZE:] = r.randbytes(len(b) - protocol.HEADER_SIZE)
                allowed = {"corrupt", "accepted", "late", "duplicate", "out_of_order"}
            data = _with_crc(bytes(b))
        elif kind == 5 and sent.get(t):  # a replay of an accepted datagram
            data = sent[t][-r.randint(1, len(sent[t]))]
            behind = (newest[t] - struct.unpack_from("<I", data, 12)[0]) & protocol.U32  # in sequence numbers
            allowed = {"duplicate"} if behind < protocol.DatagramFilter.WINDOW else {"out_of_order"}
        elif kind == 6 and t in newest:  # an older number never sent in this stream
            m = fresh(t)
            old_seq = (newest[t] - 1 - 2 * r.randint(0, 40)) & protocol.U32
            data = protocol.encode(protocol.Message(m.body, session=session, seq=old_seq))
            allowed = {"out_of_order"}
        elif kind == 7:  # a command for a step already past
            past = (episode, step - r.randint(1, 5)) if step > 5 else (episode - 1, r.randint(0, 400))
            data = protocol.encode(
                fresh(protocol.MsgType.COMMAND, protocol.Command(past[0], past[1], (0.0,)))
            )
            allowed = {"late"}
        elif kind == 12:  # from an address that is not loopback (this side has no key)
            data, allowed, sender = base, {"not_loopback"}, ("192.0.2.7", 5600)
        elif kind == 13:  # a well-tagged datagram from another port than the session's host's
            data, allowed, sender = base, {"stranger"}, elsewhere
        elif kind == 14:  # the right frame under another key (a stranger without ours)
            data, allowed = (
                base[: -protocol.TAG_SIZE] + protocol.tag(b"k" * 32, 0, base[: -protocol.TAG_SIZE]),
                {"unauthenticated"},
            )
        elif kind == 8:  # a type for the other direction
            data = protocol.encode(fresh(r.choice(t2h_only)))
            allowed = {"unexpected"}
        elif kind == 9:  # another session's HELLO is let through (at the per-source rate); its command is not
            data = protocol.encode(
                protocol.Message(
                    protocol.Hello(r.randbytes(16)), session=r.getrandbits(32), seq=r.getrandbits(32)
                )
            )
            allowed = {"accepted", "duplicate", "out_of_order", "rate_limited"}
        elif kind == 15:  # a RESPONSE to a challenge sent to its sender: accepted once, then spent
            hs, hn, how = r.getrandbits(32), r.randbytes(16), r.randrange(3)
            tn = f.challenges.issue(protocol.source(elsewhere if how == 1 else home), hs, hn)
            if how == 0:  # answered, then the same answer again (a new number: past the window)
                feed(
                    protocol.encode(protocol.Message(protocol.Response(hn, tn), session=hs, seq=1)),
                    {"accepted"},
                )
            elif how == 2:  # a target nonce that was never sent
                tn = r.randbytes(16)
            # how == 1: the challenge went to another port than the one answering
            data = protocol.encode(protocol.Message(protocol.Response(hn, tn), session=hs, seq=2))
            allowed = {"no_challenge"}
        else:  # a valid datagram sent twice in a row
            data = base
            allowed = {"accepted"}
            if kind == 11:
                feed(base, {"accepted"})
                allowed = {"duplicate"}
        feed(data, allowed, sender)

    counts = f.counts()
    assert sum(counts.values()) == N_FUZZ == f.total
    assert counts == {k: outcome_counts.get(k, 0) for k in counts}
    # every reason the filter gives was exercised (the loop's own, queue_full, in test_rig_wire.py)
    assert all(counts[k] > 0 for k in counts if k not in protocol.DatagramFilter.LOOP_REASONS), counts
    print("fuzz:", f.total, "datagrams:", counts, "corrupt detail:", dict(sorted(f.detail.items())))


def test_arm_options_carry_the_episode_kind():
    """Protocol 2.1: ARM's options bits 1-2 are the episode kind, bit 0 stays terminate-on-catch."""
    for kind in protocol.EpisodeKind:
        for term in (0, protocol.ARM_TERMINATE_ON_CATCH):
            arm = protocol.Arm(options=term | (int(kind) << protocol.ARM_KIND_SHIFT))
            back = protocol.decode(protocol.encode(protocol.Message(arm, session=1)), b"", 0).body
            assert back.kind == kind and back.options & protocol.ARM_TERMINATE_ON_CATCH == term
