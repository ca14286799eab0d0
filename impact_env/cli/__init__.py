"""The command line, ``impact-env``: one module per command group, the shared options in
:mod:`impact_env.cli.args`, the entry point in :mod:`impact_env.cli.main`.

The names below load on first use (PEP 562): the command modules import their machinery at their
top, and importing this package (as ``impact-env --version`` does) must not."""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["add_scene_arguments", "main", "parse_overrides", "scene_from_args"]
_LAZY = {"add_scene_arguments": "impact_env.cli.args", "parse_overrides": "impact_env.cli.args",
         "scene_from_args": "impact_env.cli.args"}


def main(argv=None) -> int:
    """The command line (:func:`impact_env.cli.main.main`)."""
    return importlib.import_module("impact_env.cli.main").main(argv)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
