"""``fxc train --backend rllib --task rings20-v2``: RLlib PPO on the named task's environment, recorded in its run."""

from __future__ import annotations

import json

import pytest
import yaml

from fxc_env.cli.main import main
from fxc_env.config.tasks import TASKS
from fxc_env.training.args import HYPERPARAMS


@pytest.mark.slow
def test_rllib_trains_on_the_task(tmp_path, local_ray):
    table = yaml.safe_load(HYPERPARAMS.read_text())
    entry = table["rings20-v2"]
    entry["rllib_ppo"].update(train_batch_size_per_learner=50, minibatch_size=50, num_epochs=1)
    hyperparams = tmp_path / "hyperparams.yml"
    hyperparams.write_text(yaml.safe_dump({"rings20-v2": entry}))
    run_dir = tmp_path / "run"
    argv = ["train", "--backend", "rllib", "--task", "rings20-v2", "--run-dir", str(run_dir),
            "--hyperparams", str(hyperparams), "--timesteps", "1000", "--num-env-runners", "0"]  # fmt: skip
    assert main(argv) == 0
    record = json.loads((run_dir / "config.json").read_text())
    assert record["args"]["task"] == "rings20-v2"
    env = {key: value for key, value in record["hyperparams"]["env"].items() if key != "n_envs"}
    assert env == {"scenario": None, **TASKS["rings20-v2"].settings, "initial_state": "random"}
