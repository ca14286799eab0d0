"""impact_env: catching a falling body with a shaker so that it does not bounce.

Layers (each imports only those below it): ``plant`` (numba kernels) <- ``effects`` <-
``scene`` (typed configs, presets) <- ``simulate`` / ``simulator`` <- ``env`` (Gymnasium) <- ``cli``.
Importing this package compiles nothing; kernels compile on first use (and are cached).
It registers the Gymnasium env ``ImpactCatch-v0``.
"""

from impact_env.env import ENV_ID, register_envs
from impact_env.scene import Scene, load_scene
from impact_env.sim.drop import SimulationDiverged, simulate
from impact_env.sim.trajectory import Trajectory

register_envs()

__all__ = ["ENV_ID", "Scene", "SimulationDiverged", "Trajectory", "load_scene", "simulate"]
__version__ = "0.2.0"  # the package's version, read by pyproject.toml, --version and CITATION.cff
