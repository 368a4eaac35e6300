"""The documentation's RLlib blocks run in .venv-rllib (tests/docs_blocks.py hands them here; tutorials/rllib.md)."""

from __future__ import annotations

import pytest
from docs_blocks import assigned, run


@pytest.mark.slow
def test_the_rllib_tutorial_trains_one_iteration_with_a_shared_module(local_ray, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for block in assigned(
        "tests/rllib/test_docs_blocks.py::test_the_rllib_tutorial_trains_one_iteration_with_a_shared_module"
    ):
        namespace = run(block)
    assert namespace["result"]["env_runners"]["num_env_steps_sampled_lifetime"] >= 400
    assert "mean team return" in capsys.readouterr().out
