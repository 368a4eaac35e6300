"""Shared test settings: headless matplotlib and no leaked pyplot figures."""

from __future__ import annotations

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import pytest


@pytest.fixture(autouse=True)
def _close_pyplot_figures():
    """``render_mode="human"`` opens pyplot figures; close them after every test."""
    yield
    import sys

    if "matplotlib.pyplot" in sys.modules:
        sys.modules["matplotlib.pyplot"].close("all")
