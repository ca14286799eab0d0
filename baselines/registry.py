"""Policies by name: ``make_policy("thesis-rig:h01=2.3e6,h11=18", scene)``.

Spec syntax: ``NAME[:KEY=VALUE,KEY=VALUE...]`` for a baseline (values are numbers, or words for
choice parameters), or a saved stable-baselines3 model: ``PATH.zip``, ``ALGO:PATH.zip``
(``ppo``, ``sac``, ``td3``, ``a2c``, ``ddpg``), optionally followed by
``:observation=sensors,history=4`` (see :mod:`baselines.sb3`).  Unknown names or parameters
raise :class:`impact_env.config.ConfigError` listing the valid ones.
"""

from __future__ import annotations

from baselines.base import Policy
from baselines.passive import Passive
from baselines.pd_penetration import PDPenetration
from baselines.thesis_ideal import ThesisIdeal
from baselines.thesis_rig import ThesisRig
from impact_env.config import ConfigError
from impact_env.scene import Scene, load_scene

POLICIES: dict[str, type[Policy]] = {
    cls.name: cls for cls in (Passive, ThesisIdeal, ThesisRig, PDPenetration)}


def parse_spec(spec: str) -> tuple[str, dict[str, object]]:
    """``"name:k=v,k=v"`` -> (name, {k: value}); values parsed as floats where they are numbers."""
    if not isinstance(spec, str) or not spec.strip():
        raise ConfigError("policy spec must be a non-empty string like 'thesis-rig:h01=2.3e6,h11=18', "
                          f"got {spec!r}")
    name, _, rest = spec.strip().partition(":")
    params: dict[str, object] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise ConfigError(f"policy {name!r}: parameter {item!r} must be KEY=VALUE (e.g. h01=2.3e6)")
        value = value.strip()
        try:
            params[key.strip()] = float(value)
        except ValueError:
            params[key.strip()] = value
    return name.strip(), params


def is_model_spec(spec: str) -> bool:
    """True if ``spec`` names a saved SB3 model (a ``.zip`` path, possibly ``algo:``-prefixed)."""
    return ".zip" in spec


def make_policy(spec: str, scene: Scene | str | dict):
    """A policy from its spec (see the module doc), built for ``scene``."""
    if is_model_spec(spec):
        from baselines.sb3 import load_model_policy

        return load_model_policy(spec, scene)
    name, params = parse_spec(spec)
    if name not in POLICIES:
        import difflib

        hint = difflib.get_close_matches(name, list(POLICIES), n=1)
        near = f"; did you mean {hint[0]!r}?" if hint else ""
        raise ConfigError(f"unknown policy {name!r}{near} (valid: {', '.join(POLICIES)}, or a path to a "
                          "saved SB3 model .zip, optionally as ALGO:PATH.zip)")
    return POLICIES[name](load_scene(scene), **params)


def describe_policies() -> str:
    """One block per baseline: name, observation, parameters with defaults and units."""
    lines = []
    for name, cls in POLICIES.items():
        lines.append(f"{name} ({cls.observation} observation, module {cls.__module__})")
        for key, p in cls.PARAMS.items():
            default = "scene" if p.default is None else p.default
            lines.append(f"    {key} = {default} {p.unit}  {p.doc}")
    return "\n".join(lines)
