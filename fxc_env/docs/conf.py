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

import builtins
import importlib
import importlib.util
import os
import re
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
    ("py:.*", r"(DummyVecEnv|VecEnv|VecNormalize|PPO|SAC)"),
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


# The docstrings' tables (every env card's Arguments table) are Markdown pipe tables and their section
# titles Markdown headings, which reST does not read; autodoc hands each table over as a reST
# list-table and each heading as a rubric.
_SEPARATOR = re.compile(r"\s*\|(\s*:?-+:?\s*\|)+\s*")


def _cells(line: str) -> list[str]:
    cells = [cell.strip() for cell in re.split(r"(?<!\\)\|", line.strip())[1:-1]]
    return [re.sub(r"``.*?``", lambda m: m.group(0).replace("\\|", "|"), cell) for cell in cells]


def pipe_tables_to_list_tables(app, what, name, obj, options, lines):
    out, i = [], 0
    while i < len(lines):
        stripped = lines[i].lstrip()
        heading = re.fullmatch(r"(#{1,4}) (.+)", stripped)
        if heading:  # a Markdown heading in a docstring ("## Arguments") becomes a rubric
            out += ["", f"{lines[i][: len(lines[i]) - len(stripped)]}.. rubric:: {heading.group(2)}", ""]
            i += 1
            continue
        if not (stripped.startswith("|") and i + 1 < len(lines) and _SEPARATOR.fullmatch(lines[i + 1])):
            out.append(lines[i])
            i += 1
            continue
        indent = lines[i][: len(lines[i]) - len(stripped)]
        j = i + 2
        while j < len(lines) and lines[j].lstrip().startswith("|"):
            j += 1
        out += ["", f"{indent}.. list-table::", f"{indent}   :header-rows: 1", ""]
        for row in [_cells(lines[i]), *(_cells(line) for line in lines[i + 2 : j])]:
            out += [f"{indent}   * - {row[0]}", *(f"{indent}     - {cell}" for cell in row[1:]), ""]
        i = j
    lines[:] = out


# -n makes every unresolved reference an error. A docstring may name an object of this package (or
# one it imports) that the API pages do not render: it stays as code, unlinked, when the name exists;
# a dotted name that exists nowhere is still an error. Napoleon reads some prose as a type
# ("ValueError / TypeError naming ...", a "Raises:" line that starts with the argument's name): such
# text stays as it is, as do an instance's own attributes and methods named without a dot.
def _exists(dotted: str) -> bool:
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        try:
            for part in parts[cut:]:
                obj = getattr(obj, part)
        except AttributeError:
            return False
        return True
    return hasattr(builtins, dotted)


def existing_names_stay_code(app, env, node, contnode):
    if node.get("refdomain") != "py":
        return None
    target = node.get("reftarget", "")
    if not re.fullmatch(r"[A-Za-z_][\w.]*", target):
        return contnode
    if "." not in target and node.get("reftype") in ("attr", "meth", "exc"):
        return contnode
    module, cls = node.get("py:module") or "", node.get("py:class") or ""
    candidates = [target, f"fxc_env.{target}", f"{module}.{target}", f"{module}.{cls}.{target}"]
    candidates.append(f"fxc_env.core.validation.{target}")  # ArgumentError, named bare in many docstrings
    return contnode if any(_exists(name) for name in candidates if not name.startswith(".")) else None


def setup(app):
    app.connect("autodoc-process-docstring", pipe_tables_to_list_tables)
    app.connect("missing-reference", existing_names_stay_code)
