"""The command line, ``impact-env``: one module per command group, the shared options in
:mod:`impact_env.cli.args`, the entry point in :mod:`impact_env.cli.main`."""

from impact_env.cli.args import add_scene_arguments, parse_overrides, scene_from_args

# imported here so that ``impact_env.cli.main`` is the function whichever import comes first
# (importing the submodule later would otherwise rebind the package's ``main`` to the module)
from impact_env.cli.main import main  # noqa: E402

__all__ = ["add_scene_arguments", "main", "parse_overrides", "scene_from_args"]
