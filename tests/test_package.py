"""The package as users install and cite it: one version everywhere, the licence pyproject
declares, a citation file, torch and stable-baselines3 optional."""

from __future__ import annotations

import re
from importlib.metadata import version
from pathlib import Path

import tomllib

import impact_env

ROOT = Path(__file__).resolve().parent.parent


def test_one_version_everywhere(capsys):
    from impact_env.cli.main import main  # inside: a collection-time import shadows impact_env.cli.main()

    assert version("impact-env") == impact_env.__version__
    try:
        main(["--version"])
    except SystemExit as exc:
        assert exc.code == 0
    assert capsys.readouterr().out.strip() == f"impact-env {impact_env.__version__}"
    cff = (ROOT / "CITATION.cff").read_text()
    assert re.search(rf'^version: "{re.escape(impact_env.__version__)}"', cff, re.M)
    assert "Controlling a one degree of motion impact" in cff and "Nyström" in cff
    assert f"## {impact_env.__version__}" in (ROOT / "CHANGELOG.md").read_text()


def test_licence_matches_pyproject_and_the_heavy_deps_are_optional():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert meta["license"]["text"] == "MIT" and (ROOT / "LICENSE").read_text().startswith("MIT License")
    core = " ".join(meta["dependencies"])
    assert "torch" not in core and "stable-baselines3" not in core
    assert any("stable-baselines3" in d for d in meta["optional-dependencies"]["sb3"])
    assert "sb3" in " ".join(meta["optional-dependencies"]["dev"])
