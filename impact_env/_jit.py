"""The project's one numba jit helper.

Every kernel in ``impact_env`` is decorated with :func:`jit`, so caching and compilation
flags are set in one place.  Nothing is compiled at import time: numba compiles a kernel
lazily on its first call, and with caching on the machine code is reused across processes.

Environment variables
---------------------
``IMPACT_ENV_NUMBA_CACHE``
    ``1`` (default) caches compiled kernels on disk (``__pycache__`` next to the source);
    ``0`` turns the cache off, e.g. when a stale or broken cache is suspected.
``NUMBA_DISABLE_JIT``
    numba's own switch; ``1`` runs every kernel as plain Python (slow, but coverage and
    debuggers see the code).
"""

from __future__ import annotations

import os

import numba

CACHE = os.environ.get("IMPACT_ENV_NUMBA_CACHE", "1").strip().lower() not in ("0", "false", "no", "off")


def jit(func=None, **options):
    """``numba.njit`` with the project's defaults (``cache`` from the environment, no fastmath).

    fastmath stays off: the kernels are compared bitwise between runs and against references,
    and reassociation would make results depend on the compiler's choices.
    """
    options.setdefault("cache", CACHE)
    options.setdefault("fastmath", False)
    options.setdefault("error_model", "numpy")
    if func is None:
        return lambda f: numba.njit(**options)(f)
    return numba.njit(**options)(func)
