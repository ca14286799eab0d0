"""numba's TBB layer from pip (``pip install -e ".[tbb]"``): in this process the threaded compiled
rollout (``compare --threads``: one compiled parallel region over blocks of episodes) runs on TBB
(``impact_env._threads._pip_tbb`` loads pip's libtbb, which the loader does not find by itself)
and gives bitwise the serial results.  The env's step runs its blocks in Python threads (no
parallel region), so the rollout is the one user of the layer.  A script, not a pytest module:
the layer is chosen once per process, and the dev venv has no TBB.  Run by ``.ci/run`` in the core
venv after installing the extra, and by ``tests/test_threads.py`` where TBB is installed.  Prints
OK."""

from __future__ import annotations

import numba
import numpy as np

from impact_env.eval.rollout import MIN_BLOCK_EPISODES, rollout
from impact_env.policy.export import export_policy
from impact_env.scene import load_scene

SCENE = load_scene("rig-randomized")


def run(threads: int):
    policy = export_policy("pd-penetration", SCENE)
    seeds = list(range(3, 3 + 2 * MIN_BLOCK_EPISODES))  # two blocks: both threads get one
    return rollout(SCENE, policy, seeds, horizon=0.02, threads=threads, record_commands=False)


def _arrays(result) -> list[np.ndarray]:
    return [np.asarray(v) for v in vars(result).values() if isinstance(v, np.ndarray)] + \
        [np.asarray(v) for v in result.metrics.values()]


def main() -> int:
    ref, got = run(1), run(2)
    assert numba.threading_layer() == "tbb", f"the threading layer is {numba.threading_layer()}, not tbb"
    assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(_arrays(ref), _arrays(got), strict=True)), \
        "TBB's threaded rollout differs from the serial one"
    print("OK")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
