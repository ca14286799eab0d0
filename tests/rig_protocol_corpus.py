"""A seeded corpus of rig wire-protocol datagrams and what decoding them gives, recorded in
tests/golden/rig_protocol_corpus.json (tests/test_rig_protocol_corpus.py): the proof that the
message declarations of :mod:`impact_env.rig.protocol` encode and decode byte for byte, and refuse
with the same errors, as the hand-written classes they replaced.

Per message type, ``N_BODIES`` valid payloads drawn here (their ranges written out by hand, not
read from the declarations), each encoded under a key and a session nonce (recorded by its
sha256); then ``N_MUTANTS`` mutations of each payload (bytes flipped, set to 0x00 or 0xff, cut or
extended), framed without a key so that decoding reaches the payload, and the outcome of decoding
each: the sha256 of the message's repr, or the error's class, detail, field and refusal text (its
prose is free to change; ``full=True`` keeps it, to compare two versions by hand).

Run ``python tests/rig_protocol_corpus.py`` to rewrite the golden file (only when the wire format
changes on purpose)."""

from __future__ import annotations

import hashlib
import json
import random
import string
import struct
from pathlib import Path

from impact_env.rig import protocol

GOLDEN = Path(__file__).parent / "golden" / "rig_protocol_corpus.json"
N_BODIES, N_MUTANTS = 8, 16
KEY = bytes(range(100, 132))
NONCE = 0x0F1E2D3C4B5A6978


def _uint(r: random.Random, bits: int, lo: int = 0, hi: int | None = None) -> int:
    top = (1 << bits) - 1 if hi is None else hi
    return r.choice([lo, top, r.randint(lo, top), r.randint(lo, min(top, lo + 300))])


def _floats(r: random.Random, n: int, f32: bool = False) -> tuple[float, ...]:
    pool = [0.0, -0.0, 1.5, -2.25, 1e-3, float("inf"), float("-inf")]
    out = []
    for _ in range(n):
        v = r.choice(pool) if r.random() < 0.3 else r.uniform(-1e4, 1e4)
        if f32:
            v = struct.unpack("<f", struct.pack("<f", v))[0]
        out.append(v)
    return tuple(out)


def _window(r: random.Random) -> tuple[int, int, bytes]:
    data = r.randbytes(r.choice([0, 1, r.randint(0, protocol.CHUNK_DATA)]))
    total = r.choice([len(data), r.randint(len(data), protocol.MAX_TRANSFER)])
    offset = r.randint(0, total - len(data))
    return total, offset, data


def bodies(r: random.Random) -> list[protocol.Body]:
    """One valid payload of every message type, its fields drawn within their ranges."""
    nonce = lambda: r.randbytes(protocol.NONCE_SIZE)  # noqa: E731
    sha = lambda: r.randbytes(32)  # noqa: E731
    rate = lambda: r.choice([1e4, 0.5, r.uniform(1.0, 1e6)])  # noqa: E731
    out: list[protocol.Body] = [
        protocol.Hello(nonce()),
        protocol.Challenge(nonce(), nonce()),
        protocol.Response(nonce(), nonce()),
        protocol.Info(nonce(), rate(), r.randint(0, 3), r.randint(0, 1), r.random() < 0.5, _uint(r, 32), sha(),
               _uint(r, 64), r.random() < 0.5, _uint(r, 16)),
        protocol.Arm(r.choice(["host", "onboard"]), r.choice(["sensors", "privileged", "both"]), _uint(r, 8, 1, 64),
              _uint(r, 8), _uint(r, 16, 1), _uint(r, 64), _uint(r, 32, 1), _uint(r, 32), _uint(r, 32),
              _uint(r, 32), sha()),
        protocol.Armed(_uint(r, 32), _uint(r, 64), _uint(r, 13, 0, protocol.MAX_VALUES), _uint(r, 13, 0, protocol.MAX_VALUES),
                r.choice([4, 8]), _uint(r, 8), _uint(r, 16, 1), rate(), sha()),
        protocol.PolicyChunk(_uint(r, 64), *_window(r)),
        protocol.Ack(_uint(r, 8), _uint(r, 8), _uint(r, 32), _uint(r, 64)),
        protocol.Command(_uint(r, 32), _uint(r, 32), _floats(r, r.choice([1, 1, 2, r.randint(1, 40)]))),
        protocol.EpisodeEnd(_uint(r, 32), _uint(r, 8), _uint(r, 32), _uint(r, 64), _uint(r, 32), _uint(r, 32),
                     sha()),
        protocol.Fetch(_uint(r, 8), _uint(r, 32), _uint(r, 32), _uint(r, 16, 1)),
        protocol.Chunk(_uint(r, 8), _uint(r, 32), *_window(r)),
        protocol.Disarm(r.randint(0, 3)),
        protocol.Heartbeat(_uint(r, 8), _uint(r, 32), _uint(r, 32), _uint(r, 32)),
        protocol.Error(_uint(r, 16), _uint(r, 32), "".join(r.choice(string.printable + "éß漢") for _ in
                                                     range(r.choice([0, 5, r.randint(0, 300)])))),
    ]
    dtype = r.choice([4, 8])
    out.append(protocol.Observation(_uint(r, 32), _uint(r, 32), _uint(r, 32), dtype,
                             _floats(r, r.randint(0, 30), f32=dtype == 4), _floats(r, r.randint(0, 8))))
    return out


def _mutate(r: random.Random, payload: bytes) -> bytes:
    b = bytearray(payload)
    kind = r.randrange(6)
    if kind == 0 and b:  # flip one bit
        i = r.randrange(len(b))
        b[i] ^= 1 << r.randrange(8)
    elif kind == 1 and b:  # one byte to 0x00 or 0xff
        b[r.randrange(len(b))] = r.choice([0, 0xFF])
    elif kind == 2 and b:  # one byte to anything
        b[r.randrange(len(b))] = r.randrange(256)
    elif kind == 3:  # cut
        del b[r.randint(0, len(b)):]
    elif kind == 4:  # extend
        b += r.randbytes(r.randint(1, 12))
    elif b:  # a little-endian u16/u32 count or field set large
        i = r.randrange(len(b))
        b[i:i + 2] = r.choice([b"\xff\xff", b"\x00\x10", b"\x01\x10", b"\x00\x00"])
    return bytes(b)


def _digest(text: str | bytes) -> str:
    return hashlib.sha256(text.encode() if isinstance(text, str) else text).hexdigest()[:16]


def _outcome(data: bytes, full: bool) -> list:
    try:
        msg = protocol.decode(data)
    except protocol.ProtocolError as exc:
        return [type(exc).__name__, exc.reason, exc.detail, getattr(exc, "field", ""),
                getattr(exc, "refusal", "")] + ([str(exc)] if full else [])
    except Exception as exc:  # decode must raise nothing else: recorded, so the golden shows it
        return ["UNEXPECTED", type(exc).__name__, str(exc)]
    return ["ok", repr(msg) if full else _digest(repr(msg))]


def records(full: bool = False) -> dict:
    """The corpus: ``encoded`` (hex datagrams of valid messages) and ``decoded`` (outcomes)."""
    r = random.Random(20260036)
    encoded, decoded = [], []
    for _ in range(N_BODIES):
        for body in bodies(r):
            msg = protocol.Message(body, session=_uint(r, 32), seq=_uint(r, 32), tick=_uint(r, 64),
                            host_ns=_uint(r, 64), target_ns=_uint(r, 64), flags=_uint(r, 8))
            data = protocol.encode(msg, KEY, NONCE)
            encoded.append(data.hex() if full else _digest(data))
            assert protocol.decode(data, KEY, NONCE) == msg
            payload = data[protocol.HEADER_SIZE:-protocol.TAG_SIZE]
            for _ in range(N_MUTANTS):
                mutant = _mutate(r, payload)
                minor = protocol.VERSION_MINOR + (1 if r.random() < 0.15 else 0)
                head = protocol.HEADER.pack(protocol.MAGIC, protocol.VERSION_MAJOR, minor, body.TYPE, 0, msg.session, msg.seq, 0,
                                     0, 0, len(mutant))
                frame = head + mutant
                data = frame + protocol.tag(b"", 0, frame)
                decoded.append([body.TYPE.name] + ([data.hex()] if full else []) + _outcome(data, full))
    return {"encoded": encoded, "decoded": decoded}


if __name__ == "__main__":
    # one record a line, so that a change shows as the lines it changes
    parts = [f'"{k}": [\n' + ",\n".join(json.dumps(v, ensure_ascii=False) for v in rows) + "\n]"
             for k, rows in records().items()]
    GOLDEN.write_text("{\n" + ",\n".join(parts) + "\n}\n")
    print(f"wrote {GOLDEN}")
