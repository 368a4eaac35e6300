"""Sphinx configuration of the fxc_env documentation site (``make docs``; the "About these docs" page).

Why Sphinx with MyST-Parser: the pages are Markdown (as the README was), the API reference
comes from the docstrings through autodoc and napoleon, and it is the tool of the projects a
user compares this one with (Gymnasium, PettingZoo, TorchRL, BenchMARL). The theme is furo when
it is installed (the ``docs`` extra brings it), else Sphinx's own alabaster.

The source lives in ``fxc_env/docs/`` because the project's layout allows no new top-level
folder; it has no ``__init__.py`` and is not in the wheel. ``make docs`` builds it into
``build/docs/`` offline: no intersphinx, nothing fetched, warnings are errors (``-W -n``).
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
os.environ.setdefault("MPLBACKEND", "Agg")

project = "fxc_env"
author = "fxc_env contributors"
copyright = "fxc_env contributors, MIT licence"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "fxc_cards",  # _ext/fxc_cards.py: the scenario and task cards, built from the library at build time
]
source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "README.md"]
myst_enable_extensions = ["colon_fence"]
myst_heading_anchors = 3

# Offline: no intersphinx. References to other projects' types (numpy, torch, gymnasium, ...) stay
# plain text instead of links; with -n every other unresolved reference is an error.
nitpick_ignore_regex = [
    ("py:.*", r"(numpy|np|torch|tensordict|torchrl|gymnasium|gym|pettingzoo|networkx|nx|scipy|matplotlib)(\..*)?"),
    ("py:.*", r"(stable_baselines3|benchmarl|ray|pathlib|collections|typing|types|argparse|enum|dataclasses)(\..*)?"),
    ("py:.*", r"(Path|Any|Callable|Mapping|Sequence|Iterable|Iterator|ArrayLike|NDArray|Array|Tensor|TensorDict)"),
]

autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"undoc-members": False}
napoleon_google_docstring = True
napoleon_numpy_docstring = False

html_theme = "furo" if importlib.util.find_spec("furo") else "alabaster"
html_title = "fxc_env"
html_static_path = ["_static"]
