"""The scene: every number a simulation needs, as typed, frozen, validated records.

:class:`Scene` and its sections (:mod:`impact_env.scene.scene`), the ``[effects]`` section
(:mod:`~impact_env.scene.effects`), the ``[randomize]`` ranges and seed policy
(:mod:`~impact_env.scene.randomize`), the presets (:mod:`~impact_env.scene.presets`) and
:func:`load_scene` (:mod:`~impact_env.scene.load`).
"""

from impact_env.scene.load import load_scene, scene_from_dict
from impact_env.scene.presets import PRESETS
from impact_env.scene.scene import Scene

__all__ = ["PRESETS", "Scene", "load_scene", "scene_from_dict"]
