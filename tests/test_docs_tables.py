"""The docs' generated blocks (``python scripts/docs_tables.py``) are current, and the facts they
hold come from one place: the layers from pyproject's import-linter contract (README, a project card,
links to docs/architecture.md rather than repeating them), the "where is it" index from the
scene's dataclasses and the registries of effects and laws."""

from __future__ import annotations

import dataclasses
import re

import docs_tables

from impact_env.control import laws
from impact_env.effects import registry
from impact_env.scene import Scene


def test_every_generated_block_is_current(capsys):
    assert docs_tables.main(["--check"]) == 0, capsys.readouterr().err


def _leaves(cls, prefix: str) -> list[str]:
    out = []
    for f in dataclasses.fields(cls):
        sub = f.default_factory if f.default_factory is not dataclasses.MISSING else None
        if dataclasses.is_dataclass(sub):
            out += _leaves(sub if isinstance(sub, type) else type(sub()), f"{prefix}{f.name}.")
        elif "doc" in f.metadata:
            out.append(prefix + f.name)
    return out


def test_the_index_has_every_scene_field_effect_and_law_once():
    lines = docs_tables.where_is_it().splitlines()
    names = [re.search(r"`([^`]+)`", line).group(1) for line in lines]
    expected = list(registry.NAMES) + list(laws.LAWS) + _leaves(Scene, "")
    assert sorted(names) == sorted(expected)
    assert "effects.sensors.force.offset" in names  # a force-sensor bias exists: the index says where
