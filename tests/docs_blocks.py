"""The ```python blocks of the documentation (every page under ``fxc_env/docs/`` and README.md), for the tests that run them.

Every block runs, so none can rot. ``tests/test_docs.py`` runs each one in ``.venv``, unless the
line above its fence is a comment naming the test that runs it instead::

    <!-- runs in tests/benchmarl/test_docs_blocks.py::test_the_benchmarl_tutorial_trains_and_scores -->

(the BenchMARL and RLlib blocks, whose packages live in ``.venv-benchmarl`` and ``.venv-rllib``).
That test takes its blocks with :func:`assigned`; ``tests/test_docs.py`` checks that every named
test exists and calls it, so a block is run either there or by the test it names, never by neither.
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "fxc_env" / "docs"
README = ROOT / "README.md"
#: The comment that hands the next block to another test.
MARKER = re.compile(r"<!-- runs in (tests/[\w/]+\.py)::(\w+) -->")
FENCE = re.compile(r"^(`{3,})([^\n`]*)\n(.*?)^\1[ \t]*$", re.S | re.M)


@dataclass(frozen=True)
class Block:
    """One fenced ```python block: where it is, its code, and the test it is handed to (None: test_docs runs it)."""

    page: Path
    line: int
    code: str
    runs_in: str | None

    @property
    def name(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def pages() -> list[Path]:
    """Every Markdown page of the site, then README.md."""
    return [*sorted(DOCS.rglob("*.md")), README]


def fences(page: Path) -> list[tuple[int, str, str, str]]:
    """``(line, info string, code, text before the fence)`` of every fenced block on ``page``."""
    text = page.read_text()
    return [
        (text.count("\n", 0, m.start()) + 1, m.group(2).strip(), m.group(3), text[: m.start()])
        for m in FENCE.finditer(text)
    ]


def blocks(page: Path) -> list[Block]:
    """The ```python blocks of ``page``, each with the test named in the comment right above it (if any)."""
    found = []
    for line, info, code, before in fences(page):
        if info != "python":
            continue
        previous = before.rstrip().rsplit("\n", 1)[-1]
        marker = MARKER.fullmatch(previous.strip())
        found.append(Block(page, line, code, f"{marker.group(1)}::{marker.group(2)}" if marker else None))
    return found


def all_blocks() -> list[Block]:
    return [block for page in pages() for block in blocks(page)]


def assigned(test_id: str) -> list[Block]:
    """The blocks whose comment names ``test_id`` (``"tests/<file>.py::<test>"``); at least one."""
    found = [block for block in all_blocks() if block.runs_in == test_id]
    if not found:
        raise LookupError(f"no documentation block names {test_id!r}")
    return found


def run(block: Block) -> dict:
    """Run ``block`` as a script of its own (``sys.argv`` is just its name) and return its globals."""
    namespace = {"__name__": "__main__"}
    argv, sys.argv = sys.argv, [block.name]
    try:
        exec(compile(block.code, block.name, "exec"), namespace)
    finally:
        sys.argv = argv
    return namespace
