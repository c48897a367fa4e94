"""Sphinx configuration of the ffmpc manual (``make docs``: warnings are errors)."""

from __future__ import annotations

import os
import sys
from importlib import metadata
from pathlib import Path

# The manual's own extension (docs/_ext/ffmpc_docs): Sphinx loads local extensions from
# sys.path, the way its documentation describes ("extensions in a directory of the project").
sys.path.insert(0, str(Path(__file__).resolve().parent / "_ext"))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

project = "ffmpc"
author = "the ffmpc developers"
release = metadata.version("ffmpc")
version = release
copyright = "the ffmpc developers, BSD-3-Clause"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "ffmpc_docs",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "_ext", "README.md"]
templates_path = ["_templates"]

# -- MyST --
myst_enable_extensions = ["colon_fence", "deflist", "attrs_inline"]
myst_heading_anchors = 3

# -- the Python API of ffmpc_core (autodoc + autosummary) --
autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {
    "members": True,
    "member-order": "bysource",
    "show-inheritance": True,
    # document what each module defines (its __module__), once: re-exports in a package's
    # __all__ (ffmpc_core.impact) would document the same class twice
    "ignore-module-all": True,
}
autodoc_typehints = "description"
autodoc_typehints_format = "short"
autodoc_inherit_docstrings = True
autodoc_class_signature = "separated"
# The compiled module has no source to import in a docs-only sense; every other import is real.
autodoc_mock_imports: list[str] = []
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False
napoleon_custom_sections = [("Modules", "params_style")]
# "Attributes:" sections as fields of their class (a field with a #: comment is documented by
# autodoc itself: as directives it would be documented twice)
napoleon_use_ivar = True

# -- warnings --
# Every cross-reference must resolve (nitpicky), except names of other projects: no intersphinx
# (the build runs without a network), so their types stay plain text.
nitpicky = True
_EXTERNAL = (
    r"(np|numpy|npt|numpy\.typing|pin|pinocchio|crocoddyl|mim_solvers|scipy|osqp|daqp|yaml"
    r"|rclpy|pybullet|example_robot_data|collections\.abc|typing|typing_extensions|os|pathlib"
    r"|dataclasses|enum|abc|concurrent|json|re|io|argparse|builtins|types|functools)"
)
nitpick_ignore_regex = [
    (r"py:.*", _EXTERNAL + r"\..*"),
    (
        r"py:.*",
        r"(NDArray|ArrayLike|Any|Callable|Iterable|Iterator|Sequence|Mapping|Path"
        r"|ModuleType|TypeVar|Generic|Enum|Literal|ndarray|float64|_ConfigT|_SectionT|T)",
    ),
]
suppress_warnings: list[str] = []

# -- HTML --
html_theme = "furo"
html_title = f"ffmpc {release}"
html_static_path = ["_static"]
html_css_files = ["ffmpc.css"]
html_show_sourcelink = False
html_theme_options = {"navigation_with_keys": True}
