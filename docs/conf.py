"""Sphinx configuration of piezopreload's documentation site.

Built by CI with warnings as errors and no network: ``sphinx-build -W --keep-going -b html docs
docs/_build/html``. Pages are Markdown (MyST); notebooks are executed at build (myst-nb); the
examples in ``examples/`` become the gallery, run at build (sphinx-gallery: the figures they save
are shown, the library builds its figures without pyplot); the API reference comes from the
docstrings (autodoc + numpydoc) and the CLI reference from the parser (sphinx-argparse). The
tables of study keys come from the table declarations (:func:`piezopreload.tables.study_keys_markdown`).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

from matplotlib.figure import Figure

import piezopreload

os.environ.setdefault("MPLBACKEND", "Agg")

# ---- the gallery's figure scraper: the figures an example saves, shown under the code that saved them ----------
# The library draws without pyplot (each .plot() returns a Figure) and the examples save their figures to files, so
# sphinx-gallery's pyplot scraper sees nothing. While the docs build, Figure.savefig also records the figure it
# saves; the scraper writes each recorded figure into the gallery and forgets it.

_saved: list[Figure] = []
_savefig = Figure.savefig


def _recording_savefig(self: Figure, *args: Any, **kwargs: Any) -> Any:
    if not any(f is self for f in _saved):
        _saved.append(self)
    return _savefig(self, *args, **kwargs)


Figure.savefig = _recording_savefig  # type: ignore[method-assign]


def saved_figure_scraper(block: Any, block_vars: dict[str, Any], gallery_conf: dict[str, Any]) -> str:
    """sphinx-gallery's scraper interface: the figures saved since the last block, as the gallery's images."""
    from sphinx_gallery.scrapers import figure_rst

    paths = []
    for figure, path in zip(list(_saved), block_vars["image_path_iterator"]):
        _savefig(figure, path, dpi=110)
        paths.append(path)
    _saved.clear()
    return figure_rst(paths, gallery_conf["src_dir"])


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
    "sphinx_gallery.gen_gallery",
    "sphinxarg.ext",
]

source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".ipynb": "myst-nb"}
root_doc = "index"
exclude_patterns = ["_build", "README.md", "auto_examples/*.ipynb", "auto_examples/*.py", "auto_examples/*.zip",
                    "auto_examples/*.json", "auto_examples/*.md5", "**.ipynb_checkpoints", "jupyter_execute"]
templates_path = []
html_static_path = ["_static"]
html_theme = "furo"
html_title = f"piezopreload {release}"

myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence", "deflist"]
myst_heading_anchors = 3
nb_execution_mode = "force"          # every notebook runs at build: a stale output cannot ship
nb_execution_timeout = 900
nb_execution_raise_on_error = True

autosummary_generate = True
autodoc_typehints = "none"            # numpydoc renders the types from the docstrings
autodoc_default_options = {"members": True, "inherited-members": False, "show-inheritance": False}
numpydoc_show_class_members = False
numpydoc_xref_param_type = False

#: where the examples write what they make during the build (not into the repository)
_GALLERY_OUT = Path(tempfile.mkdtemp(prefix="piezopreload-gallery-"))
#: each example's command line at build: its outputs into the build's folder, the Monte Carlo sets smaller
_GALLERY_ARGV = {
    "sweep_bolt_preload.py": ["--plants", "50", "--out", str(_GALLERY_OUT / "sweep")],
    "identify_and_export.py": ["--plants", "50", "--out", str(_GALLERY_OUT / "gains")],
    "pareto_catalogue_screw.py": ["--points", "20", "--out", str(_GALLERY_OUT / "pareto")],
}


def _argv(_gallery_conf: object, script_vars: dict) -> list[str]:
    return _GALLERY_ARGV.get(Path(script_vars["src_file"]).name, [])


sphinx_gallery_conf = {
    "examples_dirs": ["../examples"],
    "gallery_dirs": ["auto_examples"],
    "filename_pattern": r"/[a-z_]+\.py$",   # every example runs at build
    "reset_argv": _argv,
    "image_scrapers": (saved_figure_scraper,),
    "download_all_examples": False,
    "remove_config_comments": True,
    "plot_gallery": "True",
    "capture_repr": ("_repr_html_", "__repr__"),
}

# the gallery's configuration holds functions, which Sphinx cannot pickle into its environment cache
suppress_warnings = ["config.cache"]
nitpicky = False
