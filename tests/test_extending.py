"""The "Extending fxc_env" page (fxc_env/docs/extending.md): each recipe lists the files it touches, those files
exist (a new one's folder does), and each lists the one table that holds its kind of thing, not the lists the
tables replaced."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "fxc_env" / "docs" / "extending.md"
#: Each recipe and the table it must list.
TABLES = {
    "A graph family": "fxc_env/core/graph_kinds.py",
    "An agent model": "fxc_env/core/models.py",
    "A baseline": "baselines/registry.py",
    "A training back end": "training/registry.py",
    "A scenario": "fxc_env/config/scenarios.py",
    "A named task": "fxc_env/config/tasks.py",
}
#: Files a recipe no longer touches: they read the tables.
DERIVED = {
    "A graph family": ("fxc_env/core/graphs.py", "fxc_env/core/families.py", "fxc_env/config/flags.py"),
    "An agent model": ("fxc_env/config/flags.py",),
    "A baseline": ("baselines/__init__.py", "fxc_env/__init__.py", "baselines/harness/figures.py"),
}


def _recipes() -> dict[str, list[tuple[str, bool]]]:
    """Each recipe's listed files: ``(path, new)`` from the numbered list after its "Files touched"."""
    recipes: dict[str, list[tuple[str, bool]]] = {}
    for section in re.split(r"^## ", PAGE.read_text(encoding="utf-8"), flags=re.M)[1:]:
        title, _, body = section.partition("\n")
        listing = body.split("**Files touched**", 1)[1].split("\n\n", 2)[1]
        files = []
        for item in re.findall(r"^\d+\. (.*)$", listing, flags=re.M):
            for path, after in re.findall(r"`([\w.-]+/[\w./-]+\.\w+)`( \(new\))?", item):
                files.append((path, bool(after)))
        recipes[title.strip()] = files
    return recipes


def test_every_recipe_lists_existing_files_and_its_table():
    recipes = _recipes()
    assert set(recipes) == set(TABLES)
    for title, files in recipes.items():
        assert files, title
        for path, new in files:
            target = ROOT / path
            assert (target.parent.is_dir() and not target.exists()) if new else target.is_file(), (title, path)
        assert TABLES[title] in {path for path, _ in files}, title
        listed = {path for path, _ in files}
        assert not listed & set(DERIVED.get(title, ())), (title, listed & set(DERIVED[title]))
