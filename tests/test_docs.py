"""The documentation as a user meets it.

* Every tutorial (docs/tutorials/*.md) runs top to bottom: its ```bash and ```python blocks, in
  page order, in one scratch folder (python blocks share one namespace per page, as in a
  notebook; bash blocks run with ``set -e`` and the repository on PYTHONPATH, so
  ``python -m agents.train`` works as from the repository root).  A block whose first line is
  ``# not run by the tests: REASON`` is skipped (hardware, a long real run).  The pages keep
  their budgets small so that the three cost about a minute or two each after the kernels are
  compiled; each test asserts what the page says the user will see.
* README and the docs carry no dated prose outside generated blocks: no dates, UTC times, load
  averages, CPU model names or issue numbers (a page states today's figure and the command that
  reproduces it; a script writes figures with their machine and date into generated blocks).
* A hand-written page of docs/ holds at most 2,500 words outside its generated blocks: a longer
  one is split by topic.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
TUTORIALS = sorted((DOCS / "tutorials").glob("*.md"))
SKIP = "# not run by the tests:"
BLOCK = re.compile(r"^```(bash|python)\n(.*?)^```$", re.S | re.M)


def blocks(page: Path) -> list[tuple[str, str]]:
    """The (language, code) blocks of a page that the tests run, in page order."""
    return [(lang, code) for lang, code in BLOCK.findall(page.read_text()) if not code.startswith(SKIP)]


def run_page(page: Path, folder: Path) -> list[str]:
    """Run every block of ``page`` in ``folder``; returns each block's output (stdout + stderr)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           "MPLBACKEND": "Agg", "IMPACT_ENV_REPO": str(ROOT)}
    bindir = str(Path(sys.executable).parent)  # impact-env and python of this venv
    env["PATH"] = bindir + os.pathsep + env.get("PATH", "")
    if not (folder / "agents").exists():  # the pages run from the repository root: its agents/ is there
        (folder / "agents").symlink_to(ROOT / "agents")
    namespace: dict = {"__name__": "__tutorial__"}
    outputs = []
    for lang, code in blocks(page):
        if lang == "bash":
            out = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", code], cwd=folder, env=env,
                                 capture_output=True, text=True, timeout=1200)
            assert out.returncode == 0, \
                f"{page.name}: block failed:\n{code}\n{out.stdout[-3000:]}\n{out.stderr[-3000:]}"
            outputs.append(out.stdout + out.stderr)
        else:
            old = Path.cwd()
            os.chdir(folder)
            try:
                exec(compile(code, f"{page.name}:python block", "exec"), namespace)  # noqa: S102
            finally:
                os.chdir(old)
            outputs.append("")
    return outputs


def test_every_tutorial_has_blocks_the_tests_run():
    assert [p.name for p in TUTORIALS] == ["benchmark-your-policy.md", "deploy.md", "train-and-compare.md"]
    for page in TUTORIALS:
        assert len(blocks(page)) >= 3, page


@pytest.mark.slow
@pytest.mark.training
def test_tutorial_train_and_compare(tmp_path):
    out = run_page(DOCS / "tutorials" / "train-and-compare.md", tmp_path)
    text = "\n".join(out)
    assert "next: impact-env compare" in text and "best_model.zip" in text
    assert (tmp_path / "runs" / "tutorial" / "best_model.zip").is_file()
    assert "thesis-rig" in text and "pd-penetration" in text


@pytest.mark.slow
def test_tutorial_benchmark_your_policy(tmp_path):
    run_page(DOCS / "tutorials" / "benchmark-your-policy.md", tmp_path)
    summary = (tmp_path / "bench" / "summary.json").read_text()
    assert "relative-damper:gain=800" in summary and "pd-penetration" in summary


@pytest.mark.slow
def test_tutorial_deploy(tmp_path):
    try:
        out = run_page(DOCS / "tutorials" / "deploy.md", tmp_path)
    finally:  # a block that failed before the page's own kill must not leave the target running
        pid_file = tmp_path / "rig.pid"
        if pid_file.is_file():
            subprocess.run(["kill", pid_file.read_text().strip()], capture_output=True)
    text = "\n".join(out)
    assert "listening on" in text and "compiled:pd.policy.json" in text
    assert "PASS" in text and "FAIL" not in text
    assert (tmp_path / "best_c" / "impact_policy.o").is_file()
    assert (tmp_path / "pd_c" / "impact_policy.c").is_file()
    assert list((tmp_path / "rig_logs").glob("*.h5"))


# -- dated prose ---------------------------------------------------------------------------------
MONTHS = ("January|February|March|April|May|June|July|August|September|October|November|December")
DATED = {
    "a date": re.compile(rf"\b(19|20)\d\d-\d\d-\d\d\b|\b\d{{1,2}} ({MONTHS}) (19|20)\d\d\b"),
    "a UTC time": re.compile(r"\b\d{1,2}:\d\d(:\d\d)? ?UTC\b"),
    "a load average": re.compile(r"\bload( average)?( of)? ~?\d+(\.\d+)?\b", re.I),
    "a CPU model": re.compile(r"\b(Xeon|EPYC|Ryzen|Core i[3579]|Rocket Lake|Cascade Lake|Ice Lake|"
                              r"Sapphire Rapids|Zen ?[2345]|znver\d)\b"),
    "an issue number": re.compile(r"\b(issue|issues|PR) #?\d+\b|#\d{2,}\b", re.I),
}
GENERATED = re.compile(r"<!-- ([\w:-]+?):(start|begin) -->.*?<!-- \1:(end) -->", re.S)


def prose_pages() -> list[Path]:
    pages = [ROOT / "README.md", ROOT / "CHANGELOG.md"]
    pages += [p for p in DOCS.rglob("*.md")
              if "results" not in p.relative_to(DOCS).parts and "_build" not in p.parts
              and "generated" not in p.relative_to(DOCS).parts]
    return sorted(pages)


def dated_lines(text: str) -> list[tuple[int, str, str]]:
    """(line number, what, line) of dated prose outside generated blocks."""
    blanked = GENERATED.sub(lambda m: "\n" * m.group(0).count("\n"), text)
    found = []
    for number, line in enumerate(blanked.splitlines(), 1):
        for what, pattern in DATED.items():
            if pattern.search(line):
                found.append((number, what, line.strip()[:120]))
    return found


def test_the_dated_prose_detector_finds_what_it_should_and_skips_generated_blocks():
    text = ("took 833 s (2026-11-27 21:44 UTC, load average 5.4) on a Xeon (Rocket Lake)\n"
            "issue 26's goals\n<!-- t:start -->\n2026-11-27 on a znver4\n<!-- t:end -->\nplain\n")
    found = {what for _, what, _ in dated_lines(text)}
    assert found == set(DATED), found
    assert [n for n, _, _ in dated_lines(text)] == [1, 1, 1, 1, 2]


@pytest.mark.parametrize("page", prose_pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_dated_prose_outside_generated_blocks(page):
    text = page.read_text()
    if page.name == "CHANGELOG.md":  # a release heading carries its date (Keep a Changelog)
        text = re.sub(r"^## \[[\d.]+\] - \d{4}-\d\d-\d\d$", "", text, flags=re.M)
    found = dated_lines(text)
    assert not found, "\n".join(f"{page.relative_to(ROOT)}:{n}: {what}: {line}" for n, what, line in found)


# -- page length ---------------------------------------------------------------------------------
WORD_LIMIT = 2500  # words a hand-written page may hold outside its generated blocks


def hand_written_pages() -> list[Path]:
    """The docs' pages a person writes: every page of docs/ but the results and the reference pages
    generated at build time (and the build)."""
    return [p for p in prose_pages() if p.is_relative_to(DOCS)]


def hand_written_words(text: str) -> int:
    """The words of ``text`` outside its generated blocks, as ``wc -w`` counts them."""
    return len(GENERATED.sub(" ", text).split())


def test_the_word_count_skips_generated_blocks_only():
    text = ("one two\n<!-- t:start -->\nthree four\n<!-- t:end -->\nfive\n"
            "<!-- r:begin -->six<!-- r:end -->seven")
    assert hand_written_words(text) == 4
    assert hand_written_words("<!-- t:start -->\nan unclosed block counts\n") == 7  # marker too
    pages = {str(p.relative_to(DOCS)) for p in hand_written_pages()}
    assert {"index.md", "agents.md", "rig/index.md", "tutorials/deploy.md"} <= pages
    assert not any(p.startswith(("results/", "_build/", "reference/generated/")) for p in pages)


def _page_case(page: Path):
    name = str(page.relative_to(ROOT))
    return pytest.param(page, id=name)


@pytest.mark.parametrize("page", [_page_case(p) for p in hand_written_pages()])
def test_a_hand_written_page_has_at_most_2500_words(page):
    words = hand_written_words(page.read_text())
    assert words <= WORD_LIMIT, (f"{page.relative_to(ROOT)}: {words} words outside generated blocks, over "
                                 f"the limit of {WORD_LIMIT}: split it by topic")
