"""The wire protocol's declarations (impact_env.rig.layout, impact_env.rig.protocol).

The seeded corpus (tests/rig_protocol_corpus.py) against its golden record: every message type
encodes to the same bytes, and every mutated payload decodes to the same message or the same error
(class, counter, detail, field and refusal) as when the golden was written, before the
declarations replaced the hand-written classes.  Then what the declarations derive: each field's
refusal of a value out of its declaration (naming the field, its range and its unit), the structs,
and the docs' table."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import rig_protocol_corpus as corpus

from impact_env.rig import layout, protocol

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "docs" / "_ext"))
import generated_reference  # noqa: E402


def test_corpus_matches_its_golden():
    golden = json.loads(corpus.GOLDEN.read_text())
    now = json.loads(json.dumps(corpus.records()))
    assert len(now["encoded"]) == len(golden["encoded"])
    changed = [i for i, (a, b) in enumerate(zip(now["encoded"], golden["encoded"], strict=True)) if a != b]
    assert not changed, f"{len(changed)} datagrams encode differently, the first at {changed[0]}"
    diff = [(a, b) for a, b in zip(now["decoded"], golden["decoded"], strict=True) if a != b]
    assert not diff, f"{len(diff)} decodes differ, e.g. now {diff[0][0]}, golden {diff[0][1]}"
    assert not [d for d in now["decoded"] if d[1] == "UNEXPECTED"]  # decode raises ProtocolError only


# -- the declarations (impact_env.rig.layout): checks and docs derived from them ------------------------
def _out_of_range(f: layout.Field):
    """Values of the declared field ``f`` outside its declaration, each with what its error names."""
    if f.kind in ("u8", "u16", "u32", "u64"):
        rng = f"[{int(f.low)}, {int(f.top)}]"
        out = [int(f.top) + 1] + ([int(f.low) - 1] if f.low > 0 else [-1])
        return [(v, (f"{f.name} = {v}", rng, f.unit)) for v in out]
    if f.kind == "floats":
        return [(tuple([0.0] * (int(f.top) + 1)), (f.name, f"{int(f.low)} to {int(f.top)}"))] + (
            [((), (f.name, f"{int(f.low)} to"))] if f.low > 0 else [])
    cases = {"f64": lambda: [(f.low, (f.name, f"> {f.low:g}", f.unit)), (float("nan"), (f.name, f.unit))],
             "bool": lambda: [(1, (f.name, "bool"))],
             "enum": lambda: [("nope", (f.name, ", ".join(f.choices)))],
             "choice": lambda: [(3, (f.name, *map(str, f.choices)))],
             "bytes": lambda: [(bytes(f.size + 1), (f.name, f"{f.size} bytes")),
                               (b"", (f.name, f"{f.size} bytes"))],
             "data": lambda: [("text", (f.name, "bytes"))],
             "text": lambda: [("x" * (int(f.top) + 1), (f.name, f"at most {int(f.top)}")),
                              (b"", (f.name, "str"))]}
    return cases[f.kind]()


@pytest.mark.parametrize("cls", list(protocol.BODIES.values()), ids=lambda c: c.__name__)
def test_every_declared_field_refuses_what_is_out_of_its_declaration_by_name_range_and_unit(cls):
    for f in cls.FIELDS:
        for value, named in _out_of_range(f):
            with pytest.raises(ValueError) as info:
                cls(**{f.name: value})
            assert all(part in str(info.value) for part in named), (f.name, value, str(info.value))
            if isinstance(info.value, layout.FieldError):  # what a target's refusal says: field=value [range]
                assert info.value.field == f.name and info.value.refusal.startswith(f"{f.name}=") or \
                    info.value.refusal.startswith("n=")


def test_the_declarations_are_the_structs_and_the_docs_table():
    assert protocol.HEADER.format == "<4sBBBBIIQQQH" and protocol.HEADER_SIZE == 42
    assert {c.__name__: c.FMT.format for c in protocol.BODIES.values()} == {
        "Hello": "<16s64x", "Info": "<16sdBBBI32sQBH", "Arm": "<BBBBHQIIII32s", "Armed": "<IQHHBBHd32s",
        "PolicyChunk": "<QIIH", "Ack": "<BBIQ", "Command": "<IIH", "Observation": "<IIIBHH",
        "EpisodeEnd": "<IBIQII32s", "Fetch": "<BIIH", "Chunk": "<BIIIH", "Disarm": "<B", "Heartbeat": "<BIII",
        "Error": "<HIH", "Challenge": "<16s16s", "Response": "<16s16s48x"}
    page = generated_reference.protocol_page()
    for cls in protocol.BODIES.values():
        section = page.split(f"## {cls.TYPE.name} ({int(cls.TYPE)})\n")[1].split("\n## ")[0]
        for f in cls.FIELDS:
            rows = [line for line in section.splitlines() if f"| `{f.name}` " in line]
            assert rows[0].startswith(f"| {cls.OFFSETS[f.name]} |"), rows
            assert f.range_text().removeprefix("count ") in rows[0], rows
            assert f.unit in rows[-1] and f.meaning in rows[-1], rows
