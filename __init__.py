"""Not a package: the root of the impact_env repository (the package is the folder ``impact_env/``
inside it).

Why this file exists: a clone is named ``impact_env`` by default, so a script run from the
folder that holds the clone would import the clone itself as an empty namespace package
(``import impact_env`` succeeds, registers nothing, and ``gymnasium.make("ImpactCatch-v0")`` then
fails with ``NameNotFound``).  With this file the clone is a regular package, and importing it
as ``impact_env`` loads the real package inside it instead.  (mypy: ``explicit_package_bases`` in
pyproject.toml keeps the modules' names ``impact_env.*``.)
"""

import importlib.util
import os
import sys

_HERE = os.path.dirname(os.path.abspath(__file__))
_INNER = os.path.join(_HERE, "impact_env")

# Under any other name (pytest imports this file as the package of the tests' root folder) it
# does nothing.
if __name__ == "impact_env" and os.path.isfile(os.path.join(_INNER, "__init__.py")):
    _spec = importlib.util.spec_from_file_location("impact_env", os.path.join(_INNER, "__init__.py"),
                                                   submodule_search_locations=[_INNER])
    assert _spec is not None and _spec.loader is not None
    _module = importlib.util.module_from_spec(_spec)
    sys.modules["impact_env"] = _module  # the import statement returns this module, the real package
    _spec.loader.exec_module(_module)
