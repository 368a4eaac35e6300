"""The architecture page says what each module holds in the module's own words (issue 36, item 4).

Two parts of the docs are drawn from the module docstrings, and these tests fail when they differ:

* ``architecture.md``'s "Modules" section: every folder and module with its docstring's summary (first paragraph);
* every section headed by a module's import name (`` ### `fxc_env.engine.clock` ``, in ``architecture.md``,
  ``training.md`` and ``optimality.md``): that module's whole docstring.

After editing a docstring, ``.venv/bin/python tests/test_architecture_page.py`` writes both again.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

from helpers import ROOT
from helpers import library_modules as modules

DOCS = ROOT / "fxc_env" / "docs"
BEGIN = "<!-- modules: written from the module docstrings by tests/test_architecture_page.py; edit the docstrings -->"
END = "<!-- end of modules -->"
HEADING = re.compile(r"^### `(fxc_env(?:\.[a-z_0-9]+)+)`\n", re.M)
ROLE = re.compile(r":(?:class|func|mod|meth|data|attr|exc|obj):`(~?)([^`]+)`")


def docstring(path: Path) -> str:
    """The module's docstring, as written (empty when it has none)."""
    return ast.get_docstring(ast.parse(path.read_text()), clean=True) or ""


def as_markdown(text: str) -> str:
    """Sphinx roles as Markdown code spans (``:class:`~a.B``` -> `` `a.B` ``), a literal block's ``::`` as ``:``."""
    return re.sub(r"::$", ":", ROLE.sub(r"`\2`", text), flags=re.M)


def first_line(path: Path) -> str:
    """The docstring's summary: its first paragraph, on one line (a table cell)."""
    return as_markdown(" ".join(docstring(path).split("\n\n", 1)[0].split())).replace("|", "\\|")


def module_section() -> str:
    """The "Modules" section's body: one table per package, a row per module."""
    found = modules()
    packages = [name for name, path in found.items() if path.name == "__init__.py"]
    out = [BEGIN]
    for package in packages:
        folder = found[package].parent.relative_to(ROOT)
        children = [n for n in found if n.rpartition(".")[0] == package and found[n].name != "__init__.py"]
        out += [
            "",
            f"**`{package}`** (`{folder}/`, {len(children)} module{'s' * (len(children) != 1)}): {first_line(found[package])}",
        ]
        if children:
            out += ["", "| module | what it holds |", "|---|---|"]
            out += [f"| `{name.rpartition('.')[2]}` | {first_line(found[name])} |" for name in children]
    return "\n".join([*out, "", END])


def written(page: Path) -> str:
    """``page`` as the docstrings write it: the modules section and every section headed by a module."""
    text = page.read_text()
    if BEGIN in text:
        head, rest = text.split(BEGIN, 1)
        text = head + module_section() + rest.split(END, 1)[1]
    found = modules()
    parts = HEADING.split(text)  # [before, name, body, name, body, ...]
    for i in range(1, len(parts), 2):
        body = parts[i + 1]
        following = re.search(r"^#{1,3} ", body, re.M)  # the section ends at the next heading
        rest = body[following.start() :] if following else ""
        last = not rest and i + 2 == len(parts)  # the page ends with this section
        parts[i + 1] = "\n" + as_markdown(docstring(found[parts[i]])) + ("\n" if last else "\n\n" + rest)
        parts[i] = f"### `{parts[i]}`\n"
    return "".join(parts)


PAGES = [DOCS / "architecture.md", DOCS / "training.md", DOCS / "optimality.md"]


def test_the_architecture_page_lists_every_module_with_its_docstrings_first_line():
    page = PAGES[0]
    assert BEGIN in page.read_text() and END in page.read_text()
    assert page.read_text() == written(page), f"{page.name} differs from the docstrings: run {Path(__file__).name}"


def test_every_section_named_after_a_module_is_that_modules_docstring():
    for page in PAGES:
        names = HEADING.findall(page.read_text())
        assert set(names) <= set(modules()), f"{page.name}: sections named after no module"
        assert page.read_text() == written(page), f"{page.name} differs from the docstrings: run {Path(__file__).name}"


def test_a_changed_docstring_shows_on_the_page(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# Page\n\n### `fxc_env.engine.clock`\n\nAn old text.\n\n## Next\n")
    assert "An old text" not in written(page)
    assert written(page).startswith("# Page\n\n### `fxc_env.engine.clock`\n\nThe engine's clock")
    assert written(page).endswith("\n\n## Next\n")


if __name__ == "__main__":
    for page in PAGES:
        page.write_text(written(page))
    sys.exit(0)
