"""The package's layers: no import cycles between modules, and the import-linter layers contract
of ``pyproject.toml`` (each layer imports only those below it; ``impact_env`` never imports
``baselines`` or ``agents``); scripts and tests share helpers through the package; and no project
module is imported under a one- or two-letter alias (counted by scripts/count_aliases.py)."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parent.parent


def test_no_import_cycles():
    g = grimp.build_graph("impact_env", "baselines", "agents")
    adj = {m: g.find_modules_directly_imported_by(m) for m in g.modules}
    state: dict[str, int] = {}
    cycles = []

    def visit(u, path):
        state[u] = 1
        path.append(u)
        for v in adj[u]:
            if state.get(v) == 1:
                cycles.append(path[path.index(v):] + [v])
            elif v not in state:
                visit(v, path)
        path.pop()
        state[u] = 2

    for m in sorted(adj):
        if m not in state:
            visit(m, [])
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles[:5])


def test_layers_contract_kept():
    exe = Path(sys.executable).with_name("lint-imports")
    out = subprocess.run([str(exe)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]


#: scripts that still reach into tests/ for a helper: none (the plant's solve_ivp reference, the
#: loopback Dask cluster and the loopback rig target moved into impact_env)
THROUGH_TESTS: set[str] = set()


def test_scripts_share_helpers_through_the_package_not_tests():
    reach = {p.name for p in (ROOT / "scripts").glob("*.py")
             if re.search(r"sys\.path\.insert\([^)]*\"tests\"", p.read_text())}
    assert reach <= THROUGH_TESTS, f"scripts that import from tests/: {sorted(reach - THROUGH_TESTS)}"


def test_tests_import_only_the_scripts_they_test():
    """A test may import a script it tests: one its file is named after or its docstring names."""
    scripts = {p.stem for p in (ROOT / "scripts").glob("*.py")}
    bad = []
    for test in (ROOT / "tests").glob("*.py"):
        tree = ast.parse(test.read_text())
        doc = ast.get_docstring(tree) or ""
        for node in ast.walk(tree):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module] if isinstance(node, ast.ImportFrom) and node.module else []
            for name in names:
                if name in scripts and name not in test.stem and f"scripts/{name}.py" not in doc:
                    bad.append(f"{test.name} imports {name}")
    assert not bad, bad


def test_no_project_module_has_a_one_or_two_letter_alias():
    """``import impact_env.rig.protocol as P``: one letter that means the protocol here and the
    plant's parameters elsewhere; the project's modules are imported by their own names
    (scripts/count_aliases.py counts them)."""
    from count_aliases import count

    assert count()["module_aliases"]["project"] == 0, "python scripts/count_aliases.py --list names them"
