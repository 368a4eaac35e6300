"""fxc_env.training.run_dir: the files, checkpoints, resume and Ctrl-C that every back end of ``fxc train`` shares."""

from __future__ import annotations

import csv
import json
import signal

import pytest

from fxc_env.core.validation import ArgumentError
from fxc_env.training import TrainArgs, registry
from fxc_env.training.run_dir import CHECKPOINT_NAMES, RunDir, versions, write_training_curve

COLUMNS = ("time/iterations", "time/total_timesteps", "rollout/ep_rew_mean", "train/loss")


def rows(run: RunDir) -> list[dict[str, str]]:
    with (run.path / "progress.csv").open(newline="") as handle:
        return list(csv.DictReader(handle))


def row(iteration: int, reward: float | None = 1.0) -> dict:
    return {
        "time/iterations": iteration,
        "time/total_timesteps": 100 * iteration,
        "rollout/ep_rew_mean": reward,
        "train/loss": 0.5,
    }


def test_a_run_directory_is_named_by_its_arguments(tmp_path):
    assert RunDir.of(TrainArgs(run_dir=str(tmp_path / "x"))).path == tmp_path / "x"
    assert str(RunDir.of(TrainArgs(backend="rllib", seed=2)).path) == "runs/paper_fig1-rllib-ppo-seed2"
    old = RunDir(tmp_path, "torchrl")
    assert old.backend == "torch" and old.checkpoint_path(2400) == tmp_path / "checkpoints" / "model_2400_steps.pt"
    assert RunDir(tmp_path, "sb3").checkpoint_path(4800).name == "model_4800_steps.zip"
    assert RunDir(tmp_path, "rllib").checkpoint_path(19200).name == "rllib_19200_steps"
    assert set(CHECKPOINT_NAMES) == set(registry.BACKENDS)  # every registered back end names its checkpoints


@pytest.mark.parametrize("backend", ["sb3", "torch"])
def test_the_newest_checkpoint_is_the_one_with_the_most_steps(tmp_path, backend):
    run = RunDir(tmp_path, backend)
    assert run.newest_checkpoint() is None
    run.checkpoints.mkdir()
    for steps in (9600, 10000, 800):  # 10000 sorts before 9600 as text
        run.checkpoint_path(steps).write_bytes(b"")
    (run.checkpoints / "model_20000_steps.pt.partial").write_bytes(b"")  # a torch save cut short
    (run.checkpoints / "model_vecnormalize_20000_steps.pkl").write_bytes(b"")  # SB3's statistics
    (run.checkpoints / "model_x_steps.zip").write_bytes(b"")
    assert run.newest_checkpoint() == run.checkpoint_path(10000)
    assert run.checkpoint_steps(run.checkpoint_path(10000)) == 10000
    assert run.checkpoint_steps(tmp_path / "notes.txt") is None
    other = "torch" if backend == "sb3" else "sb3"
    assert RunDir(tmp_path, other).newest_checkpoint() is None, "another back end's checkpoints are not resumed"


def test_an_rllib_checkpoint_counts_once_it_is_whole(tmp_path):
    run = RunDir(tmp_path, "rllib")
    for steps in (2400, 4800):
        run.checkpoint_path(steps).mkdir(parents=True)
    (run.checkpoint_path(2400) / "rllib_checkpoint.json").write_text("{}")
    assert run.newest_checkpoint() == run.checkpoint_path(2400)  # 4800 is still being written


def test_resume_needs_a_checkpoint_and_says_which_names_it_looked_for(tmp_path):
    run = RunDir(tmp_path / "run", "torch")
    assert run.resume_checkpoint(False) is None
    message = r"^resume: no checkpoint in .*run/checkpoints \(expected model_<timesteps>_steps.pt\)$"
    with pytest.raises(ArgumentError, match=message):
        run.resume_checkpoint(True)
    assert not (tmp_path / "run").exists()
    run.checkpoints.mkdir(parents=True)
    run.checkpoint_path(5).write_bytes(b"")
    assert run.resume_checkpoint(True) == run.checkpoint_path(5)


def test_a_fresh_run_writes_its_config_and_versions(tmp_path, capsys):
    run = RunDir(tmp_path / "a" / "run", "sb3")
    run.start({"args": {"seed": 3}, "n_agents": 6})
    assert json.loads((run.path / "config.json").read_text()) == {"args": {"seed": 3}, "n_agents": 6}
    recorded = json.loads((run.path / "versions.json").read_text())
    assert recorded == versions()
    assert {"python", "numpy", "torch", "stable-baselines3", "ray"} <= set(recorded)
    run.announce_resume(run.checkpoint_path(4800), "4800 timesteps")
    assert capsys.readouterr().out == f"fxc train: resuming {run.path} from model_4800_steps.zip at 4800 timesteps\n"


def test_progress_rows_have_fixed_columns_and_tensorboard_gets_the_same_scalars(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    run = RunDir(tmp_path, "torch")
    with run.progress(COLUMNS, tensorboard=True) as progress:
        progress.write(row(1, reward=None))  # no episode ended in this rollout
        progress.write(row(2, reward=2.5))
    assert rows(run) == [
        {"time/iterations": "1", "time/total_timesteps": "100", "rollout/ep_rew_mean": "", "train/loss": "0.5"},
        {"time/iterations": "2", "time/total_timesteps": "200", "rollout/ep_rew_mean": "2.5", "train/loss": "0.5"},
    ]
    events = EventAccumulator(str(tmp_path))
    events.Reload()
    assert [(e.step, e.value) for e in events.Scalars("rollout/ep_rew_mean")] == [(200, 2.5)]
    assert [e.step for e in events.Scalars("train/loss")] == [100, 200]


def test_a_resumed_log_drops_the_rows_after_the_checkpoint(tmp_path):
    run = RunDir(tmp_path, "rllib")
    with run.progress(COLUMNS, tensorboard=False) as progress:
        for iteration in (1, 2, 3):  # the run went on to iteration 3 after its checkpoint at 2, then died
            progress.write(row(iteration))
    assert not list(tmp_path.glob("events.out.tfevents.*"))
    with run.progress(COLUMNS, tensorboard=False, resumed_at=(2, 200)) as progress:
        assert [r["time/iterations"] for r in rows(run)] == ["1", "2"]
        progress.write(row(3, reward=9.0))
    assert [(r["time/iterations"], r["rollout/ep_rew_mean"]) for r in rows(run)] == [
        ("1", "1.0"),
        ("2", "1.0"),
        ("3", "9.0"),
    ]
    (run.path / "progress.csv").unlink()
    with run.progress(COLUMNS, tensorboard=False, resumed_at=(2, 200)):
        pass
    assert (run.path / "progress.csv").read_text() == ",".join(COLUMNS) + "\n", (
        "a lost log starts again with its header"
    )


def test_ctrl_c_finishes_the_unit_then_saves_and_stops(tmp_path, capsys):
    run = RunDir(tmp_path, "torch")
    saved, done = [], []
    handler = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        with run.interruptible("rollout", lambda: saved.append(1) or run.checkpoint_path(7)) as pressed:
            for unit in range(5):
                if pressed:
                    break
                if unit == 1:
                    signal.raise_signal(signal.SIGINT)  # during the second unit
                done.append(unit)
    assert done == [0, 1] and saved == [1]
    err = capsys.readouterr().err
    assert "fxc train: Ctrl-C; finishing this rollout, then saving a checkpoint" in err
    assert f"fxc train: interrupted; saved {run.checkpoint_path(7)} (resume with --resume)" in err
    assert signal.getsignal(signal.SIGINT) is handler


def test_a_second_ctrl_c_stops_at_once_without_a_checkpoint(tmp_path):
    run = RunDir(tmp_path, "torch")
    saved = []
    with pytest.raises(KeyboardInterrupt):
        with run.interruptible("rollout", lambda: saved.append(1)):
            signal.raise_signal(signal.SIGINT)
            signal.raise_signal(signal.SIGINT)  # the unit is half done: nothing to save
            pytest.fail("the second Ctrl-C did not stop the unit")
    assert saved == []


def test_without_ctrl_c_nothing_is_saved_and_errors_pass_through(tmp_path):
    run = RunDir(tmp_path, "sb3")
    saved = []
    with run.interruptible("rollout", lambda: saved.append(1)) as pressed:
        assert not pressed
    with pytest.raises(ZeroDivisionError):
        with run.interruptible("rollout", lambda: saved.append(1)):
            1 / 0  # noqa: B018
    assert saved == []


def test_the_training_curve_is_drawn_from_the_rows_with_a_return(tmp_path, capsys):
    run = RunDir(tmp_path, "torch")
    with run.progress(COLUMNS, tensorboard=False) as progress:
        progress.write(row(1, reward=None))
    assert write_training_curve(tmp_path) is None, "no episode ended: no curve"
    with run.progress(COLUMNS, tensorboard=False, resumed_at=(1, 100)) as progress:
        for iteration in range(2, 14):
            progress.write(row(iteration, reward=float(iteration)))
    assert run.finish(1300, tmp_path / "policy.pt") == tmp_path / "training_curve.png"
    assert (tmp_path / "training_curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (
        capsys.readouterr().out
        == f"fxc train: 1300 timesteps; wrote {tmp_path / 'policy.pt'} and {tmp_path / 'training_curve.png'}\n"
    )


def test_a_resumed_sb3_log_keeps_the_rows_up_to_the_checkpoint_and_grows_its_columns(tmp_path):
    run = RunDir(tmp_path, "sb3")
    (tmp_path / "progress.csv").write_text(
        "time/total_timesteps,rollout/ep_rew_mean\n4800,1.5\n9600,2.5\n14400,3.5\n"  # 14400: after the checkpoint
    )
    logger = run.sb3_logger(resumed_at=9600)
    logger.record("time/total_timesteps", 14400)
    logger.record("rollout/ep_rew_mean", 4.0)
    logger.record("train/approx_kl", 0.01)  # a column the earlier rows did not have
    logger.dump(14400)
    logger.close()
    with (tmp_path / "progress.csv").open(newline="") as handle:
        logged = list(csv.DictReader(handle))
    assert [(r["time/total_timesteps"], r["rollout/ep_rew_mean"], r["train/approx_kl"]) for r in logged] == [
        ("4800", "1.5", ""),
        ("9600", "2.5", ""),
        ("14400", "4.0", "0.01"),
    ]
    assert list(tmp_path.glob("events.out.tfevents.*")), "TensorBoard events beside it"
    fresh = RunDir(tmp_path / "fresh", "sb3").sb3_logger()
    fresh.record("time/total_timesteps", 4800)
    fresh.dump(4800)
    fresh.close()
    assert (tmp_path / "fresh" / "progress.csv").read_text() == "time/total_timesteps\n4800\n"


def started_run(tmp_path, steps: int, **args) -> RunDir:
    """A torch run directory as a run of ``args`` leaves it, with one (empty) checkpoint at ``steps``."""
    run = RunDir(tmp_path / "run", "torch")
    run.start({"args": {"scenario": "paper_fig1", "critic": "local", **args}})
    run.checkpoints.mkdir()
    run.checkpoint_path(steps).write_bytes(b"")
    return run


def test_resume_keeps_the_scenario_and_critic_the_run_was_started_with(tmp_path):
    run = started_run(tmp_path, 100)
    assert run.resume_checkpoint(True, TrainArgs(timesteps=200)) == run.checkpoint_path(100)
    with pytest.raises(ArgumentError, match=r"^scenario: .*started with scenario 'paper_fig1'.*not 'ring'"):
        run.resume_checkpoint(True, TrainArgs(scenario="ring", timesteps=200))
    with pytest.raises(ArgumentError, match=r"^critic: .*started with critic 'local'.*not 'central'"):
        run.resume_checkpoint(True, TrainArgs(critic="central", timesteps=200))


def test_resume_to_a_target_already_reached_is_refused(tmp_path):
    run = started_run(tmp_path, 100)
    for timesteps in (50, 100):
        with pytest.raises(ArgumentError, match=r"^timesteps: .* already at 100 timesteps .*nothing to train"):
            run.resume_checkpoint(True, TrainArgs(timesteps=timesteps))


def test_a_run_directory_that_cannot_be_created_is_a_usage_error_naming_it(tmp_path):
    (tmp_path / "notes.txt").write_text("a file\n")
    run = RunDir(tmp_path / "notes.txt" / "run", "torch")
    with pytest.raises(ArgumentError, match=r"^run_dir: cannot create '.*notes.txt/run'"):
        run.start({"args": {}})
