"""Sphinx configuration of the documentation site (furo theme, MyST Markdown pages).

Build: ``python -m sphinx -W --keep-going -b html docs docs/_build/html`` (the ``docs``
extra: ``pip install -e ".[docs]"``).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # document this checkout, not an installed copy
os.environ.setdefault("OMP_NUM_THREADS", "1")

project = "coop-loc-env"
author = "The coop-loc-env contributors"
copyright = "The coop-loc-env contributors, MIT license"
release = "0.1.0"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
# docs/README.md is the folder's guide for readers browsing the repository.
exclude_patterns = ["_build", "README.md", "models", "figures/README.md"]
# Pages listed in a table of contents only when they exist (configs.md: config files).
OPTIONAL_PAGES = ("configs",)

myst_enable_extensions = ["colon_fence", "deflist", "dollarmath"]
myst_heading_anchors = 3

autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "show-inheritance": False}
autosummary_generate = False
napoleon_google_docstring = True
napoleon_numpy_docstring = False

html_theme = "furo"
html_title = "coop-loc-env"
html_static_path = ["_static"]
pygments_style = "sphinx"
pygments_dark_style = "monokai"


def _drop_missing_optional_pages(app, docname: str, source: list[str]) -> None:
    """Leave an optional page that does not exist out of the index's tables of contents."""
    if docname != "index":
        return
    for page in OPTIONAL_PAGES:
        if not (Path(app.srcdir) / f"{page}.md").exists():
            source[0] = source[0].replace(f"\n{page}\n", "\n")


def setup(app) -> None:
    app.connect("source-read", _drop_missing_optional_pages)
