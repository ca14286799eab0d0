"""numba's TBB layer from pip (``pip install -e ".[tbb]"``): in this process the threaded vector
env runs on TBB (``impact_env._threads._pip_tbb`` loads pip's libtbb, which the loader does not
find by itself) and gives bitwise the serial results.  A script, not a pytest module: the layer
is chosen once per process, and the dev venv has no TBB.  Run by ``.ci/run`` in the core venv
after installing the extra, and by ``tests/test_threads.py`` where TBB is installed.  Prints OK."""

from __future__ import annotations

import numba
import numpy as np

from impact_env.env.vector import ImpactCatchVectorEnv


def run(threads: int) -> list:
    env = ImpactCatchVectorEnv(256, "rig-randomized", hold_ticks=4, threads=threads)
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    out = [obs]
    for _ in range(60):
        obs, r, te, tr, _ = env.step(rng.uniform(-1, 1, (256, 1)))
        out += [obs, r, te, tr]
    return out


def main() -> int:
    ref, got = run(1), run(2)  # 256 envs: two blocks of MIN_BLOCK_ENVS or more
    assert numba.threading_layer() == "tbb", f"the threading layer is {numba.threading_layer()}, not tbb"
    assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(ref, got, strict=True)), \
        "TBB's threaded steps differ from the serial ones"
    print("OK")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
