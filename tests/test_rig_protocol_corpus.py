"""The wire protocol's seeded corpus (tests/rig_protocol_corpus.py) against its golden record: every
message type encodes to the same bytes, and every mutated payload decodes to the same message or
the same error (class, counter, detail, field and refusal) as when the golden was written."""

from __future__ import annotations

import json

import rig_protocol_corpus as corpus


def test_corpus_matches_its_golden():
    golden = json.loads(corpus.GOLDEN.read_text())
    now = json.loads(json.dumps(corpus.records()))
    assert len(now["encoded"]) == len(golden["encoded"])
    changed = [i for i, (a, b) in enumerate(zip(now["encoded"], golden["encoded"], strict=True)) if a != b]
    assert not changed, f"{len(changed)} datagrams encode differently, the first at {changed[0]}"
    diff = [(a, b) for a, b in zip(now["decoded"], golden["decoded"], strict=True) if a != b]
    assert not diff, f"{len(diff)} decodes differ, e.g. now {diff[0][0]}, golden {diff[0][1]}"
    assert not [d for d in now["decoded"] if d[1] == "UNEXPECTED"]  # decode raises ProtocolError only
