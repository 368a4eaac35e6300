"""fxc_env.training.backends.sb3_train (``fxc train``, ``--backend sb3``): a short real PPO run, checkpoints, resume, Ctrl-C, reproducibility."""

from __future__ import annotations

import csv
import json
import signal

import numpy as np
import pytest

from fxc_env import ReferencePolicy, make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine
from fxc_env.policies.learned import LearnedPolicy, load_model
from fxc_env.training import TrainArgs, train
from fxc_env.training.args import check_train_args, load_hyperparams
from fxc_env.training.backends.sb3_train import RolloutCheckpoint
from fxc_env.training.run_dir import RunDir

# 4 episodes x 6 agents = 24 sub-environments; one PPO rollout is 200 x 24 = 4800 timesteps.
SHORT = {"scenario": "paper_fig1", "n_envs": 4, "progress_bar": False}


def short_args(tmp_path, **changes) -> TrainArgs:
    return TrainArgs(
        **{**SHORT, "run_dir": str(tmp_path / "run"), "timesteps": 9600, "checkpoint_every": 4800, **changes}
    )


def latest_checkpoint(run_dir):
    return RunDir(run_dir, "sb3").newest_checkpoint()


@pytest.mark.slow
def test_a_short_run_writes_the_run_directory_and_an_evaluable_model(tmp_path):
    run_dir = train(short_args(tmp_path))
    record = json.loads((run_dir / "config.json").read_text())
    assert record["args"]["timesteps"] == 9600 and record["num_envs"] == 24
    assert record["hyperparams"]["algo"]["n_steps"] == 200
    assert "torch" in json.loads((run_dir / "versions.json").read_text())
    assert (run_dir / "progress.csv").read_text().count("\n") >= 2
    assert list(run_dir.glob("events.out.tfevents.*")), "TensorBoard logs"
    assert (run_dir / "training_curve.png").stat().st_size > 0
    model = load_model(run_dir / "model.zip")
    assert model.num_timesteps == 9600
    # The saved model evaluates on the environment it was trained for.
    config = make_config("paper_fig1", obs_slots=4, initial_state="random")
    policy = LearnedPolicy(model, config)
    engine = ConsensusEngine(config, n_episodes=3)
    x0, v0 = zip(*(engine.sample_initial_state(np.random.default_rng(s)) for s in range(3)), strict=True)
    engine.reset(np.stack(x0), np.stack(v0))
    while not engine.done:
        engine.step(engine.validate_actions(policy(engine.observations())))
    metrics = engine.batch_metrics()
    assert np.all(np.isfinite(metrics["relative_deadline_error"])) and np.all(metrics["sampling_instants"] == 200)


@pytest.mark.slow
def test_resume_continues_from_the_newest_checkpoint_with_its_step_count_and_optimiser(tmp_path, capsys):
    train(short_args(tmp_path, timesteps=4800))
    checkpoint = latest_checkpoint(tmp_path / "run")
    assert checkpoint.name == "model_4800_steps.zip"
    saved = load_model(checkpoint, trusted=True)  # SB3's whole model (the optimiser too): our own file
    run_dir = train(short_args(tmp_path, resume=True))
    out = capsys.readouterr().out
    assert "resuming" in out and "from model_4800_steps.zip at 4800 timesteps" in out
    resumed = load_model(run_dir / "model.zip", trusted=True)
    assert resumed.num_timesteps == 9600
    # The log reads as one run: the first run's row, then the resumed run's (SB3 alone would start it afresh).
    with (run_dir / "progress.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [row["time/total_timesteps"] for row in rows] == ["4800", "9600"]
    # The checkpoint follows the first update, and Adam's step counter goes on from it.
    step_saved = max(s["step"].item() for s in saved.policy.optimizer.state_dict()["state"].values())
    step_resumed = max(s["step"].item() for s in resumed.policy.optimizer.state_dict()["state"].values())
    assert step_saved > 0 and step_resumed == 2 * step_saved


@pytest.mark.slow
def test_ctrl_c_saves_a_checkpoint_after_the_rollout_under_way_and_resume_finishes(tmp_path, monkeypatch, capsys):
    on_step = RolloutCheckpoint._on_step
    steps = []

    def pressed(self):  # the user presses Ctrl-C in the middle of the second rollout (200 steps each)
        steps.append(1)
        if len(steps) == 300:
            signal.raise_signal(signal.SIGINT)
        return on_step(self)

    monkeypatch.setattr(RolloutCheckpoint, "_on_step", pressed)
    handler = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        train(short_args(tmp_path, timesteps=3 * 4800, checkpoint_every=10**9))
    err = capsys.readouterr().err
    assert "Ctrl-C; finishing this rollout" in err and "interrupted; saved" in err and "model_9600_steps.zip" in err
    # The rollout under way and its update finish; the checkpoint is taken where the next rollout starts.
    checkpoint = latest_checkpoint(tmp_path / "run")
    assert checkpoint.name == "model_9600_steps.zip" and load_model(checkpoint).num_timesteps == 9600
    assert not (tmp_path / "run" / "model.zip").exists()
    assert signal.getsignal(signal.SIGINT) is handler, "Ctrl-C is the user's again"
    monkeypatch.undo()
    run_dir = train(short_args(tmp_path, timesteps=3 * 4800, resume=True))
    assert load_model(run_dir / "model.zip").num_timesteps == 3 * 4800


@pytest.mark.slow
def test_same_seed_same_policy(tmp_path):
    first = load_model(train(short_args(tmp_path / "a", timesteps=4800)) / "model.zip")
    second = load_model(train(short_args(tmp_path / "b", timesteps=4800)) / "model.zip")
    for a, b in zip(first.policy.parameters(), second.policy.parameters(), strict=True):
        assert np.array_equal(a.detach().numpy(), b.detach().numpy())


def test_resume_without_checkpoint_and_bad_arguments_are_refused(tmp_path):
    with pytest.raises(
        ValueError, match=r"^resume: no checkpoint in .*run/checkpoints \(expected model_<timesteps>_steps.zip\)"
    ):
        train(short_args(tmp_path, resume=True))
    with pytest.raises(ValueError, match="algo: expected one of"):
        train(short_args(tmp_path, algo="dqn"))
    with pytest.raises(ValueError, match=r"algo: .* no 'a2c' entry"):
        load_hyperparams(TrainArgs().hyperparams, "paper_fig1", "a2c")


def test_the_reference_is_not_what_the_model_learns_from(tmp_path):
    """The learned policy sees the same observation layout as the reference (a fair comparison)."""
    config = make_config("paper_fig1", obs_slots=4)
    assert ReferencePolicy(config).layout.size == LearnedPolicy(load_model_pretrained(), config).obs_size


def load_model_pretrained():
    from fxc_env.policies.learned import pretrained_path

    return load_model(pretrained_path())


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"n_envs": 0}, "n_envs: expected an integer >= 1"),
        ({"torch_threads": 0}, "torch_threads: expected an integer >= 1"),
        ({"checkpoint_every": -1}, "checkpoint_every: expected an integer >= 1"),
        ({"timesteps": 0}, "timesteps: expected an integer >= 1"),
        ({"seed": -1}, "seed: expected an integer"),
        ({"num_env_runners": -1}, "num_env_runners: expected an integer >= 0"),
        ({"envs_per_runner": 0}, "envs_per_runner: expected an integer >= 1"),
        ({"algo": "dqn"}, "algo: expected one of"),
        ({"hyperparams": "missing.yml"}, "hyperparams: expected a YAML file"),
        ({"scenario": "paper_fig9"}, "scenario 'paper_fig9'"),
    ],
)
def test_every_argument_is_checked_before_work_starts(tmp_path, change, message):
    args = short_args(tmp_path, **change)
    with pytest.raises(ArgumentError, match=f"^{message}"):
        check_train_args(args)
    with pytest.raises(ArgumentError, match=f"^{message}"):
        train(args)  # the back end checks first too
    assert not (tmp_path / "run").exists()


def test_command_line_checks_name_the_flags(tmp_path):
    with pytest.raises(ArgumentError, match=r"^--n-envs: "):
        check_train_args(short_args(tmp_path, n_envs=0), flags=True)
    with pytest.raises(ArgumentError, match=r"^--num-env-runners: "):
        check_train_args(short_args(tmp_path, backend="rllib", num_env_runners=-1), flags=True)


def test_hyperparameter_files_are_read_with_care(tmp_path):
    path = tmp_path / "h.yml"
    for text, message in [
        ("a: [unclosed\n", "not valid YAML"),
        ("- ppo\n", "expected a YAML mapping"),
        ("other: {ppo: {}}\n", "has neither 'paper_fig1' nor 'default'"),
        ("default: {ppo: 3}\n", "'ppo' of 'paper_fig1'.* is not a mapping"),
        ("default: [ppo]\n", "is not a mapping"),
    ]:
        path.write_text(text)
        with pytest.raises(ArgumentError, match=message):
            load_hyperparams(path, "paper_fig1", "ppo")
    assert load_hyperparams(TrainArgs().hyperparams, "paper_fig1", "ppo")["algo"]["n_steps"] == 200


def test_resume_from_a_garbage_sb3_checkpoint_is_a_usage_error_naming_it(tmp_path):
    checkpoint = tmp_path / "run" / "checkpoints" / "model_1_steps.zip"
    checkpoint.parent.mkdir(parents=True)
    checkpoint.write_bytes(b"PK not really a zip\n" * 8)
    (checkpoint.parent / "model_vecnormalize_1_steps.pkl").write_bytes(b"not a pickle")
    with pytest.raises(ArgumentError, match=r"^resume: cannot read the checkpoint '.*model_(vecnormalize_)?1_steps"):
        train(short_args(tmp_path, resume=True))
