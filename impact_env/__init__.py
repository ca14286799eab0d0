"""impact_env: catching a falling body with a shaker so that it does not bounce.

Layers (each imports only those below it): ``plant`` (numba kernels) <- ``scene`` (typed
configs, presets) <- ``simulate`` (the headless entry point) <- ``cli``.
Importing this package compiles nothing; kernels compile on first use (and are cached).
"""

from impact_env.scene import Scene, load_scene
from impact_env.simulate import SimulationDiverged, Trajectory, simulate

__all__ = ["Scene", "SimulationDiverged", "Trajectory", "load_scene", "simulate"]
__version__ = "0.1.0"
