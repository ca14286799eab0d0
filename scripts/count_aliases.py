"""Count short module aliases and positional slot reads in compiled kernels; print JSON.

What it counts (a static reading of the sources with :mod:`ast`; nothing is imported but
:func:`importlib.util.find_spec`, which tells a module from a name inside one):

``module_aliases``
    Every ``import a.b as XY`` and every ``from a import b as XY`` where ``a.b`` is a module
    (``find_spec`` finds it), whose alias is one or two characters once leading underscores are
    stripped (``T``, ``SF``, ``_L``), in the ``.py`` files under ``impact_env/``, ``tests/``,
    ``scripts/``, ``agents/`` and ``baselines/``; imports inside functions count too.
    ``project`` counts those whose module is the project's own (``impact_env``, ``agents``,
    ``baselines``, ``scripts``, ``tests``): the ones the guide forbids.  ``third_party`` counts
    the field's own conventions (``numpy as np``, ``hypothesis.strategies as st``,
    ``torch.nn as nn``), listed apart and not the target.

``kernel_slot_reads``
    Inside a function whose decorator is ``jit``/``njit``/``numba.njit`` (called or not), every
    subscript read (``Load`` context) whose last index (the slot axis: a vector's entry, a row's
    column) is a non-negative integer literal: ``y[0]``, ``p[3]``, ``info[i, 2]``; not
    ``Y[0, STATE.x1]`` (row 0 of a batch, its slot by name) nor ``k[0, j]``.  Not counted:
    ``.shape[k]`` and ``.strides[k]`` (an array's dimensions, not a slot), negative literals
    (``a[-1]``: the last entry), slices (``a[1:]``), and writes (``y[0] = ...``: counted apart as
    ``kernel_slot_writes``).  Nested functions inside a kernel count as the kernel.  The count is
    syntactic: it includes literal reads that are not named slots by nature (a one-element holder
    ``count[0]``, a Butcher tableau's stage ``k[s, 0]``, a returned tuple's ``[0]``); ``--list``
    shows each.

``python scripts/count_aliases.py --list`` prints every hit (file:line and the text) on stderr
besides the JSON on stdout.
"""

from __future__ import annotations

import ast
import importlib.util
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FOLDERS = ("impact_env", "tests", "scripts", "agents", "baselines")
PROJECT = ("impact_env", "agents", "baselines", "scripts", "tests")
JIT_NAMES = {"jit", "njit"}


def _is_module(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError, AttributeError):
        return False


def _short(alias: str) -> bool:
    return len(alias.lstrip("_")) <= 2


def _module_aliases(tree: ast.AST) -> list[tuple[int, str, str]]:
    """(line, module, alias) of each short module alias in ``tree``."""
    hits = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            hits += [(node.lineno, a.name, a.asname) for a in node.names if a.asname and _short(a.asname)]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for a in node.names:
                if a.asname and _short(a.asname) and _is_module(f"{node.module}.{a.name}"):
                    hits.append((node.lineno, f"{node.module}.{a.name}", a.asname))
    return hits


def _decorator_name(dec: ast.expr) -> str:
    if isinstance(dec, ast.Call):
        dec = dec.func
    if isinstance(dec, ast.Attribute):
        return dec.attr
    return dec.id if isinstance(dec, ast.Name) else ""


def _literal_slot(index: ast.expr) -> bool:
    last = index.elts[-1] if isinstance(index, ast.Tuple) and index.elts else index
    return isinstance(last, ast.Constant) and type(last.value) is int and last.value >= 0


def _kernel_slots(tree: ast.AST) -> tuple[list[int], list[int]]:
    """Lines of the literal-slot reads and writes inside jit kernels of ``tree``."""
    reads: list[int] = []
    writes: list[int] = []
    for fn in ast.walk(tree):
        if not isinstance(fn, ast.FunctionDef):
            continue
        if not any(_decorator_name(d) in JIT_NAMES for d in fn.decorator_list):
            continue
        for node in ast.walk(fn):
            if not isinstance(node, ast.Subscript) or not _literal_slot(node.slice):
                continue
            if isinstance(node.value, ast.Attribute) and node.value.attr in ("shape", "strides"):
                continue
            (reads if isinstance(node.ctx, ast.Load) else writes).append(node.lineno)
    return reads, writes


def count(listing: bool = False) -> dict:
    sys.path.insert(0, str(ROOT))
    project = third_party = reads = writes = 0
    by_file: dict[str, dict[str, int]] = {}
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = str(path.relative_to(ROOT))
            source = path.read_text()
            lines = source.splitlines()
            tree = ast.parse(source, filename=rel)
            mine = 0
            for line, module, alias in _module_aliases(tree):
                own = module.split(".")[0] in PROJECT
                project += own
                third_party += not own
                mine += own
                if listing and own:
                    print(f"alias {rel}:{line}: {module} as {alias}", file=sys.stderr)
            kernel_reads, kernel_writes = _kernel_slots(tree)
            reads += len(kernel_reads)
            writes += len(kernel_writes)
            if listing:
                for line in kernel_reads:
                    print(f"slot {rel}:{line}: {lines[line - 1].strip()}", file=sys.stderr)
            if mine or kernel_reads:
                by_file[rel] = {"module_aliases": mine, "kernel_slot_reads": len(kernel_reads)}
    return {
        "command": "python scripts/count_aliases.py",
        "module_aliases": {"project": project, "third_party": third_party},
        "kernel_slot_reads": reads,
        "kernel_slot_writes": writes,
        "by_file": by_file,
    }


if __name__ == "__main__":
    print(json.dumps(count(listing="--list" in sys.argv[1:]), indent=1))
