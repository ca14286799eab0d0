"""Record the golden outputs that ``tests/test_golden.py`` checks bitwise.

    python scripts/record_golden.py [CASE ...]      # default: every case

Writes ``tests/golden/CASE.npz`` (the case's arrays) and ``tests/golden/fingerprint.json`` (the
machine and library versions bitwise equality is defined on; see ``scripts/golden_cases.py``).
Re-record only on purpose: when a change is meant to alter simulated numbers, say which and why
in the commit.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
from golden_cases import CASES, fingerprint, run_case

ROOT = Path(__file__).resolve().parent.parent

GOLDEN = ROOT / "tests" / "golden"


def main(argv: list[str]) -> int:
    names = argv or list(CASES)
    unknown = [n for n in names if n not in CASES]
    if unknown:
        print(f"unknown case(s) {unknown}; cases: {', '.join(CASES)}", file=sys.stderr)
        return 2
    GOLDEN.mkdir(parents=True, exist_ok=True)
    for name in names:
        t0 = time.perf_counter()
        arrays = run_case(name)
        np.savez_compressed(GOLDEN / f"{name}.npz", **arrays)
        print(f"{name}: {len(arrays)} arrays in {time.perf_counter() - t0:.1f} s")
    (GOLDEN / "fingerprint.json").write_text(json.dumps(fingerprint(), indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
