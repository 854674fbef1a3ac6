"""Sphinx configuration of the sb3_crowdnav documentation (``make docs``)."""

import os
import sys

sys.path.insert(0, os.path.abspath(".."))
os.environ.setdefault("MPLBACKEND", "Agg")

from sb3_crowdnav.version import __version__

project = "sb3_crowdnav"
author = "the sb3_crowdnav developers"
copyright = "2026, the sb3_crowdnav developers"
release = version = __version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.viewcode",
    "sphinx.ext.mathjax",
    "myst_parser",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
myst_enable_extensions = ["colon_fence"]
myst_heading_anchors = 3
exclude_patterns = ["_build"]
autodoc_member_order = "bysource"
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_typehints = "description"
autodoc_mock_imports: list[str] = []
suppress_warnings = ["myst.xref_missing"]
nitpicky = False

html_theme = "sphinx_rtd_theme"
html_title = f"sb3_crowdnav {release}"
html_static_path: list[str] = []
