"""fxc speed: its tables on tiny sizes, table selection and the command's report (figures are printed, never asserted)."""

from __future__ import annotations

import argparse
import math
import re

import pytest

from fxc_env import cli
from fxc_env.core.validation import ArgumentError
from fxc_env.speed import harness as speed


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


def _rates_of(rows: list[str], column: int) -> list[float]:
    return [float(row.split("|")[column].replace(",", "")) for row in rows]


def test_torchrl_rates_on_tiny_sizes_are_positive_and_finite():
    pytest.importorskip("torchrl")
    rates = speed.torchrl_rates(1, sizes=(12, 30), seconds=0.001)
    assert set(rates) == {("wrapper", 6)} | {(key, agents) for key, _ in speed.TORCHRL_ROWS for agents in (12, 30)}
    assert all(math.isfinite(rate) and rate > 0 for rate in rates.values())


def test_torchrl_table_prints_every_contender_and_both_goals():
    pytest.importorskip("torchrl")
    lines = speed.torchrl_table(1, sizes=(12, 30), seconds=0.001)
    rows = [line for line in lines[2:] if line.startswith("|")]
    assert len(rows) == 1 + 2 * len(speed.TORCHRL_ROWS)
    assert rows[0].startswith(f"| {speed.WRAPPER_LABEL} | 1 | 6 |")
    assert all(math.isfinite(rate) and rate > 0 for rate in _rates_of(rows, 4))
    goals = [line for line in lines if "goal" in line]
    assert len(goals) == 2 and all(line.endswith(("met)", "not met)")) for line in goals)
    assert "PettingZoo wrapper" in goals[0] and "numpy engine at 30 agents" in goals[1]


def test_cuda_tables_run_on_the_cpu_at_tiny_sizes():
    """The CUDA tables' code path, on torch's CPU device (this machine has no GPU)."""
    printed: list[str] = []
    speed.cuda_tables(
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
    ours = [row for row in rows if row.startswith(f"| {speed.OURS_ON_GPU} |")]
    assert len(ours) == 1 and _rates_of(ours, 4)[0] > 0
    assert "no size of >= 1,000,000 agents was measured" in text  # the goal needs >= 1e6 agents


def test_cuda_sizes_that_run_out_of_memory_are_skipped_with_a_note(monkeypatch):
    def out_of_memory(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(speed, "engine_stepper", out_of_memory)
    lines, rates = speed.cuda_sweep_table("cpu", 1, sizes=(60,), episode_sizes=(6,), seconds=0.001)
    assert rates == {} and lines[-1] == "| paper_fig1 | 6 | 10 | 60 | out of memory: skipped | |"
    assert speed.cuda_compare_table("cpu", 1, 4, contenders=False)[-1] == "fxc_env engine: out of memory at 24 agents"


@pytest.mark.parametrize(
    "argv", [["--device", "cuda"], ["--device", "cuda:0", "--only", "scaling"], ["--only", "cuda"]]
)
def test_cuda_without_cuda_is_a_usage_error_naming_device(one_thread, capsys, monkeypatch, argv):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert speed.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("fxc speed: error: --device:") and "CUDA" in err
    with pytest.raises(ArgumentError, match=r"^--device"):  # what `fxc speed`'s handler raises for cli.main to print
        speed.run(speed.add_arguments(argparse.ArgumentParser()).parse_args(argv))


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--only", "torchrl,bogus"], "'bogus'"),
        (["--only", ""], "''"),
        (["--device", "tpu"], "'tpu'"),
        (["--only", "torchrl", "--skip-contenders"], "--skip-contenders"),
    ],
)
def test_bad_table_selection_names_the_option(one_thread, capsys, argv, named):
    assert speed.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"fxc speed: error: {argv[0]}:") and named in err


def test_table_selection_defaults_to_the_cpu_tables():
    parse = speed.add_arguments(argparse.ArgumentParser()).parse_args
    assert speed.selected_tables(parse([])) == (speed.CPU_TABLES, "cpu")
    assert speed.selected_tables(parse(["--skip-contenders"]))[0] == ("training", "scaling", "models")
    assert speed.selected_tables(parse(["--only", "scaling, torchrl"]))[0] == ("torchrl", "scaling")
    assert speed.selected_tables(argparse.Namespace(skip_contenders=False))[0] == speed.CPU_TABLES  # an older parser


def test_only_runs_the_named_table(one_thread, capsys):
    assert speed.main(["--only", "scaling", "--largest", "100", "--rounds", "1"]) == 0
    out = capsys.readouterr().out
    assert "tables: scaling" in out and "| 100 |" in out and "TorchRL" not in out and "MPE2" not in out


def test_the_torchrl_table_names_its_extra_when_torchrl_is_missing(one_thread, capsys, monkeypatch):
    monkeypatch.setattr(speed, "_importable", lambda name: name != "torchrl")
    assert speed.main(["--only", "torchrl", "--rounds", "1"]) == 2
    assert "torchrl missing" in capsys.readouterr().err and '".[torchrl]"' in speed.install_hint(["torchrl"])


def test_only_out_of_memory_errors_are_skipped(monkeypatch):
    import torch

    assert speed.out_of_memory(torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 GiB"))
    assert speed.out_of_memory(RuntimeError("CUDA error: CUBLAS_STATUS_ALLOC_FAILED when calling cublasCreate"))
    assert not speed.out_of_memory(RuntimeError("shape mismatch"))

    def broken(*args, **kwargs):
        raise RuntimeError("shape mismatch")

    monkeypatch.setattr(speed, "engine_stepper", broken)
    with pytest.raises(RuntimeError, match="shape mismatch"):  # a bug is never reported as a skipped size
        speed.cuda_sweep_table("cpu", 1, sizes=(60,), episode_sizes=(6,), seconds=0.001)


def test_the_models_table_compares_every_agent_model_with_the_closed_forms(one_thread):
    lines = speed.models_table(n_agents=200, steps=2)
    text = "\n".join(lines)
    assert "| double_integrator as (A, B) (general path) |" in text and "| oscillator |" in text
    assert "general path / closed forms at N=200:" in lines[-1] and "goal <= 10x" in lines[-1]


def test_the_training_table_times_every_back_end_in_this_environment(one_thread, monkeypatch):
    monkeypatch.setattr(speed, "TRAINING_TIMESTEPS", {"sb3": 16 * 6 * 200, "torchrl": 64 * 6 * 200})
    lines = speed.training_table(threads=1)
    rows = {line.split("|")[1].strip(): line for line in lines if line.startswith("| ") and "---" not in line}
    assert {"sb3", "torchrl", "rllib"} <= set(rows)
    assert any(name.startswith("TorchRL Collector + ClipPPOLoss") for name in rows)
    for backend in ("sb3", "torchrl"):
        rate = float(rows[backend].split("|")[4].replace(",", ""))
        assert rate > 0 and math.isfinite(rate)
    assert "goal >= 100,000" in lines[-1]
