"""Options every command shares: the scene and ``--set KEY=VALUE``."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from impact_env.config import ConfigError
from impact_env.eval.parallel import parse_cluster
from impact_env.figstyle import DPI, FORMATS, output_figure
from impact_env.scene import load_scene
from impact_env.scene.scene import ADAPTIVE


def parse_overrides(pairs: list[str] | None) -> dict[str, str]:
    """``["a.b=1", ...]`` (the ``--set`` values) -> ``{"a.b": "1"}``; values are parsed as TOML
    when the scene is built.  ConfigError on an item without ``=``."""
    out: dict[str, str] = {}
    for item in pairs or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set expects KEY=VALUE (e.g. plant.m1=0.05), got {item!r}")
        out[key.strip()] = value.strip()
    return out


def add_scene_arguments(p: argparse.ArgumentParser, positional: bool = False, default: str | None = "ideal",
                        scene: bool = True, default_text: str | None = None) -> None:
    """Give a (sub)command the shared scene options: the scene (``--scene NAME|FILE.toml``, or a
    positional ``scene`` with ``positional=True``) and the repeatable ``--set KEY=VALUE``.
    Every command that builds a scene uses this and :func:`scene_from_args`, so ``--set`` works
    the same way everywhere.  ``scene=False`` adds ``--set`` only (commands over many scenes)."""
    if scene:
        if positional:
            p.add_argument("scene", help="preset name or path to a scene .toml")
        else:
            p.add_argument("--scene", default=default,
                           help=f"preset name or path to a scene .toml (default: {default_text or default})")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", default=[],
                   help="override a scene field, e.g. --set plant.m1=0.05 (repeatable; values are TOML, "
                        "e.g. --set 'randomize.m1=[0.08, 0.12]')")


def scene_from_args(args, scene: str | None = None):
    """The scene named by ``args.scene`` (or ``scene``) with ``args.set`` and the integrator
    options (``--method``, ``--dt``, ``--rtol``, where the command has them) applied."""

    ov = parse_overrides(getattr(args, "set", None))
    if getattr(args, "method", None):
        ov["integrator.method"] = args.method
    if getattr(args, "dt", None) is not None:
        ov["integrator.dt"] = str(args.dt)
    if getattr(args, "rtol", None) is not None:
        ov["integrator.rtol"] = str(args.rtol)
    out = load_scene(scene if scene is not None else args.scene, ov)
    integ = out.integrator
    if "integrator.dt" in ov and integ.method in ADAPTIVE and out.control.rate is not None:
        # a step that would silently do nothing: the adaptive methods have no fixed step
        raise ConfigError(f"integrator.dt = {integ.dt:g} s has no effect with integrator.method = "
                          f"{integ.method} (adaptive; its accuracy is integrator.rtol = {integ.rtol:g}); "
                          "add --method rk4 (or --set integrator.method=rk4) to step at a fixed dt")
    return out


def output_dir(path: str | Path, option: str = "--out") -> Path:
    """Make sure ``path`` is (or can be made) a writable folder, before anything runs: the
    folder is created; a file in its place or a read-only location raises ConfigError naming
    the option."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise ConfigError(f"{option} {str(p)!r} is a file; give a folder (the outputs go inside it)")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{option} {str(p)!r}: cannot create the folder ({exc.strerror or exc})") from None
    if not os.access(p, os.W_OK | os.X_OK):
        raise ConfigError(f"{option} {str(p)!r}: the folder is not writable")
    return p


def add_format_argument(p: argparse.ArgumentParser, default: str | None = "png",
                        what: str = "the plots'") -> None:
    """``--format png|pdf|svg``, the same on every command that plots (:mod:`impact_env.figstyle`)."""

    extra = f"default {default}, {DPI} dpi" if default else f"default: the file's suffix; PNG at {DPI} dpi"
    p.add_argument("--format", default=default, choices=FORMATS, help=f"{what} file format ({extra})")


def output_figure_file(path: str | Path, fmt: str | None, option: str) -> Path:
    """The figure file ``option PATH [--format FMT]`` names (:func:`impact_env.figstyle.output_figure`:
    the suffix and the format agree), writable; checked before anything runs.  ConfigError naming
    the option otherwise."""

    try:
        p = output_figure(path, fmt, option)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    return output_file(p, option)


def output_file(path: str | Path, option: str) -> Path:
    """Make sure the file ``path`` can be written, before anything runs (its folder exists and
    is writable, and it is not a folder); ConfigError naming the option otherwise."""
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{option} {str(p)!r} is a folder; give a file name")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise ConfigError(f"{option} {str(p)!r}: the folder {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise ConfigError(f"{option} {str(p)!r}: not writable")
    return p


def add_workers_arguments(p: argparse.ArgumentParser) -> None:
    """``--workers N`` and ``--cluster tcp://HOST:PORT``, the same on every command that runs
    independent tasks (compare, sweep, robustness; :mod:`impact_env.eval.parallel`)."""
    p.add_argument("--workers", type=workers_arg, default=None,
                   help="processes, >= 1 (default: the available cores); with --cluster, how many parts the "
                        "work is cut into (default: the cluster's worker threads)")
    p.add_argument("--cluster", metavar="tcp://HOST:PORT", default=None,
                   help="run the tasks on the workers of this Dask scheduler instead of local processes, "
                        "with the same results (needs pip install 'impact-env[cluster]'; docs/cluster.md)")


def workers_arg(text: str) -> int:
    """``--workers``: an integer >= 1 (argparse's error, naming the option, otherwise)."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer (processes, >= 1)") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"{n} must be an integer >= 1 (processes; the default is the "
                                         "available cores)")
    return n


def cluster_from_args(args) -> str | None:
    """``--cluster``'s address, checked before anything runs (ConfigError naming the option); the
    connection itself is made, and checked, by the command before its first task."""

    value = getattr(args, "cluster", None)
    if value is None:
        return None
    if getattr(args, "workers", None) is not None and args.workers < 1:
        raise ConfigError(f"--workers {args.workers} must be >= 1")
    return parse_cluster(value, "--cluster")
