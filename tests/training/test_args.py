"""fxc_env.training.args: ``fxc train``'s flags come from the TrainArgs dataclass, one per field, and are checked."""

from __future__ import annotations

import argparse
import dataclasses
import json
import warnings
from pathlib import Path

import pytest
import yaml

from fxc_env.cli import main
from fxc_env.config.argument_types import plain_text
from fxc_env.core.validation import ArgumentError
from fxc_env.training import TrainArgs, registry
from fxc_env.training.args import (
    BACKENDS,
    HYPERPARAMS,
    add_train_parser,
    args_from_namespace,
    canonical_backend,
    check_train_args,
    default_run_dir,
    flag_type,
    load_hyperparams,
)

FIELDS = dataclasses.fields(TrainArgs)


def flag(field: dataclasses.Field) -> str:
    return "--" + field.name.replace("_", "-")


@pytest.fixture
def parser() -> argparse.ArgumentParser:
    return add_train_parser(argparse.ArgumentParser(prog="fxc").add_subparsers())


def test_every_field_is_a_flag_with_its_default_and_help(parser):
    actions = {action.dest: action for action in parser._actions if action.dest != "help"}
    assert set(actions) == {field.name for field in FIELDS}
    for field in FIELDS:
        action = actions[field.name]
        assert action.default == field.default, field.name
        assert action.help == field.metadata["help"] and len(action.help) > 10, field.name
        if flag_type(field) is bool:
            assert action.option_strings == [flag(field), "--no-" + flag(field)[2:]]
        else:
            assert action.option_strings == [flag(field)]
    # Nothing given: the dataclass's defaults, with their types.
    assert args_from_namespace(parser.parse_args([])) == TrainArgs()


def test_the_help_text_of_fxc_train_lists_every_flag(capsys):
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
    for field in FIELDS:
        assert flag(field) in text
        assert " ".join(plain_text(field.metadata["help"]).split()[:4]) in text, field.name


def test_a_command_line_reaches_every_field_with_its_type(parser):
    given = {
        "scenario": "ring_6",
        "task": "rings20-v2",  # fxc train refuses it beside --scenario (tests/training/test_train_task.py)
        "algo": "sac",
        "timesteps": 1234,
        "seed": 7,
        "seeds": "0-2,5",  # parsed as text; fxc train refuses it beside --seed (tests/training/test_train_seeds.py)
        "run_dir": "runs/x",
        "checkpoint_every": 99,
        "resume": True,
        "trust_policy_file": True,
        "hyperparams": "h.yml",
        "n_envs": 3,
        "progress_bar": False,
        "torch_threads": 2,
        "backend": "rllib",
        "num_env_runners": 0,
        "envs_per_runner": 4,
        "address": "auto",
        "device": "cuda:1",
        "critic": "central",
        "policy_arch": "gru",
        "init_from": "rings_gru",
    }
    assert set(given) == {field.name for field in FIELDS}
    argv = []
    for field in FIELDS:
        value = given[field.name]
        if isinstance(value, bool):
            argv.append(flag(field) if value else "--no-" + flag(field)[2:])
        else:
            argv += [flag(field), str(value)]
    assert args_from_namespace(parser.parse_args(argv)) == TrainArgs(**given)


INTEGER_FIELDS = [field for field in FIELDS if flag_type(field) is int]


@pytest.mark.parametrize("field", INTEGER_FIELDS, ids=[f.name for f in INTEGER_FIELDS])
@pytest.mark.parametrize("text", ["abc", "2.5", ""])
def test_a_value_that_is_not_an_integer_is_a_one_line_error_naming_the_flag(tmp_path, capsys, field, text):
    status = main(["train", flag(field), text, "--run-dir", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert status == 2
    assert err.startswith(f"fxc train: error: {flag(field)}: expected an integer") and err.count("\n") == 1, err
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--backend", "jax"], f"--backend: expected one of {tuple(registry.BACKENDS)}, got 'jax'"),
        (["--algo", "dqn"], f"--algo: expected one of {registry.algorithms()}, got 'dqn'"),
        (["--backend", "torch", "--critic", "global"], "--critic: expected one of ('local', 'central'), got 'global'"),
        (
            ["--backend", "torch", "--device", "tpu"],
            "--device: expected a torch device such as 'cpu' or 'cuda', got 'tpu'",
        ),
        (["--timesteps", "-5"], "--timesteps: expected an integer >= 1, got -5"),
    ],
)
def test_bad_values_are_one_line_errors_naming_the_flag(tmp_path, capsys, argv, message):
    assert main(["train", *argv, "--run-dir", str(tmp_path / "run")]) == 2
    assert capsys.readouterr().err == f"fxc train: error: {message}\n"


def test_backend_torchrl_on_the_command_line_is_torch_with_a_deprecation_line(parser, capsys):
    args = args_from_namespace(parser.parse_args(["--backend", "torchrl"]))
    assert args.backend == "torch"
    assert capsys.readouterr().err == "fxc train: --backend torchrl is deprecated; use --backend torch\n"
    args_from_namespace(parser.parse_args(["--backend", "torch"]))
    assert capsys.readouterr().err == ""
    assert BACKENDS == tuple(registry.BACKENDS) and "torchrl" not in BACKENDS  # the old name is an alias only


def test_the_old_name_is_accepted_by_the_functions_with_a_deprecation_warning(tmp_path):
    old = TrainArgs(backend="torchrl", n_envs=2, run_dir=str(tmp_path / "run"))
    with pytest.warns(DeprecationWarning, match="backend 'torchrl' is deprecated; use 'torch'"):
        params = check_train_args(old)
    assert params == check_train_args(dataclasses.replace(old, backend="torch"))
    assert canonical_backend("torch") == "torch" and canonical_backend("jax") == "jax"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert canonical_backend("torchrl", warn=False) == "torch"
    assert not (tmp_path / "run").exists()


def test_default_run_directories_and_the_old_torch_default(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert default_run_dir(TrainArgs()) == "runs/paper_fig1-ppo-seed0"
    assert default_run_dir(TrainArgs(backend="rllib", seed=3)) == "runs/paper_fig1-rllib-ppo-seed3"
    assert default_run_dir(TrainArgs(backend="torch")) == "runs/paper_fig1-torch-ppo-seed0"
    assert default_run_dir(TrainArgs(backend="torchrl")) == "runs/paper_fig1-torch-ppo-seed0"
    # A run started under the old name, resumed without --run-dir, goes on where it is.
    Path("runs/paper_fig1-torchrl-ppo-seed0").mkdir(parents=True)
    assert default_run_dir(TrainArgs(backend="torch")) == "runs/paper_fig1-torch-ppo-seed0"
    assert default_run_dir(TrainArgs(backend="torch", resume=True)) == "runs/paper_fig1-torchrl-ppo-seed0"
    Path("runs/paper_fig1-torch-ppo-seed0").mkdir()
    assert default_run_dir(TrainArgs(backend="torch", resume=True)) == "runs/paper_fig1-torch-ppo-seed0"


def test_an_older_hyperparameter_file_with_torchrl_ppo_is_read(tmp_path):
    table = yaml.safe_load(HYPERPARAMS.read_text())
    shipped = load_hyperparams(HYPERPARAMS, "paper_fig1", "torch_ppo")
    entry = table["paper_fig1"]
    entry["torchrl_ppo"] = entry.pop("torch_ppo")
    path = tmp_path / "old.yml"
    path.write_text(yaml.safe_dump({"paper_fig1": entry}))
    assert load_hyperparams(path, "paper_fig1", "torch_ppo") == shipped
    assert shipped["algo"]["rollout_steps"] == 200
    del entry["torchrl_ppo"]
    path.write_text(yaml.safe_dump({"paper_fig1": entry}))
    with pytest.raises(ArgumentError, match=r"^algo: .* has no 'torch_ppo' entry for 'paper_fig1'"):
        load_hyperparams(path, "paper_fig1", "torch_ppo")


def test_the_arguments_are_recorded_as_plain_json():
    record = json.loads(json.dumps(dataclasses.asdict(TrainArgs())))
    assert record == {field.name: field.default for field in FIELDS}
