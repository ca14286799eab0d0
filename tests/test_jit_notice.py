"""The compile progress on stderr: only while kernels compile (a cold cache for the current
source stamp), never at import, saying which kernel and how far; one compiled version per kernel
for calls with different constants (fewer specialisations, less to compile); and one cache for
every copy of the same sources under ``NUMBA_CACHE_DIR``."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SNIPPET = """
import numpy as np
import impact_env  # importing compiles nothing and says nothing
import sys
print("imported", file=sys.stderr, flush=True)
from impact_env.effects.delay import delay_block, make_delay_state
from impact_env.effects.saturation import saturate_block
buf, head = make_delay_state(2, 1)
x = np.ones((4, 1))
delay_block(buf, head, x, np.empty_like(x))
saturate_block(np.ones(3), np.zeros(2), np.array([1.0, -1.0, 0.5, np.inf]), np.empty(3), np.zeros(3, bool))
"""
# kernels defined here are not cached (no file to key them on): IMPACT_ENV_NUMBA_CACHE=0
NESTED = """
import sys
import numpy as np
from impact_env._jit import jit

@jit
def plus_one(x):
    return x + 1.0

@jit
def leaf(which, x):
    return x * which

@jit
def middle(x):
    return leaf(2, x) + leaf(3, x)  # two constants: one compiled version of leaf

@jit
def entry(x):
    return middle(x) + leaf(4, x) + plus_one(x)

print(entry(1.5), file=sys.stderr)
print("signatures", len(leaf.signatures), leaf.signatures, file=sys.stderr)
"""


def run(code: str, cache_dir: Path, cache: str = "1") -> str:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir), "PYTHONPATH": str(ROOT),
           "IMPACT_ENV_NUMBA_CACHE": cache}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=600, check=True)
    return out.stderr


def test_a_cold_compile_shows_progress_and_a_summary_and_a_warm_cache_is_silent(tmp_path):
    from impact_env._jit import PROGRESS_HEAD

    cold = run(SNIPPET, tmp_path)
    assert PROGRESS_HEAD in cold
    assert cold.index("imported") < cold.index(PROGRESS_HEAD)  # not at import
    assert re.search(r": 1 so far, now effects\.delay\.delay_block, \d+ s", cold), cold
    assert re.search(r"compiled 2 numba kernels in \d+ s; later runs load them from the cache", cold), cold
    warm = run(SNIPPET, tmp_path)
    assert "numba" not in warm and "compil" not in warm, warm


def test_each_kernel_is_counted_once_and_constants_share_one_version(tmp_path):
    """entry -> middle -> leaf (and entry -> leaf, entry -> plus_one): 4 kernels compiled, each
    counted once, the count never going back while numba returns from a callee
    to its caller; leaf called with 2, 3 and 4 is compiled once, for int64 (numba would type each
    constant as a literal and compile leaf three times)."""
    err = run(NESTED, tmp_path, cache="0")
    assert re.search(r": 1 so far, now __main__\.entry, \d+ s", err), err
    assert "caching is off" in err
    assert "compiled 4 numba kernels" in err, err
    # the count climbs and never exceeds the kernels compiled
    numbers = [int(n) for n in re.findall(r": (\d+) so far, now ", err)]
    assert numbers == sorted(numbers) and set(numbers) <= {1, 2, 3, 4}, err
    assert "signatures 1 [(int64, float64)]" in err, err
    assert "16.0" in err.splitlines()  # the value is the same: (2 + 3) 1.5 + 4 1.5 + (1.5 + 1)


def _copy_package(dest: Path) -> Path:
    shutil.copytree(ROOT / "impact_env", dest / "impact_env",
                    ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    return dest


def test_two_copies_of_the_same_sources_share_the_cache_and_others_do_not(tmp_path):
    """A checkout and an installed wheel hold the same sources at different paths: under one
    NUMBA_CACHE_DIR the second copy loads what the first compiled; a copy with other sources
    compiles its own and leaves the first one's kernels in place."""
    cache = tmp_path / "cache"
    first, second, edited = (_copy_package(tmp_path / name) for name in ("first", "second", "edited"))
    with open(edited / "impact_env" / "effects" / "delay.py", "a") as fh:
        fh.write("\n# another source: another hash\n")

    def run_in(copy: Path) -> str:
        env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(copy),
               "IMPACT_ENV_NUMBA_CACHE": "1"}
        code = SNIPPET + "\nprint(impact_env.__file__, file=sys.stderr)\n"
        out = subprocess.run([sys.executable, "-c", code], env=env, cwd=copy, capture_output=True, text=True,
                             timeout=600, check=True)
        assert str(copy) in out.stderr, out.stderr  # this copy's package was the one imported
        return out.stderr

    assert "compiled 2 numba kernels" in run_in(first)
    assert "compil" not in run_in(second)
    assert "compiled 2 numba kernels" in run_in(edited)
    assert "compil" not in run_in(first)
