"""The command line, ``impact-env``: one module per command group, the shared options in
:mod:`impact_env.cli.args`, the entry point in :mod:`impact_env.cli.main`."""

from impact_env.cli.args import add_scene_arguments, parse_overrides, scene_from_args

__all__ = ["add_scene_arguments", "main", "parse_overrides", "scene_from_args"]


def main(argv=None) -> int:
    from impact_env.cli.main import main as _main

    return _main(argv)
