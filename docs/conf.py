"""Sphinx configuration of the documentation site (docs/tooling.md says why Sphinx, MyST and furo).

    pip install -e ".[docs]"
    sphinx-build -W docs docs/_build/html      # warnings as errors, as .ci/run builds it

The reference pages under reference/generated/ are written at every build from the code
(docs/_ext/generated_reference.py): the CLI from its argparse parsers, the scene fields, effects,
laws and task options from their registries, the wire protocol's tables from its message classes.
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # the package of this checkout, not an installed one
sys.path.insert(0, str(HERE / "_ext"))

import impact_env  # noqa: E402

project = "impact_env"
author = "the impact_env developers"
copyright = "the impact_env developers, MIT licence"  # noqa: A001  (Sphinx's name)
release = version = impact_env.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "generated_reference",
]
myst_enable_extensions = ["colon_fence", "dollarmath", "deflist"]
myst_heading_anchors = 3  # links to a section, page.md#a-heading, as GitHub renders them
source_suffix = {".md": "markdown"}
root_doc = "index"
# results/ holds the records the pages' generated blocks are made from (JSON, logs, a few notes
# kept beside their data): files, not pages
exclude_patterns = ["_build", "results/**", "README.md", "**/README.md"]
html_theme = "furo"
html_title = f"impact_env {release}"
html_static_path: list[str] = []
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_mock_imports = ["torch", "stable_baselines3", "h5py", "onnx", "onnxruntime", "cma", "distributed",
                        "dask"]
nitpicky = False


def _docstring_as_written(app, what, name, obj, options, lines):
    """The package's docstrings are plain text for a terminal (``help()``), with Gymnasium-style
    tables and aligned lists, not reStructuredText; show them as written, in a literal block,
    rather than have docutils misread their indentation."""
    if lines:
        lines[:] = ["::", ""] + ["    " + line for line in lines] + [""]


def setup(app):
    app.connect("autodoc-process-docstring", _docstring_as_written)
