"""Write the docs' tables that the registries derive, so that a doc cannot lag behind the code.

Each table sits in a doc between ``<!-- NAME:start -->`` and ``<!-- NAME:end -->`` and is written
by a function of the registry that owns the list (the tests check that each doc holds what its
function writes):

* ``effects-table`` in docs/scenes.md: :func:`impact_env.effects.registry.markdown_table`;
* ``laws-table`` in docs/baselines.md: :func:`impact_env.control.laws.markdown_table`;
* ``layers`` in docs/architecture.md: :func:`layers_block`, the layers of ``pyproject.toml``'s
  import-linter contract, top first, each with the first line of its modules' docstrings;
* ``where-is-it`` in docs/architecture.md: :func:`where_is_it`, every scene field, effect and
  classic law, one line each, with the file that holds it.

    python scripts/docs_tables.py            # rewrite the tables
    python scripts/docs_tables.py --check    # fail if a doc's table is stale
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import re
import sys
from pathlib import Path

import tomllib

from impact_env.control import laws
from impact_env.effects import registry as effects
from impact_env.scene import Scene

ROOT = Path(__file__).resolve().parents[1]


def contract_layers() -> list[list[str]]:
    """The layers of pyproject's import-linter ``layers`` contract, top first, each a list of the
    modules that share it (``a | b``)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    (contract,) = [c for c in config["contracts"] if c["type"] == "layers"]
    return [[m.strip() for m in layer.split("|")] for layer in contract["layers"]]


def _summary(module: str) -> str:
    """The first line of ``module``'s docstring, read from its file (nothing is imported)."""
    path = ROOT.joinpath(*module.split("."))
    path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    doc = ast.get_docstring(ast.parse(path.read_text())) or ""
    first = re.split(r"\.\s+(?=[A-Z])", doc.strip().split("\n\n")[0].replace("\n", " "))[0].rstrip(".")
    if len(first) > 90:  # a long sentence: its head
        first = re.split(r": |, in |, ", first)[0]
    return first.rstrip(":")


def layers_block() -> str:
    """The layers, top first: each module of a layer with its docstring's first sentence."""
    lines = ["```"]
    for layer in contract_layers():
        for j, module in enumerate(layer):
            lines.append(f"{'|' if j else ' '} {module:<28} {_summary(module)}")
    return "\n".join(lines + ["```"])


def _where(obj) -> str:
    return str(Path(inspect.getsourcefile(obj)).relative_to(ROOT))


def _scene_fields(cls, prefix: str) -> list[str]:
    rows = []
    for f in dataclasses.fields(cls):
        sub = f.default_factory if f.default_factory is not dataclasses.MISSING else None
        if dataclasses.is_dataclass(sub):
            rows += _scene_fields(type(sub()) if not isinstance(sub, type) else sub, f"{prefix}{f.name}.")
        elif "doc" in f.metadata:
            unit = f" ({f.metadata['unit']})" if f.metadata.get("unit") else ""
            rows.append(f"* scene field `{prefix}{f.name}`{unit}: {f.metadata['doc']} -- "
                        f"{_where(cls)} `{cls.__name__}`")
    return rows


def where_is_it() -> str:
    """Every scene field (with its unit and meaning), effect and classic law, one line each, with
    the file that holds it."""
    rows = [f"* effect `{e.name}` ({e.side}, `[effects.{e.section}]`): {e.doc} -- {_where(e.config)}"
            for e in effects.REGISTRY]
    rows += [f"* law `{law.name}` ({law.observation}): {law.doc} -- {_where(law.constants)}"
             for law in laws.REGISTRY]
    rows += _scene_fields(Scene, "")
    return "\n".join(rows)


TABLES = {  # marker name: (doc, the function that writes the table)
    "effects-table": (ROOT / "docs" / "scenes.md", effects.markdown_table),
    "laws-table": (ROOT / "docs" / "baselines.md", laws.markdown_table),
    "layers": (ROOT / "docs" / "architecture.md", layers_block),
    "where-is-it": (ROOT / "docs" / "architecture.md", where_is_it),
}


def rewritten(text: str, name: str, table: str) -> str:
    """``text`` with everything between the markers ``name`` replaced by ``table``."""
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
    if not pattern.search(text):
        raise SystemExit(f"the doc lacks the markers {start} ... {end}")
    return pattern.sub(lambda _m: f"{start}\n{table}\n{end}", text, count=1)


def write_block(doc: Path, name: str, table: str) -> None:
    """Rewrite the block ``name`` of the page ``doc`` with ``table`` (the scripts that make records)."""
    doc.write_text(rewritten(doc.read_text(), name, table))


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
