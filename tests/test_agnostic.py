"""The shipped ``agnostic`` policy: one gain schedule for every graph, learned without being told the graph.

Goals (docs: results.md, "What learning reached"): at K = 200, T_s = 20 s on the paper's schedule, at least ten
times below the paper's controller on directed rings of sizes it was never trained on (N in
12..40); its inputs are the agent's own rows, mask and clock only (no N, no graph, no spectrum).
Measured (docs: results.md, "What learning reached"): ten times below at the held-out N = 15 and 19, below the reference at every
held-out size, 1.8 times at N = 39 (the goal is not met there).
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from fxc_env.baselines.jobs import Job, run_job
from fxc_env.baselines.suite import BenchmarkCase, builtin_contenders, learned_contender
from fxc_env.config import make_config
from fxc_env.core.families import TopologyFamily
from fxc_env.core.validation import ArgumentError
from fxc_env.envs.parallel import ConsensusParallelEnv
from fxc_env.policies.interval_gains import IntervalGainPolicy, read_interval_gains
from fxc_env.policies.learned import load_learned_policy, pretrained_path
from fxc_env.training.agnostic import HELD_OUT_RINGS, TRAINED_RINGS, case_config, main
from fxc_env.training.rings import TASK


def deadline_errors(contender, n_agents, seeds) -> np.ndarray:
    result = run_job(Job(contender, BenchmarkCase(TopologyFamily("ring"), n_agents), 200, seeds, 20.0, False))
    assert result.error is None, result.error
    return np.asarray(result.metrics["relative_deadline_error"])


def test_the_agnostic_policy_is_ten_times_below_the_reference_on_a_ring_size_it_never_met():
    assert 15 in HELD_OUT_RINGS and 15 not in TRAINED_RINGS
    seeds = (0, 1, 2)
    ours = np.median(deadline_errors(learned_contender("agnostic"), 15, seeds))
    reference = np.median(deadline_errors(builtin_contenders(["reference"])[0], 15, seeds))
    assert reference > 1e-3
    assert ours * 10 <= reference


@pytest.mark.slow
@pytest.mark.parametrize("n_agents", HELD_OUT_RINGS)
def test_the_agnostic_policy_beats_the_reference_on_every_held_out_ring_size_over_20_seeds(n_agents):
    """Tenfold at N = 15 and 19 (the goal); below the reference at every held-out size (the goal is unmet above 19)."""
    seeds = tuple(range(20))
    ours = np.median(deadline_errors(learned_contender("agnostic"), n_agents, seeds))
    reference = np.median(deadline_errors(builtin_contenders(["reference"])[0], n_agents, seeds))
    assert ours * (10 if n_agents < 20 else 1.5) <= reference


def test_an_agent_plan_reads_only_its_own_rows_mask_and_clock():
    """Scrambling every other agent's observation, or swapping the graph and N, changes no agent's plan."""
    policy = load_learned_policy("agnostic", case_config({"kind": "ring"}, 20))
    random = TopologyFamily("random", mean_in_degree=(1.5, 3.0))
    env = ConsensusParallelEnv(None, **{**TASK, "n_agents": 20, "topology": random, "obs_slots": 4})
    observations, _ = env.reset(seed=3)
    obs = np.stack([observations[a] for a in env.agents])
    plans = policy(obs)
    rng = np.random.default_rng(0)
    for i in (0, 7):
        alone = policy(obs[i])
        scrambled = rng.normal(size=(13, obs.shape[1])) * 1e3  # another N, other agents, anything
        scrambled[5] = obs[i]
        np.testing.assert_array_equal(policy(scrambled)[5], alone)
        np.testing.assert_array_equal(plans[i], alone)
    assert "eigenvalues" not in policy.header  # no spectrum in the file either


def test_the_agnostic_file_records_a_training_without_teacher_over_graph_families():
    path = pretrained_path("agnostic")
    assert path.suffix == ".npz" and path.stat().st_size < 2**16
    with np.load(path, allow_pickle=False) as arrays:
        gains, header = arrays["gains"], json.loads(str(arrays["header"]))
    assert gains.shape == (200, 2, 2) and header["name"] == "agnostic"
    assert header["training"]["teacher"] is None
    assert header["training"]["command"].startswith("python -m fxc_env.training.agnostic")
    domain = header["domain"]
    assert domain["n_agents"] == [12, 40] and domain["schedule"] == ["paper"] and domain["n_intervals"] == [200, 200]
    assert {g["family"] for g in domain["graphs"]} == {"ring", "random", "path", "star"}
    config = make_config(None, **{**TASK, "topology": TopologyFamily("ring"), "n_agents": 33})
    assert isinstance(load_learned_policy("agnostic", config), IntervalGainPolicy)


def test_the_agnostic_policy_refuses_a_ring_outside_its_sizes_by_name():
    config = make_config(None, **{**TASK, "topology": TopologyFamily("ring"), "n_agents": 100})
    with pytest.raises(ArgumentError, match=r"^policy: .*agnostic.npz was trained on another domain.*n_agents"):
        load_learned_policy("agnostic", config)


def test_quick_training_writes_a_policy_that_beats_the_reference_on_a_held_out_ring(tmp_path, capsys):
    out = tmp_path / "agnostic.npz"
    assert main(["--quick", "--out", str(out)]) == 0
    policy = read_interval_gains(out)
    assert policy.header["training"]["teacher"] is None and policy.header["name"] == "agnostic"
    printed = re.search(r"ring N = 15, 2 held-out seeds: .*, ([0-9.e+]+)x below", capsys.readouterr().out)
    assert printed is not None and float(printed.group(1)) >= 10


@pytest.mark.parametrize(("keyword", "value"), [("steps", 0), ("seed", -1)])
def test_bad_training_settings_are_refused_by_name(keyword, value):
    from fxc_env.training.agnostic import train

    with pytest.raises(ArgumentError, match=f"^{keyword}"):
        train(**{keyword: value})
