"""``fxc train --resume`` runs no code from a run directory without ``--trust-policy-file`` (fxc_env.training.run_dir).

A crafted run directory (a checkpoint whose pickled entries would create a file, a crafted
VecNormalize ``.pkl``, a crafted ``config.json``) creates no file on any back end; one's own
run resumes without the flag. Budgets are a few hundred timesteps.
"""

from __future__ import annotations

import base64
import json
import pickle
import shutil
import sys
import zipfile

import pytest
import torch
import yaml

from fxc_env.cli.main import main
from fxc_env.core.validation import ArgumentError
from fxc_env.training import TrainArgs, train
from fxc_env.training.args import HYPERPARAMS
from fxc_env.training.run_dir import RunDir


class CreatesFile:
    """Unpickled, it opens (and so creates) ``path``: what a crafted file's code could do."""

    def __init__(self, path) -> None:
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


def tiny_hyperparams(tmp_path) -> str:
    """paper_fig1's entry with 120-timestep PPO rollouts (1 episode x 6 agents x 20 steps), VecNormalize on."""
    entry = yaml.safe_load(HYPERPARAMS.read_text())["paper_fig1"]
    entry["normalize"] = True
    entry["ppo"] = {**entry["ppo"], "n_steps": 20, "batch_size": 60, "n_epochs": 1}
    entry["torch_ppo"] = {**entry["torch_ppo"], "rollout_steps": 20, "minibatch_size": 60, "epochs": 1}
    entry["diff_apg"] = {**entry["diff_apg"], "n_envs": 1}  # one episode of K = 200: 1,200 timesteps a batch
    path = tmp_path / "tiny.yml"
    path.write_text(yaml.safe_dump({"paper_fig1": entry}))
    return str(path)


def tiny_args(tmp_path, run_dir, **changes) -> TrainArgs:
    return TrainArgs(
        **{
            "scenario": "paper_fig1",
            "n_envs": 1,
            "timesteps": 120,
            "checkpoint_every": 120,
            "progress_bar": False,
            "hyperparams": tiny_hyperparams(tmp_path),
            "run_dir": str(run_dir),
            **changes,
        }
    )


def rewrite_zip(path, **members) -> None:
    """Replace (or, with None, drop) members of the zip at ``path``."""
    with zipfile.ZipFile(path) as archive:
        kept = {name: archive.read(name) for name in archive.namelist()}
    for name, content in members.items():
        kept.pop(name, None)
        if content is not None:
            kept[name] = content
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in kept.items():
            archive.writestr(name, content)


def test_sb3_resume_reads_a_run_directory_without_running_its_code(tmp_path, capsys):
    own = tmp_path / "own"
    train(tiny_args(tmp_path, own))
    checkpoint = RunDir(own, "sb3").newest_checkpoint()
    assert checkpoint.name == "model_120_steps.zip"
    assert checkpoint.with_name("model_vecnormalize_120_steps.json").is_file()

    # One's own run resumes without the flag: step count and statistics go on.
    train(tiny_args(tmp_path, own, timesteps=240, resume=True))
    assert "from model_120_steps.zip at 120 timesteps" in capsys.readouterr().out
    assert RunDir(own, "sb3").newest_checkpoint().name == "model_240_steps.zip"
    before = json.loads(checkpoint.with_name("model_vecnormalize_120_steps.json").read_text())["obs_rms"]["count"]
    after = json.loads((own / "checkpoints/model_vecnormalize_240_steps.json").read_text())["obs_rms"]["count"]
    assert after > before > 0

    marker = tmp_path / "ran-code"
    crafted = {
        ":type:": "<class 'abc.ABCMeta'>",
        ":serialized:": base64.b64encode(pickle.dumps(CreatesFile(marker))).decode(),
    }

    # A crafted config.json (a policy class to import, nesting too deep to parse) is read as data only.
    run = tmp_path / "config"
    shutil.copytree(own, run)
    record = json.loads((run / "config.json").read_text())
    record["hyperparams"]["algo"]["policy"] = "crafted_module.Policy"
    (run / "config.json").write_text(json.dumps(record))
    (tmp_path / "crafted_module.py").write_text(f"open({str(marker)!r}, 'w')\nPolicy = None\n")
    sys.path.insert(0, str(tmp_path))
    try:
        train(tiny_args(tmp_path, run, timesteps=360, resume=True))
        (run / "config.json").write_text("[" * 100_000)
        train(tiny_args(tmp_path, run, timesteps=480, resume=True))
    finally:
        sys.path.remove(str(tmp_path))
    assert not marker.exists()

    # A checkpoint whose pickled data would create a file: refused naming the flag, nothing run.
    run = tmp_path / "checkpoint"
    shutil.copytree(own, run)
    newest = run / "checkpoints/model_240_steps.zip"
    data = json.loads(zipfile.ZipFile(newest).read("data"))
    data["policy_class"] = crafted
    rewrite_zip(newest, data=json.dumps(data), **{"fxc_policy.json": None})
    argv = ["train", "--run-dir", str(run), "--resume", "--timesteps", "360", "--n-envs", "1", "--no-progress-bar"]
    assert main([*argv, "--hyperparams", tiny_hyperparams(tmp_path)]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "resume: cannot read the checkpoint" in error and "--trust-policy-file" in error
    assert not marker.exists()

    # VecNormalize statistics only as a crafted pickle: refused naming the flag, nothing run.
    run = tmp_path / "vecnormalize"
    shutil.copytree(own, run)
    (run / "checkpoints/model_vecnormalize_240_steps.json").unlink()
    (run / "checkpoints/model_vecnormalize_240_steps.pkl").write_bytes(pickle.dumps(CreatesFile(marker)))
    with pytest.raises(ArgumentError, match=r"^resume: the VecNormalize statistics .* a pickle .*--trust-policy-file"):
        train(tiny_args(tmp_path, run, timesteps=360, resume=True))
    assert not marker.exists()

    # With the flag the user vouches for the files: SB3's own loader reads them (and runs the pickle).
    with pytest.raises((ArgumentError, AttributeError)):  # the "statistics" are the file object it opened
        train(tiny_args(tmp_path, run, timesteps=360, resume=True, trust_policy_file=True))
    assert marker.exists()


def test_torch_resume_refuses_a_pickled_checkpoint_naming_the_flag(tmp_path, capsys):
    own = tmp_path / "own"
    train(tiny_args(tmp_path, own, backend="torch"))
    train(tiny_args(tmp_path, own, backend="torch", timesteps=240, resume=True))
    assert "from model_120_steps.pt at 120 timesteps" in capsys.readouterr().out

    marker = tmp_path / "ran-code"
    checkpoint = own / "checkpoints/model_360_steps.pt"
    torch.save({"format": "crafted", "payload": CreatesFile(marker)}, checkpoint)
    with pytest.raises(ArgumentError, match=r"^resume: cannot read the checkpoint .*--trust-policy-file"):
        train(tiny_args(tmp_path, own, backend="torch", timesteps=480, resume=True))
    assert not marker.exists()


def test_diff_resume_refuses_a_pickled_checkpoint_naming_the_flag(tmp_path, capsys):
    own = tmp_path / "own"
    train(tiny_args(tmp_path, own, backend="diff", algo="apg", timesteps=1200, checkpoint_every=1200))
    train(tiny_args(tmp_path, own, backend="diff", algo="apg", timesteps=2400, checkpoint_every=1200, resume=True))
    assert "from model_1200_steps.pt at 1200 timesteps" in capsys.readouterr().out  # its own run: no flag needed

    marker = tmp_path / "ran-code"
    checkpoint = own / "checkpoints/model_3600_steps.pt"
    torch.save({"format": "crafted", "payload": CreatesFile(marker)}, checkpoint)
    with pytest.raises(ArgumentError, match=r"^resume: cannot read the checkpoint .*--trust-policy-file"):
        train(tiny_args(tmp_path, own, backend="diff", algo="apg", timesteps=4800, resume=True))
    assert not marker.exists()


def test_rllib_resume_needs_the_flag_before_anything_is_read(tmp_path):
    run = tmp_path / "run"
    checkpoint = run / "checkpoints/rllib_4000_steps"
    checkpoint.mkdir(parents=True)
    (checkpoint / "rllib_checkpoint.json").write_text("{}")
    marker = tmp_path / "ran-code"
    (checkpoint / "class_and_ctor_args.pkl").write_bytes(pickle.dumps(CreatesFile(marker)))
    args = TrainArgs(backend="rllib", run_dir=str(run), resume=True, timesteps=8000, progress_bar=False)
    with pytest.raises(ArgumentError, match=r"^resume: .*rllib_4000_steps is an RLlib checkpoint.*--trust-policy-file"):
        train(args)
    assert not marker.exists()


def test_the_trust_flag_without_resume_is_refused_by_name(tmp_path):
    with pytest.raises(ArgumentError, match=r"^trust_policy_file: only --resume reads files from a run directory"):
        train(tiny_args(tmp_path, tmp_path / "run", trust_policy_file=True))
