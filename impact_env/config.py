"""Typed, frozen configuration records: dict/TOML round trip, unknown keys rejected, dotted overrides.

Every config section is a frozen dataclass whose ``__post_init__`` validates its fields with
:func:`check_range` (naming the field, the value, the unit and the allowed range).  This module
turns such dataclasses into and out of plain dicts and TOML, and applies ``a.b=value`` overrides.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import numbers
import types
import typing
from typing import Any

import tomllib


def whole_multiple(ratio: float) -> int:
    """``round(ratio)`` when ``ratio`` (a period over a step, say) is a whole number >= 1 up to
    float noise (1e-6 relative: 0.3 s / 0.1 s is 2.9999999999999996 in floats), else 0."""
    if not ratio >= 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6 * ratio:
        return 0
    return int(round(ratio))


def doc_field(default, unit: str, doc: str):
    """A dataclass field whose unit and documentation ``scene show`` prints beside the value."""
    return dataclasses.field(default=default, metadata={"unit": unit, "doc": doc})


class ConfigError(ValueError):
    """A configuration value or key is invalid; the message names the field."""


MAX_HOLD_TICKS = 10_000


def check_hold_ticks(hold_ticks) -> int:
    """``hold_ticks`` (control periods per policy step) as an int, or ConfigError naming it and its
    range [1, MAX_HOLD_TICKS]: the one check of it (simulator, task, compiled policy, target)."""
    whole = isinstance(hold_ticks, numbers.Integral) and not isinstance(hold_ticks, bool)
    if not whole or not 1 <= hold_ticks <= MAX_HOLD_TICKS:
        raise ConfigError(f"hold_ticks = {hold_ticks!r} is out of range: an integer number of control "
                          f"periods in [1, {MAX_HOLD_TICKS}] per policy step")
    return int(hold_ticks)


def check_range(name: str, value: float, unit: str, lo: float | None = None, hi: float | None = None,
                lo_open: bool = False, hi_open: bool = False) -> None:
    """Raise ConfigError unless ``value`` is a finite number in the given range."""
    u = f" {unit}" if unit else ""
    lo_s = "" if lo is None else (f"> {lo:g}{u}" if lo_open else f">= {lo:g}{u}")
    hi_s = "" if hi is None else (f"< {hi:g}{u}" if hi_open else f"<= {hi:g}{u}")
    allowed = " and ".join(s for s in (lo_s, hi_s) if s) or "finite"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{name} must be a number ({allowed}), got {value!r}")
    bad = not math.isfinite(value)
    if lo is not None and (value <= lo if lo_open else value < lo):
        bad = True
    if hi is not None and (value >= hi if hi_open else value > hi):
        bad = True
    if bad:
        raise ConfigError(f"{name} = {value!r}{u} is out of range: must be {allowed}")


def check_choice(name: str, value: str, choices: typing.Iterable[str]) -> None:
    choices = list(choices)
    if value not in choices:
        hint = difflib.get_close_matches(str(value), choices, n=1)
        near = f" (did you mean {hint[0]!r}?)" if hint else ""
        raise ConfigError(f"{name} = {value!r} is not one of {', '.join(choices)}{near}")


def _unknown_key(path: str, key: str, valid: list[str]) -> ConfigError:
    hint = difflib.get_close_matches(key, valid, n=1, cutoff=0.5)
    near = f"; did you mean {hint[0]!r}?" if hint else ""
    where = f"{path}.{key}" if path else key
    return ConfigError(f"unknown key {where!r}{near} (valid keys here: {', '.join(valid)})")


@functools.cache
def _hints(cls) -> dict[str, Any]:
    return typing.get_type_hints(cls)  # cached: resolving the hints dominated building a scene


def _coerce(tp: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        return _coerce(args[0], value, where)
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise ConfigError(f"{where} must be a table of keys, got {value!r}")
        return from_dict(tp, value, where)
    if origin is tuple:
        (inner, *_rest) = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where} must be a list, got {value!r}")
        return tuple(_coerce(inner, v, f"{where}[{i}]") for i, v in enumerate(value))
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where} must be a number, got {value!r}")
        return float(value)
    if tp is int:
        whole = isinstance(value, int) or (isinstance(value, float) and value.is_integer())
        if isinstance(value, bool) or not whole:
            raise ConfigError(f"{where} must be an integer, got {value!r}")
        return int(value)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where} must be true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where} must be a string, got {value!r}")
        return value
    return value


def from_dict(cls, data: dict, path: str = ""):
    """Build dataclass ``cls`` from a nested dict; unknown keys raise with the nearest valid one."""
    if not isinstance(data, dict):
        raise ConfigError(f"{path or cls.__name__} must be a table, got {data!r}")
    hints = _hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    kwargs = {}
    for key, value in data.items():
        if key not in names:
            raise _unknown_key(path, key, names)
        where = f"{path}.{key}" if path else key
        kwargs[key] = _coerce(hints[key], value, where)
    return cls(**kwargs)


def to_dict(obj) -> dict:
    """Nested plain dict of a config dataclass (None values are left out)."""
    out = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if v is None:
            continue
        if dataclasses.is_dataclass(v):
            v = to_dict(v)
        elif isinstance(v, tuple):
            v = [to_dict(x) if dataclasses.is_dataclass(x) else x for x in v]
        out[f.name] = v
    return out


def parse_value(text: str) -> Any:
    """Parse the right-hand side of ``--set key=value`` as a TOML value, else a bare string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        low = text.strip().lower()
        if low in ("none", "null"):
            return None
        return text.strip()


def set_dotted(cls, data: dict, key: str, value: Any, path: str = "", split_lists: bool = False) -> None:
    """Set the dotted ``key`` of the plain dict ``data`` (shaped like dataclass ``cls``) in place.

    The key is checked against the schema (unknown keys raise with the nearest valid one); the
    value is checked when the dataclass is built.  A class may define ``_override_clears``,
    a dict from a field to the sibling fields that setting it clears.  ``split_lists``: a string
    for a list field is split at commas (``--set effects.active=shaker,sensors``); a scene file's
    string is not, and is refused as not a list.
    """
    head, _, rest = key.partition(".")
    names = [f.name for f in dataclasses.fields(cls)]
    if head not in names:
        raise _unknown_key(path, head, names)
    where = f"{path}.{head}" if path else head
    tp = _hints(cls)[head]
    sub = _dataclass_of(tp)
    if rest:
        if sub is None:
            raise ConfigError(f"{where} is a value, not a table: cannot set {where}.{rest}")
        set_dotted(sub, data.setdefault(head, {}), rest, value, where, split_lists)
        return
    if split_lists and isinstance(value, str) and typing.get_origin(tp) is tuple:
        value = [v.strip() for v in value.split(",") if v.strip()]
    if sub is not None and not isinstance(value, dict):
        raise ConfigError(f"{where} is a table: set one of its keys, e.g. {where}.<key>=value")
    data[head] = value
    for other in getattr(cls, "_override_clears", {}).get(head, ()):
        if value is not None:
            data[other] = None


def _dataclass_of(tp: Any):
    if dataclasses.is_dataclass(tp):
        return tp
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        for a in typing.get_args(tp):
            if dataclasses.is_dataclass(a):
                return a
    return None


def with_overrides(obj, overrides: dict[str, Any], parse: bool = True):
    """A copy of config ``obj`` with all dotted overrides applied at once, then validated.
    ``parse``: string values are TOML text (``--set``: ``"1e-6"`` is a number); a scene file's
    values are typed already and are taken as they are (``name = "2024"`` stays a string,
    ``m1 = "0.2"`` is refused as a string, with or without ``base``).

    A class may define ``_override_clears_dotted``, a dict from a dotted key to the dotted keys
    (anywhere in it) that setting it resets to their defaults, unless the same overrides set
    them too (e.g. a scene given by impact speed drops its drop-height range)."""
    data = to_dict(obj)
    clears = getattr(type(obj), "_override_clears_dotted", {})
    for key, value in overrides.items():
        if parse and isinstance(value, str):
            value = parse_value(value)
        set_dotted(type(obj), data, key, value, split_lists=parse)
        if value is not None:
            for other in clears.get(key, ()):
                if other not in overrides:
                    _reset_dotted(data, other)
    return from_dict(type(obj), data)


def get_dotted(obj, key: str) -> Any:
    """The value of config ``obj``'s dotted field ``key`` (``"plant.c"``)."""
    for part in key.split("."):
        obj = getattr(obj, part)
    return obj


def replace_dotted(obj, values: dict[str, Any]):
    """A copy of config ``obj`` with the dotted fields ``values`` set to typed values (coerced and
    checked as :func:`from_dict` does), by ``dataclasses.replace`` along each path: the replaced
    dataclasses and their parents are built again (their ``__post_init__`` validates them), the
    others are kept as they are.  What :func:`with_overrides` gives for the same typed values
    without ``_override_clears_dotted``, at a small fraction of its cost (it rebuilds every
    field): for values that are drawn many times (a randomised scene's per-episode draws)."""
    cls: Any = type(obj)
    hints = _hints(cls)
    changes: dict[str, Any] = {}
    nested: dict[str, dict[str, Any]] = {}
    for key, value in values.items():
        head, _, rest = key.partition(".")
        if head not in hints:
            raise _unknown_key("", head, [f.name for f in dataclasses.fields(obj)])
        if rest:
            nested.setdefault(head, {})[rest] = value
        else:
            changes[head] = _coerce(hints[head], value, key)
    for head, sub in nested.items():
        changes[head] = replace_dotted(changes.get(head, getattr(obj, head)), sub)
    return dataclasses.replace(obj, **changes)


def _reset_dotted(data: dict, key: str) -> None:
    """Drop the dotted ``key`` from the plain dict ``data`` (it takes its default again)."""
    head, _, rest = key.partition(".")
    if rest:
        if isinstance(data.get(head), dict):
            _reset_dotted(data[head], rest)
    else:
        data.pop(head, None)


def _toml_scalar(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_scalar(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as TOML")


def dumps_toml(data: dict, comments: dict[str, str] | None = None) -> str:
    """Write a nested dict of scalars/lists as TOML; ``comments`` maps dotted keys to a comment."""
    comments = comments or {}
    lines: list[str] = []

    def emit(d: dict, prefix: str):
        scalars = [(k, v) for k, v in d.items() if not isinstance(v, dict)]
        tables = [(k, v) for k, v in d.items() if isinstance(v, dict)]
        for k, v in scalars:
            full = f"{prefix}.{k}" if prefix else k
            c = comments.get(full)
            lines.append(f"{k} = {_toml_scalar(v)}" + (f"  # {c}" if c else ""))
        for k, v in tables:
            full = f"{prefix}.{k}" if prefix else k
            lines.append("")
            lines.append(f"[{full}]")
            emit(v, full)

    emit(data, "")
    return "\n".join(lines).lstrip("\n") + "\n"
