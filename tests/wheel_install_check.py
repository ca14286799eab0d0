"""The wheel as a user installs it (run by .ci/run after ``python -m build``; not a pytest module):
the wheel holds ``impact_env`` alone (no top-level ``agents`` or ``baselines`` in site-packages),
installs non-editable into a fresh venv, and README's main command runs from a folder outside the
repository, with a few episodes, writing the table and the files README names.

    python tests/wheel_install_check.py dist/impact_env-X-py3-none-any.whl

The venv takes its dependencies from pip's cache (the core venv of .ci/run fetched them).  With
``NUMBA_CACHE_DIR`` set (.ci/run sets it for both of its lanes), the installed copy loads the
kernels that the checkout compiled, since its sources are the same (impact_env/_jit.py); without
it, most of the step's time is numba compiling the installed copy's kernels.  The last line says
which it was.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: the free space the fresh venv needs: its dependencies take about 0.4 GB installed (llvmlite
#: 0.17, scipy 0.1, numpy, numba, matplotlib and fonttools about 0.03 each) and pip unpacks each
#: wheel beside its install; below this the check would fail midway with pip's "No space left"
NEEDS_BYTES = 1.5e9


def main_command() -> list[str]:
    """README's main command (the first ``impact-env compare`` line of its two commands)."""
    readme = (ROOT / "README.md").read_text()
    match = re.search(r"(impact-env compare [^\n`]*)", readme)
    assert match, "README.md has no 'impact-env compare' command"
    return match.group(1).split()


def top_level_names(wheel: Path) -> set[str]:
    with zipfile.ZipFile(wheel) as archive:
        return {name.split("/")[0] for name in archive.namelist()}


def main(argv: list[str]) -> int:
    wheel = Path(argv[0]).resolve()
    names = top_level_names(wheel)
    extra = {n for n in names if n != "impact_env" and not n.endswith(".dist-info")}
    assert not extra, f"the wheel installs more than impact_env: {sorted(extra)}"
    free = shutil.disk_usage(tempfile.gettempdir()).free
    if free < NEEDS_BYTES:
        raise SystemExit(f"the wheel check builds a fresh venv under {tempfile.gettempdir()} (TMPDIR): it "
                         f"needs about {NEEDS_BYTES / 1e9:.1f} GB free there, and {free / 1e9:.2f} GB are")
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="impact-wheel-") as tmp:
        venv = Path(tmp) / "venv"
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        python = venv / "bin" / "python"
        # --no-compile: Python byte-compiles what it imports, on import (.ci/run installs the same way)
        subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-compile", str(wheel)], check=True)
        installed = time.perf_counter()
        work = Path(tmp) / "elsewhere"
        work.mkdir()
        # from a folder with no repository beside it: the package must come from site-packages
        code = ("import impact_env, importlib.util as u; "
                "print(impact_env.__file__, u.find_spec('agents'), u.find_spec('baselines'))")
        probe = subprocess.run([str(python), "-c", code], capture_output=True, text=True, cwd=work,
                               check=True).stdout.split()
        assert "site-packages" in probe[0] and probe[1:] == ["None", "None"], probe
        command = main_command()
        episodes = command.index("--episodes")
        command[episodes + 1] = "3"  # a few drops: the check is that it runs, not the figures
        command = [str(venv / "bin" / command[0]), *command[1:], "--no-progress"]
        out = subprocess.run(command, capture_output=True, text=True, cwd=work, timeout=1800)
        assert out.returncode == 0, out.stderr[-3000:]
        for policy in ("passive", "thesis-rig", "pd-penetration", "thesis-ideal"):
            assert policy in out.stdout, out.stdout
        results = work / command[command.index("--out") + 1]
        for name in ("summary.csv", "summary.json", "episodes.csv", "energy.png", "catch_time.png"):
            assert (results / name).is_file(), f"{name} missing: {sorted(p.name for p in results.iterdir())}"
    done = time.perf_counter()
    compiled = re.findall(r"compiled \d+ numba kernels in \d+ s", out.stderr)
    print(f"wheel check passed: {wheel.name} installed in {installed - started:.0f} s, README's main "
          f"command (3 episodes) from another folder in {done - installed:.0f} s "
          f"({'; '.join(compiled) if compiled else 'every kernel loaded from the cache'})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
