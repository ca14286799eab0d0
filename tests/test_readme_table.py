"""The README's table is written by scripts/readme_table.py from the README's own command."""

from __future__ import annotations

from pathlib import Path

import readme_table

ROOT = Path(__file__).resolve().parents[1]


def test_the_readme_command_is_the_main_job():
    cmd = readme_table.main_command((ROOT / "README.md").read_text())
    assert cmd[:3] == ["compare", "--scene", "rig"] and "--out" in cmd
    assert "--episodes" in cmd and cmd[cmd.index("--episodes") + 1] == "100"


def test_the_table_sits_between_the_markers_and_is_replaced_whole():
    text = "a\n" + readme_table.START + "\nold\n" + readme_table.END + "\nb\n"
    new = readme_table.between_markers(text, "new table")
    assert new == "a\n" + readme_table.START + "\nnew table\n" + readme_table.END + "\nb\n"
    assert readme_table.between_markers(new, "again").count("again") == 1


def test_the_readme_holds_a_table_of_the_main_job():
    """README.md holds the command's table between the markers, one row per policy of the
    command (the numbers are checked by ``python scripts/readme_table.py --check``, which
    runs the command: too long for the suite)."""
    readme = (ROOT / "README.md").read_text()
    inside = readme.split(readme_table.START)[1].split(readme_table.END)[0]
    cmd = readme_table.main_command(readme)
    policies = cmd[cmd.index("--policies") + 1].split(",")
    assert "catch s: median (IQR)" in inside and "int E ms*" in inside
    stats, _, metrics = inside.partition("catch s: median (IQR)")
    for table in (stats, metrics):
        rows = [ln.split()[0] for ln in table.splitlines() if ln.split() and ln.split()[0] in policies]
        assert rows == policies
    # the primary score's statistics, against the reference (thesis-rig)
    assert "int E ms* [95 % CI]" in stats and "P(better than thesis-rig)" in stats
