"""The frozen suite (impact_env.eval.suite), the benchmark's record (impact_env.eval.benchmark)
and the leaderboard generated from records (scripts/leaderboard.py); README's main job on held-out
seeds (scripts/readme_table.py)."""

from __future__ import annotations

import inspect
import json
from pathlib import Path

import leaderboard
import numpy as np
import pytest

from impact_env.eval.benchmark import run_benchmark, scores_per_drop, write_record
from impact_env.eval.oracle_cache import OracleCache
from impact_env.eval.rollout import rollout
from impact_env.eval.suite import HELD_OUT, README_SEED, SUITES, DropSet, Suite
from impact_env.policy.registry import make_policy

ROOT = Path(__file__).resolve().parents[1]


# -- the suite's seeds are held out -------------------------------------------------------------------
def agents_seeds() -> list[tuple[str, range]]:
    """Every seed range agents/ trains, validates or tests on, from its own constants and the
    shipped models' records."""
    from agents import distill, train

    distill_params = inspect.signature(distill.distill).parameters
    first = distill_params["eval_seed"].default
    out = [("training (below the test drops)", range(0, train.TEST_SEED)),
           ("test drops", range(train.TEST_SEED, train.TEST_SEED + train.TEST_EPISODES)),
           ("validation", range(train.EVAL_SEED, train.EVAL_SEED + train.Tooling.eval_episodes)),
           ("distill validation", range(first, first + distill_params["eval_episodes"].default)),
           ("compare's old default", range(0, 100))]
    for meta in (ROOT / "agents" / "models").glob("*/model.json"):
        d = json.loads(meta.read_text())
        v = d.get("validation") or {}
        if "seeds" in v:
            out.append((f"{meta.parent.name} validation", range(v["seeds"][0], v["seeds"][1] + 1)))
        seed = int(d.get("seed", 0))
        out.append((f"{meta.parent.name} training", range(seed, seed + int(d.get("envs", 1)))))
    return out


def test_suite_seeds_are_disjoint_from_every_seed_the_agents_use():
    taken = agents_seeds()
    for suite in SUITES.values():
        seen: set[int] = set()
        for ds in suite.sets:
            seeds = set(ds.seeds)
            assert seeds <= set(HELD_OUT), ds.name
            assert not seeds & seen, f"{suite.name}: set {ds.name} shares seeds with another set"
            seen |= seeds
            for what, r in taken:
                assert not seeds & set(r), f"{suite.name}/{ds.name} meets the agents' {what} seeds"
    readme = set(range(README_SEED, README_SEED + 100))
    assert not any(readme & set(r) for _what, r in taken)
    assert not any(readme & set(ds.seeds) for s in SUITES.values() for ds in s.sets)


def test_the_readme_main_job_runs_on_held_out_seeds():
    import readme_table

    cmd = readme_table.main_command((ROOT / "README.md").read_text())
    assert int(cmd[cmd.index("--seed") + 1]) == README_SEED


def test_every_set_of_every_suite_builds_its_scene():
    for suite in SUITES.values():
        for ds in suite.sets:
            scene = ds.build_scene()
            assert ds.drops >= 20 and scene.episode.horizon > 0


# -- a small suite, with a fake oracle (a real replay of pd-penetration's commands) ---------------------
def _tiny_suite() -> Suite:
    short = (("episode.horizon", 0.03),)
    return Suite("tiny-v1", 1, (
        DropSet("rig", "rig", 7_900_000, 3, "rig, 30 ms", short),
        DropSet("light", "rig-randomized", 7_900_100, 4, "light bodies",
                (*short, ("randomize.m1", [0.05, 0.07]))),
    ), "a test suite")


def _fake_oracle(suite: Suite, root: Path) -> None:
    for ds in suite.sets:
        scene = ds.build_scene()
        r = rollout(scene, make_policy("pd-penetration", scene), list(ds.seeds), trace_rate=0.0,
                    record_commands=True)
        cache = OracleCache.of(scene, scene.episode.horizon, root=root)
        for i, s in enumerate(ds.seeds):
            cache.store(s, r.extras["commands"][:, i],
                        {"cpu_seconds": 0.0, "improvement_ms": 0.0, "source": "x"})


@pytest.fixture(scope="module")
def tiny(tmp_path_factory, warm_kernels):
    root = tmp_path_factory.mktemp("cache")
    suite = _tiny_suite()
    _fake_oracle(suite, root)
    return suite, root


@pytest.fixture(scope="module")
def record(tiny):
    suite, root = tiny
    return run_benchmark(["pd-penetration"], suite, workers=1, progress=False, oracle_cache=root,
                         command="impact-env benchmark pd-penetration")


def test_the_command_line_writes_the_record_and_refuses_the_oracle(tiny, tmp_path, monkeypatch, capsys):
    from impact_env.cli.main import main

    suite, root = tiny
    monkeypatch.setitem(SUITES, suite.name, suite)
    code = main(["benchmark", "thesis-ideal", "--suite", suite.name, "--drops", "2", "--out", str(tmp_path),
                 "--oracle-cache", str(root), "--workers", "1", "--no-progress"])
    out = capsys.readouterr().out
    assert code == 0 and "score*" in out and "thesis-ideal" in out
    rec = json.loads((tmp_path / "tiny-v1.json").read_text())
    assert not rec["complete"] and rec["sets"]["light"]["drops"] == 2
    assert main(["benchmark", "oracle", "--suite", suite.name, "--out", str(tmp_path)]) == 2
    assert "always in a benchmark" in capsys.readouterr().err


def test_the_record_holds_every_metric_per_drop_and_where_it_was_made(record):
    assert record["suite"]["name"] == "tiny-v1" and record["suite"]["version"] == 1 and record["complete"]
    for name, s in record["sets"].items():
        assert list(s["policies"]) == ["passive", "thesis-rig", "pd-penetration", "oracle"], name
        for pol in s["policies"].values():
            assert len(pol["metrics"]["energy_integral_ms"]) == s["drops"]
            assert "exit_speed_ratio" in pol["metrics"] and "energy_integral_ms_ci95" in pol["summary"]
    meta = record["meta"]
    for key in ("versions", "git", "cpu", "command", "date", "wall_time_s"):
        assert key in meta, key
    assert meta["versions"]["numpy"] == np.__version__
    assert meta["command"] == "impact-env benchmark pd-penetration"


def test_passive_scores_zero_the_oracle_one_hundred_and_the_reference_one_half(record):
    overall = record["overall"]
    assert overall["passive"]["score"] == 0.0 and overall["oracle"]["score"] == 100.0
    assert overall["pd-penetration"]["score"] == 100.0  # the fake oracle replays its commands
    assert overall["thesis-rig"]["prob_improvement"] == 0.5
    assert overall["oracle"]["drops"] == 7 and overall["oracle"]["sets"] == ["rig", "light"]
    scores, strata = scores_per_drop(record, "passive")
    assert np.all(scores == 0.0) and list(strata) == [0, 0, 0, 1, 1, 1, 1]


def test_the_record_and_its_profile_are_written(record, tmp_path):
    paths = write_record(record, tmp_path)
    assert [p.name for p in paths] == ["tiny-v1.json", "tiny-v1_profile.png"]
    assert json.loads(paths[0].read_text())["overall"]["oracle"]["score"] == 100.0
    assert paths[1].stat().st_size > 10_000


def test_the_leaderboard_is_generated_from_the_records_and_checked(record, tmp_path):
    records = tmp_path / "records"
    write_record(record, records)
    page = tmp_path / "leaderboard.md"
    page.write_text(f"# Leaderboard\n\n{leaderboard.START}\nold\n{leaderboard.END}\n")
    args = ["--records", str(records), "--page", str(page), "--suite", "tiny-v1",
            "--suite-page", str(tmp_path / "absent.md")]
    assert leaderboard.main([*args, "--check"]) == 1  # stale
    assert leaderboard.main(args) == 0
    assert leaderboard.main([*args, "--check"]) == 0
    text = page.read_text()
    rows = [ln for ln in text.splitlines() if ln.startswith("| ") and ln[2].isdigit()]
    assert [r.split("|")[2].strip() for r in rows][-1] == "`passive`"
    assert "| 1 |" in rows[0] and "100.0 [100.0, 100.0]" in text
    assert rows[0].count(", 1.00x") == len(record["sets"]), "the oracle is 1.00x of itself on every set"
    # a changed record makes the page stale again
    rec = json.loads((records / "tiny-v1.json").read_text())
    rec["overall"]["thesis-rig"]["score"] = 1.0
    (records / "tiny-v1.json").write_text(json.dumps(rec))
    assert leaderboard.main([*args, "--check"]) == 1


def test_the_repository_leaderboard_matches_its_records():
    """docs/leaderboard.md is what scripts/leaderboard.py writes from docs/results/benchmark."""
    assert leaderboard.main(["--check"]) == 0
