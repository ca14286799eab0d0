"""Golden outputs: the simulator, the env and compare give today exactly the numbers they gave
when the files were recorded (``scripts/record_golden.py``; cases in ``golden_cases.py``).

Bitwise (``np.array_equal``, NaN equal to NaN) on the machine of the recording; elsewhere the
test is skipped with the reason, since BLAS kernels inside scipy differ between CPUs in the last
bit (see ``golden_cases``)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from golden_cases import CASES, fingerprint, run_case  # noqa: E402

GOLDEN = Path(__file__).resolve().parent / "golden"


@pytest.fixture(scope="module")
def same_machine():
    recorded = json.loads((GOLDEN / "fingerprint.json").read_text())
    here = fingerprint()
    if recorded != here:
        diff = {k: (recorded.get(k), here.get(k)) for k in here if recorded.get(k) != here.get(k)}
        pytest.skip(f"golden files were recorded on another machine or library set {diff}; bitwise "
                    "equality is defined only there (re-record with scripts/record_golden.py)")


@pytest.mark.parametrize("name", list(CASES))
def test_golden_outputs_bitwise(name, same_machine):
    want = np.load(GOLDEN / f"{name}.npz")
    got = run_case(name)
    assert sorted(got) == sorted(want.files), f"{name}: arrays added or missing"
    bad = [k for k in want.files if not (got[k].shape == want[k].shape
                                         and np.array_equal(got[k], want[k], equal_nan=True))]
    assert not bad, f"{name}: arrays differ from the golden recording: {bad[:8]}"
