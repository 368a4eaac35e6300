"""The documentation site (``fxc_env/docs/``, built by ``make docs``) and the README: every code block runs.

``make docs`` builds the site with warnings as errors (``make test`` runs it); these tests run the
pages' ```python blocks (``tests/docs_blocks.py`` says how a block is handed to another test) and
check that every scenario and named task has its page, and that the README stays a short entrance.
"""

from __future__ import annotations

import ast
import re

import pytest
from docs_blocks import DOCS, MARKER, README, ROOT, all_blocks, fences, pages, run

from fxc_env import SCENARIOS
from fxc_env.config.tasks import TASKS

HERE_BLOCKS = [block for block in all_blocks() if block.runs_in is None]


@pytest.mark.slow  # about two minutes in all: `make test` runs them, `make check` leaves them
@pytest.mark.parametrize("block", HERE_BLOCKS, ids=lambda block: block.name)
def test_every_python_block_of_the_docs_runs(block, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # blocks that write files write them here
    run(block)


def test_a_block_handed_to_another_test_names_one_that_takes_it():
    handed = [block for block in all_blocks() if block.runs_in is not None]
    assert {block.runs_in.split("::")[0] for block in handed} >= {
        "tests/benchmarl/test_docs_blocks.py",
        "tests/rllib/test_docs_blocks.py",
    }
    for block in handed:
        path, name = block.runs_in.split("::")
        tree = ast.parse((ROOT / path).read_text())
        (test,) = [node for node in tree.body if isinstance(node, ast.FunctionDef) and node.name == name]
        calls = [
            node.func.id for node in ast.walk(test) if isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
        ]
        assert "assigned" in calls and "run" in calls, f"{block.name}: {block.runs_in} does not run its blocks"


def test_every_python_fence_is_one_the_tests_find():
    """A block the tests would miss (indented, or spelled ``py``) is refused, as is a marker before no block."""
    for page in pages():
        text = page.read_text()
        assert not re.search(r"^[ \t]+`{3,}\s*(\{code-block\}\s*)?py", text, re.M), f"{page}: an indented python fence"
        for line, info, _, before in fences(page):
            assert info == "python" or "py" not in info.lower(), f"{page}:{line}: fence {info!r}; write ```python"
            if MARKER.search(before.rstrip().rsplit("\n", 1)[-1]):
                assert info == "python", f"{page}:{line}: a 'runs in' comment before a {info!r} block"
        markers = [line for line in text.splitlines() if MARKER.fullmatch(line.strip())]
        assert len(markers) == sum(1 for block in all_blocks() if block.page == page and block.runs_in), page


@pytest.mark.parametrize("kind, names", [("scenario", list(SCENARIOS)), ("task", list(TASKS))])
def test_every_scenario_and_task_has_a_page_with_its_card_and_video(kind, names):
    for name in names:
        page = DOCS / f"{kind}s" / f"{name}.md"
        text = page.read_text()
        assert f"```{{fxc-card}} {kind}:{name}\n" in text, page
        (gif,) = re.findall(r"\]\((\.\./_static/gifs/[\w.-]+\.gif)\)", text)
        assert (page.parent / gif).resolve().is_file(), f"{page}: {gif}"
        assert "fxc simulate " in text and "--video " in text, f"{page}: say the command that made the video"


def test_the_readme_is_a_short_entrance_whose_links_into_the_docs_resolve():
    text = README.read_text()
    assert len(text.splitlines()) <= 250
    links = re.findall(r"\]\(((?:fxc_env|tests|baselines|training)/[^)#\s]+)", text)
    assert sum(link.startswith("fxc_env/docs/") for link in links) >= 10
    for link in links:
        assert (ROOT / link).exists(), link


def test_the_benchmarl_pages_say_benchmarl_writes_no_video_for_fxc_tasks():
    """BenchMARL skips rendering, without a message, for a task whose ``has_render`` is False (fxc's): its default
    ``render: true`` writes nothing, so the pages a BenchMARL user reads say so and where frames come from."""
    for page in (DOCS / "tutorials" / "benchmarl.md", DOCS / "tasks" / "index.md"):
        text = " ".join(page.read_text().split())
        assert "writes no video" in text and "`render`" in text and "fxc simulate --video" in text, page
