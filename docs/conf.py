"""Sphinx configuration: built offline (no intersphinx), warnings are errors in the build command.

Build: ``python -m sphinx -W --keep-going -b html docs docs/_build/html``.  The tutorials are
MyST-NB text notebooks, executed at build time in a temporary directory (their figures and
printed output are the package's own); ``-D nb_execution_mode=off`` skips that (the test suite
runs their code cells itself, ``tests/docs/test_tutorials.py``).
"""

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS / "_ext"))
sys.path.insert(0, str(DOCS.parent))  # the package of this checkout, not an installed copy

import jko_cvx  # noqa: E402

project = "jko_cvx"
author = "the jko_cvx authors"
release = jko_cvx.__version__
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "myst_nb",  # MyST Markdown, and the tutorials executed as notebooks
    "jko_references",
    "jko_results",  # the results pages, rendered from studies/results at every build
]

source_suffix = {".rst": "restructuredtext", ".md": "myst-nb"}
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
root_doc = "index"

autosummary_generate = True
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_typehints = "description"
autodoc_member_order = "bysource"
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False

myst_enable_extensions = ["dollarmath"]

nb_execution_mode = "force"  # every build runs every tutorial: no cached outputs from older code
nb_execution_in_temp = True  # what a tutorial writes (run directories) lands in a temporary directory
nb_execution_raise_on_error = True
nb_execution_timeout = 300  # seconds per cell
nb_merge_streams = True
myst_heading_anchors = 3

html_theme = "furo"
html_title = f"jko_cvx {release}"
smartquotes = False  # the generated references quote the code's own strings verbatim
