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
    # Keep a Changelog: a section per release, "## [X.Y.Z] - date", and one for what is unreleased
    changelog = (ROOT / "CHANGELOG.md").read_text()
    assert re.search(rf"^## \[{re.escape(impact_env.__version__)}\] - \d{{4}}-\d\d-\d\d$", changelog, re.M)
    assert "## [Unreleased]" in changelog


def test_licence_matches_pyproject_and_the_heavy_deps_are_optional():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert meta["license"] == "MIT" and meta["license-files"] == ["LICENSE"]  # PEP 639: an SPDX expression
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    core = " ".join(meta["dependencies"])
    assert "torch" not in core and "stable-baselines3" not in core
    assert any("stable-baselines3" in d for d in meta["optional-dependencies"]["sb3"])
    # PyYAML: only agents/run_config.py (training's YAML files) reads YAML, so it is the extra's
    assert "PyYAML" not in core and any("PyYAML" in d for d in meta["optional-dependencies"]["sb3"])
    users = [str(f.relative_to(ROOT)) for f in (ROOT / "impact_env").rglob("*.py")
             if re.search(r"^\s*(import yaml|from yaml)", f.read_text(), re.M)]
    assert users == [], f"impact_env imports yaml (a core module would need PyYAML back in the core): {users}"
    assert "sb3" in " ".join(meta["optional-dependencies"]["dev"])
    # Dask: only --cluster needs it (impact_env.eval.parallel imports it when asked), so it is an extra
    assert "dask" not in core and any("distributed" in d for d in meta["optional-dependencies"]["cluster"])
    assert "cluster" in " ".join(meta["optional-dependencies"]["dev"])
    users = [str(f.relative_to(ROOT)) for f in (ROOT / "impact_env").rglob("*.py")
             if re.search(r"^(import|from) (dask|distributed)", f.read_text(), re.M)]
    assert users == [], f"a module imports Dask at its top (the core would need it): {users}"


def test_gymnasium_make_with_the_module_prefix_in_a_fresh_interpreter(warm_kernels):
    """The documented form ``gymnasium.make("impact_env:ImpactCatch-v0")`` (no import of
    impact_env first) works in a new interpreter: gymnasium imports the module, which registers
    the env.  In this process impact_env is already imported, which would hide a failure."""
    import subprocess
    import sys

    code = ("import sys, gymnasium as gym\n"
            "assert 'impact_env' not in sys.modules\n"
            "env = gym.make('impact_env:ImpactCatch-v0')\n"
            "obs, info = env.reset(seed=0)\n"
            "obs, r, te, tr, info = env.step(env.action_space.sample())\n"
            "assert env.observation_space.contains(obs), obs\n"
            "print('made', env.spec.id, obs.shape)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.startswith("made ImpactCatch-v0"), out.stdout


def test_version_and_help_import_neither_numba_nor_scipy():
    """``impact-env --version`` took 21 s under load: it imported every command's modules, numba
    and scipy.signal among them.  Now the package's public names load on first use, and the
    commands import their machinery when they run."""
    import subprocess
    import sys

    code = ("import sys\n"
            "from impact_env.cli.main import build_parser, main\n"
            "build_parser().format_help()\n"
            "try:\n"
            "    main(['--version'])\n"
            "except SystemExit:\n"
            "    pass\n"
            "heavy = [m for m in ('numba', 'scipy', 'matplotlib', 'torch', 'impact_env.scene')\n"
            "         if m in sys.modules]\n"
            "print('heavy', heavy)\n"
            "import impact_env\n"
            "assert impact_env.load_scene('rig').name == 'rig'  # the lazy names still work\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "heavy []" in out.stdout and f"impact-env {impact_env.__version__}" in out.stdout, out.stdout


def test_the_wheel_holds_impact_env_alone_with_all_its_data_files():
    """The wheel installs ``impact_env`` only (``agents`` and ``baselines`` are generic names that
    would collide in site-packages; they run from the repository), with every data file the
    package reads (C sources of the export, py.typed).  .ci/run builds the wheel and installs it
    in a fresh venv (tests/wheel_install_check.py); this is the cheap half of that check."""
    import fnmatch
    import subprocess

    tool = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert tool["packages"]["find"]["include"] == ["impact_env*"]
    globs = tool["package-data"]["impact_env"]
    tracked = subprocess.run(["git", "ls-files", "impact_env"], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout.split()
    data = [f.removeprefix("impact_env/") for f in tracked if not f.endswith(".py")]
    assert data, "git ls-files found no data files in impact_env"
    missing = [f for f in data if not any(fnmatch.fnmatch(f, g) for g in globs)]
    assert not missing, f"data files the wheel would leave out (add them to package-data): {missing}"
    # nothing in the package imports the repository's agents/ or baselines/
    users = [str(f.relative_to(ROOT)) for f in (ROOT / "impact_env").rglob("*.py")
             if re.search(r"^\s*(from|import) (agents|baselines)\b", f.read_text(), re.M)]
    assert users == [], f"impact_env imports a package the wheel does not install: {users}"
