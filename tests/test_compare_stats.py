"""compare's statistics (impact_env.eval.paired's bootstrap, impact_env.eval.scores), the cached
oracle's score and the refusals of requests out of proportion."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from impact_env.config import ConfigError
from impact_env.eval import limits
from impact_env.eval.compare import ENERGY_CURVE_RATE, compare, format_statistics, summary_json, write_outputs
from impact_env.eval.oracle_cache import OracleCache, law_warm_starts
from impact_env.eval.paired import bootstrap, iqm, mean, prob_improvement, resample_indices
from impact_env.eval.rollout import rollout
from impact_env.eval.scores import PRIMARY, normalized_score
from impact_env.policy.registry import make_policy

H = 0.05  # s: short episodes
SEED = 7


# -- the bootstrap and its statistics, against cases computed by hand ---------------------------------
def test_the_bootstrap_interval_of_a_mean_matches_the_enumerated_distribution():
    """x = [0, 0, 0, 1]: a resample's mean is k/4 with k ~ Binomial(4, 1/4): P(k = 0) = 81/256,
    so the 2.5 % quantile is 0; P(k <= 2) = 243/256 = 94.9 % and P(k <= 3) = 255/256, so the
    97.5 % quantile is 3/4.  With 10 000 resamples the empirical quantiles sit 12 standard
    errors inside those steps."""
    ci = bootstrap(mean, [0.0, 0.0, 0.0, 1.0], seed=3)
    assert (ci.value, ci.low, ci.high) == (0.25, 0.0, 0.75)


def test_iqm_and_probability_of_improvement_by_hand():
    assert iqm(np.arange(1.0, 9.0)) == 4.5  # the mean of 3, 4, 5, 6
    assert iqm(np.array([100.0, 1.0, 2.0, 3.0])) == 2.5  # the outer quarter at each end dropped
    # lower is better: a wins drop 0, ties drop 1, loses drop 2
    assert prob_improvement(np.array([1.0, 2.0, 3.0]), np.array([2.0, 2.0, 2.0])) == 0.5
    assert prob_improvement(np.array([1.0, 1.0, 3.0, 0.0]), np.array([2.0, 2.0, 2.0, 2.0])) == 0.75


def test_a_policy_against_itself_has_probability_one_half_exactly():
    x = np.random.default_rng(0).normal(10.0, 3.0, 40)
    ci = bootstrap(prob_improvement, x, x)
    assert (ci.value, ci.low, ci.high) == (0.5, 0.5, 0.5)


def test_the_stratified_bootstrap_resamples_within_each_stratum():
    strata = np.array([0, 0, 0, 1, 1, 2])
    idx = resample_indices(strata, 500, np.random.default_rng(1))
    assert idx.shape == (500, 6)
    assert np.all(strata[idx] == strata[None, :])  # every resample keeps each stratum's size
    assert set(np.unique(idx[:, 5])) == {5}  # a stratum of one drop is always that drop
    # stratification removes the spread between strata: a mean over two far-apart strata is exact
    x = np.array([0.0, 0.0, 10.0, 10.0])
    assert bootstrap(mean, x, strata=[0, 0, 1, 1]).pair() == [5.0, 5.0]
    assert bootstrap(mean, x).high > 5.0


def test_one_seed_gives_one_interval():
    x = np.random.default_rng(2).normal(size=30)
    assert bootstrap(mean, x, seed=5) == bootstrap(mean, x, seed=5)
    assert bootstrap(mean, x, seed=5) != bootstrap(mean, x, seed=6)


def test_failed_drops_are_left_out_of_an_interval():
    ci = bootstrap(mean, [1.0, np.nan, 1.0])
    assert (ci.value, ci.low, ci.high) == (1.0, 1.0, 1.0)


def test_the_normalised_score_is_exactly_zero_and_one_hundred_at_its_ends():
    rng = np.random.default_rng(4)
    passive = rng.uniform(50, 90, 20)
    oracle = rng.uniform(1, 5, 20)
    assert np.all(normalized_score(passive, passive, oracle) == 0.0)
    assert np.all(normalized_score(oracle, passive, oracle) == 100.0)
    assert np.isnan(normalized_score([3.0], [2.0], [2.0])[0])  # oracle no better than passive: undefined


# -- compare with the cached oracle ------------------------------------------------------------------
def _fake_oracle(scene, seeds, root, spec="pd-penetration"):
    """A cache whose 'oracle' replays pd-penetration's commands (a real replay, a fake search)."""
    cache = OracleCache.of(scene, H, root=root)
    r = rollout(scene, make_policy(spec, scene), seeds, horizon=H, trace_rate=0.0, record_commands=True)
    for i, s in enumerate(seeds):
        cache.store(s, r.extras["commands"][:, i],
                    {"cpu_seconds": 0.0, "improvement_ms": 0.0, "source": "fake"})
    return r


@pytest.fixture(scope="module")
def scored(tmp_path_factory, scene, warm_kernels):
    root = tmp_path_factory.mktemp("oracle-cache")
    rig = scene("rig")
    pd = _fake_oracle(rig, [SEED + j for j in range(6)], root)
    runs = compare(rig, ["thesis-rig", "pd-penetration"], episodes=6, seed=SEED, horizon=H, workers=1,
                   progress=False, reference="thesis-rig", oracle="auto", oracle_cache=root)
    return runs, pd, root


def test_passive_scores_zero_and_the_oracle_one_hundred_exactly(scored):
    runs, pd, _root = scored
    assert list(runs) == ["passive", "thesis-rig", "pd-penetration", "oracle"]  # passive and the oracle added
    assert runs["passive"].summary["score"] == 0.0
    assert runs["oracle"].summary["score"] == 100.0
    assert runs["passive"].summary["score_ci95"] == [0.0, 0.0]
    # the replayed commands reproduce pd-penetration's episodes bitwise: the same score
    assert np.array_equal(runs["oracle"].metrics[PRIMARY], pd.metrics[PRIMARY])
    assert runs["pd-penetration"].summary["score"] == 100.0
    assert 0.0 < runs["thesis-rig"].summary["score"] < 100.0


def test_the_reference_against_itself_and_the_json_names(scored):
    runs, _pd, _root = scored
    ref = runs["thesis-rig"].summary
    assert ref["prob_improvement"] == 0.5 and ref["prob_improvement_ci95"] == [0.5, 0.5]
    assert ref[f"{PRIMARY}_diff"] == 0.0
    out = json.loads(json.dumps(summary_json(runs)))
    for row in out.values():
        for key in ("energy_integral_ms", "energy_integral_ms_ci95", "energy_integral_ms_iqm", "score",
                    "prob_improvement", "prob_improvement_ci95", "exit_speed_ratio_ci95"):
            assert key in row, key
        low, high = row["energy_integral_ms_ci95"]
        assert low <= row["energy_integral_ms"] <= high
    pd, ref_ei = runs["pd-penetration"].metrics[PRIMARY], runs["thesis-rig"].metrics[PRIMARY]
    row = out["pd-penetration"]
    assert row["prob_improvement"] == np.mean((pd < ref_ei) + 0.5 * (pd == ref_ei))
    assert row["energy_integral_ms_diff"] == pytest.approx(np.mean(pd - ref_ei), rel=1e-12)
    text = format_statistics(runs)
    assert "int E ms*" in text and "thesis-rig (reference)" in text and "score" in text


def test_summary_csv_holds_the_intervals_as_two_columns(scored, tmp_path, scene):
    runs, _pd, _root = scored
    write_outputs(runs, tmp_path, scene("rig"), SEED, H)
    with open(tmp_path / "summary.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert {"energy_integral_ms_ci95_low", "energy_integral_ms_ci95_high", "score", "prob_improvement",
            "prob_improvement_ci95_low", "reference"} <= set(rows[0])
    assert float(rows[0]["score"]) == 0.0 and rows[0]["policy"] == "passive"
    assert json.loads((tmp_path / "summary.json").read_text())["primary"] == PRIMARY


def test_without_a_complete_cache_there_is_no_score(scored, scene):
    _runs, _pd, root = scored
    runs = compare(scene("rig"), ["passive"], episodes=7, seed=SEED, horizon=H, workers=1, progress=False,
                   oracle="auto", oracle_cache=root)  # drop 7 is not cached
    assert list(runs) == ["passive"] and "score" not in runs["passive"].summary


def test_the_cached_oracle_is_the_oracle_searched_again(tmp_path, scene, warm_kernels):
    """A real search at a tiny budget: the cached commands are the oracle's own, bitwise, and the
    replayed row's energy integral is the one its search chose."""
    pytest.importorskip("cma")
    from impact_env.eval.oracle import OraclePolicy

    rig = scene("rig")
    params = {"generations": 2, "popsize": 4}
    runs = compare(rig, ["passive"], episodes=1, seed=SEED, horizon=H, workers=1, progress=False,
                   oracle="compute", oracle_cache=tmp_path, oracle_params=params)
    direct = OraclePolicy(rig, **params)
    direct.prepare(rig, [SEED], H, law_warm_starts(rig, SEED, H))
    cached, _ = OracleCache.of(rig, H, params, root=tmp_path).load([SEED])
    assert np.array_equal(cached, direct.open_loop)
    assert runs["oracle"].metrics[PRIMARY][0] == direct.stats["energy_integral_ms"][0]
    assert runs["oracle"].summary["score"] == 100.0 and runs["passive"].summary["score"] == 0.0


def test_the_cache_key_follows_the_scene_horizon_budget_and_warm_start_laws(tmp_path, scene, monkeypatch):
    """A law added to the classic laws (whose commands join every cached search), or a law's
    default changed, moves the key: a search made without it could be beaten by it."""
    import dataclasses

    from impact_env.control import laws

    rig = scene("rig")
    a = OracleCache.of(rig, H, root=tmp_path).folder
    assert OracleCache.of(rig, H, root=tmp_path).folder == a
    assert OracleCache.of(rig, 2 * H, root=tmp_path).folder != a
    assert OracleCache.of(rig, H, {"generations": 50}, root=tmp_path).folder != a
    assert OracleCache.of(rig.with_overrides({"plant.m1": 0.11}), H, root=tmp_path).folder != a
    with pytest.raises(ConfigError, match="warm"):
        OracleCache.of(rig, H, {"warm": "given"}, root=tmp_path)
    registry = list(laws.REGISTRY)
    assert set(OracleCache.of(rig, H, root=tmp_path).what["warm_start_laws"]) == {law.name for law in registry}
    monkeypatch.setattr(laws, "REGISTRY", registry[:-1])  # a registry without its last law
    assert OracleCache.of(rig, H, root=tmp_path).folder != a
    pd = next(law for law in registry if law.name == "pd-penetration")
    kp = dataclasses.replace(pd.params["kp"], default=2 * pd.params["kp"].default)
    monkeypatch.setattr(laws, "REGISTRY", [dataclasses.replace(law, params={**law.params, "kp": kp})
                                           if law is pd else law for law in registry])
    assert OracleCache.of(rig, H, root=tmp_path).folder != a
    monkeypatch.setattr(laws, "REGISTRY", registry)
    assert OracleCache.of(rig, H, root=tmp_path).folder == a


# -- limits ----------------------------------------------------------------------------------------------
def test_zero_workers_are_refused(scene):
    for bad in (0, -2):
        with pytest.raises(ValueError, match=r"workers = .* must be an integer >= 1"):
            compare(scene("rig"), ["passive"], episodes=1, horizon=H, workers=bad, progress=False)


def test_a_request_out_of_proportion_is_refused_with_an_estimate(scene, warm_kernels):
    with pytest.raises(ConfigError, match=r"would need about .*B of memory.*per episode.*available") as err:
        compare(scene("rig"), ["passive"], episodes=100_000_000, progress=False, workers=2)
    assert "--episodes" in str(err.value)


def test_a_request_of_days_is_refused_unless_allowed(scene, monkeypatch):
    monkeypatch.setattr(limits, "measure", lambda *a, **k: (1.0, 1.0))  # 1 s per episode-period
    monkeypatch.setattr(limits, "SMALL_STEPS", 0)  # measured however small
    with pytest.raises(ConfigError, match=r"days.*--allow-long"):
        compare(scene("rig"), ["passive"], episodes=1000, horizon=H, workers=1, progress=False)
    cost = limits.estimate(scene("rig"), H, 1000, 1, 1, 1e4, ENERGY_CURVE_RATE)
    assert cost.seconds == pytest.approx(1000 * H / scene("rig").control_period)


def test_the_command_line_refuses_zero_workers(capsys):
    from impact_env.cli.main import main

    for bad in ("0", "-1"):
        with pytest.raises(SystemExit) as exit_:
            main(["compare", "--workers", bad, "--episodes", "1"])
        assert exit_.value.code == 2
        assert "--workers" in capsys.readouterr().err
