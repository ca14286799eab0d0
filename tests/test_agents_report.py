"""scripts/agents_report.py rebuilds docs/agents.md's results section and its figure from the
per-drop results kept in the repository (docs/agents_results), exactly: no hand edits, no run
folders needed."""

import importlib.util
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "agents_results"


def _report():
    spec = importlib.util.spec_from_file_location("agents_report", ROOT / "scripts" / "agents_report.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _section(text: str, mod) -> str:
    return text.partition(mod.BEGIN)[2].partition(mod.END)[0]


def test_the_results_section_regenerates_exactly_from_the_kept_results(tmp_path):
    mod = _report()
    doc = tmp_path / "docs" / "agents.md"
    doc.parent.mkdir()
    shutil.copyfile(ROOT / "docs" / "agents.md", doc)
    committed = _section(doc.read_text(), mod)
    # a stale section is replaced, not kept
    doc.write_text(doc.read_text().replace(committed, "\nstale\n"))
    assert mod.main(["--results", str(RESULTS), "--doc", str(doc),
                     "--figure", str(tmp_path / "docs" / "figures" / "agents_results.png")]) == 0
    assert _section(doc.read_text(), mod) == committed
    assert (tmp_path / "docs" / "figures" / "agents_results.png").stat().st_size > 10_000
