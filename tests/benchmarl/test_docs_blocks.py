"""The documentation's BenchMARL blocks run in .venv-benchmarl (tests/docs_blocks.py hands them here; tutorials/benchmarl.md)."""

from __future__ import annotations

import re

import pytest
from docs_blocks import assigned, run


@pytest.mark.slow
def test_the_benchmarl_tutorial_trains_mappo_with_a_gnn_and_scores_it_beside_eq_11(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # its CSV logs go to runs/benchmarl here
    test_id = "tests/benchmarl/test_docs_blocks.py::test_the_benchmarl_tutorial_trains_mappo_with_a_gnn_and_scores_it_beside_eq_11"
    for block in assigned(test_id):
        run(block)
    printed = capsys.readouterr().out
    (reference,) = re.findall(r"eq\. \(11\)    D\(T_s\)/D\(0\): ([\d.e+-]+)", printed)
    assert float(reference) == pytest.approx(0.10659417510032866, rel=1e-9)  # the figure the page prints
    assert re.search(r"MAPPO \+ GNN D\(T_s\)/D\(0\): [\d.e+-]+", printed)
