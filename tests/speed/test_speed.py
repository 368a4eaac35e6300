"""fxc speed: its tables on tiny sizes, table selection and the command's report (figures are printed, never asserted)."""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import re
import subprocess
import sys

import pytest

from fxc_env import cli
from fxc_env.core.validation import ArgumentError
from fxc_env.speed import command, cuda, models, scaling, training
from fxc_env.speed import parallel as speed_parallel
from fxc_env.speed import torchrl as speed_torchrl
from fxc_env.speed import vecenv as speed_vecenv
from fxc_env.utils.threads import THREAD_VARIABLES


@pytest.fixture
def one_thread(monkeypatch):
    """With every thread variable at 1 the command runs in-process (no re-exec)."""
    for name in THREAD_VARIABLES:
        monkeypatch.setenv(name, "1")


def _rates_of(rows: list[str], column: int) -> list[float]:
    return [float(row.split("|")[column].replace(",", "")) for row in rows]


def _goal_lines(lines: list[str]) -> list[str]:
    return [line for line in lines if "(goal" in line]


def test_scaling_rows_cover_each_power_of_ten_with_positive_costs():
    lines = scaling.scaling_table(1000)
    rows = [line for line in lines[2:] if line.startswith("|")]
    sizes = [int(row.split("|")[1].replace(",", "")) for row in rows]
    assert sizes == [100, 1000]
    for row in rows:
        seconds, per_agent, memory = (float(cell.replace(",", "")) for cell in row.split("|")[2:5])
        assert seconds > 0 and per_agent > 0 and memory > 0
    # The engine's interval goal is stated at N = 10^6, which --largest 1000 does not reach.
    assert lines[-1] == scaling.interval_goal_line(None)
    assert "N=1,000,000" in lines[-1] and "not measured" in lines[-1] and "--largest 1000000" in lines[-1]
    # So is its comparison with a bare scipy CSR product, measured in the same run.
    assert lines[-2] == scaling.product_goal_line(None, None)
    assert "CSR product" in lines[-2] and "not measured" in lines[-2] and "(goal <= 1.2x" in lines[-2]


@pytest.mark.parametrize(("interval", "verdict"), [(0.06, "met"), (0.12, "met"), (0.2, "not met")])
def test_the_product_goal_line_gives_the_interval_over_the_csr_product(interval, verdict):
    line = scaling.product_goal_line(interval, 0.1)
    assert f": {interval / 0.1:.2f}x (" in line and line.endswith(f"(goal <= 1.2x: {verdict})")
    assert "N=1,000,000" in line and "Laplacian x [x v]" in line


def test_interval_and_product_time_both_on_the_same_graph():
    interval, product = scaling.interval_and_product(2000, rounds=1, steps=1)
    assert 0 < interval < 10 and 0 < product < 10


@pytest.mark.parametrize(("seconds", "verdict"), [(0.05, "met"), (0.1, "met"), (0.2, "not met")])
def test_the_interval_goal_line_gives_the_ratio_to_a_tenth_of_a_second(seconds, verdict):
    line = scaling.interval_goal_line(seconds)
    assert f"{seconds / 0.1:.2f}x the goal" in line and line.endswith(f"(goal <= 0.1 s: {verdict})")


@pytest.mark.slow
def test_speed_command_states_machine_threads_tables_and_goals_without_training(one_thread, capsys, monkeypatch):
    """The smoke test: --skip-contenders runs our own tables (scaling, agent models), never a training."""
    monkeypatch.setattr(models, "MODELS_N", 300)
    monkeypatch.setattr(models, "MODELS_STEPS", 2)

    def no_training(*args, **kwargs):
        raise AssertionError("fxc speed --skip-contenders trained")

    monkeypatch.setattr(training, "training_rate", no_training)
    code = cli.main(["speed", "--skip-contenders", "--largest", "100", "--rounds", "1"])
    out = capsys.readouterr().out
    assert code == 0
    assert "machine:" in out and "cores" in out
    assert re.search(r"OMP_NUM_THREADS=1", out)
    assert "tables: scaling, models" in out and "Training" not in out
    assert "| 100 |" in out and "| oscillator |" in out
    tables, summary = out.split("## Goals measured in this run")
    summary = summary.strip().splitlines()
    assert summary == [f"- {line}" for line in _goal_lines(tables.splitlines())]  # every goal line, repeated
    assert any("one interval at N=1,000,000" in line for line in summary)
    assert any("general path / closed forms at N=300" in line for line in summary)


def test_speed_command_names_the_missing_extra(one_thread, capsys, monkeypatch):
    monkeypatch.setattr(command, "importable", lambda name: name != "vmas")
    code = cli.main(["speed", "--rounds", "1"])
    assert code == 2
    assert "vmas missing" in capsys.readouterr().err and ".[bench]" in command.BENCH_HINT


def test_parallel_table_prints_both_sizes_and_the_mpe2_goal_at_n6():
    pytest.importorskip("mpe2")
    lines = speed_parallel.parallel_table(1, seconds=0.001)
    rows = [line for line in lines[2:] if line.startswith("|")]
    assert [int(row.split("|")[1]) for row in rows] == [6, 20]
    assert all(math.isfinite(rate) and rate > 0 for rate in _rates_of(rows, 2) + _rates_of(rows, 3))
    goals = _goal_lines(lines)
    assert len(goals) == 1 and "MPE2 simple_spread_v3 at N=6" in goals[0]
    assert goals[0].endswith(("(goal >= 20x: met)", "(goal >= 20x: not met)"))


def test_vecenv_table_prints_ours_and_both_vmas_scenarios_at_the_same_agent_count():
    pytest.importorskip("vmas")
    lines = speed_vecenv.vec_table(60, 1)
    rows = [line for line in lines[2:] if line.startswith("|")]
    assert [row.split("|")[1].strip() for row in rows] == [
        "fxc_env ConsensusVecEnv + ReferencePolicy (paper_fig1)",
        "VMAS navigation (CPU, random actions)",
        "VMAS simple_spread (CPU, random actions)",
    ]
    assert {int(row.split("|")[2].replace(",", "")) for row in rows} == {60}
    assert all(math.isfinite(rate) and rate > 0 for rate in _rates_of(rows, 3))


def test_torchrl_rates_on_tiny_sizes_are_positive_and_finite():
    pytest.importorskip("torchrl")
    rates = speed_torchrl.torchrl_rates(1, sizes=(12, 30), seconds=0.001)
    expected = {("wrapper", 6)} | {(key, agents) for key, _ in speed_torchrl.TORCHRL_ROWS for agents in (12, 30)}
    assert set(rates) == expected
    assert all(math.isfinite(rate) and rate > 0 for rate in rates.values())


def test_torchrl_table_prints_every_contender_and_both_goals():
    pytest.importorskip("torchrl")
    lines = speed_torchrl.torchrl_table(1, sizes=(12, 30), seconds=0.001)
    rows = [line for line in lines[2:] if line.startswith("|")]
    assert len(rows) == 1 + 2 * len(speed_torchrl.TORCHRL_ROWS)
    assert rows[0].startswith(f"| {speed_torchrl.WRAPPER_LABEL} | 1 | 6 |")
    assert all(math.isfinite(rate) and rate > 0 for rate in _rates_of(rows, 4))
    goals = _goal_lines(lines)
    assert len(goals) == 2 and all(line.endswith(("met)", "not met)")) for line in goals)
    assert "PettingZoo wrapper" in goals[0] and "numpy engine at 30 agents" in goals[1]


@pytest.mark.slow
def test_cuda_tables_run_on_the_cpu_at_tiny_sizes():
    """The CUDA tables' code path, on torch's CPU device (this machine has no GPU)."""
    printed: list[str] = []
    cuda.cuda_tables(
        "cpu",
        1,
        contenders=False,
        sizes=(60,),
        episode_sizes=(20, 6),
        single=(50,),
        compare_envs=4,
        seconds=0.001,
        out=printed.append,
    )
    text = "\n".join(printed)
    rows = [line for line in text.splitlines() if line.startswith("| ") and line[2].isalnum()]
    sweep = [row for row in rows if row.startswith(("| random", "| paper_fig1"))]
    assert [int(row.split("|")[4].replace(",", "")) for row in sweep] == [60, 60]
    assert all(math.isfinite(rate) and rate > 0 for rate in _rates_of(sweep, 6))
    single = [row for row in rows if row.startswith("| 50 |")]
    assert len(single) == 1 and _rates_of(single, 3)[0] > 0
    ours = [row for row in rows if row.startswith(f"| {cuda.OURS_ON_GPU} |")]
    assert len(ours) == 1 and _rates_of(ours, 4)[0] > 0
    assert "no size of >= 1,000,000 agents was measured" in text  # the goal needs >= 1e6 agents


def test_cuda_sizes_that_run_out_of_memory_are_skipped_with_a_note(monkeypatch):
    def out_of_memory(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(cuda, "engine_stepper", out_of_memory)
    lines, rates = cuda.cuda_sweep_table("cpu", 1, sizes=(60,), episode_sizes=(6,), seconds=0.001)
    assert rates == {} and lines[-1] == "| paper_fig1 | 6 | 10 | 60 | out of memory: skipped | |"
    assert cuda.cuda_compare_table("cpu", 1, 4, contenders=False)[-1] == "fxc_env engine: out of memory at 24 agents"


@pytest.mark.parametrize(
    "argv", [["--device", "cuda"], ["--device", "cuda:0", "--only", "scaling"], ["--only", "cuda"]]
)
def test_cuda_without_cuda_is_a_usage_error_naming_device(one_thread, capsys, monkeypatch, argv):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert command.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("fxc speed: error: --device:") and "CUDA" in err
    with pytest.raises(ArgumentError, match=r"^--device"):  # what `fxc speed`'s handler raises for cli.main to print
        command.run(command.add_arguments(argparse.ArgumentParser()).parse_args(argv))


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--only", "torchrl,bogus"], "'bogus'"),
        (["--only", ""], "''"),
        (["--device", "tpu"], "'tpu'"),
        (["--only", "torchrl", "--skip-contenders"], "--skip-contenders"),
        (["--only", "training", "--skip-contenders"], "--skip-contenders"),
        (["--rounds", "0"], "--rounds"),
        (["--largest", "10"], "--largest"),
    ],
)
def test_bad_options_are_usage_errors_naming_the_option(one_thread, capsys, argv, named):
    assert command.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"fxc speed: error: {argv[0]}") and named in err


def test_table_selection_defaults_to_the_cpu_tables_and_skip_contenders_trains_nothing():
    parse = command.add_arguments(argparse.ArgumentParser()).parse_args
    assert command.selected_tables(parse([])) == (command.CPU_TABLES, "cpu")
    assert "training" in command.CPU_TABLES  # the full run still times the training back ends
    assert command.selected_tables(parse(["--skip-contenders"]))[0] == ("scaling", "models")
    assert command.selected_tables(parse(["--only", "training"]))[0] == ("training",)
    assert command.selected_tables(parse(["--only", "scaling, torchrl"]))[0] == ("torchrl", "scaling")
    assert command.selected_tables(argparse.Namespace(skip_contenders=False))[0] == command.CPU_TABLES  # older parser
    assert set(command.TABLE_RUNNERS) == set(command.CPU_TABLES)


@pytest.mark.slow
def test_only_runs_the_named_table(one_thread, capsys):
    assert command.main(["--only", "scaling", "--largest", "100", "--rounds", "1"]) == 0
    out = capsys.readouterr().out
    assert "tables: scaling" in out and "| 100 |" in out and "TorchRL" not in out and "MPE2" not in out


def test_the_torchrl_table_names_its_extra_when_torchrl_is_missing(one_thread, capsys, monkeypatch):
    monkeypatch.setattr(command, "importable", lambda name: name != "torchrl")
    assert command.main(["--only", "torchrl", "--rounds", "1"]) == 2
    assert "torchrl missing" in capsys.readouterr().err and '".[torchrl]"' in command.install_hint(["torchrl"])


@pytest.mark.slow
def test_python_dash_m_fxc_env_speed_pins_threads_and_runs(tmp_path):
    """The module the command re-executes (``python -m fxc_env.speed``) exists and runs the same tables."""
    assert command.MODULE == "fxc_env.speed" and importlib.util.find_spec("fxc_env.speed.__main__") is not None
    environment = {name: value for name, value in os.environ.items() if name not in THREAD_VARIABLES}
    result = subprocess.run(
        [sys.executable, "-m", "fxc_env.speed", "--only", "scaling", "--largest", "100", "--rounds", "1"],
        capture_output=True,
        text=True,
        env=environment,
        cwd=tmp_path,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert "OMP_NUM_THREADS=1" in result.stdout and "| 100 |" in result.stdout  # re-executed with one thread


def test_only_out_of_memory_errors_are_skipped(monkeypatch):
    import torch

    assert cuda.out_of_memory(torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 GiB"))
    assert cuda.out_of_memory(RuntimeError("CUDA error: CUBLAS_STATUS_ALLOC_FAILED when calling cublasCreate"))
    assert not cuda.out_of_memory(RuntimeError("shape mismatch"))

    def broken(*args, **kwargs):
        raise RuntimeError("shape mismatch")

    monkeypatch.setattr(cuda, "engine_stepper", broken)
    with pytest.raises(RuntimeError, match="shape mismatch"):  # a bug is never reported as a skipped size
        cuda.cuda_sweep_table("cpu", 1, sizes=(60,), episode_sizes=(6,), seconds=0.001)


@pytest.mark.slow
def test_the_models_table_compares_every_agent_model_with_the_closed_forms(one_thread):
    lines = models.models_table(n_agents=200, steps=2)
    text = "\n".join(lines)
    assert "| double_integrator as (A, B) (general path) |" in text and "| oscillator |" in text
    assert "general path / closed forms at N=200:" in lines[-1] and "goal <= 10x" in lines[-1]


@pytest.mark.slow
def test_the_training_table_times_every_back_end_in_this_environment(one_thread, monkeypatch):
    """Trains SB3 and the torch back end end to end (small rollouts): slow, so left out of ``make check``."""
    monkeypatch.setattr(training, "TRAINING_TIMESTEPS", {"sb3": 16 * 6 * 200, "torch": 64 * 6 * 200})
    lines = training.training_table(threads=1)
    rows = {line.split("|")[1].strip(): line for line in lines if line.startswith("| ") and "---" not in line}
    assert {"sb3", "torch", "rllib"} <= set(rows)
    assert any(name.startswith("TorchRL Collector + ClipPPOLoss") for name in rows)
    for backend in ("sb3", "torch"):
        rate = float(rows[backend].split("|")[4].replace(",", ""))
        assert rate > 0 and math.isfinite(rate)
    assert "goal >= 100,000" in lines[-1]
