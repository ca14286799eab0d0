"""Loading a scene: from a preset name, a TOML file, a dict or a Scene, with dotted overrides."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from impact_env.config import ConfigError, from_dict
from impact_env.scene.presets import PRESETS
from impact_env.scene.scene import Scene


def scene_from_dict(data: dict) -> Scene:
    return from_dict(Scene, data)


def load_scene(spec: str | Path | Scene | dict, overrides: dict[str, Any] | None = None) -> Scene:
    """A scene from a preset name, a TOML path, a dict or a Scene, with dotted overrides applied."""
    if isinstance(spec, Scene):
        scene = spec
    elif isinstance(spec, dict):
        scene = scene_from_dict(spec)
    else:
        text = str(spec)
        if text in PRESETS:
            scene = PRESETS[text]()
        elif text.endswith(".toml") or Path(text).is_file():
            import tomllib

            with open(text, "rb") as fh:
                scene = scene_from_dict(tomllib.load(fh))
        else:
            import difflib

            hint = difflib.get_close_matches(text, list(PRESETS), n=1)
            near = f"; did you mean {hint[0]!r}?" if hint else ""
            raise ConfigError(f"unknown scene {text!r}{near} (presets: {', '.join(PRESETS)}; "
                              "or give a path to a .toml file)")
    if overrides:
        scene = scene.with_overrides(overrides)
    return scene
