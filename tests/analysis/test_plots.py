"""Figures of a whole run written as PNG (docs: getting-started.md, "Getting started")."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from matplotlib.image import imread

from fxc_env import simulate
from fxc_env.analysis.plots import LEGEND_LIMIT, inputs_figure, write_figures

FIGURES = ["topology.png", "positions.png", "velocities.png", "inputs.png", "disagreement.png"]


def assert_png_picture(path):
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = imread(path)
    assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
    assert len(np.unique(image[..., :3].reshape(-1, 3), axis=0)) > 10  # not blank


@pytest.mark.slow
def test_write_figures(tmp_path):
    # The paper example's figures are checked through `fxc simulate` (test_cli.py); here a
    # planar run too large for legends and for drawing the graph.
    trajectory = simulate(scenario=None, topology="random", n_agents=70, dim=2, n_intervals=10, points_per_interval=3)
    out = tmp_path / "nested" / "figures"
    files = write_figures(trajectory, out)
    assert set(FIGURES) <= {f.name for f in files}
    for path in files:
        assert path.parent == out
        assert_png_picture(path)


def test_inputs_figure_of_many_agents_has_no_empty_legend(tmp_path):
    # Beyond LEGEND_LIMIT agents the curves carry no label; asking for a legend anyway
    # makes matplotlib warn "No artists with labels found to put in legend".
    trajectory = simulate(scenario=None, topology="ring", n_agents=LEGEND_LIMIT + 1, n_intervals=5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        inputs_figure(trajectory, tmp_path / "inputs.png")
    assert_png_picture(tmp_path / "inputs.png")
