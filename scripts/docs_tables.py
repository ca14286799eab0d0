"""Write the docs' tables that the registries derive, so that a doc cannot lag behind the code.

Each table sits in a doc between ``<!-- NAME:start -->`` and ``<!-- NAME:end -->`` and is written
by a function of the registry that owns the list (the tests check that each doc holds what its
function writes):

* ``effects-table`` in docs/scenes.md: :func:`impact_env.effects.registry.markdown_table`;
* ``laws-table`` in docs/baselines.md: :func:`impact_env.control.laws.markdown_table`.

    python scripts/docs_tables.py            # rewrite the tables
    python scripts/docs_tables.py --check    # fail if a doc's table is stale
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from impact_env.control import laws
from impact_env.effects import registry as effects

ROOT = Path(__file__).resolve().parents[1]
TABLES = {  # marker name: (doc, the function that writes the table)
    "effects-table": (ROOT / "docs" / "scenes.md", effects.markdown_table),
    "laws-table": (ROOT / "docs" / "baselines.md", laws.markdown_table),
}


def rewritten(text: str, name: str, table: str) -> str:
    """``text`` with everything between the markers ``name`` replaced by ``table``."""
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
    if not pattern.search(text):
        raise SystemExit(f"the doc lacks the markers {start} ... {end}")
    return pattern.sub(lambda _m: f"{start}\n{table}\n{end}", text, count=1)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="fail if a table is stale")
    args = ap.parse_args(argv)
    stale = []
    for name, (doc, write) in TABLES.items():
        text = doc.read_text()
        new = rewritten(text, name, write())
        if new != text:
            stale.append(f"{doc.relative_to(ROOT)} ({name})")
            if not args.check:
                doc.write_text(new)
    if args.check and stale:
        print("stale: " + ", ".join(stale), file=sys.stderr)
        return 1
    print(("rewrote: " + ", ".join(stale)) if stale else "every table is current")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
