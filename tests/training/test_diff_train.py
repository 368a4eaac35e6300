"""fxc_env.training.backends.diff_train (``fxc train --backend diff``) and ``fxc train --init-from``: seconds-long runs."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch
import yaml

from fxc_env.config import make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.learned import load_learned_policy
from fxc_env.policies.torch_policy import TorchPolicy, load_torch_policy
from fxc_env.training import TrainArgs, train
from fxc_env.training.args import check_train_args
from fxc_env.training.backends.diff_train import DiffSettings, DiffTrainer
from fxc_env.training.backends.torch_ppo import PPOSettings, Trainer, run_config

# paper_fig1 cut to K = 10: 4 episodes x 6 agents a batch, two windows of 5 steps.
ENV = {"action_mode": "plan", "obs_mode": "normalized", "initial_state": "random", "obs_slots": 4, "n_intervals": 10}
PER_BATCH = 10 * 4 * 6


def hyperparams(tmp_path, **diff_apg) -> str:
    entry = {
        "env": ENV,
        "diff_apg": {"n_envs": 4, "hidden": [16], "window": 5, **diff_apg},
        "torch_ppo": {"n_envs": 4, "rollout_steps": 10, "hidden": [16], "minibatch_size": 240},
    }
    path = tmp_path / "hyperparams.yml"
    path.write_text(yaml.safe_dump({"paper_fig1": entry}))
    return str(path)


def args(tmp_path, **changes) -> TrainArgs:
    base = {
        "scenario": "paper_fig1",
        "backend": "diff",
        "algo": "apg",
        "timesteps": 2 * PER_BATCH,
        "checkpoint_every": PER_BATCH,
        "run_dir": str(tmp_path / "run"),
        "progress_bar": False,
    }
    if "hyperparams" not in changes:
        base["hyperparams"] = hyperparams(tmp_path)
    return TrainArgs(**{**base, **changes})


def rows(run_dir) -> list[dict[str, str]]:
    with (run_dir / "progress.csv").open() as handle:
        return list(csv.DictReader(handle))


def test_fxc_train_backend_diff_writes_the_run_directory_and_a_policy_fxc_evaluate_reads(tmp_path, capsys):
    from fxc_env.cli import main

    run_dir = tmp_path / "run"
    argv = ["train", "--backend", "diff", "--hyperparams", hyperparams(tmp_path), "--run-dir", str(run_dir)]
    assert main([*argv, "--timesteps", str(2 * PER_BATCH), "--checkpoint-every", str(PER_BATCH)]) == 0
    record = json.loads((run_dir / "config.json").read_text())
    assert record["args"]["algo"] == "apg", "--backend diff alone trains its one algorithm"
    assert record["diff_apg"]["window"] == 5 and record["timesteps_per_batch"] == PER_BATCH
    table = rows(run_dir)
    assert [int(row["time/total_timesteps"]) for row in table] == [PER_BATCH, 2 * PER_BATCH]
    assert [int(row["train/n_updates"]) for row in table] == [2, 4], "K / window gradient steps a batch"
    for row in table:
        assert np.isfinite(float(row["rollout/ep_rew_mean"])) and float(row["rollout/deadline_error"]) > 0
        # The two windows' losses telescope to the batch's mean ln D(T_s)/D(0).
        assert float(row["train/loss"]) == pytest.approx(float(row["rollout/log_deadline_error"]), rel=1e-9)
    assert list(run_dir.glob("events.out.tfevents.*")) and (run_dir / "training_curve.png").is_file()
    assert sorted(p.name for p in (run_dir / "checkpoints").iterdir()) == [
        f"model_{PER_BATCH}_steps.pt",
        f"model_{2 * PER_BATCH}_steps.pt",
    ]
    policy = load_learned_policy(run_dir / "policy.pt")
    assert isinstance(policy, TorchPolicy) and policy.obs_size == 15 and policy.timesteps == 2 * PER_BATCH
    out = tmp_path / "evaluate"
    # Scored inside its training domain (paper_fig1, K = 10): the file records it.
    evaluate = ["evaluate", "--policy", str(run_dir), "--scenario", "paper_fig1", "--budgets", "10", "--seeds", "1"]
    assert main([*evaluate, "--out", str(out), "--no-progress"]) == 0
    assert "torch policy" in capsys.readouterr().out


def test_the_loss_decreases_on_a_tiny_task(tmp_path):
    """The paper's initial state every episode (K = 10): the loss is a function of the weights alone."""
    path = tmp_path / "fixed.yml"
    env = {key: value for key, value in ENV.items() if key != "initial_state"}
    setting = {"n_envs": 1, "hidden": [16], "window": None, "learning_rate": 1.0e-3}
    path.write_text(yaml.safe_dump({"paper_fig1": {"env": env, "diff_apg": setting}}))
    run_dir = train(args(tmp_path, timesteps=12 * 60, hyperparams=str(path)))
    errors = [float(row["rollout/log_deadline_error"]) for row in rows(run_dir)]
    losses = [float(row["train/loss"]) for row in rows(run_dir)]
    assert losses == pytest.approx(errors, rel=1e-9), "the loss is the mean ln D(T_s)/D(0)"
    assert len(errors) == 12 and max(errors[-4:]) < errors[0] - 0.5, errors


def test_resume_goes_on_from_the_checkpoint_as_if_never_stopped(tmp_path, capsys):
    train(args(tmp_path, timesteps=PER_BATCH))
    run_dir = train(args(tmp_path, resume=True))
    assert f"from model_{PER_BATCH}_steps.pt at {PER_BATCH} timesteps" in capsys.readouterr().out
    assert [int(row["time/iterations"]) for row in rows(run_dir)] == [1, 2]
    straight = train(args(tmp_path, run_dir=str(tmp_path / "straight")))
    resumed = torch.load(run_dir / "policy.pt", weights_only=True)["actor"]
    uninterrupted = torch.load(straight / "policy.pt", weights_only=True)["actor"]
    assert all(torch.equal(resumed[k], uninterrupted[k]) for k in resumed)


def test_ctrl_c_finishes_the_batch_saves_a_checkpoint_and_resume_finishes(tmp_path, monkeypatch):
    import signal

    episode = DiffTrainer.episode
    calls = []

    def pressed(self):  # the user presses Ctrl-C during the second batch
        calls.append(1)
        if len(calls) == 2:
            signal.raise_signal(signal.SIGINT)
        return episode(self)

    monkeypatch.setattr(DiffTrainer, "episode", pressed)
    with pytest.raises(KeyboardInterrupt):
        train(args(tmp_path, timesteps=4 * PER_BATCH, checkpoint_every=10**9))
    assert sorted(p.name for p in (tmp_path / "run/checkpoints").iterdir()) == [f"model_{2 * PER_BATCH}_steps.pt"]
    monkeypatch.undo()
    run_dir = train(args(tmp_path, timesteps=3 * PER_BATCH, resume=True))
    assert [int(row["time/total_timesteps"]) for row in rows(run_dir)] == [PER_BATCH, 2 * PER_BATCH, 3 * PER_BATCH]


def first_actions(trainer: Trainer) -> torch.Tensor:
    obs = trainer.engine.observations().to(torch.float32)
    if trainer.arch == "gru":
        hidden = trainer.model.actor.initial_state(tuple(obs.shape[:-1]), obs.device)
        return trainer.model.actor.step(obs, hidden)[0].detach()
    return trainer.model.actor(obs).detach()


@pytest.mark.parametrize(("backend", "what"), [("diff", "run"), ("torch", "run"), ("diff", "checkpoint")])
def test_init_from_a_run_starts_from_its_weights(tmp_path, backend, what):
    source = train(args(tmp_path, timesteps=PER_BATCH, run_dir=str(tmp_path / "source")))
    given = source if what == "run" else source / f"checkpoints/model_{PER_BATCH}_steps.pt"
    run_args = args(tmp_path, init_from=str(given), backend=backend, algo="apg" if backend == "diff" else "ppo")
    params = check_train_args(run_args)
    if backend == "diff":
        settings = DiffSettings.from_mapping(params["algo"], make_config(**run_config(run_args, params)))
        trainer: Trainer = DiffTrainer(run_args, params, settings, torch.device("cpu"))
    else:
        settings = PPOSettings.from_mapping(params["algo"], make_config(**run_config(run_args, params)))
        trainer = Trainer(run_args, params, settings, torch.device("cpu"))
    obs = trainer.engine.observations().to(torch.float32)
    expected = load_torch_policy(source)(obs)
    assert torch.equal(first_actions(trainer).clamp(-20, 20), expected)
    fresh = args(tmp_path, backend=backend, algo=run_args.algo)
    assert not torch.equal(first_actions(type(trainer)(fresh, params, settings, torch.device("cpu"))), expected)


def rings_args(tmp_path, **changes) -> TrainArgs:
    """The task of the shipped ``rings_gru`` (directed rings of 20, one row a agent), cut to K = 200 on 2 episodes."""
    env = {
        "n_agents": 20,
        "initial_state": "random",
        "topology": {"family": "ring"},
        "settling_time": 20.0,
        "n_intervals": 200,
        "schedule": "paper",
        "action_mode": "plan",
        "obs_mode": "normalized",
        "obs_slots": 1,
        "position_range": [0.5, 50.0],
        "velocity_range": [0.2, 20.0],
    }
    actor = {"n_envs": 2, "hidden": [64], "gru_size": 64, "gru_input": "schedule"}
    path = tmp_path / "rings.yml"
    path.write_text(yaml.safe_dump({"ring_6": {"env": env, "diff_apg": actor}}))
    base = {"scenario": "ring_6", "policy_arch": "gru", "init_from": "rings_gru", "hyperparams": str(path)}
    return args(tmp_path, **{**base, **changes})


def diff_trainer(run_args: TrainArgs) -> DiffTrainer:
    params = check_train_args(run_args)
    settings = DiffSettings.from_mapping(params["algo"], make_config(**run_config(run_args, params)))
    return DiffTrainer(run_args, params, settings, torch.device("cpu"))


def test_init_from_a_shipped_name_starts_from_the_shipped_policy(tmp_path):
    trainer = diff_trainer(rings_args(tmp_path))
    obs = trainer.engine.observations().to(torch.float32)
    shipped = load_learned_policy("rings_gru")
    assert torch.equal(first_actions(trainer).clamp(-20, 20), shipped(obs))


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"policy_arch": "mlp"}, r"^init_from: 'rings_gru' has another architecture than this run: arch 'gru' there, "),
        ({"init_from": "paper_fig1"}, r"^init_from: 'paper_fig1' is not a torch policy"),
    ],
)
def test_init_from_refuses_another_architecture_by_name(tmp_path, changes, message):
    with pytest.raises(ArgumentError, match=message):
        diff_trainer(rings_args(tmp_path, **changes))


def test_init_from_refuses_another_observation_layout_or_width_by_name(tmp_path):
    source = train(args(tmp_path, timesteps=PER_BATCH, run_dir=str(tmp_path / "source")))
    path = tmp_path / "wide.yml"
    table = yaml.safe_load(open(hyperparams(tmp_path)).read())
    table["paper_fig1"]["diff_apg"]["hidden"] = [32]
    path.write_text(yaml.safe_dump(table))
    with pytest.raises(ArgumentError, match=r"architecture than this run: hidden \[16\] there, \[32\] here"):
        diff_trainer(args(tmp_path, init_from=str(source), hyperparams=str(path)))
    table["paper_fig1"]["diff_apg"]["hidden"] = [16]
    table["paper_fig1"]["env"]["obs_slots"] = 2
    path.write_text(yaml.safe_dump(table))
    with pytest.raises(ArgumentError, match=r"observation layout than this run: obs_size 15 there, 9 here"):
        diff_trainer(args(tmp_path, init_from=str(source), hyperparams=str(path)))


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"algo": "ppo"}, r"^algo: the diff backend trains 'apg' \(analytic policy gradients\), got 'ppo'"),
        ({"backend": "sb3"}, r"^algo: 'apg' needs the engine's gradients: use --backend diff"),
        ({"critic": "central"}, r"^critic: only the torch backend has a choice of critic"),
        ({"backend": "sb3", "algo": "ppo", "init_from": "rings_gru"}, r"^init_from: only the torch and diff backends"),
        ({"init_from": "rings_gru", "resume": True}, r"^init_from: --resume goes on from the run's own checkpoint"),
    ],
)
def test_bad_arguments_are_named(tmp_path, changes, message):
    with pytest.raises(ArgumentError, match=message):
        check_train_args(args(tmp_path, **changes))


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ({"window": 3}, r"^hyperparams: diff_apg.window: expected K = 10 or a divisor of it \(or null\), got 3"),
        ({"loss": "mse"}, r"^hyperparams: diff_apg.loss: expected one of"),
        ({"epochs": 2}, r"^hyperparams: diff_apg has no setting 'epochs'"),
        ({"hidden": []}, r"^hyperparams: diff_apg.hidden: expected a list of layer widths"),
    ],
)
def test_bad_settings_are_named_before_work_starts(tmp_path, setting, message):
    with pytest.raises(ArgumentError, match=message):
        check_train_args(args(tmp_path, hyperparams=hyperparams(tmp_path, **setting)))
    assert not (tmp_path / "run").exists()


def test_seeds_train_one_diff_run_per_seed(tmp_path, monkeypatch):
    from fxc_env.cli import main

    monkeypatch.chdir(tmp_path)
    argv = ["train", "--backend", "diff", "--hyperparams", hyperparams(tmp_path), "--seeds", "0-1"]
    assert main([*argv, "--timesteps", str(PER_BATCH), "--no-progress-bar"]) == 0
    for seed in (0, 1):  # the default run directory names the back end and its algorithm
        assert load_torch_policy(tmp_path / f"runs/paper_fig1-diff-apg-seed{seed}").timesteps == PER_BATCH


@pytest.mark.parametrize("name", ["paper_fig1_k50.yml", "paper_fig1_k50_finetune.yml"])
@pytest.mark.parametrize("backend", ["diff", "torch"])
def test_the_readme_hyperparameter_files_check(tmp_path, name, backend):
    from pathlib import Path

    path = Path(__file__).parents[2] / "training" / "recipes" / name
    run_args = args(tmp_path, hyperparams=str(path), backend=backend, algo="apg" if backend == "diff" else "ppo")
    assert check_train_args(run_args)["env"]["n_intervals"] == 50


def shipped_gru_with(tmp_path, change) -> str:
    """A copy of the shipped ``rings_gru`` policy record with ``change`` applied to it; its path."""
    from fxc_env.policies.learned import pretrained_path

    record = torch.load(pretrained_path("rings_gru"), map_location="cpu", weights_only=True)
    change(record)
    path = tmp_path / "crafted.pt"
    torch.save(record, path)
    return str(path)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda r: r.pop("log_std"), r"^init_from: \S+crafted\.pt has no log_std"),
        (
            lambda r: r.update(log_std=torch.zeros(3)),
            r"^init_from: policy: \S+crafted\.pt: log_std: expected shape \(2,\)",
        ),
        (lambda r: r.update(log_std=torch.zeros(2, 1)), r"^init_from: policy: \S+crafted\.pt: log_std: expected shape"),
        (lambda r: r.update(log_std=[-3.0, -3.0]), r"^init_from: policy: \S+crafted\.pt: log_std: expected shape"),
        (
            lambda r: r.update(log_std=torch.tensor([float("nan"), -3.0])),
            r"^init_from: policy: \S+crafted\.pt: log_std: every entry must be finite",
        ),
    ],
    ids=["missing", "three entries", "a column", "a list", "NaN"],
)
def test_init_from_refuses_a_missing_misshapen_or_non_finite_log_std_by_name(tmp_path, change, message):
    """Before: a missing or misshapen log_std raised KeyError/RuntimeError tracebacks; a NaN one was copied silently."""
    with pytest.raises(ArgumentError, match=message):
        diff_trainer(rings_args(tmp_path, init_from=shipped_gru_with(tmp_path, change)))


def test_an_entry_that_leaves_a_setting_out_gets_the_diff_back_ends_default_not_ppos():
    config = make_config("paper_fig1")
    assert DiffSettings.from_mapping({}, config) == DiffSettings()  # n_envs 64, max_grad_norm 1.0
    partial = DiffSettings.from_mapping({"learning_rate": 3.0e-4}, config)
    assert (partial.n_envs, partial.max_grad_norm, partial.learning_rate) == (64, 1.0, 3.0e-4)
