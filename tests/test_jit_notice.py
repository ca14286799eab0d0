"""The line on stderr before a cold compile: once per process, only when the cache for the
current source stamp is cold, never at import."""

from __future__ import annotations

import os
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


def run(cache_dir: Path) -> str:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir), "PYTHONPATH": str(ROOT),
           "IMPACT_ENV_NUMBA_CACHE": "1"}
    out = subprocess.run([sys.executable, "-c", SNIPPET], env=env, capture_output=True, text=True,
                         timeout=600, check=True)
    return out.stderr


def test_cold_compile_is_announced_once_and_a_warm_cache_is_silent(tmp_path):
    from impact_env._jit import COLD_COMPILE_NOTICE

    head = COLD_COMPILE_NOTICE.split("{")[0]
    cold = run(tmp_path)
    assert cold.count(head) == 1  # two kernels compiled, one line
    assert cold.index("imported") < cold.index(head)  # not at import
    warm = run(tmp_path)
    assert head not in warm
