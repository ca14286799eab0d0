"""tests/MAP.md says where each module of the package is tested: every module has its line, or
its package's ``pkg.*`` line, and every test file it names exists."""

from __future__ import annotations

import re


def test_every_module_has_its_tests_listed(root):
    text = (root / "tests" / "MAP.md").read_text()
    listed = dict(re.findall(r"^\| `([\w.]+(?:\.\*)?)` \| (.*) \|$", text, re.M))
    wild = [k[:-1] for k in listed if k.endswith(".*")]
    modules = sorted(str(p.relative_to(root))[:-3].replace("/", ".").removesuffix(".__init__")
                     for p in (root / "impact_env").rglob("*.py") if "__pycache__" not in p.parts)
    missing = [m for m in modules if m not in listed and not m.startswith(tuple(wild))]
    assert not missing, f"tests/MAP.md lacks a line for {missing}"
    stale = [m for m in listed if m not in modules and not m.endswith(".*")]
    assert not stale, f"tests/MAP.md lists modules that no longer exist: {stale}"
    named = {f.strip() for tests in listed.values() for f in tests.split(",") if f.strip()}
    assert all(listed.values()), "a module without tests"
    absent = sorted(f for f in named if not (root / "tests" / f).exists())
    assert not absent, f"tests/MAP.md names test files that do not exist: {absent}"
