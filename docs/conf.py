"""Sphinx configuration of pmabayes' documentation.

Build: ``bash .ci/with-venv sphinx-build -W --keep-going -b html docs docs/_build/html``.
Warnings are errors and every cross-reference must resolve (``nitpicky``); the
examples of the gallery are executed at every build, so none can rot.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # the gallery draws without a display

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

from pmabayes_docs import reexports  # noqa: E402

import pmabayes  # noqa: E402

project = "pmabayes"
author = "the pmabayes developers"
copyright = "the pmabayes developers"  # noqa: A001 (Sphinx's name)
release = version = pmabayes.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "numpydoc",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
    "sphinx.ext.mathjax",
    "sphinx-mathjax-offline",
    "pmabayes_docs",
]
# Equations are rendered by MathJax from a copy inside the built site
# (sphinx-mathjax-offline, from PyPI): the pages read offline and need no TeX on the
# machine that builds them. imgmath would need latex plus dvisvgm or dvipng, which a
# developer's machine and CI may lack, and a fallback to MathJax from a CDN would not
# render offline.

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "examples/README.rst", "**/*.ipynb", "**/*.py.md5",
                    "**/*.codeobj.json", "auto_examples/*.zip"]
templates_path = ["_templates"]
root_doc = "index"

# --- the reference: one page per module, generated recursively from the package
autosummary_generate = True
autosummary_context = {"reexports": reexports("pmabayes")}
autodoc_typehints = "none"  # numpydoc's Parameters sections carry the types
autodoc_default_options = {"member-order": "bysource"}
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_validation_checks: set[str] = set()  # tests/test_docstrings.py checks them

# --- every reference must resolve. The build fetches no inventory (CI has no network),
# so the names of pmabayes' dependencies that docstrings mention (xarray.DataTree,
# arviz.loo, scipy.io.loadmat, h5py) cannot resolve: those, and only those, are ignored
THIRD_PARTY = ("numpy", "scipy", "xarray", "arviz", "h5py", "emcee", "numba", "dask",
               "matplotlib")
nitpicky = True
nitpick_ignore_regex = [(r"py:.*", rf"({'|'.join(THIRD_PARTY)})(\..*)?")]

# --- MyST: pipe tables, ```{directive} fences and $-free code
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3

# --- the gallery: plain scripts, executed at every build (no Jupyter kernel)
sphinx_gallery_conf = {
    "examples_dirs": "examples",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "within_subsection_order": "FileNameSortKey",
    "download_all_examples": False,
    "reset_modules": ("matplotlib",),
    "show_memory": False,
    "remove_config_comments": True,
    "abort_on_example_error": True,
    "image_scrapers": ("matplotlib",),
    "min_reported_time": 0,
    "write_computation_times": False,
    "capture_repr": (),
    "matplotlib_animations": False,
    "plot_gallery": os.environ.get("PMABAYES_DOCS_GALLERY", "True"),
}

html_theme = "furo"
html_title = f"pmabayes {release}"
html_static_path = ["_static"]
html_css_files = ["pmabayes.css"]
html_show_sourcelink = False
html_theme_options = {"navigation_with_keys": True}
