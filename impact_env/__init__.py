"""impact_env: catching a falling body with a shaker so that it does not bounce.

Layers (each imports only those below it): ``plant`` (numba kernels) <- ``effects`` <-
``scene`` (typed configs, presets) <- ``simulate`` / ``simulator`` <- ``env`` (Gymnasium) <- ``cli``.
Importing this package compiles nothing and imports neither numba nor scipy: the names below
are loaded on first use (PEP 562), so ``impact-env --version`` and ``import impact_env`` stay
fast; kernels compile on first call (and are cached).
It registers the Gymnasium envs ``ImpactCatch-v0`` and ``ImpactCatchRig-v0``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from impact_env.env import ENV_ID, register_envs

if TYPE_CHECKING:
    from impact_env.scene import Scene, load_scene
    from impact_env.sim.drop import SimulationDiverged, simulate
    from impact_env.sim.trajectory import Trajectory

register_envs()

__all__ = ["ENV_ID", "Scene", "SimulationDiverged", "Trajectory", "load_scene", "simulate"]
__version__ = "0.3.0"  # the package's version, read by pyproject.toml, --version and CITATION.cff

# the public names that live in heavier modules (numba, scipy): imported when first asked for
_LAZY = {"Scene": "impact_env.scene", "load_scene": "impact_env.scene", "simulate": "impact_env.sim.drop",
         "SimulationDiverged": "impact_env.sim.drop", "Trajectory": "impact_env.sim.trajectory"}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is not None:
        value = getattr(importlib.import_module(module), name)
        globals()[name] = value
        return value
    # ``impact_env.scene`` and the like after a bare ``import impact_env``, as before the names were lazy
    try:
        return importlib.import_module(f"{__name__}.{name}")
    except ModuleNotFoundError as exc:
        if exc.name != f"{__name__}.{name}":
            raise
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
