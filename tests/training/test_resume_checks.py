"""``fxc train --resume`` refuses a damaged checkpoint, or another back end's, by name (fxc_env.training.backends.checkpoint_checks).

Each case damages a copy of a real run's checkpoint (sb3 and torch: 120 timesteps, diff: 1,200), then
resumes it through the command line: exit 2, one line naming the file and the field, and the run
directory exactly as it was.
"""

from __future__ import annotations

import io
import json
import re
import shutil
import zipfile
from pathlib import Path

import pytest
import torch
import yaml
from test_run_dir_trust import rewrite_zip, tiny_args, tiny_hyperparams

from fxc_env.cli.main import main
from fxc_env.training import train

#: A real run per back end and a resume per case: about 25 s on one core, so left out of `make check`.
pytestmark = pytest.mark.slow

#: Each back end's run: its TrainArgs changes and the timesteps of its checkpoint.
BACKENDS = {
    "sb3": ({}, 120),
    "torch": ({}, 120),
    "diff": ({"algo": "apg", "timesteps": 1200, "checkpoint_every": 1200}, 1200),
}
CHECKPOINTS = {"sb3": "model_{}_steps.zip", "torch": "model_{}_steps.pt", "diff": "model_{}_steps.pt"}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """One real (seconds-long) run per back end, in a folder the tests copy from."""
    base = tmp_path_factory.mktemp("runs")
    for backend, (changes, _) in BACKENDS.items():
        train(tiny_args(base, base / backend, backend=backend, **changes))
    return base


def copy_run(runs, tmp_path, backend):
    """A copy of ``backend``'s run and the path of its checkpoint."""
    run = shutil.copytree(runs / backend, tmp_path / "run")
    return run, run / "checkpoints" / CHECKPOINTS[backend].format(BACKENDS[backend][1])


def files(run) -> dict:
    return {path.relative_to(run): path.read_bytes() for path in sorted(run.rglob("*")) if path.is_file()}


def refused(capsys, tmp_path, run, backend, timesteps) -> str:
    """Resume ``run`` with ``--backend backend`` to ``timesteps``: the one-line error, without its prefix."""
    before = files(run)
    algo = ["--algo", "apg"] if backend == "diff" else []
    argv = ["train", "--backend", backend, *algo, "--run-dir", str(run), "--resume", "--n-envs", "1"]
    argv += ["--timesteps", str(timesteps), "--no-progress-bar"]
    capsys.readouterr()
    assert main([*argv, "--hyperparams", tiny_hyperparams(tmp_path)]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("fxc train: error: "), error
    assert files(run) == before, "a refused resume leaves the run directory as it was"
    return error.removeprefix("fxc train: error: ").strip()


def edit_pt(checkpoint, change) -> None:
    record = torch.load(checkpoint, weights_only=True)
    change(record)
    torch.save(record, checkpoint)


def edit_zip_member(checkpoint, member, change) -> None:
    """Change the state dict ``member`` (``policy.pth``, ``policy.optimizer.pth``) of an SB3 zip."""
    state = torch.load(io.BytesIO(zipfile.ZipFile(checkpoint).read(member)), weights_only=True)
    change(state)
    buffer = io.BytesIO()
    torch.save(state, buffer)
    rewrite_zip(checkpoint, **{member: buffer.getvalue()})


def edit_zip_data(checkpoint, **entries) -> None:
    data = json.loads(zipfile.ZipFile(checkpoint).read("data"))
    rewrite_zip(checkpoint, data=json.dumps({**data, **entries}))


def set_group(record, **settings) -> None:
    record["optimizer"]["param_groups"][0].update(settings)


def fill(state, key, value) -> None:
    state[key] = torch.full_like(state[key], value)


def first_moment(state, value) -> None:
    fill(state["state"][0], "exp_avg", value)


LOG_STD = "weight 'log_std': expected finite numbers, got inf"
NON_FINITE = [
    ("torch", "lr nan", lambda c: edit_pt(c, lambda r: set_group(r, lr=float("nan"))), "optimizer lr: .* got nan"),
    ("torch", "log_std inf", lambda c: edit_pt(c, lambda r: fill(r["model"], "log_std", float("inf"))), LOG_STD),
    ("torch", "betas", lambda c: edit_pt(c, lambda r: set_group(r, betas=(0.9, 1.5))), "optimizer betas: "),
    ("diff", "lr nan", lambda c: edit_pt(c, lambda r: set_group(r, lr=float("nan"))), "optimizer lr: .* got nan"),
    ("diff", "log_std inf", lambda c: edit_pt(c, lambda r: fill(r["model"], "log_std", float("inf"))), LOG_STD),
    (
        "sb3",
        "weight nan",
        lambda c: edit_zip_member(c, "policy.pth", lambda s: fill(s, "value_net.weight", float("nan"))),
        "value_net.weight: every entry must be finite",  # refused as the policy file is read
    ),
    (
        "sb3",
        "Adam moment nan",
        lambda c: edit_zip_member(c, "policy.optimizer.pth", lambda s: first_moment(s, float("nan"))),
        "policy.optimizer state 'exp_avg' of weight 0: expected finite numbers",
    ),
]


@pytest.mark.parametrize(
    ("backend", "label", "damage", "message"), NON_FINITE, ids=[f"{c[0]}-{c[1]}" for c in NON_FINITE]
)
def test_non_finite_weights_or_optimiser_settings_are_refused_naming_file_and_field(
    runs, tmp_path, capsys, backend, label, damage, message
):
    run, checkpoint = copy_run(runs, tmp_path, backend)
    damage(checkpoint)
    error = refused(capsys, tmp_path, run, backend, 2 * BACKENDS[backend][1])
    assert re.fullmatch(f"resume: .*{re.escape(str(checkpoint))}.*{message}.*", error), error


COUNTERS = [  # back end, counter, damaged value, the refusal after the file's name
    ("torch", "timesteps", -(10**12), r"timesteps: expected an integer in \[0, 240\], got -10{12}"),
    ("torch", "timesteps", 10**18, r"timesteps: expected an integer in \[0, 240\], got 10{18}"),
    ("torch", "timesteps", 240, r"timesteps is 240, expected 120 \(the timesteps in the file's name\)"),
    ("torch", "iterations", -1, r"iterations: expected an integer in \[0, .*\], got -1"),
    ("diff", "timesteps", 10**18, r"timesteps: expected an integer in \[0, 2400\], got 10{18}"),
    # an SB3 zip's counter is refused already as the policy file is read (fxc_env/policies/records.py)
    ("sb3", "num_timesteps", -1e9, r"num_timesteps: expected an integer .*, got -1(0{9}|e\+09)(\.0)?\)?"),
    ("sb3", "num_timesteps", 1e18, r"num_timesteps: expected an integer .*, got 1(0{18}|e\+18)(\.0)?\)?"),
]


@pytest.mark.parametrize(
    ("backend", "counter", "value", "message"), COUNTERS, ids=[f"{c[0]}-{c[1]}={c[2]:g}" for c in COUNTERS]
)
def test_step_counters_outside_the_runs_target_are_refused_naming_file_and_field(
    runs, tmp_path, capsys, backend, counter, value, message
):
    run, checkpoint = copy_run(runs, tmp_path, backend)
    if backend == "sb3":
        edit_zip_data(checkpoint, **{counter: value})
    else:
        edit_pt(checkpoint, lambda record: record.update({counter: value}))
    error = refused(capsys, tmp_path, run, backend, 2 * BACKENDS[backend][1])
    assert re.fullmatch(f"resume: .*{re.escape(str(checkpoint))}:? {message}", error), error


@pytest.mark.parametrize(("wrote", "resumed"), [("diff", "torch"), ("torch", "diff")])
def test_a_torch_run_refuses_a_diff_checkpoint_and_the_reverse(runs, tmp_path, capsys, wrote, resumed):
    run, checkpoint = copy_run(runs, tmp_path, wrote)  # torch and diff checkpoints share their name
    timesteps = 2 * BACKENDS[wrote][1]
    error = refused(capsys, tmp_path, run, resumed, timesteps)
    assert error.startswith(f"backend: the run in {run} was started with backend '{wrote}' (config.json)"), error
    (run / "config.json").unlink()  # without the run's record, the checkpoint's own record of its back end
    error = refused(capsys, tmp_path, run, resumed, timesteps)
    assert error.startswith(f"resume: {checkpoint}: backend is '{wrote}', this run is --backend {resumed}"), error


def test_a_resumed_torch_run_steps_with_its_own_hyperparameters_learning_rate(runs, tmp_path):
    run, checkpoint = copy_run(runs, tmp_path, "torch")
    assert torch.load(checkpoint, weights_only=True)["optimizer"]["param_groups"][0]["lr"] != 1.25e-4
    changed = yaml.safe_load(Path(tiny_hyperparams(tmp_path)).read_text())
    changed["paper_fig1"]["torch_ppo"]["learning_rate"] = 1.25e-4
    hyperparams = tmp_path / "changed.yml"
    hyperparams.write_text(yaml.safe_dump(changed))
    train(tiny_args(tmp_path, run, backend="torch", timesteps=240, resume=True, hyperparams=str(hyperparams)))
    resumed = torch.load(run / "checkpoints/model_240_steps.pt", weights_only=True)
    assert resumed["optimizer"]["param_groups"][0]["lr"] == 1.25e-4, "the rate progress.csv logs is the one used"
