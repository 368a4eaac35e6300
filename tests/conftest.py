"""Shared test settings: headless matplotlib, no leaked pyplot figures, and ``--shard`` for `make check`.

``make check`` runs the tests not marked ``slow`` as two pytest processes side by side (one
per core), ``--shard 1/2`` and ``--shard 2/2``: each takes every second selected test, so
together they run exactly what ``pytest -m "not slow"`` runs.
"""

from __future__ import annotations

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import pytest


def pytest_addoption(parser):
    parser.addoption(
        "--shard",
        metavar="I/N",
        default=None,
        help="run the I-th of N interleaved shares of the selected tests (1 <= I <= N); `make check` runs 1/2 and 2/2 at once",
    )


def _shard(text: str) -> tuple[int, int]:
    """``"I/N"`` as ``(I, N)`` with ``1 <= I <= N``; anything else is a usage error naming ``--shard``."""
    try:
        index, count = (int(part) for part in text.split("/"))
    except ValueError:
        raise pytest.UsageError(f"--shard: expected I/N with integers 1 <= I <= N, got {text!r}") from None
    if not 1 <= index <= count:
        raise pytest.UsageError(f"--shard: expected I/N with integers 1 <= I <= N, got {text!r}")
    return index, count


def pytest_configure(config):
    text = config.getoption("--shard")
    if text is not None:
        _shard(text)  # refused before collection starts


@pytest.hookimpl(trylast=True)  # after -m and -k have deselected: the shares split what is selected
def pytest_collection_modifyitems(config, items):
    text = config.getoption("--shard")
    if text is None:
        return
    index, count = _shard(text)
    kept = items[index - 1 :: count]
    kept_ids = {id(item) for item in kept}
    config.hook.pytest_deselected(items=[item for item in items if id(item) not in kept_ids])
    items[:] = kept


@pytest.fixture(autouse=True)
def _close_pyplot_figures():
    """``render_mode="human"`` opens pyplot figures; close them after every test."""
    yield
    import sys

    if "matplotlib.pyplot" in sys.modules:
        sys.modules["matplotlib.pyplot"].close("all")
