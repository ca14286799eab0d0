"""A policy of one's own: the reset/act protocol (impact_env.policy.protocol), the
MODULE:CLASS spec and a third-party package's entry point, found by the real lookup
(importlib.metadata reads a dist-info folder on sys.path)."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

from impact_env.config import ConfigError
from impact_env.eval.compare import compare, split_policies
from impact_env.policy import registry
from impact_env.policy.registry import make_policy, parse_spec

H = 0.03  # s

PACKAGE = '''
"""A third party's policies: a plain object with reset(seed) and act(observation)."""

class Yield:
    """Pulls body 2 down by ``gain`` (in command units), whatever it reads."""

    observation = "sensors"

    def __init__(self, scene, gain=0.0):
        self.gain = float(gain)
        self.seeds = []

    def reset(self, seed):
        self.seeds.append(seed)
        self.steps = 0

    def act(self, observation):
        self.steps += 1
        return -self.gain + 0.0 * float(observation[0])


class Broken:
    def __init__(self, scene):
        pass
'''


@pytest.fixture
def third_party(tmp_path, monkeypatch):
    """A package ``yieldpolicies`` with a dist-info that registers ``yield`` in the group."""
    (tmp_path / "yieldpolicies").mkdir()
    (tmp_path / "yieldpolicies" / "__init__.py").write_text(textwrap.dedent(PACKAGE))
    info = tmp_path / "yieldpolicies-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: yieldpolicies\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[{registry.GROUP}]\nyield = yieldpolicies:Yield\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    registry.entry_point_policies.cache_clear()
    registry._load.cache_clear()
    yield tmp_path
    registry.entry_point_policies.cache_clear()
    registry._load.cache_clear()


def test_the_spec_grammar_tells_a_class_from_parameters():
    assert parse_spec("thesis-rig:h01=2.3e6,h11=18") == ("thesis-rig", {"h01": 2.3e6, "h11": 18.0})
    assert parse_spec("my_policy:Yield") == ("my_policy:Yield", {})
    assert parse_spec("pkg.mod:Yield:gain=0.5,mode=soft") == ("pkg.mod:Yield", {"gain": 0.5, "mode": "soft"})
    assert split_policies("passive,pkg.mod:Yield:gain=0.5,k=2,thesis-rig") == [
        "passive", "pkg.mod:Yield:gain=0.5,k=2", "thesis-rig"]
    with pytest.raises(ConfigError, match="MODULE:ATTR"):
        parse_spec("my-policy:Yield")
    with pytest.raises(ConfigError, match="must be KEY=VALUE"):
        parse_spec("thesis-rig:h01=1,oops")


def test_a_module_class_spec_runs_and_zero_gain_is_passive_bitwise(third_party, scene, warm_kernels):
    rig = scene("rig")
    runs = compare(rig, ["yieldpolicies:Yield", "passive", "yieldpolicies:Yield:gain=0.3"], episodes=3,
                   seed=11, horizon=H, workers=1, progress=False)
    mine, passive = runs["yieldpolicies:Yield"], runs["passive"]
    assert not mine.failures
    for key, values in passive.metrics.items():
        assert np.array_equal(mine.metrics[key], values, equal_nan=True), key
    assert not np.array_equal(runs["yieldpolicies:Yield:gain=0.3"].metrics["energy_integral_ms"],
                              passive.metrics["energy_integral_ms"])


def test_one_object_per_episode_reset_with_its_seed(third_party, scene):
    from impact_env.eval.rollout import rollout

    policy = make_policy("yieldpolicies:Yield:gain=0.1", scene("rig"))
    rollout(scene("rig"), policy, [5, 6, 7], horizon=H, trace_rate=0.0)
    assert [obj.seeds for obj in policy._objects] == [[5], [6], [7]]
    assert {obj.steps for obj in policy._objects} == {round(H / scene("rig").control_period)}


def test_a_third_party_policy_runs_by_name_through_its_entry_point(third_party, scene, capsys):
    from impact_env.cli.main import main

    assert "yield" in registry.policy_names()
    assert "yield (sensors observation, module yieldpolicies, reset/act protocol)" in registry.describe_policies()
    assert registry.policy_class("yield").__module__ == "yieldpolicies"
    code = main(["compare", "--scene", "rig", "--policies", "yield:gain=0.2,passive", "--episodes", "2",
                 "--horizon", str(H), "--workers", "1", "--no-progress", "--reference", "none",
                 "--no-oracle"])
    out = capsys.readouterr().out
    assert code == 0
    assert any(line.startswith("yield:gain=0.2 ") for line in out.splitlines())


def test_a_class_without_the_protocol_is_refused_by_name(third_party, scene):
    with pytest.raises(ConfigError, match=r"neither predict .* nor reset\(seed\) and act"):
        make_policy("yieldpolicies:Broken", scene("rig"))
    with pytest.raises(ConfigError, match="cannot import module 'nowhere_to_be_found'"):
        make_policy("nowhere_to_be_found:Yield", scene("rig"))
    with pytest.raises(ConfigError, match="has no attribute 'Nope'"):
        make_policy("yieldpolicies:Nope", scene("rig"))
