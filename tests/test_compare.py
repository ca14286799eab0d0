"""impact-env compare / sweep: same seeds -> same table, failures reported, outputs, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

import baselines.registry as registry
import impact_env.policy.registry as policy_registry
from baselines import Policy
from impact_env.cli import main
from impact_env.control import laws
from impact_env.eval.compare import compare, format_table, split_policies, summary_json
from impact_env.eval.rollout import rollout
from impact_env.eval.sweep import parse_grid, sweep
from impact_env.scene import load_scene

RIG = load_scene("rig")
SHORT = 0.015  # s: the first contact and the first flight on rig


def test_split_policies_keeps_parameters_with_their_policy():
    assert split_policies("passive,thesis-rig:h01=2.3e6,h11=18,pd-penetration") == [
        "passive", "thesis-rig:h01=2.3e6,h11=18", "pd-penetration"]
    assert split_policies("thesis-rig,h11=20; passive") == ["thesis-rig:h11=20", "passive"]
    assert split_policies("ppo:runs/a.zip,passive") == ["ppo:runs/a.zip", "passive"]


def test_same_seeds_give_the_same_table_whatever_the_workers():
    specs = ["passive", "thesis-rig", "pd-penetration"]
    a = compare(RIG, specs, episodes=3, seed=5, horizon=SHORT, workers=1, progress=False)
    b = compare(RIG, specs, episodes=3, seed=5, horizon=SHORT, workers=2, progress=False)
    assert format_table(a, SHORT) == format_table(b, SHORT)
    for spec in specs:
        for key, v in a[spec].metrics.items():
            np.testing.assert_array_equal(v, b[spec].metrics[key], err_msg=f"{spec} {key}")
    ja, jb = summary_json(a), summary_json(b)
    for spec in specs:
        ja[spec].pop("wall_time_s"), jb[spec].pop("wall_time_s")
        ja[spec].pop("wall_time_total_s"), jb[spec].pop("wall_time_total_s")
    assert ja == jb


def test_episode_j_is_the_env_seeded_seed_plus_j():
    """Episode 2 of a run with seed 5 is the drop a lone env seeded 7 gives (same noise)."""
    pol = registry.make_policy("thesis-rig", RIG)
    many = rollout(RIG, pol, [5, 6, 7], horizon=SHORT)
    one = rollout(RIG, registry.make_policy("thesis-rig", RIG), [7], horizon=SHORT)
    for key, v in many.metrics.items():
        np.testing.assert_array_equal(v[2], one.metrics[key][0], err_msg=key)


@pytest.mark.parametrize("compiled", [False, True])
def test_kept_traces_are_the_full_runs_columns(compiled):
    """``trace_rows`` keeps some episodes' traces (compare keeps episode 0's): those columns are
    the full run's, bitwise, in the order asked, in the Python and the compiled loop; every
    episode's catch energy is kept either way; a bad row is refused before anything runs."""
    from impact_env.policy.export import export_policy

    def pol():
        spec = "pd-penetration"
        return export_policy(spec, RIG) if compiled else registry.make_policy(spec, RIG)

    full = rollout(RIG, pol(), [5, 6, 7], horizon=SHORT, trace_rate=2e4)
    some = rollout(RIG, pol(), [5, 6, 7], horizon=SHORT, trace_rate=2e4, trace_rows=[2, 0])
    for key, v in full.traces.items():
        assert np.array_equal(some.traces[key], v[:, [2, 0]], equal_nan=True), key
    assert np.array_equal(some.energy_trace, full.traces["catch_energy"])
    assert np.array_equal(full.energy_trace, full.traces["catch_energy"])
    assert some.traces["x1"].shape == (len(full.trace_t), 2) and some.trace_rows.tolist() == [2, 0]
    assert np.ptp(full.traces["contact_force"]) > 1.0  # the traces hold a contact
    none = rollout(RIG, pol(), [5, 6], horizon=SHORT, trace_rows=[])
    assert none.traces["x1"].shape[1] == 0 and none.energy_trace.shape[1] == 2
    for bad in ([3], [0, 0], [-1]):
        with pytest.raises(ValueError, match="trace_rows"):
            rollout(RIG, pol(), [5, 6, 7], horizon=SHORT, trace_rows=bad)


class _Broken(Policy):
    """Raises at the 20th call; returns NaN for env 1 from the 10th."""

    name = "broken"
    observation = "sensors"

    def __init__(self, scene, **params):
        super().__init__(scene, **params)
        self.calls = 0

    def force(self, values, memory):
        self.calls += 1
        f = np.zeros(values.shape[0])
        if self.calls >= 10 and values.shape[0] > 1:
            f[1] = np.nan
        if self.calls >= 20:
            raise RuntimeError("controller exploded")
        return f


def test_a_failing_policy_is_reported_with_episode_and_seed(monkeypatch):
    monkeypatch.setitem(policy_registry.REGISTERED, "broken", _Broken)
    runs = compare(RIG, ["passive", "broken"], episodes=3, seed=10, horizon=SHORT, workers=1, progress=False)
    fails = runs["broken"].failures
    by_ep = {f["episode"]: f for f in fails}
    assert set(by_ep) == {0, 1, 2}
    assert by_ep[1]["seed"] == 11 and "non-finite action" in by_ep[1]["error"]
    assert by_ep[1]["t_s"] == pytest.approx(9 * RIG.control_period)
    assert "controller exploded" in by_ep[0]["error"] and by_ep[2]["seed"] == 12
    assert runs["broken"].summary["failed_episodes"] == 3
    assert runs["passive"].summary["failed_episodes"] == 0 and not runs["passive"].failures


def test_metrics_of_a_passive_drop_are_physical():
    r = rollout(RIG, registry.make_policy("passive", RIG), [0], horizon=0.06)
    m = {k: float(v[0]) for k, v in r.metrics.items()}
    assert m["peak_force_N"] == 0.0 and m["saturation_time_s"] == 0.0
    # restitution 0.8 on a much heavier suspended body: body 1 leaves at about 0.6 of its speed
    assert 0.5 < m["exit_speed_ratio"] < 0.8 and m["exit_velocity_ratio"] > 0
    assert 0.3 < m["residual_energy_10ms"] < 0.6 and np.isinf(m["time_to_catch_s"])
    assert m["bounces"] == 1 and 0.0 < m["contact_fraction"] < 0.2


def test_cli_compare_json_and_outputs(tmp_path, capsys):
    rc = main(["compare", "--scene", "rig", "--policies", "passive,thesis-rig:h01=1.8e6,h11=18",
               "--episodes", "2", "--horizon", "0.012", "--workers", "1", "--json", "--out", str(tmp_path)])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"passive", "thesis-rig:h01=1.8e6,h11=18"}
    keys = {"time_to_catch_median_s", "time_to_catch_iqr_s", "residual_energy_10ms", "residual_energy_50ms",
            "residual_energy_100ms", "exit_speed_ratio", "bounces", "peak_force_N", "rms_force_N",
            "contact_fraction", "saturation_time_s", "episodes", "failed_episodes", "failures"}
    assert keys <= set(out["passive"])
    assert out["passive"]["residual_energy_50ms"] is None  # past the 12 ms horizon: null, not NaN
    for name in ("summary.csv", "summary.json", "episodes.csv", "energy.png", "force.png", "motion.png",
                 "catch_time.png"):
        assert (tmp_path / name).stat().st_size > 0
    assert len((tmp_path / "episodes.csv").read_text().strip().splitlines()) == 1 + 2 * 2


@pytest.mark.parametrize("argv,msg", [
    (["--policies", "thesis-rgi"], "unknown policy 'thesis-rgi'"),
    (["--policies", "thesis-rig:h03=1"], "unknown parameter"),
    (["--policies", "ppo:/no/such/model.zip"], "not found"),
    (["--episodes", "0"], "episodes = 0 must be an integer >= 1"),
])
def test_cli_compare_bad_input_exits_2(argv, msg, capsys):
    assert main(["compare", "--no-progress", *argv]) == 2
    assert msg in capsys.readouterr().err


def test_parse_grid():
    np.testing.assert_allclose(parse_grid("h01", "1e5:5e5:5", False), [1e5, 2e5, 3e5, 4e5, 5e5])
    np.testing.assert_allclose(parse_grid("h11", "1:100:3", True), [1, 10, 100])
    for bad in ("5:1:3", "1:2", "a:b:c", "0:10:3"):
        with pytest.raises(ValueError, match="grid for h11"):
            parse_grid("h11", bad, True)


def test_sweep_small_grid_batches_the_pairs(tmp_path, capsys):
    res = sweep(RIG, "thesis-rig", (("h01", np.array([1e5, 1.2e6, 3e6])), ("h11", np.array([1.0, 18.0]))),
                t_end=0.01, workers=1, progress=False)
    assert res.metrics["peak_force_N"].shape == (3, 2)
    # no force limit by default (as in the thesis's fig 4.4): the law gets more than the shaker's 200 N
    assert res.metrics["peak_demand_N"].max() > 1000.0 and res.limit == "none"
    np.testing.assert_array_equal(res.within_limit, res.metrics["peak_force_N"] <= 200.0)
    if res.best is not None:
        assert res.best["peak_force_N"] <= 200.0
    # one pair of the batch equals the same gains run alone
    alone = sweep(RIG, "thesis-rig", (("h01", np.array([1.2e6])), ("h11", np.array([18.0]))), t_end=0.01,
                  workers=1, progress=False)
    assert alone.metrics["exit_speed_ratio"][0, 0] == res.metrics["exit_speed_ratio"][1, 1]
    rc = main(["sweep", "--h01", "1e5:3e6:2", "--h11", "1:100:2", "--log", "--t-end", "0.008",
               "--workers", "1", "--json", "--out", str(tmp_path)])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["pairs"] == 4 and out["force_limit_N"] == 200.0
    assert (tmp_path / "sweep.csv").exists() and (tmp_path / "sweep.png").exists()


@pytest.mark.slow
def test_a_saved_sb3_model_joins_the_table(tmp_path):
    """A PPO model saved by stable-baselines3 (untrained: only the plumbing is tested) runs
    through compare like a baseline; its observation is named in the spec, or in PATH.json."""
    from stable_baselines3 import PPO

    from impact_env.env.sb3_vecenv import make_sb3_vec_env

    env = make_sb3_vec_env("rig", num_envs=1)
    path = tmp_path / "agent.zip"
    PPO("MlpPolicy", env, n_steps=64, batch_size=32, policy_kwargs={"net_arch": [8]}, seed=0).save(path)
    # without its settings file nothing is guessed: the spec must give the env settings
    with pytest.raises(Exception, match="hold_ticks, residual in the spec"):
        registry.make_policy(f"{path}:observation=sensors,history=1", RIG)
    with pytest.raises(Exception, match="no settings file"):
        registry.make_policy(str(path), RIG)
    spec = f"ppo:{path}:observation=sensors,history=1,hold_ticks=1,residual=none"
    runs = compare(RIG, ["passive", spec], episodes=2, seed=0, horizon=0.005, workers=1, progress=False)
    s = runs[spec].summary
    assert s["failed_episodes"] == 0 and s["peak_demand_N"] <= 200.0 + 1e-9
    (tmp_path / "agent.json").write_text(json.dumps({"observation": "sensors", "history": 1}))
    assert registry.make_policy(str(path), RIG).observation == "sensors"


@pytest.mark.parametrize("law", [law.name for law in laws.REGISTRY if law.observation == "sensors"])
def test_a_baseline_and_its_compiled_policy_print_the_same_table(law, tmp_path):
    """Each classic law exists once, as the compiled kernel: the baseline (Python, its predict
    once per step) and its exported policy file (the compiled loop) run bitwise the same
    episodes, so `compare --policies pd-penetration` prints what `compiled:pd.policy.json` does."""
    path = registry.make_policy(law, RIG).compiled().save(tmp_path / "law.policy.json")
    spec = f"compiled:{path}"
    runs = compare(RIG, [law, spec], episodes=3, seed=2, horizon=0.05, workers=1, progress=False)
    for key, v in runs[law].metrics.items():
        np.testing.assert_array_equal(v, runs[spec].metrics[key], err_msg=key)
    rows = format_table(runs, 0.05).splitlines()
    row = {r.split()[0]: r.split(None, 1)[1] for r in rows if r.split() and r.split()[0] in (law, spec)}
    assert row[law] == row[spec]
