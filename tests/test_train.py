"""fxc_env.training.train: a short real PPO run, checkpoints, resume, Ctrl-C, reproducibility."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fxc_env import ReferencePolicy, make_config
from fxc_env.engine import ConsensusEngine
from fxc_env.learned import LearnedPolicy, load_model
from fxc_env.training import TrainArgs, train
from fxc_env.training.args import load_hyperparams
from fxc_env.training.checkpoints import RolloutCheckpoint, latest_checkpoint

# 4 episodes x 6 agents = 24 sub-environments; one PPO rollout is 200 x 24 = 4800 timesteps.
SHORT = {"scenario": "paper_fig1", "n_envs": 4, "progress_bar": False}


def short_args(tmp_path, **changes) -> TrainArgs:
    return TrainArgs(
        **{**SHORT, "run_dir": str(tmp_path / "run"), "timesteps": 9600, "checkpoint_every": 4800, **changes}
    )


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


def test_resume_continues_from_the_newest_checkpoint_with_its_step_count_and_optimiser(tmp_path, capsys):
    train(short_args(tmp_path, timesteps=4800))
    checkpoint = latest_checkpoint(tmp_path / "run")
    assert checkpoint.name == "model_4800_steps.zip"
    saved = load_model(checkpoint)
    run_dir = train(short_args(tmp_path, resume=True))
    out = capsys.readouterr().out
    assert "resuming" in out and "from model_4800_steps.zip at 4800 timesteps" in out
    resumed = load_model(run_dir / "model.zip")
    assert resumed.num_timesteps == 9600
    # The checkpoint follows the first update, and Adam's step counter goes on from it.
    step_saved = max(s["step"].item() for s in saved.policy.optimizer.state_dict()["state"].values())
    step_resumed = max(s["step"].item() for s in resumed.policy.optimizer.state_dict()["state"].values())
    assert step_saved > 0 and step_resumed == 2 * step_saved


def test_ctrl_c_saves_a_checkpoint_at_the_current_step_and_resume_finishes(tmp_path, monkeypatch):
    calls = []

    def interrupt(self):  # the user presses Ctrl-C at the start of the second rollout
        calls.append(self.model.num_timesteps)
        if len(calls) == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(RolloutCheckpoint, "_on_rollout_start", interrupt)
    with pytest.raises(KeyboardInterrupt):
        train(short_args(tmp_path))
    checkpoint = latest_checkpoint(tmp_path / "run")
    interrupted_at = load_model(checkpoint).num_timesteps
    assert checkpoint.name == f"model_{interrupted_at}_steps.zip" and 0 < interrupted_at < 9600
    monkeypatch.undo()
    run_dir = train(short_args(tmp_path, resume=True))
    assert load_model(run_dir / "model.zip").num_timesteps == 9600


def test_same_seed_same_policy(tmp_path):
    first = load_model(train(short_args(tmp_path / "a", timesteps=4800)) / "model.zip")
    second = load_model(train(short_args(tmp_path / "b", timesteps=4800)) / "model.zip")
    for a, b in zip(first.policy.parameters(), second.policy.parameters(), strict=True):
        assert np.array_equal(a.detach().numpy(), b.detach().numpy())


def test_resume_without_checkpoint_and_bad_arguments_are_refused(tmp_path):
    with pytest.raises(ValueError, match="resume: no checkpoint"):
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
    from fxc_env.learned import pretrained_path

    return load_model(pretrained_path())
