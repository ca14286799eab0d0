"""The oracle (impact_env.eval.oracle) and its hooks in rollout and compare.

Small budgets and short horizons: on ``rig`` the first touch is 1 ms after the start, so a
horizon of 20-40 ms holds the first impact and the first rebound, where the energy integral is
made.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tomllib

from impact_env.config import ConfigError
from impact_env.eval import oracle
from impact_env.eval.compare import compare, format_table, summary_json
from impact_env.eval.rollout import rollout
from impact_env.policy.registry import make_policy, policy_classes, register_policy
from impact_env.scene import load_scene
from impact_env.sim.simulator import Simulator

ROOT = Path(__file__).resolve().parent.parent
RIG = load_scene("rig")
SHORT = 0.02  # s
SEEDS = [1000, 1001]
STATE = ("x1", "v1", "x2", "v2")


@pytest.fixture(autouse=True, scope="module")
def _oracle_registered():
    # an environment installed before this entry point was added does not list it yet
    if "oracle" not in policy_classes():
        register_policy(oracle.OraclePolicy, "oracle")


def _recorded(scene, spec, seeds, horizon):
    r = rollout(scene, make_policy(spec, scene), seeds, horizon=horizon, record_commands=True)
    return r, r.extras["commands"]


# -- registration and parameters ---------------------------------------------------------------------
def test_oracle_is_declared_in_the_policies_entry_point_group():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    eps = project["entry-points"]["impact_env.policies"]
    module, _, cls = eps["oracle"].partition(":")
    assert getattr(__import__(module, fromlist=[cls]), cls) is oracle.OraclePolicy
    assert policy_classes()["oracle"] is oracle.OraclePolicy


@pytest.mark.parametrize("spec, words", [
    ("oracle:generations=0", ["generations", ">= 1"]),
    ("oracle:generations=2.5", ["generations", "whole number"]),
    ("oracle:popsize=1", ["popsize", ">= 2"]),
    ("oracle:basis=3", ["basis", ">= 4"]),
    ("oracle:window=-0.01", ["window", "s"]),
    ("oracle:first_knot=0", ["first_knot", "s"]),
    ("oracle:sigma=0", ["sigma", ">= 1e-06"]),
    ("oracle:warm=all", ["warm", "classic, given"]),
    ("oracle:budget=3", ["unknown parameter", "generations"]),
])
def test_bad_budget_arguments_are_refused_before_anything_runs(spec, words):
    with pytest.raises(ConfigError) as exc:
        make_policy(spec, RIG)
    for w in words:
        assert w in str(exc.value), str(exc.value)


def test_a_span_too_short_for_the_basis_is_refused_before_anything_runs():
    pol = make_policy("oracle:generations=1,popsize=2", RIG)
    with pytest.raises(ConfigError, match="fewer than 5 control periods"):
        pol.prepare(RIG, [1000], 3e-4, {})  # 3 steps, all before the touch at 1 ms
    assert pol.open_loop is None


# -- parameterisation ---------------------------------------------------------------------------------
def test_knots_grow_geometrically_from_the_first_interval_to_the_window_end():
    kn = oracle.knots(0.0, 0.031, 12, 2.5e-4)
    h = np.diff(kn)
    assert len(kn) == 12 - 3 + 1 and kn[0] == 0.0 and kn[-1] == 0.031
    assert h[0] == pytest.approx(2.5e-4, rel=1e-9)
    np.testing.assert_allclose(h[1:] / h[:-1], h[1] / h[0], rtol=1e-9)
    np.testing.assert_allclose(np.diff(oracle.knots(0.0, 0.01, 8, 1.0)), 0.002)  # too long a first interval


def test_basis_is_a_partition_of_unity_inside_its_span_and_zero_before():
    B = oracle.basis_matrix(1e-4, 310, 0.0005, 0.031, 12, 2.5e-4)
    tj = np.arange(310) * 1e-4
    inside = tj >= 0.0005 - 1e-12
    np.testing.assert_allclose(B[inside].sum(axis=1), 1.0, rtol=1e-12)
    assert np.all(B[~inside] == 0.0) and np.all(B >= 0.0)


def test_zero_coefficients_give_the_warm_start_in_the_window_and_hold_its_last_command():
    w = np.linspace(-1.5, 1.5, 50)
    B = oracle.basis_matrix(1e-4, 30, 0.0, 0.003, 6, 2.5e-4)
    u = oracle.candidates(w, B, np.zeros((1, 6)), 50)[:, 0]
    np.testing.assert_array_equal(u[:30], np.clip(w[:30], -1, 1))
    assert np.all(u[30:] == u[29])


# -- cost model ----------------------------------------------------------------------------------------
def test_physics_scene_moves_the_bodies_bitwise_as_the_full_scene():
    """rig without its sensor side, replaying pd-penetration's commands: the same states at every
    control step, and the adapter's energy integral equals the rollout's."""
    full, U = _recorded(RIG, "pd-penetration", SEEDS, SHORT)
    for i, seed in enumerate(SEEDS):
        phys = oracle.physics_scene(RIG, seed)
        assert set(phys.effects.active) == {"shaker", "saturation"}
        r = rollout(phys, oracle.Replay(U[:, i:i + 1]), [seed], horizon=SHORT)
        for k in STATE:
            np.testing.assert_array_equal(r.traces[k][:, 0], full.traces[k][:, i], err_msg=k)
        J, end = oracle._Rig(phys, 3).run(seed, np.repeat(U[:, i:i + 1], 3, axis=1))
        np.testing.assert_array_equal(end["Y"][1], [full.traces[k][-1, i] for k in STATE])
        # same ratios summed in the same order (the adapter's objective is the tick sum, not the
        # plant's exact integral); the energy is computed by numpy here and by the env's compiled
        # kernel there: a few ulps per term, so 1e-12 relative bounds the sum
        np.testing.assert_allclose(J, full.metrics["energy_integral_ticks_ms"][i], rtol=1e-12)


@pytest.mark.parametrize("scene", ["rig", "rig-randomized"])
def test_the_compiled_population_replay_is_the_step_by_step_one_bitwise(scene):
    """_Rig.run steps the population in compiled chunks; the same commands stepped one Python
    sim.step at a time (what it did before) give the same energy integrals and end states, bit
    for bit, over more steps than one noise block holds."""
    sc = oracle.physics_scene(load_scene(scene), 1000)
    n, steps = 5, 2 * 256 + 37
    U = np.random.default_rng(3).uniform(-1, 1, (steps, n))
    got, end = oracle._Rig(sc, n).run(1000, U)
    sim = Simulator(sc, n)
    assert steps > sim.hw.noise_block  # the chunks really are cut
    sim.reset([oracle.drop_generator(1000) for _ in range(n)])
    e0 = np.array(sim.impact_energy, dtype=np.float64)
    acc = np.zeros(n)
    for k in range(steps):
        sim.step(np.ascontiguousarray(U[k]))
        acc += sim.catch_energy() / e0
    np.testing.assert_array_equal(got, acc * sc.control_period * 1e3)
    np.testing.assert_array_equal(end["Y"], sim.Y[:, :4])
    np.testing.assert_array_equal(end["ratio"], sim.catch_energy() / e0)


def test_randomised_draws_are_consumed_as_the_simulator_does():
    """rig-randomized (restitution fixed, so that no table interpolation differs): the drop's
    values are the simulator's, and the bodies move bitwise as in the full scene."""
    scene = load_scene("rig-randomized").with_overrides({"randomize.restitution": []})
    full, U = _recorded(scene, "pd-penetration", SEEDS, SHORT)
    for i, seed in enumerate(SEEDS):
        sim = Simulator(scene, 1)
        sim.reset([oracle.drop_generator(seed)])
        phys = oracle.physics_scene(scene, seed)
        assert not phys.randomized
        assert phys == scene.with_draws(sim.drawn[0]).with_overrides(
            {"effects.active": ["shaker", "saturation", "actuator_delay"]})
        r = rollout(phys, oracle.Replay(U[:, i:i + 1]), [seed], horizon=SHORT)
        for k in STATE:
            np.testing.assert_array_equal(r.traces[k][:, 0], full.traces[k][:, i], err_msg=k)


# -- rollout hook ---------------------------------------------------------------------------------------
def test_replaying_recorded_commands_reproduces_every_metric_bitwise():
    """Noise moves no body: the commands a closed-loop law issued, replayed open loop on the same
    seeds, give the same episode (the env's own arithmetic, so bitwise, not to rounding)."""
    for spec in ("pd-penetration", "thesis-rig"):
        r, U = _recorded(RIG, spec, SEEDS, SHORT)
        assert U.shape == (200, 2) and np.abs(U).max() > 0
        rp = oracle.replay(RIG, SEEDS, U, SHORT)
        for key, v in r.metrics.items():
            np.testing.assert_array_equal(rp.metrics[key], v, err_msg=f"{spec} {key}")


class _HeldResidual:
    """A policy that acts every 4 periods, its action added to pd-penetration's command every
    period (what a trained residual agent is), here a fixed function of the observation."""

    observation = "sensors"
    hold_ticks = 4
    residual = "pd-penetration"

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return 0.3 * np.tanh(np.asarray(obs, dtype=np.float64)[:, :1] - 0.5), state


@pytest.mark.parametrize("scene", ["rig", "rig-randomized"])
def test_recorded_commands_of_a_held_residual_policy_are_per_period_and_replay_bitwise(scene):
    """With hold_ticks and a residual law the recorded commands are every period's drive command
    (the law's part included): replayed open loop, one per period, they give the same episode."""
    scene = load_scene(scene)
    r = rollout(scene, _HeldResidual(), SEEDS, horizon=SHORT, record_commands=True)
    U = r.extras["commands"]
    assert U.shape == (200, 2)
    assert np.any(U[0::4] != U[1::4])  # the law moves the command inside a hold
    rp = oracle.replay(scene, SEEDS, U, SHORT)
    for key, v in r.metrics.items():
        np.testing.assert_array_equal(rp.metrics[key], v, err_msg=key)


class _BadPrepare:
    observation = "sensors"

    def __init__(self, shape=None):
        self.shape = shape

    def prepare(self, scene, seeds, horizon, warm_starts):
        if self.shape is None:
            raise RuntimeError("boom")
        self.open_loop = np.zeros(self.shape)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return np.zeros((len(obs), 1)), state


def test_a_failing_prepare_or_a_wrong_open_loop_fails_the_episodes_not_the_rollout():
    r = rollout(RIG, _BadPrepare(), SEEDS, horizon=SHORT, name="bad")
    assert len(r.failures) == 2 and "prepare: RuntimeError: boom" in r.failures[0]["error"]
    assert np.all(np.isnan(r.metrics["energy_integral_ms"]))
    r = rollout(RIG, _BadPrepare((5, 2)), SEEDS, horizon=SHORT, name="bad")
    assert len(r.failures) == 2 and "expected (200, 2)" in r.failures[0]["error"]


# -- the oracle ---------------------------------------------------------------------------------------
@pytest.mark.slow
def test_oracle_is_never_worse_than_any_warm_start_and_is_deterministic():
    horizon = 0.04  # window 30 ms after the touch at 1 ms: a held tail of 9 ms is estimated
    specs = ("pd-penetration", "thesis-rig", "passive")
    warm = {spec: _recorded(RIG, spec, SEEDS, horizon) for spec in specs}
    np.random.seed(7)
    state = np.random.get_state()[1].copy()
    runs = []
    for _ in range(2):
        pol = make_policy("oracle:generations=4,popsize=6,warm=given", RIG)
        r = rollout(RIG, pol, SEEDS, horizon=horizon, name="oracle",
                    warm_starts={k: U for k, (_, U) in warm.items()})
        assert not r.failures
        runs.append((r, pol.open_loop.copy(), pol.stats))
    np.testing.assert_array_equal(np.random.get_state()[1], state)  # numpy's global RNG untouched
    (r, u, st), (r2, u2, _) = runs
    np.testing.assert_array_equal(u, u2)
    steps = [pol.predict(None, episode_start=np.full(2, k == 0))[0][:, 0] for k in range(3)]
    np.testing.assert_array_equal(steps, u[:3])  # a per-step loop gets the same commands
    np.testing.assert_array_equal(r.metrics["energy_integral_ms"], r2.metrics["energy_integral_ms"])
    ei = r.metrics["energy_integral_ms"]
    np.testing.assert_array_equal(ei, st["energy_integral_ms"])  # the choice was made on the same rollout
    # every classic law joins the final choice, given or not (mpc-state, the strongest, was not)
    laws = {spec: warm[spec][0] if spec in warm else _recorded(RIG, spec, SEEDS, horizon)[0]
            for spec in oracle.classic_law_names()}
    assert {"mpc-state", "mpc"} <= set(laws) and not {"mpc-state", "mpc"} & set(warm)
    for spec, rw in laws.items():
        assert np.all(ei <= rw.metrics["energy_integral_ms"]), spec
    best = np.min([rw.metrics["energy_integral_ms"] for rw in laws.values()], axis=0)
    np.testing.assert_array_equal(st["best_warm_ms"], best)
    np.testing.assert_array_equal(st["improvement_ms"], best - ei)
    assert st["evaluations"][0] == 3 + 4 * 6


@pytest.mark.slow
def test_compare_runs_the_oracle_last_and_reports_every_gap_to_it():
    specs = ["pd-penetration", "oracle:generations=3,popsize=4", "passive"]
    runs = compare(RIG, specs, episodes=2, seed=1000, horizon=SHORT, workers=1, progress=False)
    assert list(runs) == specs
    oracle_run = runs["oracle:generations=3,popsize=4"]
    for spec, run in runs.items():
        gap = run.metrics["energy_integral_ms"] - oracle_run.metrics["energy_integral_ms"]
        assert run.summary["gap_to_oracle_ms"] == pytest.approx(float(np.median(gap)))
        assert run.summary["gap_to_oracle_min_ms"] >= 0.0, spec
    assert oracle_run.summary["gap_to_oracle_ms"] == 0.0
    assert oracle_run.summary["oracle_improvement_ms"] >= 0.0 and oracle_run.summary["oracle_seconds_per_drop"] > 0
    table = format_table(runs, SHORT)
    assert "gap to oracle" in table.splitlines()[0] and "oracle:generations=3,popsize=4" in table
    js = summary_json(runs)
    assert js["passive"]["gap_to_oracle_ms"] > 0
    # the oracle's drops do not depend on how its episodes are spread over workers
    two = compare(RIG, specs, episodes=2, seed=1000, horizon=SHORT, workers=2, progress=False)
    for spec in specs:
        np.testing.assert_array_equal(two[spec].metrics["energy_integral_ms"],
                                      runs[spec].metrics["energy_integral_ms"], err_msg=spec)
    # without an oracle there is no gap column
    plain = compare(RIG, ["passive"], episodes=1, seed=1000, horizon=SHORT, workers=1, progress=False)
    assert "gap to oracle" not in format_table(plain, SHORT)
