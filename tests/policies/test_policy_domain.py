"""Every policy knows where it was trained (fxc_env.policies.domain; docs: training.md, "Training learned policies").

Each shipped file records its training domain as plain data; loading it into an environment
outside that domain is refused naming every difference, unless ``allow_out_of_domain=True``,
which runs it with a warning naming them. Recurrent policies keep one memory per agent: called
agent by agent in the plane they are refused by name, and dict observations act as flat ones.
"""

from __future__ import annotations

import hashlib
import json
import re
import warnings
import zipfile

import numpy as np
import pytest
import torch
from helpers import SHIPPED_INSIDE as INSIDE

import fxc_env
from fxc_env import cli
from fxc_env.baselines.harness.jobs import Job, run_job
from fxc_env.baselines.harness.suite import BenchmarkCase, learned_contender
from fxc_env.config import make_config
from fxc_env.config.tasks import TASKS
from fxc_env.core.families import TopologyFamily
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.domain import OutOfDomainWarning, check_domain, domain_differences, training_domain
from fxc_env.policies.learned import SHIPPED, load_learned_policy, pretrained_path
from fxc_env.policies.policy_files import METADATA_MEMBER
from fxc_env.training.recipes.rings import task_config

#: The environment each shipped policy was trained on (fxc_env/pretrained/README.md).
TRAINED = {
    "generalist": lambda: make_config("generalist"),
    "saturated": lambda: make_config("saturated"),
    "paper_fig1": lambda: make_config("paper_fig1", initial_state="random", obs_slots=4),
    "rings": task_config,
    "rings_gru": task_config,
}


def recorded_domain(name):
    """The domain a shipped file records, read as plain data (nothing unpickled)."""
    path = pretrained_path(name)
    if path.suffix == ".zip":
        with zipfile.ZipFile(path) as archive:
            return json.loads(archive.read(METADATA_MEMBER))["domain"]
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as arrays:
            return json.loads(str(arrays["header"]))["domain"]
    return torch.load(path, map_location="cpu", weights_only=True)["domain"]


@pytest.mark.parametrize("name", list(TRAINED))
def test_every_shipped_file_records_the_domain_of_its_training_environment(name):
    assert recorded_domain(name) == training_domain(TRAINED[name]())


def test_the_recorded_domains_say_where_each_policy_was_trained():
    generalist = recorded_domain("generalist")
    assert [g["family"] for g in generalist["graphs"]] == ["ring", "path", "star", "random"]
    assert generalist["n_agents"] == [20, 20] and generalist["n_intervals"] == [200, 200]
    assert recorded_domain("saturated")["schedule"] == ["uniform"]
    assert recorded_domain("saturated")["u_max"] == [10.0, 1000.0]
    assert [g["topology"] for g in recorded_domain("paper_fig1")["graphs"]] == ["paper_fig1"]
    for name in ("rings", "rings_gru"):
        domain = recorded_domain(name)
        assert domain["graphs"] == [{"family": "ring", "period": [1, 1]}] and domain["n_agents"] == [20, 20]
        assert domain["switching"] == ["periodic"] and domain["schedule"] == ["paper"]


def test_recording_the_domain_kept_every_weight():
    """The digests of the weights as shipped before the domain was recorded (git 0fd173f)."""
    before = {
        "generalist": "6132a5df54ae4c7711540c8e99607515b1d3bffad705f84f660e13d7b22bd488",
        "saturated": "091c9a3e28fb52bd1bc5ff6b205f5d503df56fbbc5e5c713a644ace7f775659a",
        "paper_fig1": "10741c52bd4cc8d55d6561954cdec5966df3ca4c565658d35358b99f0271e5c8",
    }
    for name, digest in before.items():
        with zipfile.ZipFile(pretrained_path(name)) as archive:
            assert hashlib.sha256(archive.read("policy.pth")).hexdigest() == digest
    actor = torch.load(pretrained_path("rings_gru"), weights_only=True)["actor"]
    h = hashlib.sha256()
    for key in sorted(actor):
        h.update(key.encode())
        h.update(actor[key].numpy().tobytes())
    assert h.hexdigest() == "334b66035f4aa8fba01efc66333ae862a2a8db20ceae9209a10de436dfc11325"
    with np.load(pretrained_path("rings"), allow_pickle=False) as arrays:
        gains = np.ascontiguousarray(arrays["gains"])
    assert hashlib.sha256(gains.tobytes()).hexdigest() == (
        "f235614434b944eff254676973fd0f18e61ea1d3cfc39a9021deb4a653a643e5"
    )


#: Per shipped policy, an environment outside its domain and every difference the refusal names.
OUTSIDE = {
    "generalist": (
        {"topology": "ring", "n_agents": 30, "n_intervals": 100},
        ["n_agents: trained on 20, this environment has 30", "n_intervals: trained on 200, this environment has 100"],
    ),
    "saturated": (
        {"scenario": "saturated", "n_agents": 12, "obs_noise": 0.01},
        ["n_agents: trained on 6, this environment has 12", "obs_noise: trained on 0, this environment has 0.01"],
    ),
    "paper_fig1": (  # the issue: 294 on a ring of 20
        {"scenario": None, "topology": "ring", "n_agents": 20},
        [
            "n_agents: trained on 6, this environment has 20",
            "graphs: trained on the fixed topology 'paper_fig1' (3 graph(s)), this environment has the fixed "
            "topology 'ring' (ring, period 1, N = 20)",
        ],
    ),
    "rings": (
        {"scenario": "paper_fig1"},
        [
            "n_agents: trained on 20, this environment has 6",
            "graphs: trained on ring (period 1), this environment has the fixed topology 'paper_fig1' (ring, period 3",
        ],
    ),
    "rings_gru": (  # the issue: 5.7e44 on paper_fig1, 5.2e22 with random switching
        {"scenario": "paper_fig1", "switching": "random"},
        [
            "n_agents: trained on 20, this environment has 6",
            "switching: trained on 'periodic', this environment has 'random'",
            "graphs: trained on ring (period 1), this environment has the fixed topology 'paper_fig1' (ring, period 3",
        ],
    ),
    "rings_scratch": (
        {"scenario": "paper_fig1"},
        [
            "n_agents: trained on 20, this environment has 6",
            "graphs: trained on ring (period 1), this environment has the fixed topology 'paper_fig1' (ring, period 3",
        ],
    ),
    "agnostic": (
        {"scenario": None, "topology": "ring", "n_agents": 100},
        ["n_agents: trained on 12 to 40, this environment has 100"],
    ),
    "ppo_rings20": (  # the same ring at K = 200
        {"scenario": None, **TASKS["rings20-v2"].settings, "n_intervals": 200},
        ["n_intervals: trained on 50, this environment has 200"],
    ),
    "diff_rings20": (  # a ring of 24
        {"scenario": None, **TASKS["rings20-v2"].settings, "n_agents": 24},
        ["n_agents: trained on 20, this environment has 24"],
    ),
}


@pytest.mark.parametrize("name", list(OUTSIDE))
def test_every_shipped_policy_refuses_an_environment_outside_its_domain_by_name_and_runs_there_when_allowed(name):
    kwargs, differences = OUTSIDE[name]
    env = fxc_env.parallel_env(**kwargs)
    with pytest.raises(ArgumentError, match=r"^policy: the model at .* was trained on another domain") as refused:
        load_learned_policy(name, env)
    for difference in differences:
        assert difference in str(refused.value)
    assert "allow_out_of_domain=True" in str(refused.value)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        policy = load_learned_policy(name, env, allow_out_of_domain=True)
    messages = [str(w.message) for w in caught if w.category is OutOfDomainWarning]
    assert len(messages) == 1 and "runs outside its training domain" in messages[0]
    for difference in differences:
        assert difference in messages[0]
    obs, _ = env.reset(seed=0)
    actions = policy(np.stack([obs[agent] for agent in env.agents]))
    assert actions.shape == (env.unwrapped.config.n_agents, 2) and np.all(np.isfinite(actions))


def test_every_shipped_name_has_its_domain_tests():
    shipped = set(SHIPPED) - {"pretrained"}  # "pretrained" is generalist's older name
    assert set(OUTSIDE) == shipped and set(INSIDE) == shipped


@pytest.mark.parametrize("name", list(INSIDE))
def test_inside_its_domain_a_shipped_policy_loads_without_a_word(name):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_learned_policy(name, fxc_env.parallel_env(**INSIDE[name]))


def test_a_fixed_graph_is_inside_a_family_it_could_be_drawn_from():
    domain = training_domain(make_config("generalist"))
    random_20 = make_config(None, topology="random", n_agents=20, mean_in_degree=2.0)
    assert domain_differences(domain, random_20) == []
    dense = make_config(None, topology="random", n_agents=20, mean_in_degree=5.0)
    assert [d[0] for d in domain_differences(domain, dense)] == ["graphs"]
    relabelled_star = TopologyFamily("star").draw(20, np.random.default_rng(1))
    assert domain_differences(domain, make_config(None, topology=relabelled_star)) == []
    with pytest.raises(ArgumentError, match=r"^allow_out_of_domain: expected True or False, got 'yes'"):
        check_domain(domain, dense, "here", "yes")
    with pytest.raises(ArgumentError, match=r"^allow_out_of_domain: expected True or False, got 1"):
        load_learned_policy("generalist", allow_out_of_domain=1)


@pytest.mark.slow
def test_fxc_evaluate_refuses_an_environment_outside_the_domain_and_runs_it_with_allow_out_of_domain(tmp_path, capsys):
    argv = ["evaluate", "--policy", "paper_fig1", "--topology", "ring", "--n-agents", "20", "--seeds", "1"]
    argv += ["--out", str(tmp_path), "--no-progress", "--workers", "1"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("fxc evaluate: error: --policy: learned:paper_fig1_ppo could not run on any case")
    assert "n_agents: trained on 6, this environment has 20" in err and "--allow-out-of-domain" in err
    assert cli.main([*argv, "--allow-out-of-domain"]) == 0
    assert "learned:paper_fig1_ppo" in capsys.readouterr().out


def test_a_benchmark_contender_runs_an_out_of_domain_case_only_when_allowed():
    case = BenchmarkCase("paper_fig1", 6)
    refused = run_job(Job(learned_contender("rings_gru"), case, 200, (0,), 20.0, False))
    assert refused.error is not None and "n_agents: trained on 20, this environment has 6" in refused.error
    with pytest.warns(OutOfDomainWarning, match=re.escape("n_agents: trained on 20, this environment has 6")):
        allowed = run_job(Job(learned_contender("rings_gru", allow_out_of_domain=True), case, 200, (0,), 20.0, False))
    assert allowed.error is None


# ------------------------------------------------------------------------ recurrent policies (item 4)
def test_a_recurrent_policy_in_the_plane_refuses_one_agents_observation_and_acts_as_one_batch():
    """rings_gru acts per axis in dim 2; called agent by agent, every agent would share one memory."""
    env = fxc_env.parallel_env(topology="ring", n_agents=20, dim=2)
    with pytest.warns(UserWarning, match="acting per axis in dim 2"):
        batched = load_learned_policy("rings_gru", env)
    with pytest.warns(UserWarning, match="acting per axis in dim 2"):
        mapped = load_learned_policy("rings_gru", env)
    obs, _ = env.reset(seed=0)
    message = (
        r"^observations: PerAxisPolicy from .*rings_gru.pt acts for every agent at once.* an array \(\.\.\., N, 8\)"
    )
    for _ in range(5):
        with pytest.raises(ArgumentError, match=message):
            batched(obs["agent_0"])
        stacked = batched(np.stack([obs[agent] for agent in env.agents]))
        actions = mapped(obs)
        np.testing.assert_array_equal(np.stack([actions[agent] for agent in env.agents]), stacked)
        obs = env.step(actions)[0]


def test_a_recurrent_policy_reads_dict_observations_as_the_flat_ones():
    flat = fxc_env.parallel_env(topology="ring", n_agents=20)
    nested = fxc_env.parallel_env(topology="ring", n_agents=20, obs_format="dict")
    policies = load_learned_policy("rings_gru", flat), load_learned_policy("rings_gru", nested)
    (obs_flat, _), (obs_nested, _) = flat.reset(seed=1), nested.reset(seed=1)
    for _ in range(5):
        expected, actions = policies[0](obs_flat), policies[1](obs_nested)
        for agent in flat.agents:
            np.testing.assert_array_equal(actions[agent], expected[agent])
        obs_flat, obs_nested = flat.step(expected)[0], nested.step(actions)[0]
    with pytest.raises(
        ArgumentError, match=r"^observations: TorchPolicy from .*rings_gru.pt acts for every agent at once"
    ):
        policies[1](obs_nested["agent_0"])
