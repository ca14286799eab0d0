"""Write the README's table from the README's own command, so that the two cannot disagree.

Finds the ``impact-env compare ...`` command in the README's first ``bash`` block (the main
job), runs it (as ``python -m impact_env.cli.main compare ...``, in this checkout; ``--out``
into a temporary folder unless the command names one), and replaces everything between the
markers ``<!-- compare-table:start -->`` and ``<!-- compare-table:end -->`` in README.md with
what it printed (the primary score's table with its intervals, the metrics' table and their
legend lines; not the first line, which holds the wall time) and the command itself.  Unless the
command says ``--oracle``, it runs with ``--no-oracle``: the table's columns do not depend on
what this machine's oracle cache holds.  The catch-time
figure the command writes is copied to ``docs/catch_time.png``, the README's figure.

    python scripts/readme_table.py            # run and rewrite README.md (about 15-60 s)
    python scripts/readme_table.py --check    # run and fail if README.md differs
"""

from __future__ import annotations

import argparse
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
START, END = "<!-- compare-table:start -->", "<!-- compare-table:end -->"
FIGURE = ROOT / "docs" / "catch_time.png"


def main_command(readme: str) -> list[str]:
    """The argument list of the ``impact-env compare`` command in the README's first bash block."""
    block = re.search(r"```bash\n(.*?)```", readme, re.S)
    if block is None:
        raise SystemExit("README.md has no ```bash block")
    for line in block.group(1).splitlines():
        for part in line.split("&&"):
            words = shlex.split(part.strip())
            # impact-env, or the venv's own .venv/bin/impact-env (a new shell needs no activation)
            if len(words) >= 2 and Path(words[0]).name == "impact-env" and words[1] == "compare":
                return words[1:]
    raise SystemExit("no `impact-env compare` command in the README's first bash block")


def run(args: list[str], out_dir: Path) -> str:
    """Run the compare command; returns what it printed (without the 'written:' line)."""
    args = list(args)
    if "--oracle" not in args and "--no-oracle" not in args:
        args.append("--no-oracle")  # the oracle's rows only when the command asks: not from a local cache
    if "--out" in args:
        args[args.index("--out") + 1] = str(out_dir)
    else:
        args += ["--out", str(out_dir)]
    proc = subprocess.run([sys.executable, "-m", "impact_env.cli.main", *args, "--no-progress"],
                          cwd=ROOT, capture_output=True, text=True, check=True)
    # the first line holds the wall time, which no two runs share: the legend line and the table
    lines = [ln for ln in proc.stdout.splitlines() if not ln.startswith(("written:", "scene "))]
    return "\n".join(lines).rstrip()


def between_markers(readme: str, body: str) -> str:
    """README text with everything between the markers replaced by ``body``."""
    pattern = re.compile(re.escape(START) + r".*?" + re.escape(END), re.S)
    if not pattern.search(readme):
        raise SystemExit(f"README.md lacks the markers {START} ... {END}")
    return pattern.sub(lambda _m: f"{START}\n{body}\n{END}", readme, count=1)


def render(command: list[str], printed: str) -> str:
    cmd = " ".join(shlex.quote(w) for w in ["impact-env", *command])
    return (f"`{cmd}` prints (written by `python scripts/readme_table.py`, which runs it; a row whose "
            f"command saturates can differ in its last digits on another CPU):\n\n```\n{printed}\n```")


def table_of(readme: str) -> str:
    """The printed table inside the README's markers."""
    inside = readme.split(START)[1].split(END)[0]
    return inside.split("```\n", 1)[1].rsplit("\n```", 1)[0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="fail if README.md's table differs")
    args = ap.parse_args(argv)
    readme = README.read_text()
    command = main_command(readme)
    with tempfile.TemporaryDirectory() as tmp:
        printed = run(command, Path(tmp))
        new = between_markers(readme, render(command, printed))
        if args.check:  # the table only
            if table_of(new) != table_of(readme):
                print("README.md's table differs from what its command prints", file=sys.stderr)
                return 1
            print("README.md's table is what its command prints")
            return 0
        README.write_text(new)
        shutil.copyfile(Path(tmp) / "catch_time.png", FIGURE)
    print(printed)
    print(f"wrote the table into {README} and the figure {FIGURE}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
