"""fxc_env.baselines.harness.ray_jobs: ``fxc benchmark --ray`` gives the single-machine table, from Ray tasks."""

from __future__ import annotations

import csv

import pytest

from fxc_env.cli import main


def run(out, *extra):
    assert main(["benchmark", "--quick", "--seeds", "2", "--out", str(out), "--no-progress", *extra]) == 0


def rows(path):
    with path.open(newline="") as handle:
        return [{k: v for k, v in row.items() if k != "seconds"} for row in csv.DictReader(handle)]


@pytest.mark.slow
def test_the_ray_quick_table_equals_the_single_machine_one(tmp_path, capsys, local_ray):
    run(tmp_path / "processes")
    single = capsys.readouterr().out
    run(tmp_path / "ray", "--ray")
    distributed = capsys.readouterr().out
    table = (tmp_path / "processes" / "table.md").read_text()
    assert "| reference |" in table and (tmp_path / "ray" / "table.md").read_text() == table
    assert table.strip() in single and table.strip() in distributed
    assert rows(tmp_path / "ray" / "results.csv") == rows(tmp_path / "processes" / "results.csv")
    assert (tmp_path / "ray" / "episodes.csv").read_text() == (tmp_path / "processes" / "episodes.csv").read_text()
    assert local_ray.is_initialized()  # it joined the running Ray and left it running
