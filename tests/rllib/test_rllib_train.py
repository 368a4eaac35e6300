"""fxc_env.training.backends.rllib_train: RLlib PPO on paper_fig1 with 2 env runners on a local Ray, restored and evaluated;
its checkpoints record their training settings and domain, and a policy outside that domain says so."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest
import yaml
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

from fxc_env import cli, make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.domain import OutOfDomainWarning, training_domain
from fxc_env.policies.fit import training_settings
from fxc_env.policies.learned import RLlibPolicy, load_learned_policy
from fxc_env.training import TrainArgs, train
from fxc_env.training.args import HYPERPARAMS
from fxc_env.training.backends.rllib_train import ConsensusRLlibEnv
from fxc_env.training.evaluation.evaluate import EVALUATION_CASES

#: Environment steps per iteration in these tests: two episodes of K = 200 (one per env runner).
BATCH = 400
PER_ITERATION = BATCH * 6  # agent-steps (timesteps) of paper_fig1's six agents


def small_hyperparams(path):
    """The shipped hyperparameters with a small batch, so an iteration takes about a second."""
    table = yaml.safe_load(HYPERPARAMS.read_text())
    entry = table["paper_fig1"]
    entry["rllib_ppo"].update(train_batch_size_per_learner=BATCH, minibatch_size=BATCH, num_epochs=2)
    path.write_text(yaml.safe_dump({"paper_fig1": entry}))
    return str(path)


def rllib_args(tmp_path, **changes) -> TrainArgs:
    return TrainArgs(
        **{
            "backend": "rllib",
            "scenario": "paper_fig1",
            "timesteps": 2 * PER_ITERATION,
            "num_env_runners": 2,
            "run_dir": str(tmp_path / "run"),
            "hyperparams": small_hyperparams(tmp_path / "hyperparams.yml"),
            **changes,
        }
    )


def progress(run_dir):
    with (run_dir / "progress.csv").open(newline="") as handle:
        return list(csv.DictReader(handle))


@pytest.fixture(scope="module")
def trained(tmp_path_factory, local_ray):
    """A two-iteration run: the run directory of ``fxc train --backend rllib``."""
    return train(rllib_args(tmp_path_factory.mktemp("rllib")))


@pytest.mark.slow
def test_two_iterations_with_two_env_runners_write_the_run_directory(trained):
    rows = progress(trained)
    assert [int(r["time/iterations"]) for r in rows] == [1, 2]
    assert [int(r["time/env_steps"]) for r in rows] == [BATCH, 2 * BATCH]
    assert [int(r["time/total_timesteps"]) for r in rows] == [PER_ITERATION, 2 * PER_ITERATION]
    assert all(int(r["rollout/episodes"]) == 2 for r in rows)  # each runner finished one K = 200 episode
    assert all(np.isfinite(float(r["rollout/ep_rew_mean"])) for r in rows)
    record = json.loads((trained / "config.json").read_text())
    assert record["args"]["backend"] == "rllib" and record["args"]["num_env_runners"] == 2
    assert record["timesteps_per_iteration"] == PER_ITERATION
    assert json.loads((trained / "versions.json").read_text())["ray"].startswith("2.60")
    assert (trained / "checkpoints" / f"rllib_{2 * PER_ITERATION}_steps" / "rllib_checkpoint.json").is_file()
    assert (trained / "training_curve.png").stat().st_size > 0


@pytest.mark.slow
def test_resume_restores_the_checkpoint_and_continues_its_count(trained, tmp_path, capsys):
    run_dir = shutil.copytree(trained, tmp_path / "run")
    before = RLlibPolicy(run_dir, trusted=True)  # RLlib restores by unpickling: our own checkpoint
    train(rllib_args(tmp_path, timesteps=3 * PER_ITERATION, resume=True, trust_policy_file=True))
    out = capsys.readouterr().out
    assert f"resuming {run_dir} from rllib_{2 * PER_ITERATION}_steps at iteration 2" in out
    assert [int(r["time/env_steps"]) for r in progress(run_dir)] == [BATCH, 2 * BATCH, 3 * BATCH]
    after = RLlibPolicy(run_dir, trusted=True)
    assert after.checkpoint.name == f"rllib_{3 * PER_ITERATION}_steps"
    obs = np.random.default_rng(0).uniform(-1, 1, size=(8, before.obs_size))
    assert not np.array_equal(before(obs), after(obs))  # the third iteration updated the restored module


@pytest.mark.slow
def test_the_checkpoint_acts_like_a_learned_policy(trained):
    config = make_config("paper_fig1", obs_slots=4)
    policy = load_learned_policy(trained, config, trusted=True)
    assert isinstance(policy, RLlibPolicy) and policy.obs_size == config.layout.size and policy.action_size == 2
    obs = np.random.default_rng(1).uniform(-1, 1, size=(3, 6, config.layout.size))
    actions = policy(obs)
    assert actions.shape == (3, 6, 2) and np.all(np.abs(actions) <= 2.0)
    np.testing.assert_allclose(actions[2, 5], policy(obs[2, 5]), rtol=1e-5, atol=1e-6)  # float32 network
    np.testing.assert_array_equal(actions, policy(obs))  # deterministic: the Gaussian's mean
    # One slot (the paper's in-degree) is padded to the trained 4 exactly; in-degree 5 is refused by name.
    unpadded = load_learned_policy(trained, make_config("paper_fig1"), trusted=True)
    one = obs[..., [0, 1, 8, 12, 13, 14]]  # the rows and mask of slot 0, the clock
    padded = np.zeros_like(obs)
    padded[..., [0, 1, 8, 12, 13, 14]] = one
    np.testing.assert_array_equal(unpadded(one), policy(padded))
    with pytest.raises(ValueError, match=r"an RLlib module .* reads a fixed 4 neighbour rows .* up to 5 in-neighbours"):
        load_learned_policy(trained, make_config(topology="complete", n_agents=6), trusted=True)


@pytest.mark.slow
def test_fxc_evaluate_scores_the_rllib_run_next_to_the_reference(trained, tmp_path, capsys):
    out = tmp_path / "evaluate"
    arguments = ["evaluate", "--policy", str(trained), "--seeds", "2", "--out", str(out), "--no-progress"]
    # RLlib restores its modules by unpickling: refused by name unless the user trusts the file.
    assert cli.main(arguments) == 2
    refusal = capsys.readouterr().err
    assert "--policy" in refusal and "trust" in refusal and not out.exists()
    code = cli.main([*arguments, "--trust-policy-file"])
    printed = capsys.readouterr().out
    assert code == 0
    name = f"learned:{trained.name}"
    assert f"| {name} | 200 |" in printed and "RLlib checkpoint" in printed
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert {(r["policy"], r["case"]) for r in rows} == {
        (policy, s.key) for policy in ("reference", name) for s in EVALUATION_CASES
    }
    # Trained on the paper's six agents: the N = 20 cases lie outside its training domain and are not run.
    errors = {(r["policy"], r["case"]): r["error"] for r in rows}
    assert all(errors[("reference", s.key)] == "" for s in EVALUATION_CASES)
    assert errors[(name, EVALUATION_CASES[0].key)] == ""
    for case in EVALUATION_CASES[1:3]:  # the ring and path of 20 (the random one may first exceed its 4 rows)
        assert "n_agents: trained on 6, this environment has 20" in errors[(name, case.key)]
    assert all(errors[(name, case.key)] for case in EVALUATION_CASES[1:])


#: Inside paper_fig1's sizes (in-degree 1 of 4 rows), outside its training domain: eight agents on a ring.
RING_OF_8 = {"topology": "ring", "n_agents": 8, "obs_slots": 4}


@pytest.mark.slow
def test_the_checkpoint_records_its_training_settings_and_domain_as_plain_json(trained):
    trained_on = make_config("paper_fig1", obs_slots=4)  # the hyperparameter file's env for paper_fig1
    checkpoint = trained / "checkpoints" / f"rllib_{2 * PER_ITERATION}_steps"
    record = json.loads((checkpoint / "fxc_policy.json").read_text())
    assert record["format"] == "fxc_env.rllib_policy/1" and record["module"] == "shared"
    assert record["env"] == training_settings(trained_on) and record["domain"] == training_domain(trained_on)
    policy = RLlibPolicy(trained, trusted=True)
    assert policy.training_domain == training_domain(trained_on)
    assert policy.training_settings == training_settings(trained_on)


@pytest.mark.slow
def test_an_rllib_policy_outside_its_training_domain_is_refused_by_name_unless_allowed(trained):
    ring = make_config(**RING_OF_8)
    refusal = r"trained on another domain than this environment: n_agents: trained on 6, this environment has 8"
    with pytest.raises(ArgumentError, match=refusal + ".*allow_out_of_domain=True"):
        load_learned_policy(trained, ring, trusted=True)
    with pytest.raises(ArgumentError, match=refusal):
        RLlibPolicy(trained, ring, trusted=True)
    with pytest.warns(OutOfDomainWarning, match=r"outside its training domain: n_agents: trained on 6.*'ring'"):
        policy = load_learned_policy(trained, ring, trusted=True, allow_out_of_domain=True)
    assert policy(np.zeros((8, ring.layout.size))).shape == (8, 2)


@pytest.mark.slow
def test_an_older_checkpoint_without_the_record_reads_its_domain_from_the_run_directory(trained, tmp_path):
    run = shutil.copytree(trained, tmp_path / "older")
    for record in run.glob("checkpoints/*/fxc_policy.json"):
        record.unlink()  # as a run of a version before the record
    older = RLlibPolicy(run, trusted=True)
    assert older.training_domain == training_domain(make_config("paper_fig1", obs_slots=4))
    with pytest.raises(ArgumentError, match="n_agents: trained on 6, this environment has 8"):
        load_learned_policy(run, make_config(**RING_OF_8), trusted=True)
    # A checkpoint with neither record is checked as an SB3 .zip without its record: for sizes and width only.
    (run / "config.json").unlink()
    bare = load_learned_policy(run, make_config(**RING_OF_8), trusted=True)
    assert bare.training_domain is None and bare.training_settings is None
    # A record that is there but damaged is refused by name, not read as "no record".
    (older.checkpoint / "fxc_policy.json").write_text("{not json")
    with pytest.raises(ArgumentError, match=r"fxc_policy.json is not readable JSON"):
        RLlibPolicy(run, trusted=True)


def test_rllib_env_renders_with_the_pettingzoo_signature_and_keeps_agent_order():
    env = ConsensusRLlibEnv({"scenario": "paper_fig1", "render_mode": "rgb_array", "n_intervals": 5})
    assert env.agents == env.possible_agents == [f"agent_{i}" for i in range(6)]
    observations, _ = env.reset(seed=0)
    observations, rewards, terminateds, _, _ = env.step({a: np.zeros(2) for a in observations})
    assert set(rewards) == set(env.agents) and terminateds["__all__"] is False
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    with pytest.raises(TypeError):  # why the subclass: RLlib's wrapper passes the render mode
        ParallelPettingZooEnv.render(env)


def test_sac_and_bad_runner_counts_are_refused_before_ray_starts(tmp_path):
    with pytest.raises(ValueError, match="algo: the rllib backend trains 'ppo'"):
        train(rllib_args(tmp_path, algo="sac"))
    with pytest.raises(ValueError, match="num_env_runners: expected an integer >= 0"):
        train(rllib_args(tmp_path, num_env_runners=-1))
    with pytest.raises(ValueError, match="envs_per_runner: expected an integer >= 1"):
        train(rllib_args(tmp_path, envs_per_runner=0))
