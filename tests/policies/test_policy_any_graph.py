"""Shipped policies in environments of any obs_slots and N: the loader rebuilds the trained layout.

The gain-scheduled networks (generalist, saturated) read any number of neighbour rows; a
fixed-width network (the MLP of paper_fig1, torch MLPs) reads fewer rows than it was trained
with exactly (padded as an ``obs_slots=4`` environment pads them) and refuses more by name.
"""

from __future__ import annotations

import json
import shutil
import warnings
import zipfile

import numpy as np
import pytest
import torch
from helpers import torch_mlp_policy_file

import fxc_env
from fxc_env import cli
from fxc_env.config import make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.domain import OutOfDomainWarning
from fxc_env.policies.learned import (
    LearnedPolicy,
    PerAxisPolicy,
    PolicyAdaptedWarning,
    SlotAdaptedPolicy,
    load_learned_policy,
    pretrained_path,
)
from fxc_env.policies.policy_files import METADATA_MEMBER, add_metadata

RING = {"topology": "ring", "n_agents": 20}
#: saturated was trained on the uniform schedule with a visible input limit.
SETTINGS = {"generalist": {}, "saturated": {"schedule": "uniform", "u_max": 10.0}}


def episode(policy, env, seed=0):
    """Every action of one seeded episode ``(K, N, 2 dim)`` and the final episode metrics."""
    obs, infos = env.reset(seed=seed)
    taken = []
    while env.agents:
        actions = {agent: policy(o) for agent, o in obs.items()}
        taken.append(np.stack(list(actions.values())))
        obs, _, _, _, infos = env.step(actions)
    return np.stack(taken), infos["agent_0"]["episode"]


def load_quietly(name, env, allow_out_of_domain=False):
    with warnings.catch_warnings():
        warnings.simplefilter("error", PolicyAdaptedWarning)  # no warning: reading fewer rows is exact
        warnings.simplefilter("error" if not allow_out_of_domain else "ignore", OutOfDomainWarning)
        return load_learned_policy(name, env, allow_out_of_domain=allow_out_of_domain)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["generalist", "saturated"])
def test_a_gain_network_in_a_ring_of_20_with_any_slots_plays_the_four_slot_episode(name):
    """Default obs_slots (1: the ring's in-degree) and 8 give the actions of obs_slots=4, bit for bit."""
    four = fxc_env.parallel_env(**RING, **SETTINGS[name], obs_slots=4)
    allow = name == "saturated"  # trained on N = 6
    expected_actions, expected = episode(load_quietly(name, four, allow), four)
    for slots in (None, 8):
        env = fxc_env.parallel_env(**RING, **SETTINGS[name], obs_slots=slots)
        assert env.observation_space("agent_0").shape[0] != four.observation_space("agent_0").shape[0]
        policy = load_quietly(name, env, allow)
        assert isinstance(policy, SlotAdaptedPolicy)
        actions, metrics = episode(policy, env)
        np.testing.assert_array_equal(actions, expected_actions)
        assert metrics == expected
    # docs: training.md, "Training learned policies": the generalist leaves 0.29 of D(0) on rings of 20 (median), the
    # reference 0.034; saturated was trained on rings of 6 under the limit and gathers these too.
    assert expected["relative_deadline_error"] < 1.0


@pytest.mark.parametrize("name", ["generalist", "saturated"])
def test_a_gain_network_reads_more_rows_than_it_was_trained_with_and_meets_the_deadline(name):
    """A complete graph of 8 (in-degree 7 > 4 slots): a warning, and D(T_s)/D(0) below 1e-9 (the reference: 0)."""
    env = fxc_env.parallel_env(topology="complete", n_agents=8, n_intervals=100, **SETTINGS[name])
    with pytest.warns(OutOfDomainWarning, match="n_agents: trained on .*n_intervals: trained on 200.*graphs: "):
        with pytest.warns(PolicyAdaptedWarning, match="trained with 4 neighbour slots, acting on 7"):
            policy = load_learned_policy(name, env, allow_out_of_domain=True)
    _, metrics = episode(policy, env)
    assert metrics["relative_deadline_error"] < 1e-9


def test_rows_beyond_the_trained_slots_are_grouped_so_that_eq_11_stays_exact():
    """With the paper's gains ``[[1, 1], [0, 1]] / (d + 1)`` at 4 slots, the adapted network is eq. (11) at any in-degree."""
    from fxc_env.policies.gain_network import GainScheduledExtractor

    class ReferenceGains(torch.nn.Module):
        def forward(self, context):
            degree = context[..., :4].sum(dim=-1, keepdim=True)
            return torch.tensor([1.0, 1.0, 0.0, 1.0], dtype=torch.float64).repeat(4) / (degree + 1.0)

    extractor = GainScheduledExtractor(15).double()
    extractor.gains = ReferenceGains()

    class Network:
        action_size = 2

        def __call__(self, obs):
            return extractor.forward_actor(torch.as_tensor(obs)).detach().numpy()

    edges = [((i - s) % 12, i) for i in range(12) for s in range(1, 8)]  # in-degree 7
    env = fxc_env.parallel_env(topology=edges, n_agents=12, obs_slots=9)  # and two padded slots
    adapted = SlotAdaptedPolicy(Network(), env.unwrapped.config.layout, 4, reads_any_rows=True)
    reference = fxc_env.ReferencePolicy(env)
    obs, _ = env.reset(seed=3)
    for _ in range(5):
        batch = np.stack(list(obs.values()))
        np.testing.assert_allclose(adapted(batch), reference(batch), rtol=1e-12, atol=1e-15)
        obs = env.step({agent: reference(o) for agent, o in obs.items()})[0]


def test_vecnormalize_statistics_per_slot_keep_the_four_slot_actions(tmp_path):
    """A model with per-slot VecNormalize statistics (all different) acts in a 1-slot env as in the 4-slot env."""
    path = tmp_path / "normalized.zip"
    shutil.copy(pretrained_path("generalist"), path)
    with zipfile.ZipFile(path) as archive:
        record = json.loads(archive.read(METADATA_MEMBER))
    rng = np.random.default_rng(0)
    record["normalization"] = {
        "mean": rng.normal(0.0, 0.1, 15).tolist(),
        "var": rng.uniform(0.5, 2.0, 15).tolist(),
        "epsilon": 1e-8,
        "clip_obs": 10.0,
    }
    add_metadata(path, record)
    kwargs = {**RING, "n_agents": 8, "n_intervals": 30}
    four = fxc_env.parallel_env(**kwargs, obs_slots=4)
    with warnings.catch_warnings():  # N = 8 and K = 30: outside the generalist's domain (N = 20, K = 200)
        warnings.simplefilter("ignore", OutOfDomainWarning)
        old = LearnedPolicy(path, four, allow_out_of_domain=True)  # the path without adaptation
        assert old._stats is not None
        assert load_learned_policy(path, four, allow_out_of_domain=True).__class__ is LearnedPolicy
        adapted = load_learned_policy(path, fxc_env.parallel_env(**kwargs), allow_out_of_domain=True)
    expected, _ = episode(old, four)
    actions, _ = episode(adapted, fxc_env.parallel_env(**kwargs))
    np.testing.assert_array_equal(actions, expected)


def test_a_gain_network_in_the_plane_acts_per_axis_on_any_slots():
    kwargs = {"topology": "random", "n_agents": 6, "mean_in_degree": 2.0, "dim": 2, "n_intervals": 15}
    allow = {"allow_out_of_domain": True}  # N = 6, K = 15: outside the generalist's domain
    with pytest.warns(OutOfDomainWarning), pytest.warns(PolicyAdaptedWarning, match="acting per axis in dim 2"):
        four = load_learned_policy("generalist", fxc_env.parallel_env(**kwargs, obs_slots=4), **allow)
    with pytest.warns(OutOfDomainWarning), pytest.warns(PolicyAdaptedWarning, match="acting per axis in dim 2"):
        policy = load_learned_policy("generalist", env := fxc_env.parallel_env(**kwargs), **allow)
    assert isinstance(policy, PerAxisPolicy) and isinstance(policy.policy, SlotAdaptedPolicy)
    assert env.unwrapped.config.layout.slots != 4
    expected, _ = episode(four, fxc_env.parallel_env(**kwargs, obs_slots=4))
    actions, _ = episode(policy, env)
    np.testing.assert_allclose(actions, expected, rtol=0, atol=0)


def test_the_mlp_reads_fewer_rows_exactly_and_refuses_more_by_name():
    """paper_fig1's MLP: obs_slots 1 plays the obs_slots=4 episode; in-degree 5 is refused naming its width."""
    expected, metrics4 = episode(load_quietly("paper_fig1", four := fxc_env.parallel_env(obs_slots=4)), four)
    actions, metrics = episode(load_quietly("paper_fig1", env := fxc_env.parallel_env()), env)
    np.testing.assert_array_equal(actions, expected)
    assert metrics == metrics4
    complete = make_config(topology="complete", n_agents=6)
    message = (
        r"^policy: the model at .*paper_fig1_ppo.zip is an MLP \(ActorCriticPolicy, net_arch \[64, 64\]\), which "
        r"reads a fixed 4 neighbour rows \(observations of size 15\); this environment's agents have up to 5 "
        r"in-neighbours \(obs_slots: trained with 4, this environment has 5\)"
    )
    with pytest.raises(ArgumentError, match=message):
        load_learned_policy("paper_fig1", complete)


def torch_mlp(tmp_path):
    return torch_mlp_policy_file(tmp_path, {"scenario": "paper_fig1", "obs_slots": 4}, seed=0)


def test_a_torch_mlp_names_its_width_and_loads_padded(tmp_path):
    from fxc_env.policies.torch_policy import load_torch_policy

    path = torch_mlp(tmp_path)
    with pytest.raises(ArgumentError, match=r"is a torch MLP \(fxc train --backend torch\)") as refused:
        load_torch_policy(path, make_config("paper_fig1"))
    assert "reads a fixed 4 neighbour rows (observations of size 15); this environment has 1" in str(refused.value)
    with pytest.raises(ArgumentError, match=r"a torch MLP .* up to 5 in-neighbours"):
        load_learned_policy(path, make_config(topology="complete", n_agents=6))
    kwargs = {"n_intervals": 20}
    with pytest.warns(OutOfDomainWarning, match="n_intervals: trained on 200, this environment has 20"):
        four_slots = load_learned_policy(
            path, four := fxc_env.parallel_env(**kwargs, obs_slots=4), allow_out_of_domain=True
        )
    with pytest.warns(OutOfDomainWarning, match="n_intervals: trained on 200, this environment has 20"):
        one_slot = load_learned_policy(path, env := fxc_env.parallel_env(**kwargs), allow_out_of_domain=True)
    expected, _ = episode(four_slots, four)
    actions, _ = episode(one_slot, env)
    np.testing.assert_array_equal(actions, expected)


def test_rings_loads_into_a_plain_ring_of_20_and_reads_any_slots():
    """The gain table reads the aggregated row (README of the shipped policies: 4.4e-15 median on rings of 20)."""
    env = fxc_env.parallel_env(**RING)
    assert env.unwrapped.config.layout.slots == 1
    actions, metrics = episode(load_quietly("rings", env), env)
    assert metrics["relative_deadline_error"] < 1e-12
    padded = fxc_env.parallel_env(**RING, obs_slots=4)
    padded_actions, padded_metrics = episode(load_quietly("rings", padded), padded)
    np.testing.assert_array_equal(padded_actions, actions)
    assert padded_metrics == metrics


@pytest.mark.slow
def test_fxc_evaluate_the_generalist_on_a_ring_of_20(tmp_path, capsys):
    argv = ["evaluate", "--policy", "generalist", "--topology", "ring", "--n-agents", "20"]
    assert cli.main([*argv, "--seeds", "2", "--out", str(tmp_path), "--no-progress"]) == 0
    table = capsys.readouterr().out
    assert "learned:generalist" in table and "could not run" not in table


def test_masked_rows_are_ignored_and_a_fixed_width_network_refuses_a_real_row_beyond_its_width():
    config = make_config(scenario="paper_fig1", obs_slots=6)  # paper_fig1: inside its domain
    layout = config.layout
    obs = np.zeros((3, layout.size))
    obs[:, :2] = [[0.5, -1.0], [1.0, 0.25], [-0.75, 0.5]]  # slot 0's row
    obs[:, layout.rows_end] = 1.0  # slot 0 is real
    obs[:, layout.mask_end :] = [0.3, 0.05, 0.4]  # the clock
    garbage = obs.copy()
    garbage[:, 2 : layout.rows_end] = 1e6  # rows of masked slots
    for name in ("generalist", "paper_fig1"):
        policy = load_learned_policy(name, config, allow_out_of_domain=True)
        np.testing.assert_array_equal(policy(garbage), policy(obs))
    real_beyond = obs.copy()
    real_beyond[:, layout.rows_end + 5] = 1.0  # a real row in slot 5, past the MLP's 4
    with pytest.raises(ArgumentError, match=r"^observations: an agent has a real neighbour row beyond the 4 rows"):
        load_quietly("paper_fig1", config)(real_beyond)


def test_dict_observations_give_the_flat_observations_actions():
    flat = fxc_env.parallel_env(**RING)
    nested = fxc_env.parallel_env(**RING, obs_format="dict")
    expected, _ = episode(load_quietly("generalist", flat), flat)
    actions, _ = episode(load_quietly("generalist", nested), nested)
    np.testing.assert_array_equal(actions, expected)


def test_sb3s_own_loader_adapts_the_same_way():
    """trusted=True (SB3's PPO.load) rebuilds the same network: the same adapted actions on in-degree 5."""
    env = fxc_env.parallel_env(topology="complete", n_agents=6)
    obs = np.stack(list(env.reset(seed=1)[0].values()))
    with pytest.warns(OutOfDomainWarning), pytest.warns(PolicyAdaptedWarning):
        safe = load_learned_policy("generalist", env, allow_out_of_domain=True)
    with pytest.warns(OutOfDomainWarning), pytest.warns(PolicyAdaptedWarning):
        trusted = load_learned_policy(pretrained_path("generalist"), env, trusted=True, allow_out_of_domain=True)
    assert isinstance(trusted, SlotAdaptedPolicy)
    np.testing.assert_allclose(trusted(obs), safe(obs), rtol=1e-6, atol=1e-7)
