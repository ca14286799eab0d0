"""scripts/agents_report.py rebuilds docs/agents-results.md's results section and its figure from the
per-drop results kept in the repository (docs/results/agents), exactly: no hand edits, no run
folders needed."""

import importlib.util
import shutil
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results" / "agents"


def _report():
    spec = importlib.util.spec_from_file_location("agents_report", ROOT / "scripts" / "agents_report.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _section(text: str, mod) -> str:
    return text.partition(mod.BEGIN)[2].partition(mod.END)[0]


def test_the_results_section_regenerates_exactly_from_the_kept_results(tmp_path):
    mod = _report()
    doc = tmp_path / "docs" / "agents-results.md"
    doc.parent.mkdir()
    shutil.copyfile(ROOT / "docs" / "agents-results.md", doc)
    committed = _section(doc.read_text(), mod)
    # a stale section is replaced, not kept
    doc.write_text(doc.read_text().replace(committed, "\nstale\n"))
    # the README's agent table too (the README beside docs/, between its own markers)
    readme = tmp_path / "README.md"
    shutil.copyfile(ROOT / "README.md", readme)
    committed_readme = readme.read_text().partition(mod.README_BEGIN)[2].partition(mod.README_END)[0]
    assert committed_readme.strip()
    readme.write_text(readme.read_text().replace(committed_readme, "\nstale\n"))
    assert mod.main(["--results", str(RESULTS), "--doc", str(doc),
                     "--figure", str(tmp_path / "docs" / "figures" / "agents_results.png")]) == 0
    assert _section(doc.read_text(), mod) == committed
    assert readme.read_text().partition(mod.README_BEGIN)[2].partition(mod.README_END)[0] == committed_readme
    assert (tmp_path / "docs" / "figures" / "agents_results.png").stat().st_size > 10_000


def test_the_report_states_the_goals_and_the_decomposition():
    """The kept results hold every run's wall times and the issue's goals, each with its figure and
    a verdict, and (with the oracle and a privileged run) the decomposition of the gap."""
    import json

    rep = json.loads((RESULTS / "report.json").read_text())
    text = (ROOT / "docs" / "agents-results.md").read_text()
    section = _section(text, _report())
    for run in rep["runs"]:
        assert f"| {run['label']} |" in section
        assert run["meta"]["env_share"] is not None and run["meta"]["validation_history"]
    assert "### The shipped agent's goals" in section and section.count("**met**") + section.count("**NOT met**") >= 3
    if rep["settings"]["oracle"] != "none" and any(r["privileged"] for r in rep["runs"]):
        assert section.count("the information's share") == len(rep["settings"]["scenes"])


def test_only_a_run_within_the_float32_bound_ships():
    """The agent shipped is the best validation return among the sensor runs whose float32 C build
    stayed within the export's bound (a privileged run never ships); the kept results name it, and
    agents/models/best is that run."""
    import json

    mod = _report()

    def run(label, val, failed=None, privileged=False):
        c = None if failed is None else {"bound": 1e-4, "drops": 20, "failed": failed, "max_same": 0.0}
        return {"label": label, "val_best": val, "privileged": privileged, "c_float32": c}

    infos = [run("a", -3.0, ["rig:1"]), run("b", -5.0, []), run("c", -6.0), run("p", -1.0, privileged=True)]
    assert mod.best_sensor_run(infos)["label"] == "a"
    assert mod.shipped_run(infos)["label"] == "b"
    assert mod.shipped_run([run("c", -6.0), run("b", -5.5, [])])["label"] == "b"  # unchecked: allowed
    rep = json.loads((RESULTS / "report.json").read_text())
    shipped = mod.shipped_run(rep["runs"])
    assert shipped["c_float32"] is not None and not shipped["c_float32"]["failed"]
    meta = json.loads((ROOT / "agents" / "models" / "best" / "model.json").read_text())
    assert meta["shipped_from"]["label"] == shipped["label"]


def test_joining_the_laws_into_a_kept_oracle_row_gives_todays_oracle_bitwise(monkeypatch):
    """A kept oracle row whose final choice saw only its comparison's laws, brought up to date by
    ``--join-laws``, is the row today's oracle gives on the same drops: every metric bitwise and
    the same source per drop; and a kept row that has not been brought up to date is refused."""
    from impact_env.eval import oracle
    from impact_env.eval.compare import compare

    mod = _report()
    spec = "oracle:generations=2,popsize=4,warm=given"  # a weak search: the laws win drops
    kw = dict(episodes=2, seed=1000, workers=1, progress=False, trace_rate=2000.0)
    today = compare("rig", ["pd-penetration", spec], **kw)[spec]
    monkeypatch.setattr(oracle, "classic_law_names", lambda: list(oracle.WARM_POLICIES))  # its choice before
    runs = compare("rig", ["pd-penetration", spec], **kw)
    monkeypatch.undo()
    before = runs[spec]
    assert not np.array_equal(before.metrics["energy_integral_ms"], today.metrics["energy_integral_ms"])
    kept = {"labels": ["pd-penetration", "oracle"], "oracle|source": np.asarray(before.stats["source"], str),
            **{f"{label}|{key}": np.asarray(runs[s].metrics[key], float) for key in mod.METRICS
               for label, s in (("pd-penetration", "pd-penetration"), ("oracle", spec))}}
    assert set(mod.unseen_laws(kept)) == set(oracle.classic_law_names()) - {"pd-penetration"}
    # rows made by another simulator or metric (here: one drop's pd-penetration off by 1e-9 ms) are refused
    other = {**kept, "pd-penetration|energy_integral_ms": kept["pd-penetration|energy_integral_ms"] + [1e-9, 0.0]}
    with pytest.raises(ValueError, match="pd-penetration on the kept drops differs"):
        mod.join_classic_laws(other, "rig", 2, 1000, 1)
    assert "oracle|joined" not in other and other["oracle|energy_integral_ms"] is kept["oracle|energy_integral_ms"]
    mod.join_classic_laws(kept, "rig", 2, 1000, 1)
    assert mod.unseen_laws(kept) == []
    for key in mod.METRICS:
        np.testing.assert_array_equal(kept[f"oracle|{key}"], today.metrics[key], err_msg=key)
    assert list(kept["oracle|source"]) == list(today.stats["source"])
    assert set(today.stats["source"]) & {"mpc-state", "mpc"}
