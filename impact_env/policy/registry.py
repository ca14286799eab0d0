"""Policies by spec: ``make_policy("thesis-rig:h01=2.3e6,h11=18", scene)``.

Spec syntax: ``NAME[:KEY=VALUE,KEY=VALUE...]`` for a named policy (values are numbers, or words
for choice parameters), ``MODULE:ATTR[:KEY=VALUE,...]`` for a policy of your own that Python
imports (``my_policies.yielding:Yield``; ``MODULE`` a dotted module path on ``sys.path``,
``ATTR`` a class or factory; :mod:`impact_env.policy.protocol`), a saved stable-baselines3
model: ``PATH.zip``, ``ALGO:PATH.zip``
(``ppo``, ``sac``, ``td3``, ``a2c``, ``ddpg``), optionally followed by
``:observation=sensors,history=4`` (see :mod:`impact_env.policy.sb3`), or a compiled policy
file: ``compiled:FILE`` (:mod:`impact_env.control.policy`; ``impact-env export`` writes one).
Unknown names or parameters raise :class:`impact_env.config.ConfigError` listing the valid ones.
The grammar is unambiguous because a parameter list always holds ``=`` and an attribute name
never does: the part after the first ``:`` is ``ATTR`` when it holds no ``=`` before the next
``:``, parameters otherwise.

Named policies: the classic laws (:data:`impact_env.policy.laws.LAW_POLICIES`, one per law of
:mod:`impact_env.control.laws`), then the entry-point group ``impact_env.policies`` (name ->
``module:Class``), where a user's own package adds policies without :mod:`impact_env` importing
it (this project's ``pyproject.toml`` registers the oracle there, which needs the ``oracle``
extra), then :func:`register_policy` (a class of this process; it wins over both).  A class
takes ``(scene, **params)`` and has either ``observation``, ``PARAMS`` and SB3's ``predict`` (the
classic laws) or the small protocol of :mod:`impact_env.policy.protocol` (``reset(seed)`` and
``act(observation)``), which :func:`make_policy` wraps.
"""

from __future__ import annotations

import functools
from importlib.metadata import entry_points
from typing import Any

from impact_env.config import ConfigError
from impact_env.control.policy import CompiledPolicy
from impact_env.policy.laws import LAW_POLICIES
from impact_env.policy.protocol import wrap
from impact_env.policy.sb3 import load_model_policy, model_settings, parse_model_spec, require_sb3
from impact_env.scene import Scene, load_scene

GROUP = "impact_env.policies"


REGISTERED: dict[str, type] = {}  # added at run time with register_policy (they win over entry points)


@functools.cache
def entry_point_policies() -> dict:
    """The policies other packages register (entry-point group ``impact_env.policies``): name ->
    entry point, loaded when first asked for."""
    out: dict = {}
    for ep in entry_points(group=GROUP):  # in the order each package declares them
        out.setdefault(ep.name, ep)
    return out


@functools.cache
def _load(name: str) -> type:
    ep = entry_point_policies()[name]
    try:
        return ep.load()
    except Exception as exc:  # one broken plugin must not take the others down
        raise ConfigError(f"policy {name!r} is registered ({ep.value}) but does not load: "
                          f"{type(exc).__name__}: {exc}") from None


def policy_names() -> list[str]:
    return list(dict.fromkeys([*LAW_POLICIES, *entry_point_policies(), *REGISTERED]))


def policy_classes() -> dict[str, Any]:
    """Every named policy that loads: name -> class, the classic laws, the entry points (each
    loaded when first asked for) and :func:`register_policy`."""
    out = {}
    for name in policy_names():
        try:
            out[name] = policy_class(name)
        except ConfigError:
            continue
    return out


def register_policy(cls: Any, name: str | None = None) -> None:
    """Make ``cls`` available by ``name`` (default ``cls.name``) in this process, e.g. a policy
    written in a notebook.  Worker processes of ``compare`` inherit it where they are forked."""
    REGISTERED[name or cls.name] = cls


def import_policy(target: str) -> Any:
    """The class or factory ``MODULE:ATTR`` names, imported (ConfigError naming what failed)."""
    import importlib

    module, _, attr = target.partition(":")
    try:
        mod = importlib.import_module(module)
    except ImportError as exc:
        raise ConfigError(f"policy {target!r}: cannot import module {module!r} ({exc}); is it on sys.path "
                          "(the current folder, PYTHONPATH) or installed?") from None
    try:
        return getattr(mod, attr)
    except AttributeError:
        raise ConfigError(f"policy {target!r}: module {module!r} has no attribute {attr!r}") from None


def policy_class(name: str) -> Any:
    if ":" in name:
        return import_policy(name)
    if name in REGISTERED:
        return REGISTERED[name]
    if name in LAW_POLICIES:
        return LAW_POLICIES[name]
    if name in entry_point_policies():
        return _load(name)
    import difflib

    classes = policy_names()
    hint = difflib.get_close_matches(name, classes, n=1)
    near = f"; did you mean {hint[0]!r}?" if hint else ""
    valid = ", ".join(classes) or f"none: no package registers the entry-point group {GROUP!r}; " \
        "is the project installed (pip install -e .)?"
    raise ConfigError(f"unknown policy {name!r}{near} (valid: {valid}, or a path to a saved SB3 "
                      "model .zip, optionally as ALGO:PATH.zip, or compiled:FILE, or MODULE:CLASS for a "
                      "policy of your own)")


def parse_spec(spec: str) -> tuple[str, dict[str, object]]:
    """``"name:k=v,k=v"`` -> (name, {k: value}); ``"pkg.module:Class:k=v"`` -> ("pkg.module:Class",
    {k: value}) (module doc); values parsed as floats where they are numbers."""
    if not isinstance(spec, str) or not spec.strip():
        raise ConfigError("policy spec must be a non-empty string like 'thesis-rig:h01=2.3e6,h11=18', "
                          f"got {spec!r}")
    name, _, rest = spec.strip().partition(":")
    attr, colon, after = rest.partition(":")
    if attr.strip() and "=" not in attr:  # MODULE:ATTR[:params]
        if not (all(part.isidentifier() for part in name.strip().split(".")) and attr.strip().isidentifier()):
            raise ConfigError(f"policy {spec!r}: a policy of your own is MODULE:ATTR[:KEY=VALUE,...] with "
                              "a dotted module path and a class name (e.g. my_policies.yielding:Yield); a "
                              "named policy's parameters are KEY=VALUE (e.g. thesis-rig:h01=2.3e6)")
        name, rest = f"{name.strip()}:{attr.strip()}", after
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
    return ".zip" in spec and not spec.startswith("compiled:")


def make_policy(spec: str, scene: Scene | str | dict):
    """A policy from its spec (see the module doc), built for ``scene``."""
    if spec.startswith("compiled:"):
        pol = CompiledPolicy.load(spec.partition(":")[2])
        pol.check_scene(load_scene(scene))
        return pol
    if is_model_spec(spec):
        return load_model_policy(spec, scene)
    name, params = parse_spec(spec)
    return wrap(policy_class(name), load_scene(scene), params, name)


def check_spec(spec: str, scene) -> None:
    """Validate a spec without the cost of loading a model (models: syntax, file and settings,
    so that a model without its settings is one error before anything runs, not one per episode)."""
    if is_model_spec(spec) and not spec.startswith("compiled:"):
        _algo, path, opts = parse_model_spec(spec)
        model_settings(path, opts, spec)
        require_sb3()
    else:
        make_policy(spec, scene)


def describe_policies() -> str:
    """One block per named policy: name, observation, parameters with defaults and units."""
    lines = []
    for name, cls in policy_classes().items():
        kind = "" if hasattr(cls, "predict") else ", reset/act protocol"
        observation = getattr(cls, "observation", "sensors")
        lines.append(f"{name} ({observation} observation, module {cls.__module__}{kind})")
        for key, p in getattr(cls, "PARAMS", {}).items():
            default = "scene" if p.default is None else p.default
            lines.append(f"    {key} = {default} {p.unit}  {p.doc}")
    return "\n".join(lines)
