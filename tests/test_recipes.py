"""docs/architecture.md's "How to add an effect, a law, a task option": the files each recipe
names are where the code has those things, and each registry picks up every module of its kind
(a new effect or law module without its registry line fails here, as does a task option the
kernel reads without saying so); and the three changes made again from the recipes
(scripts/recipe_trial.py's patches) still apply and touch only files their recipes name."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
from dataclasses import fields
from pathlib import Path

import impact_env.control.laws as laws
import impact_env.effects as effects_pkg
from impact_env.control.laws.law import Law
from impact_env.effects import registry
from impact_env.effects.effect import Effect
from impact_env.env import task, task_kernel
from impact_env.hardware import stage


def _recipes(root) -> dict[str, list[str]]:
    """Each recipe's numbered files (the first path in backticks of each numbered item)."""
    doc = (root / "docs" / "architecture.md").read_text()
    section = doc.split("## How to add an effect, a law, a task option", 1)[1].split("\n## ", 1)[0]
    out = {}
    recipe = r"\*\*(An effect|A classic law|A task option)\*\*(.*?)(?=\n\*\*|\Z)"
    for head, body in re.findall(recipe, section, re.S):
        out[head] = re.findall(r"^\d+\. `([^`]+)`", body, re.M)
    return out


def _path(root, module) -> str:
    return str(Path(inspect.getsourcefile(module)).relative_to(root))


def _declared(package, cls) -> list:
    found = []
    for info in pkgutil.iter_modules(package.__path__):
        m = importlib.import_module(f"{package.__name__}.{info.name}")
        found += [v for v in vars(m).values() if isinstance(v, cls)]
    return found


def test_the_recipes_name_the_files_that_hold_each_thing(root):
    r = _recipes(root)
    assert set(r) == {"An effect", "A classic law", "A task option"}, r
    assert [len(r[k]) for k in ("An effect", "A classic law", "A task option")] == [4, 3, 3], r
    new_effect, effect_registry, effect_stage, effect_test = r["An effect"]
    assert effect_stage == _path(root, stage)
    assert (root / new_effect).parent == root / _path(root, effects_pkg).rsplit("/", 1)[0]
    assert effect_registry == _path(root, registry) and (root / effect_test).exists()
    new_law, law_registry, law_test = r["A classic law"]
    assert (root / new_law).parent == root / _path(root, laws).rsplit("/", 1)[0]
    assert law_registry == _path(root, laws) and (root / law_test).exists()
    config, kernel, option_test = r["A task option"]
    assert config == _path(root, task) and kernel == _path(root, task_kernel)
    assert (root / option_test).exists()


def test_every_effect_module_is_registered():
    assert set(_declared(effects_pkg, Effect)) == set(registry.REGISTRY)


def test_every_law_module_is_registered_and_dispatched():
    assert set(_declared(laws, Law)) == set(laws.REGISTRY)
    source = inspect.getsource(laws.law_force)
    for law in laws.REGISTRY[1:]:  # (passive: the fall-through 0)
        module = law.constants.__module__.rsplit(".", 1)[1]
        assert f"return {module}.force(" in source, f"law_force has no branch for {law.name}"


def test_every_option_the_kernel_reads_says_so():
    read = set(re.findall(r"\bp\.(\w+)", inspect.getsource(task_kernel)))
    options = {f.name: f.metadata["kernel"] for f in fields(task.TaskConfig)}
    assert read <= set(task.TaskParams._fields), read - set(task.TaskParams._fields)
    assert {name for name, kernel in options.items() if kernel} == read & set(options)


def _recipe_text(root, heading: str) -> str:
    doc = (root / "docs" / "architecture.md").read_text()
    section = doc.split("## How to add an effect, a law, a task option", 1)[1].split("\n## ", 1)[0]
    return section.split(f"**{heading}**", 1)[1].split("\n**", 1)[0]


def test_each_recipe_trial_still_applies_and_touches_only_what_its_recipe_names(root):
    """The three changes made again from the recipes (scripts/recipe_trial.py) are kept as patches:
    each still applies to the tree as it is (``git apply --check``, or is in it already: the
    trial's own worktree; no compile), and every file
    it writes by hand is named in its recipe (a change that needs a file the recipe does not
    name fails here)."""
    import subprocess

    import recipe_trial

    assert set(recipe_trial.TRIALS) == {"effect", "law", "option"}
    for change, (heading, _what, named_tests) in recipe_trial.TRIALS.items():
        patch = recipe_trial.patch_of(change)
        run = subprocess.run(["git", "apply", "--check", str(patch)], cwd=root, capture_output=True,
                             text=True)
        applied = subprocess.run(["git", "apply", "--check", "--reverse", str(patch)], cwd=root,
                                 capture_output=True, text=True)  # (the trial's own tree has it)
        assert run.returncode == 0 or applied.returncode == 0, f"{patch.name} no longer applies: {run.stderr}"
        text = _recipe_text(root, heading)
        named = set(re.findall(r"`([\w./-]+\.(?:py|md))`", text))
        files = recipe_trial.patch_files(patch)
        assert files and set(files) <= named, f"{change}: the recipe does not name {set(files) - named}"
        assert set(named_tests) <= set(files), change  # (its test is in the patch)


def test_the_effect_recipe_names_every_text_that_spells_the_path_out(root):
    """The texts ``tests/test_signal_path.py`` holds to the code's order are the ones the effect
    recipe says to edit (no more, no fewer)."""
    import test_signal_path

    texts = {where for where, _text, _names in test_signal_path._docs(root)}
    named = set(re.findall(r"`([\w./-]+\.(?:py|md))`", _recipe_text(root, "An effect")))
    assert texts <= named, texts - named
    assert "README.md" not in named  # (it spells no path out)
