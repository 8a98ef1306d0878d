"""Sphinx configuration: the ltmstore documentation, built from docs/ (``sphinx-build -W``)."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # autodoc imports ltmstore from this checkout

project = "ltmstore"
author = "ltmstore contributors"
copyright = "ltmstore contributors"  # noqa: A001 (Sphinx's name)

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "numpydoc",
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
exclude_patterns = ["_build"]
templates_path = ["_templates"]
root_doc = "index"

myst_heading_anchors = 3  # [text](page.md#a-heading) links resolve, as on GitHub
# <img src=... width=...> in a page is a Sphinx image (copied into the site), as on GitHub
myst_enable_extensions = ["html_image"]

autosummary_generate = True
autosummary_imported_members = False
# Some modules name re-exports in __all__ (for ruff); document what each module defines.
autodoc_default_options = {"members": True, "undoc-members": False,
                           "ignore-module-all": True}
autodoc_typehints = "none"  # the numpydoc sections name the types
numpydoc_show_class_members = False  # autodoc lists them
numpydoc_class_members_toctree = False
numpydoc_validation_checks: set[str] = set()  # the build's -W checks what the docstrings say

html_theme = "pydata_sphinx_theme"
html_title = "ltmstore"
html_static_path: list[str] = []
html_theme_options = {
    "show_toc_level": 2,  # the page's own contents, in the right-hand column
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": [],
}
# The pages are one level deep (their links are in the top bar): no empty left column on them.
# The API reference keeps it, to list its modules.
html_sidebars = {page: [] for page in (
    "index", "getting-started", "gallery", "method", "benchmarks", "store", "share",
    "two-phones", "6d", "flows", "archives", "development")}
