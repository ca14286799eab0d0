"""The package's layers: no import cycles between modules, and the import-linter layers contract
of ``pyproject.toml`` (each layer imports only those below it; ``impact_env`` never imports
``baselines`` or ``agents``)."""

from __future__ import annotations

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
