"""Facts and small helpers that agents.train and agents.distill both use (kept here so that
neither imports the other for them): the held-out drops, the machine's load, the versions a
record names, and the parsing of KEY=VALUE options."""

from __future__ import annotations

import ast
import sys

from impact_env.config import ConfigError

TEST_SEED = 1000  # the README's held-out drops (compare --seed 1000)
TEST_EPISODES = 100


LABEL_MAX = 64  # characters of a run's label


def check_label(label: str | None) -> None:
    """A run's ``--label``, its name in reports (``model.json``'s ``label``; agents_report keys its
    per-drop results by it as ``LABEL|METRIC``): 1 to LABEL_MAX characters, no white space, ``|``
    or path separators.  ConfigError before any work."""
    if label is None:
        return
    if not (0 < len(label) <= LABEL_MAX) or any(c.isspace() or c in "|/\\" for c in label):
        raise ConfigError(f"--label {label!r}: a run's name in reports, 1 to {LABEL_MAX} characters "
                          "without spaces, '|', '/' or '\\'")


def _load_average() -> float | None:
    """The 1-minute load average (None where the OS has none): wall times on a shared machine are
    read with it."""
    import os

    try:
        return round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):
        return None


def _versions() -> dict:
    import gymnasium
    import numpy
    import stable_baselines3
    import torch

    return {"python": sys.version.split()[0], "stable_baselines3": stable_baselines3.__version__,
            "torch": torch.__version__, "gymnasium": gymnasium.__version__, "numpy": numpy.__version__}


def _literal(text: str):
    """A ``--hp`` value: a Python literal (``3e-4``, ``[32, 32]``, ``'auto'``) or a bare word."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return {"true": True, "false": False, "null": None, "none": None}.get(text.lower(), text)


def _pairs(items: list[str], what: str) -> dict:
    out = {}
    for item in items:
        key, eq, value = item.partition("=")
        if not eq or not key.strip() or not value.strip():
            raise ConfigError(f"{what} {item!r} must be KEY=VALUE")
        out[key.strip()] = _literal(value.strip())
    return out
