"""`fxc simulate`: files, metrics.json and the printed table meet the acceptance numbers."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys

import numpy as np
import pytest
from helpers import PAPER_V_STAR, PAPER_X_STAR, PAPER_XI
from matplotlib.image import imread

from fxc_env.cli import main

FILES = ["topology.png", "positions.png", "velocities.png", "inputs.png", "disagreement.png", "metrics.json"]


def table_rows(text: str) -> dict[str, list[str]]:
    """Markdown table rows of the printed summary: first cell -> other cells."""
    rows = {}
    for line in text.splitlines():
        if line.startswith("|") and not line.startswith("|-"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            rows[cells[0]] = cells[1:]
    return rows


def find_row(rows: dict[str, list[str]], start: str) -> list[str]:
    matches = [cells for name, cells in rows.items() if name.startswith(start)]
    assert len(matches) == 1, (start, list(rows))
    return matches[0]


def assert_figures(out):
    for name in FILES[:-1]:
        path = out / name
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        image = imread(path)
        assert image.ndim == 3 and len(np.unique(image[..., :3].reshape(-1, 3), axis=0)) > 10


@pytest.mark.slow
def test_simulate_the_paper_example(tmp_path, capsys):
    assert main(["simulate", "--scenario", "paper_fig1", "--out", str(tmp_path)]) == 0
    for name in FILES:
        assert (tmp_path / name).is_file(), name
    assert_figures(tmp_path)

    record = json.loads((tmp_path / "metrics.json").read_text())
    m = record["metrics"]
    assert abs(m["achieved_final_position"] - PAPER_X_STAR) <= 1e-9
    assert abs(m["achieved_final_velocity"] - PAPER_V_STAR) <= 1e-9
    assert abs(m["predicted_final_position"] - PAPER_X_STAR) <= 1e-12
    assert abs(m["predicted_final_velocity"] - PAPER_V_STAR) <= 1e-12
    assert 0 <= m["relative_deadline_error"] <= 1e-9
    assert m["sampling_instants"] == 200
    np.testing.assert_allclose(record["xi"], PAPER_XI, atol=1e-12)
    settings = record["settings"]
    assert settings["n_agents"] == 6 and settings["settling_time"] == 20.0 and settings["n_intervals"] == 200
    assert "assumed" in settings["topology_note"]  # the reconstruction is labelled wherever it appears

    printed = capsys.readouterr().out
    assert "assumed" in printed
    rows = table_rows(printed)
    predicted_x, achieved_x = (float(c) for c in find_row(rows, "x*(T_s)"))
    predicted_v, achieved_v = (float(c) for c in find_row(rows, "v*"))
    assert abs(predicted_x - PAPER_X_STAR) <= 1e-12 and abs(achieved_x - PAPER_X_STAR) <= 1e-9
    assert abs(predicted_v - PAPER_V_STAR) <= 1e-12 and abs(achieved_v - PAPER_V_STAR) <= 1e-9
    deadline_error = float(find_row(rows, "relative deadline error")[-1])
    assert 0 <= deadline_error <= 1e-9
    assert deadline_error == pytest.approx(m["relative_deadline_error"], rel=1e-3)
    # The intervals bounds, named for what they bound: any law (the radius, 5) and laws using every root (7).
    assert find_row(rows, "intervals to 1e-9, any law (radius)")[0] == "5" and m["radius_bound"] == 5
    assert find_row(rows, "intervals, laws using every root")[0] == "7" and m["all_roots_bound"] == 7


@pytest.mark.slow
def test_simulate_with_other_options(tmp_path, capsys):
    out = tmp_path / "ring10"
    argv = [
        "simulate",
        "--scenario",
        "none",
        "--topology",
        "ring",
        "--n-agents",
        "10",
        "--dim",
        "2",
        "--n-intervals",
        "100",
        "--seed",
        "3",
        "--action-mode",
        "accel",
        "--obs-mode",
        "raw",
        "--points-per-interval",
        "4",
        "--out",
        str(out),
    ]
    assert main(argv) == 0
    for name in FILES:
        assert (out / name).is_file(), name
    record = json.loads((out / "metrics.json").read_text())
    s = record["settings"]
    assert (s["n_agents"], s["dim"], s["n_intervals"], s["seed"]) == (10, 2, 100, 3)
    assert (s["action_mode"], s["obs_mode"]) == ("accel", "raw")
    assert "ring" in s["topology"]
    # Directed ring: W is doubly stochastic, xi = 1/N.
    np.testing.assert_allclose(record["xi"], np.full(10, 0.1), rtol=1e-12)
    m = record["metrics"]
    assert m["sampling_instants"] == 100
    assert m["relative_deadline_error"] < 1.0
    assert abs(m["achieved_final_position"] - m["predicted_final_position"]) <= m["final_position_spread"] + 1e-9
    assert "K = 100" in capsys.readouterr().out


@pytest.mark.slow
def test_simulate_random_switching_topology(tmp_path):
    argv = ["simulate", "--scenario", "none", "--topology", "random", "--n-agents", "12", "--topology-period", "2"]
    argv += ["--topology-seed", "5", "--n-intervals", "30", "--points-per-interval", "2", "--out", str(tmp_path)]
    assert main(argv) == 0
    record = json.loads((tmp_path / "metrics.json").read_text())
    assert record["settings"]["n_agents"] == 12 and "period 2" in record["settings"]["topology"]
    assert sum(record["xi"]) == pytest.approx(1.0)


@pytest.mark.slow
def test_simulate_a_scenario_in_the_plane(tmp_path):
    # --dim overrides the scenario; its fixed 1-D initial state cannot apply and gives way
    # to seeded random draws (make_config's documented behaviour).
    argv = ["simulate", "--scenario", "ring_6", "--dim", "2", "--n-intervals", "20", "--points-per-interval", "2"]
    assert main([*argv, "--out", str(tmp_path)]) == 0
    assert json.loads((tmp_path / "metrics.json").read_text())["settings"]["dim"] == 2


@pytest.mark.parametrize(
    ("option", "name"),
    [
        (["--n-intervals", "0"], "n_intervals"),
        (["--settling-time", "-5"], "settling_time"),
        (["--settling-time", "nan"], "settling_time"),
        (["--topology", "hexagon", "--scenario", "none"], "topology"),
        (["--n-agents", "0", "--topology", "ring", "--scenario", "none"], "n_agents"),
        (["--dim", "0"], "dim"),
        (["--scenario", "paper_fig9"], "scenario"),
        (["--mean-in-degree", "-1", "--topology", "random", "--scenario", "none"], "mean_in_degree"),
    ],
)
def test_bad_option_values_fail_naming_the_argument(tmp_path, capsys, option, name):
    status = main(["simulate", *option, "--out", str(tmp_path / "out")])
    assert status != 0
    assert name in capsys.readouterr().err
    assert not (tmp_path / "out" / "metrics.json").exists()


@pytest.mark.parametrize(
    ("option", "name"),
    [
        (["--n-intervals", "many"], "--n-intervals"),
        (["--action-mode", "torque"], "--action-mode"),
        (["--schedule", "geometric"], "--schedule"),
    ],
)
def test_unparseable_options_exit_naming_the_option(capsys, option, name):
    with pytest.raises(SystemExit) as info:
        main(["simulate", *option])
    assert info.value.code != 0
    assert name in capsys.readouterr().err


def test_module_entry_point_exits_non_zero_on_a_bad_value(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "fxc_env.cli", "simulate", "--n-intervals", "0", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
    )
    assert result.returncode != 0
    assert "n_intervals" in result.stderr


# ------------------------------------------------------------------ usage errors of every subcommand
#
# Each row: argv (``{tmp}`` is the test's directory, ``{file}`` a regular file in it, ``{...}``
# the other fixtures of ``placeholders``) and the flag the one-line message must name. Every
# row runs in ``{tmp}`` and must leave it as it was: nothing is written before the checks pass.


def _override(base, *row):
    """``base`` with ``row`` after it, less the flags (and their values) ``row`` gives again: a flag is given once."""
    kept, skip = [], False
    for i, token in enumerate(base):
        if skip:
            skip = False
        elif token.startswith("--") and token in row:
            skip = i + 1 < len(base) and not base[i + 1].startswith("--")
        else:
            kept.append(token)
    return [*kept, *row]


TRAIN = ["train", "--run-dir", "{tmp}/run", "--no-progress-bar", "--timesteps", "100"]
EVALUATE = ["evaluate", "--policy", "reference", "--no-progress", "--out", "{tmp}/eval"]
BENCHMARK = ["benchmark", "--quick", "--no-progress", "--policies", "reference", "--out", "{tmp}/bench"]
USAGE_ERRORS = [
    # fxc simulate
    (["simulate", "--out", "{file}"], "--out"),
    (["simulate", "--out", "{file}/sub"], "--out"),
    (["simulate", "--out", "{file}/sub/deeper"], "--out"),
    (["simulate", "--out", ""], "--out"),
    (["simulate", "--points-per-interval", "0", "--out", "{tmp}/sim"], "--points-per-interval"),
    (["simulate", "--seed", "-1", "--out", "{tmp}/sim"], "--seed"),
    (["simulate", "--n-agents", "0", "--topology", "ring", "--scenario", "none", "--out", "{tmp}/sim"], "n_agents"),
    (["simulate", "--settling-time", "1e300", "--out", "{tmp}/sim"], "settling_time"),
    # fxc speed (refused before it re-executes itself with pinned threads)
    (["speed", "--rounds", "0"], "--rounds"),
    (["speed", "--total-agents", "0"], "--total-agents"),
    (["speed", "--largest", "0"], "--largest"),
    # fxc train
    (_override(TRAIN, "--hyperparams", "{tmp}/missing.yml"), "--hyperparams"),
    (_override(TRAIN, "--hyperparams", "{bad_yaml}"), "--hyperparams"),
    (_override(TRAIN, "--hyperparams", "{list_yaml}"), "--hyperparams"),
    (_override(TRAIN, "--hyperparams", "{tmp}"), "--hyperparams"),
    (_override(TRAIN, "--torch-threads", "0"), "--torch-threads"),
    (_override(TRAIN, "--n-envs", "0"), "--n-envs"),
    (_override(TRAIN, "--checkpoint-every", "-1"), "--checkpoint-every"),
    (_override(TRAIN, "--checkpoint-every", "0"), "--checkpoint-every"),
    (_override(TRAIN, "--timesteps", "0"), "--timesteps"),
    (_override(TRAIN, "--seed", "-1"), "--seed"),
    (_override(TRAIN, "--algo", "dqn"), "--algo"),
    (_override(TRAIN, "--backend", "tf"), "--backend"),
    (_override(TRAIN, "--backend", "rllib", "--algo", "sac"), "--algo"),
    (_override(TRAIN, "--backend", "rllib", "--num-env-runners", "-1"), "--num-env-runners"),
    (_override(TRAIN, "--backend", "rllib", "--envs-per-runner", "0"), "--envs-per-runner"),
    (_override(TRAIN, "--scenario", "paper_fig9"), "--scenario"),
    (_override(TRAIN, "--run-dir", "{file}"), "--run-dir"),
    (_override(TRAIN, "--run-dir", "{file}/run"), "--run-dir"),
    # fxc evaluate
    (_override(EVALUATE, "--budgets", "0"), "--budgets"),
    (_override(EVALUATE, "--budgets", "0,200"), "--budgets"),
    (_override(EVALUATE, "--budgets", "abc"), "--budgets"),
    (_override(EVALUATE, "--budgets", ""), "--budgets"),
    (_override(EVALUATE, "--budgets", "200,200"), "--budgets"),
    (_override(EVALUATE, "--seeds", "0"), "--seeds"),
    (_override(EVALUATE, "--workers", "0"), "--workers"),
    (_override(EVALUATE, "--out", "{file}"), "--out"),
    (_override(EVALUATE, "--out", "{file}/sub"), "--out"),
    (_override(EVALUATE, "--policy", "{tmp}/missing.zip"), "--policy"),
    (_override(EVALUATE, "--policy", "{empty_zip}"), "--policy"),
    (_override(EVALUATE, "--policy", "{text_zip}"), "--policy"),
    (_override(EVALUATE, "--policy", "{foreign_zip}"), "--policy"),
    (_override(EVALUATE, "--policy", "{truncated_zip}"), "--policy"),
    (_override(EVALUATE, "--policy", "{garbage_weights}"), "--policy"),
    (_override(EVALUATE, "--policy", "{half_weights}"), "--policy"),
    (_override(EVALUATE, "--policy", "{no_weights}"), "--policy"),
    (_override(EVALUATE, "--policy", "{bad_data}"), "--policy"),
    (_override(EVALUATE, "--policy", "{tmp}/empty_dir"), "--policy"),
    # fxc benchmark
    (_override(BENCHMARK, "--seeds", "0"), "--seeds"),
    (_override(BENCHMARK, "--workers", "0"), "--workers"),
    (_override(BENCHMARK, "--fine-intervals", "0"), "--fine-intervals"),
    (_override(BENCHMARK, "--out", "{file}"), "--out"),
    (_override(BENCHMARK, "--out", "{file}/sub"), "--out"),
    (_override(BENCHMARK, "--policies", "oracle"), "--policies"),
    (_override(BENCHMARK, "--policies", ","), "--policies"),
    (_override(BENCHMARK, "--address", "auto"), "--address"),
    (_override(BENCHMARK, "--policy", "{tmp}/missing.zip"), "--policy"),
    (_override(BENCHMARK, "--policy", "{empty_zip}"), "--policy"),
    (_override(BENCHMARK, "--policy", "{text_zip}"), "--policy"),
    (_override(BENCHMARK, "--policy", "{foreign_zip}"), "--policy"),
]


@pytest.fixture
def placeholders(tmp_path):
    """Fixture files for the argv templates, keyed by placeholder name."""
    import zipfile

    from fxc_env.policies.learned import pretrained_path

    (tmp_path / "notes.txt").write_text("not a directory\n")
    (tmp_path / "bad.yml").write_text("default: [unclosed\n")
    (tmp_path / "list.yml").write_text("- ppo\n- sac\n")
    (tmp_path / "empty.zip").write_bytes(b"")
    (tmp_path / "text.zip").write_text("this is not a zip archive\n")
    with zipfile.ZipFile(tmp_path / "foreign.zip", "w") as archive:
        archive.writestr("readme.txt", "a zip, but not a saved model")
    (tmp_path / "truncated.zip").write_bytes(pretrained_path().read_bytes()[:4000])
    # Zips whose directory is sound but whose members are damaged: torch's, pickle's and JSON's errors.
    with zipfile.ZipFile(pretrained_path()) as saved:
        members = {info.filename: saved.read(info.filename) for info in saved.infolist()}
    damaged = {
        "garbage_weights": {"policy.pth": b"garbage" * 10},
        "half_weights": {"policy.pth": members["policy.pth"][: len(members["policy.pth"]) // 2]},
        "no_weights": {"policy.pth": b""},
        "bad_data": {"data": members["data"][:100]},
    }
    for name, changes in damaged.items():
        with zipfile.ZipFile(tmp_path / f"{name}.zip", "w") as archive:
            for member, content in {**members, **changes}.items():
                archive.writestr(member, content)
    (tmp_path / "empty_dir").mkdir()
    return {
        "tmp": str(tmp_path),
        "file": str(tmp_path / "notes.txt"),
        "bad_yaml": str(tmp_path / "bad.yml"),
        "list_yaml": str(tmp_path / "list.yml"),
        "empty_zip": str(tmp_path / "empty.zip"),
        "text_zip": str(tmp_path / "text.zip"),
        "foreign_zip": str(tmp_path / "foreign.zip"),
        "truncated_zip": str(tmp_path / "truncated.zip"),
        **{name: str(tmp_path / f"{name}.zip") for name in damaged},
    }


def tree(path):
    """Every path below ``path`` with its size (directories as -1)."""
    return {p: (-1 if p.is_dir() else p.stat().st_size) for p in path.rglob("*")}


@pytest.mark.parametrize(("argv", "flag"), USAGE_ERRORS, ids=[" ".join(a) for a, _ in USAGE_ERRORS])
def test_usage_errors_are_one_line_naming_the_flag_and_write_nothing(
    tmp_path, monkeypatch, capsys, placeholders, argv, flag
):
    monkeypatch.chdir(tmp_path)  # defaults such as --out out and runs/ would land here too
    before = tree(tmp_path)
    status = main([arg.format(**placeholders) for arg in argv])
    err = capsys.readouterr().err
    assert status == 2, err
    assert err.startswith(f"fxc {argv[0]}: error: ") and flag in err, err
    assert err.endswith("\n") and err.count("\n") == 1 and "Traceback" not in err, err
    assert tree(tmp_path) == before


def test_out_with_missing_parents_is_created_like_mkdir_p(tmp_path):
    out = tmp_path / "a" / "b" / "c"
    assert main(["simulate", "--n-intervals", "5", "--points-per-interval", "2", "--out", str(out)]) == 0
    assert (out / "metrics.json").is_file()


@pytest.mark.parametrize("error", [ValueError("boom"), TypeError("boom"), RuntimeError("boom")])
def test_a_bug_in_a_handler_is_not_swallowed(tmp_path, monkeypatch, capsys, error):
    import fxc_env.analysis.simulation

    def broken(*args, **kwargs):
        raise error

    monkeypatch.setattr(fxc_env.analysis.simulation, "simulate", broken)
    with pytest.raises(type(error), match="boom"):
        main(["simulate", "--n-intervals", "5", "--out", str(tmp_path / "out")])
    assert capsys.readouterr().err == ""


def test_only_the_usage_error_class_is_a_usage_error(tmp_path, monkeypatch, capsys):
    import fxc_env.analysis.simulation
    from fxc_env.cli import UsageError
    from fxc_env.core.validation import ArgumentError, ArgumentTypeError

    assert UsageError is ArgumentError and issubclass(ArgumentTypeError, UsageError)

    def refuses(*args, **kwargs):
        raise ArgumentTypeError("x0: expected an array of real numbers, got 'abc'")

    monkeypatch.setattr(fxc_env.analysis.simulation, "simulate", refuses)
    assert main(["simulate", "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err == "fxc simulate: error: x0: expected an array of real numbers, got 'abc'\n"


def test_output_directory_helper(tmp_path):
    from fxc_env.core.validation import ArgumentError
    from fxc_env.utils.cli_checks import output_directory

    (tmp_path / "file").write_text("x")
    assert output_directory("--out", tmp_path) == tmp_path
    assert output_directory("--out", str(tmp_path / "new" / "deeper")) == tmp_path / "new" / "deeper"
    assert not (tmp_path / "new").exists()  # checks only: the command creates it when it writes
    for bad in (tmp_path / "file", tmp_path / "file" / "sub", ""):
        with pytest.raises(ArgumentError, match=r"^--out: "):
            output_directory("--out", bad)
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    with pytest.raises(ArgumentError, match="dangling"):
        output_directory("--out", tmp_path / "dangling" / "sub")


def test_benchmark_of_a_policy_refused_on_every_case_exits_2_naming_it(tmp_path, capsys, monkeypatch):
    from types import SimpleNamespace

    import fxc_env.baselines.harness.benchmark as benchmark

    def every_case_refused(suite, contenders, out, **kwargs):
        results = [
            SimpleNamespace(
                job=SimpleNamespace(contender=c), error="obs size 30, not 12" if "learned" in c.name else None
            )
            for c in contenders
            for _ in suite.cases
        ]
        return SimpleNamespace(markdown="Not run", files=[], results=results, seconds=0.0)

    monkeypatch.setattr(benchmark, "run_benchmark", every_case_refused)
    argv = ["benchmark", "--quick", "--seeds", "1", "--policy", "saturated", "--out", str(tmp_path), "--no-progress"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("fxc benchmark: error: --policy: ") and "(obs size 30, not 12)" in err


def test_benchmark_out_that_cannot_be_created_is_a_usage_error(capsys):
    argv = ["benchmark", "--quick", "--seeds", "1", "--out", "/proc/fxc-benchmark/out", "--no-progress"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("fxc benchmark: error: --out: ") and "/proc" in err


def test_simulate_out_that_cannot_be_created_is_a_usage_error(capsys):
    assert main(["simulate", "--out", "/proc/fxc-simulate/out"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fxc simulate: error: --out: ") and "/proc" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    ("argv", "flag"),
    [
        (["evaluate", "--task", "rings20-v1", "--task", "paper_fig1-v1"], "--task"),
        (["simulate", "--seed", "1", "--seed", "2"], "--seed"),
        (["train", "--timesteps", "1000", "--timesteps", "2000"], "--timesteps"),
        (["leaderboard", "--tasks", "rings20-v1", "--tasks", "saturated-v1"], "--tasks"),
    ],
)
def test_a_flag_given_twice_is_refused_in_one_line_not_overridden_by_the_last(argv, flag, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"fxc {argv[0]}: error: {flag}: given twice (") and err.endswith("; give it once\n")
    assert err.count("\n") == 1


@pytest.mark.parametrize(
    ("module", "argv"),
    [
        ("fxc_env.speed.command", ["--rounds", "1", "--rounds", "2"]),
        ("fxc_env.training.recipes.rings", ["--out", "a.npz", "--out", "b.npz"]),
        ("fxc_env.training.recipes.agnostic", ["--out", "a.npz", "--out", "b.npz"]),
        ("fxc_env.training.recipes.noise_gains", ["--sigma", "1e-3", "--sigma", "1e-2"]),
    ],
)
def test_the_module_entry_points_refuse_a_flag_given_twice_too(module, argv, capsys):
    with pytest.raises(SystemExit) as info:
        importlib.import_module(module).main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert f"error: {argv[0]}: given twice (" in err and err.count("\n") == 1
