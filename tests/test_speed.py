"""fxc speed: the scaling table and the command's report (figures are printed, never asserted)."""

from __future__ import annotations

import re

import pytest

from fxc_env import cli, speed


@pytest.fixture
def one_thread(monkeypatch):
    """With every thread variable at 1 the command runs in-process (no re-exec)."""
    for name in speed.THREAD_VARIABLES:
        monkeypatch.setenv(name, "1")


def test_scaling_rows_cover_each_power_of_ten_with_positive_costs():
    lines = speed.scaling_table(1000)
    rows = [line for line in lines[2:] if line.startswith("|")]
    sizes = [int(row.split("|")[1].replace(",", "")) for row in rows]
    assert sizes == [100, 1000]
    for row in rows:
        seconds, per_agent, memory = (float(cell.replace(",", "")) for cell in row.split("|")[2:5])
        assert seconds > 0 and per_agent > 0 and memory > 0


def test_speed_command_states_machine_threads_and_prints_the_scaling_table(one_thread, capsys):
    code = cli.main(["speed", "--skip-contenders", "--largest", "1000", "--rounds", "1"])
    out = capsys.readouterr().out
    assert code == 0
    assert "machine:" in out and "cores" in out
    assert re.search(r"OMP_NUM_THREADS=1", out)
    assert "| 1,000 |" in out


def test_speed_command_names_the_missing_extra(one_thread, capsys, monkeypatch):
    monkeypatch.setattr(speed, "_importable", lambda name: name != "vmas")
    code = cli.main(["speed", "--rounds", "1"])
    assert code == 2
    assert "vmas missing" in capsys.readouterr().err and ".[bench]" in speed.BENCH_HINT
