"""The optimality figure (`fxc benchmark --suite optimality`): every registered law, each its own marker and colour."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from fxc_env.baselines.harness import figures
from fxc_env.baselines.harness.jobs import Job, JobResult
from fxc_env.baselines.harness.suite import BASELINES, floor_cases, optimality_cases, optimality_contenders


def test_every_registered_law_is_a_contender_with_its_own_marker_and_colour():
    contenders = optimality_contenders()
    assert {"reference", *BASELINES} <= {c.spec for c in contenders}
    styles = [figures.optimality_style(contenders, c.name) for c in contenders]
    assert len({marker for marker, _ in styles}) == len(contenders)
    assert len({colour for _, colour in styles}) == len(contenders)


def test_the_figure_has_its_legend_outside_the_axes_and_both_floors(tmp_path, monkeypatch):
    contenders = optimality_contenders()[:3]
    results = []
    for case in (*optimality_cases((20,))[:2], *floor_cases()):
        for contender in contenders:
            result = JobResult(Job(contender, case, 200, (0, 1), 20.0, False))
            result.metrics = {
                "relative_deadline_error": np.array([1e-3, 2e-3]),
                "energy_ratio": np.array([10.0, 20.0]),
                "noise_floor": np.array([2e-5, 2e-5]),
                "input_floor": np.array([0.22, 0.24]),
            }
            results.append(result)
    drawn: list[Figure] = []
    monkeypatch.setattr(Figure, "savefig", lambda self, path, **kw: drawn.append(self))
    figures.optimality_figure(results, contenders, tmp_path / "figure.png")
    (fig,) = drawn
    fig.canvas.draw()
    (legend,) = fig.legends
    box = legend.get_window_extent()
    assert all(box.x0 >= ax.get_window_extent().x1 for ax in fig.axes)  # nothing of any panel hidden
    labels = [t.get_text() for t in legend.get_texts()]
    assert "noise floor (paper, K=200)" in labels and any(label.startswith("input floor") for label in labels)
    assert {c.name for c in contenders} <= set(labels)
