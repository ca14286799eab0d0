"""Loading a scene: from a preset name, a TOML file, a dict or a Scene, with dotted overrides.

A TOML file (or a dict) may start from another scene: ``base = "rig"`` (a preset name, or a
path to another scene file, relative to the file that names it), followed by only the fields
it changes, in the usual tables::

    base = "rig"
    name = "rig-heavy"

    [plant]
    m1 = 0.2

    [effects.saturation]
    peak_n = 300.0

The fields are applied to the base as dotted overrides (so ``initial.impact_speed`` replaces
the base's drop height, as ``--set`` does); ``impact-env scene show FILE`` prints the resolved
scene.  Without ``base`` every field not given takes its default.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import tomllib

from impact_env.config import ConfigError, from_dict, with_overrides
from impact_env.scene.presets import PRESETS
from impact_env.scene.scene import Scene

MAX_BASE_DEPTH = 8
_CHAIN: list[str] = []  # the scene files being loaded, outermost first (a base cycle is named)


def scene_from_dict(data: dict, origin: Path | None = None, _depth: int = 0) -> Scene:
    """A scene from a nested dict (the TOML's tables); ``base`` as in the module doc.
    ``origin``: the file the dict came from (relative ``base`` paths start at its folder)."""
    if not isinstance(data, dict):
        raise ConfigError(f"a scene must be a table of keys, got {data!r}")
    if "base" not in data:
        return from_dict(Scene, data)
    data = dict(data)
    base = data.pop("base")
    if not isinstance(base, str):
        raise ConfigError(f"base must be a preset name or a path to a scene .toml, got {base!r}")
    if _depth >= MAX_BASE_DEPTH:
        raise ConfigError(f"base = {base!r}: more than {MAX_BASE_DEPTH} bases in a chain (a cycle?)")
    if base not in PRESETS and origin is not None and not Path(base).is_absolute():
        joined = origin.parent / base
        if base.endswith(".toml") or joined.exists():
            base = str(joined)
    scene = _load(base, _depth + 1)
    flat = _flatten(data)
    return with_overrides(scene, flat, parse=False) if flat else scene


def _flatten(data: dict, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in data.items():
        where = f"{prefix}.{key}" if prefix else key
        if isinstance(value, dict):
            out.update(_flatten(value, where))
        else:
            out[where] = value
    return out


def load_toml(path: str | Path, _depth: int = 0) -> Scene:
    """A scene from a TOML file; a missing file or a syntax error raises ConfigError naming
    the file."""
    path = Path(path)
    if not path.is_file():
        what = "is a directory" if path.is_dir() else "does not exist"
        raise ConfigError(f"scene file {str(path)!r} {what} (give a preset: {', '.join(PRESETS)}; "
                          "or a path to a scene .toml)")
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"scene file {str(path)!r} is not valid TOML: {exc}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"scene file {str(path)!r} cannot be read: {exc}") from None
    key = str(path.resolve())
    if key in _CHAIN:
        chain = " -> ".join(repr(p) for p in [*_CHAIN, key])
        raise ConfigError(f"base: the scene files form a cycle: {chain}")
    _CHAIN.append(key)
    try:
        return scene_from_dict(data, origin=path, _depth=_depth)
    except ConfigError as exc:
        msg = str(exc)  # the innermost file names itself once; outer files do not repeat it
        raise ConfigError(msg if msg.startswith(("scene file ", "base: ")) else
                          f"scene file {str(path)!r}: {msg}") from None
    finally:
        _CHAIN.pop()


def _load(text: str, depth: int = 0) -> Scene:
    if text in PRESETS:
        return PRESETS[text]()
    if text.endswith(".toml") or Path(text).exists():
        return load_toml(text, depth)
    import difflib

    hint = difflib.get_close_matches(text, list(PRESETS), n=1)
    near = f"; did you mean {hint[0]!r}?" if hint else ""
    raise ConfigError(f"unknown scene {text!r}{near} (presets: {', '.join(PRESETS)}; "
                      "or give a path to a .toml file)")


def load_scene(spec: str | Path | Scene | dict, overrides: dict[str, Any] | None = None) -> Scene:
    """A scene from a preset name, a TOML path, a dict or a Scene, with dotted overrides applied."""
    if isinstance(spec, Scene):
        scene = spec
    elif isinstance(spec, dict):
        scene = scene_from_dict(spec)
    else:
        scene = _load(str(spec))
    if overrides:
        scene = scene.with_overrides(overrides)
    return scene
