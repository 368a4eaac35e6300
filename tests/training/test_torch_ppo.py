"""fxc_env.training.backends.torch_ppo (``fxc train --backend torch``): short runs, checkpoints, resume, the saved policy."""

from __future__ import annotations

import csv
import json
import signal

import numpy as np
import pytest
import torch
import yaml

from fxc_env import make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine
from fxc_env.policies.torch_policy import load_torch_policy
from fxc_env.training import TrainArgs, train
from fxc_env.training.args import HYPERPARAMS, check_train_args
from fxc_env.training.backends.torch_ppo import Trainer, latest_torch_checkpoint

# 2 episodes x 6 agents, one whole episode (K = 200) per rollout: 2400 timesteps a rollout.
PER_ROLLOUT = 2400


def short_args(tmp_path, **changes) -> TrainArgs:
    base = {
        "scenario": "paper_fig1",
        "backend": "torch",
        "n_envs": 2,
        "timesteps": 2 * PER_ROLLOUT,
        "checkpoint_every": PER_ROLLOUT,
        "run_dir": str(tmp_path / "run"),
        "progress_bar": False,
    }
    return TrainArgs(**{**base, **changes})


def hyperparams_with(tmp_path, **torch_ppo) -> str:
    """The shipped hyperparameter file with some ``torch_ppo`` settings changed."""
    table = yaml.safe_load(HYPERPARAMS.read_text())
    entry = table["paper_fig1"]
    entry["torch_ppo"] = {**entry["torch_ppo"], **torch_ppo}
    path = tmp_path / "hyperparams.yml"
    path.write_text(yaml.safe_dump({"paper_fig1": entry}))
    return str(path)


def progress_rows(run_dir) -> list[dict[str, str]]:
    with (run_dir / "progress.csv").open() as handle:
        return list(csv.DictReader(handle))


def adam_steps(checkpoint) -> float:
    record = torch.load(checkpoint, weights_only=True)
    return max(float(state["step"]) for state in record["optimizer"]["state"].values())


@pytest.mark.slow
def test_a_short_run_writes_the_run_directory_and_a_loadable_policy(tmp_path):
    run_dir = train(short_args(tmp_path))
    record = json.loads((run_dir / "config.json").read_text())
    assert record["args"]["backend"] == "torch" and record["timesteps_per_rollout"] == PER_ROLLOUT
    assert record["torch_ppo"]["gamma"] == 1.0
    assert "torch" in json.loads((run_dir / "versions.json").read_text())
    rows = progress_rows(run_dir)
    assert [int(row["time/total_timesteps"]) for row in rows] == [PER_ROLLOUT, 2 * PER_ROLLOUT]
    for row in rows:  # every rollout ends its episodes here (T = K)
        assert np.isfinite(float(row["rollout/ep_rew_mean"])) and float(row["rollout/deadline_error"]) > 0
        assert float(row["time/fps"]) > 0 and int(row["rollout/episodes"]) == 2
    assert list(run_dir.glob("events.out.tfevents.*")), "TensorBoard logs"
    assert (run_dir / "training_curve.png").stat().st_size > 0
    names = sorted(path.name for path in (run_dir / "checkpoints").iterdir())
    assert names == [f"model_{PER_ROLLOUT}_steps.pt", f"model_{2 * PER_ROLLOUT}_steps.pt"]

    policy = load_torch_policy(run_dir)
    config = make_config("paper_fig1", obs_slots=4, initial_state="random")
    engine = ConsensusEngine(config, n_episodes=3)
    x0, v0 = zip(*(engine.sample_initial_state(np.random.default_rng(s)) for s in range(3)), strict=True)
    engine.reset(np.stack(x0), np.stack(v0))
    obs = engine.observations()
    actions = policy(obs)
    assert isinstance(actions, np.ndarray) and actions.shape == (3, 6, 2) and actions.dtype == np.float64
    assert np.array_equal(actions, policy(obs)), "deterministic: the mean action"
    assert np.all(np.abs(actions) <= config.action_bound)
    single = policy(torch.as_tensor(obs[0, 0], dtype=torch.float32))
    assert isinstance(single, torch.Tensor) and single.shape == (2,) and single.dtype == torch.float32
    assert np.allclose(single.numpy(), actions[0, 0], atol=1e-6)
    # The saved policy plays whole episodes on the numpy engine.
    while not engine.done:
        engine.step(engine.validate_actions(policy(engine.observations())))
    assert np.all(np.isfinite(engine.batch_metrics()["relative_deadline_error"]))
    # A checkpoint is a policy file too.
    assert np.array_equal(load_torch_policy(latest_torch_checkpoint(run_dir))(obs), actions)
    with pytest.raises(ArgumentError, match=r"^observations: expected shape \[\.\.\., 15\]"):
        policy(np.zeros((3, 14)))
    with pytest.raises(ArgumentError, match=r"^policy: no torch policy file"):
        load_torch_policy(tmp_path / "missing")


@pytest.mark.slow
def test_resume_continues_the_step_count_optimiser_and_generators(tmp_path, capsys):
    train(short_args(tmp_path, timesteps=PER_ROLLOUT))
    first = latest_torch_checkpoint(tmp_path / "run")
    assert first.name == f"model_{PER_ROLLOUT}_steps.pt"
    run_dir = train(short_args(tmp_path, resume=True))
    assert f"resuming {run_dir} from {first.name} at {PER_ROLLOUT} timesteps" in capsys.readouterr().out
    assert [int(row["time/total_timesteps"]) for row in progress_rows(run_dir)] == [PER_ROLLOUT, 2 * PER_ROLLOUT]
    assert [int(row["time/iterations"]) for row in progress_rows(run_dir)] == [1, 2]
    last = latest_torch_checkpoint(run_dir)
    assert last.name == f"model_{2 * PER_ROLLOUT}_steps.pt"
    # Adam's step counter goes on from the checkpoint's.
    assert adam_steps(first) > 0 and adam_steps(last) == 2 * adam_steps(first)
    # Resuming at a rollout boundary gives the run that was never stopped, bit for bit.
    straight = train(short_args(tmp_path, run_dir=str(tmp_path / "straight")))
    resumed = torch.load(run_dir / "policy.pt", weights_only=True)["actor"]
    uninterrupted = torch.load(straight / "policy.pt", weights_only=True)["actor"]
    assert all(torch.equal(resumed[k], uninterrupted[k]) for k in resumed)


@pytest.mark.slow
def test_ctrl_c_finishes_the_rollout_saves_a_checkpoint_and_resume_finishes(tmp_path, monkeypatch):
    collect = Trainer.collect
    calls = []

    def pressed(self):  # the user presses Ctrl-C during the second rollout
        calls.append(1)
        if len(calls) == 2:
            signal.raise_signal(signal.SIGINT)
        return collect(self)

    monkeypatch.setattr(Trainer, "collect", pressed)
    with pytest.raises(KeyboardInterrupt):
        train(short_args(tmp_path, timesteps=4 * PER_ROLLOUT, checkpoint_every=10**9))
    assert latest_torch_checkpoint(tmp_path / "run").name == f"model_{2 * PER_ROLLOUT}_steps.pt"
    monkeypatch.undo()
    run_dir = train(short_args(tmp_path, timesteps=3 * PER_ROLLOUT, resume=True))
    assert [int(row["time/total_timesteps"]) for row in progress_rows(run_dir)] == [2400, 4800, 7200]


@pytest.mark.slow
def test_a_central_critic_and_rollouts_shorter_than_an_episode(tmp_path):
    """``--critic central`` reads the normalized global state; T = K / 2 bootstraps the cut episodes."""
    hyperparams = hyperparams_with(tmp_path, rollout_steps=100, minibatch_size=600, epochs=2)
    run_dir = train(short_args(tmp_path, critic="central", hyperparams=hyperparams, timesteps=3 * 1200))
    rows = progress_rows(run_dir)
    assert [int(row["time/total_timesteps"]) for row in rows] == [1200, 2400, 3600]
    assert [row["rollout/ep_rew_mean"] != "" for row in rows] == [False, True, False]  # episodes end every 2nd
    assert int(rows[0]["train/n_updates"]) == 2 * 2
    record = torch.load(latest_torch_checkpoint(run_dir), weights_only=True)
    assert record["model"]["critic.0.weight"].shape[1] == 6 * 2 + 3  # N * 2 dim + clock
    assert load_torch_policy(run_dir)(np.zeros((4, 15))).shape == (4, 2)


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
def test_cuda_without_cuda_names_the_device(tmp_path):
    with pytest.raises(ArgumentError, match=r"^device: 'cuda' asks for CUDA"):
        train(short_args(tmp_path, device="cuda"))
    with pytest.raises(ArgumentError, match=r"^--device: 'cuda' asks for CUDA"):
        check_train_args(short_args(tmp_path, device="cuda"), flags=True)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"critic": "global"}, r"critic: expected one of \('local', 'central'\), got 'global'"),
        ({"critic": "central", "backend": "sb3"}, "critic: only the torch backend"),
        ({"device": "cuda", "backend": "sb3"}, "device: only the torch and diff backends"),
        ({"device": "tpu"}, "device: expected"),
        ({"algo": "sac"}, "algo: the torch backend trains 'ppo'"),
    ],
)
def test_bad_arguments_are_named(tmp_path, change, message):
    with pytest.raises(ArgumentError, match=f"^{message}"):
        check_train_args(short_args(tmp_path, **change))
    flag = "--" + message.split(":")[0]
    with pytest.raises(ArgumentError, match=f"^{flag}:"):
        check_train_args(short_args(tmp_path, **change), flags=True)
    with pytest.raises(ArgumentError, match=f"^{message}"):
        train(short_args(tmp_path, **change))
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ({"rollout_steps": 7}, r"hyperparams: torch_ppo.rollout_steps: expected K = 200 or a divisor of it, got 7"),
        ({"epochs": 0}, r"hyperparams: torch_ppo.epochs: expected an integer >= 1"),
        ({"activation": "sigmoid"}, r"hyperparams: torch_ppo.activation: expected one of"),
        ({"hidden": []}, r"hyperparams: torch_ppo.hidden: expected a list of layer widths"),
        ({"gamma": 1.5}, r"hyperparams: torch_ppo.gamma: expected a finite number"),
        ({"n_step": 3}, r"hyperparams: torch_ppo has no setting 'n_step'"),
    ],
)
def test_bad_hyperparameters_are_named_before_work_starts(tmp_path, setting, message):
    args = short_args(tmp_path, hyperparams=hyperparams_with(tmp_path, **setting))
    with pytest.raises(ArgumentError, match=f"^{message}"):
        train(args)
    assert not (tmp_path / "run").exists()


def test_resume_without_a_checkpoint_is_refused(tmp_path):
    with pytest.raises(ArgumentError, match=r"^resume: no checkpoint in .* \(expected model_<timesteps>_steps.pt\)"):
        train(short_args(tmp_path, resume=True))


@pytest.mark.slow
def test_fxc_evaluate_scores_a_torch_run_next_to_the_reference(tmp_path, capsys):
    from fxc_env.cli import main
    from fxc_env.policies.learned import load_learned_policy
    from fxc_env.policies.torch_policy import TorchPolicy

    run_dir = train(short_args(tmp_path, timesteps=PER_ROLLOUT))
    assert isinstance(load_learned_policy(run_dir / "policy.pt"), TorchPolicy)
    out = tmp_path / "evaluate"
    # Scored inside the run's training domain (paper_fig1, as the file records).
    arguments = ["evaluate", "--policy", str(run_dir), "--scenario", "paper_fig1", "--seeds", "2"]
    assert main([*arguments, "--out", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "learned:run" in text and "torch policy" in text


@pytest.mark.slow
def test_backend_torchrl_is_the_same_run_with_a_deprecation_message(tmp_path, capsys):
    from fxc_env.cli import main

    common = ["train", "--n-envs", "2", "--timesteps", str(PER_ROLLOUT), "--no-progress-bar"]
    assert main([*common, "--backend", "torch", "--run-dir", str(tmp_path / "torch")]) == 0
    assert "deprecated" not in capsys.readouterr().err
    assert main([*common, "--backend", "torchrl", "--run-dir", str(tmp_path / "old_name")]) == 0
    err = capsys.readouterr().err
    assert err == "fxc train: --backend torchrl is deprecated; use --backend torch\n"
    configs = [json.loads((tmp_path / name / "config.json").read_text()) for name in ("torch", "old_name")]
    assert [config["args"]["backend"] for config in configs] == ["torch", "torch"]
    assert {**configs[0]["args"], "run_dir": None} == {**configs[1]["args"], "run_dir": None}
    first, second = (
        torch.load(tmp_path / name / "policy.pt", weights_only=True)["actor"] for name in ("torch", "old_name")
    )
    assert all(torch.equal(first[k], second[k]) for k in first), "the same seed trains the same policy"


@pytest.mark.slow
def test_a_run_of_the_old_backend_name_resumes_and_loads(tmp_path, monkeypatch, capsys):
    """A run written as ``--backend torchrl`` (its config, its default directory, a ``torchrl_ppo`` entry) goes on."""
    from fxc_env.cli import main

    monkeypatch.chdir(tmp_path)
    old = tmp_path / "runs" / "paper_fig1-torchrl-ppo-seed0"
    train(short_args(tmp_path, run_dir=str(old), timesteps=PER_ROLLOUT))
    record = json.loads((old / "config.json").read_text())
    record["args"]["backend"] = "torchrl"
    record["torchrl_ppo"] = record.pop("torch_ppo")
    (old / "config.json").write_text(json.dumps(record))
    table = yaml.safe_load(HYPERPARAMS.read_text())
    table["paper_fig1"]["torchrl_ppo"] = table["paper_fig1"].pop("torch_ppo")
    (tmp_path / "old.yml").write_text(yaml.safe_dump({"paper_fig1": table["paper_fig1"]}))
    capsys.readouterr()
    argv = ["train", "--backend", "torch", "--resume", "--n-envs", "2", "--timesteps", str(2 * PER_ROLLOUT)]
    assert main([*argv, "--hyperparams", "old.yml", "--no-progress-bar"]) == 0
    assert f"resuming runs/paper_fig1-torchrl-ppo-seed0 from model_{PER_ROLLOUT}_steps.pt" in capsys.readouterr().out
    assert not (tmp_path / "runs" / "paper_fig1-torch-ppo-seed0").exists()
    assert [int(row["time/total_timesteps"]) for row in progress_rows(old)] == [PER_ROLLOUT, 2 * PER_ROLLOUT]
    assert load_torch_policy(old)(np.zeros((3, 15))).shape == (3, 2)


@pytest.mark.parametrize("damage", ["garbage", "truncated"])
def test_resume_from_a_damaged_checkpoint_is_a_usage_error_naming_it(tmp_path, damage):
    checkpoint = tmp_path / "run" / "checkpoints" / "model_1_steps.pt"
    checkpoint.parent.mkdir(parents=True)
    if damage == "garbage":
        checkpoint.write_bytes(b"not a checkpoint\n" * 8)
    else:
        torch.save({"format": "x", "weights": torch.zeros(4096)}, checkpoint)
        checkpoint.write_bytes(checkpoint.read_bytes()[:2000])  # a save cut short
    with pytest.raises(ArgumentError, match=r"^resume: cannot read the checkpoint '.*model_1_steps.pt'"):
        train(short_args(tmp_path, resume=True))


@pytest.mark.parametrize(
    ("flag", "value"), [("--num-env-runners", "4"), ("--envs-per-runner", "2"), ("--address", "auto")]
)
def test_rllib_only_flags_are_refused_by_the_torch_backend(tmp_path, capsys, flag, value):
    from fxc_env.cli import main

    argv = ["train", "--backend", "torch", "--run-dir", str(tmp_path / "run"), flag, value]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"fxc train: error: {flag}: only the rllib backend reads it; the torch backend")
    assert not (tmp_path / "run").exists()


def test_resume_to_a_reached_target_exits_2_saying_so(tmp_path, capsys):
    from fxc_env.cli import main

    checkpoint = tmp_path / "run" / "checkpoints" / f"model_{PER_ROLLOUT}_steps.pt"
    checkpoint.parent.mkdir(parents=True)
    checkpoint.write_bytes(b"")
    argv = ["train", "--backend", "torch", "--run-dir", str(tmp_path / "run"), "--resume", "--n-envs", "2"]
    assert main([*argv, "--timesteps", str(PER_ROLLOUT), "--no-progress-bar"]) == 2
    assert f"already at {PER_ROLLOUT} timesteps" in capsys.readouterr().err


def test_a_run_directory_in_an_unwritable_place_is_a_usage_error(capsys):
    from fxc_env.cli import main

    assert main(["train", "--backend", "torch", "--run-dir", "/proc/fxc-train/run", "--timesteps", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fxc train: error: ") and "/proc" in err and len(err.strip().splitlines()) == 1
