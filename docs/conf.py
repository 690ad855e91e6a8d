"""Sphinx configuration of piezopreload's documentation site.

Built by CI with warnings as errors and no network: ``sphinx-build -W --keep-going -b html docs
docs/_build/html``. Pages are Markdown (MyST); notebooks are executed at build (myst-nb); the
examples in ``examples/`` become the gallery, run at build (sphinx-gallery); the API reference
comes from the docstrings (autodoc + numpydoc) and the CLI reference from the parser
(sphinx-argparse).
"""

from __future__ import annotations

import os

import piezopreload

os.environ.setdefault("MPLBACKEND", "Agg")

project = "piezopreload"
author = "the piezopreload developers"
copyright = "2026, the piezopreload developers"
release = version = piezopreload.__version__

extensions = [
    "myst_nb",
    "numpydoc",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "sphinx_gallery.gen_gallery",
    "sphinxarg.ext",
]

source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".ipynb": "myst-nb"}
root_doc = "index"
exclude_patterns = ["_build", "README.md", "auto_examples/*.ipynb", "auto_examples/*.py",
                    "auto_examples/*.zip", "auto_examples/*.json", "auto_examples/*.md5", "**.ipynb_checkpoints"]
templates_path = ["_templates"]
html_static_path = ["_static"]
html_theme = "furo"
html_title = f"piezopreload {release}"

myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence", "deflist"]
myst_heading_anchors = 3
nb_execution_mode = "force"          # every notebook runs at build: a stale output cannot ship
nb_execution_timeout = 600
nb_execution_raise_on_error = True

autosummary_generate = True
autodoc_typehints = "none"            # numpydoc renders the types from the docstrings
autodoc_default_options = {"members": True, "inherited-members": False, "show-inheritance": False}
numpydoc_show_class_members = False
numpydoc_xref_param_type = False

sphinx_gallery_conf = {
    "examples_dirs": ["../examples"],
    "gallery_dirs": ["auto_examples"],
    "filename_pattern": r"/[a-z_]+\.py$",   # every example runs at build
    "reset_argv": lambda gallery_conf, script_vars: [],
    "download_all_examples": False,
    "remove_config_comments": True,
    "plot_gallery": "True",
    "capture_repr": ("_repr_html_", "__repr__"),
}

suppress_warnings = ["myst.header"]
nitpicky = False
