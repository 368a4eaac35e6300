"""The TorchRL-native batched environment: its spec contract, the reference through it, seeding and resets."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs, step_mdp

from fxc_env import ConsensusEngine, ReferencePolicy, make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.envs.torch_env import GROUP, ConsensusTorchEnv
from fxc_env.policies.torchrl_reference import ReferenceModule, reference_policy

SPEC_CASES = [
    dict(scenario="paper_fig1"),
    dict(scenario="paper_fig1", dim=2, action_mode="accel", obs_mode="raw", obs_dtype="float32"),
    dict(scenario="generalist", global_state="normalized"),
    dict(scenario="saturated"),
    dict(scenario="paper_fig1", switching="random", obs_noise=0.01, link_dropout=0.1, max_cycles=5),
]


@pytest.mark.parametrize("kwargs", SPEC_CASES, ids=lambda kw: ",".join(f"{k}={v}" for k, v in kw.items()))
def test_check_env_specs_passes(kwargs):
    env = ConsensusTorchEnv(batch_size=4, seed=0, **kwargs)
    check_env_specs(env)
    assert env.batch_size == torch.Size([4])
    assert env.observation_spec[GROUP, "observation"].shape == (4, env.n_agents, env.config.layout.size)
    assert env.action_spec[GROUP, "action"].shape == (4, env.n_agents, env.config.action_size)
    assert env.reward_spec[GROUP, "reward"].shape == (4, env.n_agents, 1)
    assert set(env.done_keys) == {"done", "terminated", "truncated"}


def test_the_reference_rollout_reaches_the_papers_deadline_error_and_terminates_at_K():
    env = ConsensusTorchEnv(scenario="paper_fig1", batch_size=3, seed=1)
    rollout = env.rollout(1000, reference_policy(env))
    K = env.config.n_intervals
    assert rollout.shape == (3, K)  # stops at the deadline: every episode terminated at step K
    assert rollout["next", "terminated"][:, -1].all() and not rollout["next", "terminated"][:, :-1].any()
    assert not rollout["next", "truncated"].any()
    error = env.episode_metrics()["relative_deadline_error"]
    assert np.all(error < 3e-12)  # docs: agent-models.md: 2.9e-12 at K = 200
    # The rewards telescope to the log-reduction of the disagreement, the same for every agent.
    returns = rollout["next", GROUP, "reward"].sum(dim=1)[..., 0]
    assert torch.allclose(returns, returns[:, :1].expand_as(returns))


def test_the_torchrl_env_plays_the_numpy_engines_episodes():
    env = ConsensusTorchEnv(scenario="generalist", batch_size=2, seed=3)
    td = env.reset()
    engine = env.engine
    numpy_engine = ConsensusEngine(env.config, 2)
    numpy_engine.reset(engine.x0.numpy(), engine.v0.numpy(), topologies=engine.topologies)
    policy = ReferencePolicy(env.config)
    module = reference_policy(env)
    while not numpy_engine.done:
        np.testing.assert_allclose(td[GROUP, "observation"].numpy(), numpy_engine.observations(), rtol=0, atol=1e-12)
        td = step_mdp(env.step(module(td)))
        numpy_engine.step(policy.act(numpy_engine.observations()))
    np.testing.assert_allclose(env.engine.state.numpy(), numpy_engine.state, rtol=1e-12, atol=1e-12 * 10)


def test_set_seed_gives_identical_episodes_and_different_seeds_differ():
    def first_observations(seed):
        env = ConsensusTorchEnv(scenario="generalist", batch_size=4)
        env.set_seed(seed)
        return env.rollout(5, reference_policy(env))[GROUP, "observation"]

    assert torch.equal(first_observations(7), first_observations(7))
    assert not torch.equal(first_observations(7), first_observations(8))


def test_a_reset_mask_restarts_only_the_chosen_episodes():
    env = ConsensusTorchEnv(scenario="paper_fig1", initial_state="random", batch_size=4, seed=0)
    module = reference_policy(env)
    td = env.reset()
    for _ in range(5):
        td = step_mdp(env.step(module(td)))
    before = env.engine.state.clone()
    td.set("_reset", torch.tensor([[True], [False], [True], [False]]))
    td = env.reset(td)
    assert env.engine.steps.tolist() == [0, 5, 0, 5]
    assert torch.equal(env.engine.state[[1, 3]], before[[1, 3]])
    assert not torch.equal(env.engine.state[[0, 2]], before[[0, 2]])
    # The restarted episodes see the first instant's clock; the others the sixth's.
    clock = td[GROUP, "observation"][:, 0, -1]  # k / K
    assert clock.tolist() == [0.0, 5 / 200, 0.0, 5 / 200]


def test_max_cycles_truncates():
    env = ConsensusTorchEnv(scenario="paper_fig1", batch_size=2, max_cycles=4, seed=0)
    rollout = env.rollout(100, reference_policy(env))
    assert rollout.shape == (2, 4)
    assert rollout["next", "truncated"][:, -1].all() and not rollout["next", "terminated"].any()


def test_a_non_finite_action_is_reported_at_the_episode_end():
    env = ConsensusTorchEnv(scenario="paper_fig1", batch_size=2, n_intervals=3, seed=0)
    td = env.reset()
    action = torch.zeros((2, env.n_agents, 2), dtype=torch.float64)
    action[1, 0, 0] = float("inf")
    td.set((GROUP, "action"), action)
    td = step_mdp(env.step(td))  # not read on the stepping path
    td.set((GROUP, "action"), torch.zeros_like(action))
    td = step_mdp(env.step(td))
    td.set((GROUP, "action"), torch.zeros_like(action))
    with pytest.raises(ArgumentError, match=r"actions: episodes \[1\]"):
        env.step(td)  # the episode end reads the flags


def test_a_wrong_action_shape_is_refused_and_the_env_stays_usable():
    env = ConsensusTorchEnv(scenario="paper_fig1", batch_size=2, seed=0)
    td = env.reset()
    before = env.engine.state.clone()
    bad = td.clone().set((GROUP, "action"), torch.zeros((2, env.n_agents, 3)))
    with pytest.raises(ArgumentError, match=r"actions: expected shape \(2, 6, 2\), got \(2, 6, 3\)"):
        env._step(bad)
    assert torch.equal(env.engine.state, before) and env.engine.k == 0
    td.set((GROUP, "action"), torch.zeros((2, env.n_agents, 2), dtype=torch.float64))
    env.step(td)
    assert env.engine.k == 1


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(batch_size=0), "batch_size"),
        (dict(batch_size=[2, 3]), "batch_size"),
        (dict(dtype="float16"), "dtype"),
        (dict(max_cycles=0), "max_cycles"),
        (dict(n_agents=1), "n_agents|topology"),
    ],
)
def test_bad_arguments_name_themselves(kwargs, message):
    with pytest.raises(ArgumentError, match=message):
        ConsensusTorchEnv(scenario="paper_fig1", **kwargs)


def test_reference_module_equals_the_numpy_reference():
    config = make_config("generalist")
    obs = np.random.default_rng(0).uniform(-1, 1, size=(5, config.n_agents, config.layout.size))
    obs[..., config.layout.rows_end : config.layout.mask_end] = 1.0
    expected = ReferencePolicy(config).act(obs)
    np.testing.assert_allclose(ReferenceModule(config)(torch.as_tensor(obs)).numpy(), expected, rtol=1e-15, atol=1e-15)


def _one_step_with(env, td, action):
    td.set((GROUP, "action"), action)
    return step_mdp(env.step(td))


def test_a_reported_bad_value_is_reported_once_and_the_next_reset_starts_clean_episodes():
    env = ConsensusTorchEnv(scenario="paper_fig1", batch_size=2, n_intervals=2, seed=0)
    td = env.reset()
    action = torch.zeros((2, env.n_agents, 2), dtype=torch.float64)
    bad = action.clone()
    bad[0, 0, 0] = float("nan")
    td = _one_step_with(env, td, bad)
    with pytest.raises(ArgumentError, match=r"actions: episodes \[0\]"):
        _one_step_with(env, td, action)  # the episode end reports it
    td = env.reset()  # once: the next reset starts clean episodes
    assert torch.isfinite(env.engine.state).all() and not env.engine.invalid.any()
    for _ in range(2):
        td = _one_step_with(env, td, action)  # a clean episode plays to its end without an error
    env.reset()


def test_a_step_past_the_deadline_after_a_partial_reset_is_reported_once():
    env = ConsensusTorchEnv(scenario="paper_fig1", batch_size=2, n_intervals=2, seed=0)
    td = env.reset()
    action = torch.zeros((2, env.n_agents, 2), dtype=torch.float64)
    td = _one_step_with(env, td, action)
    td.set("_reset", torch.tensor([[True], [False]]))
    td = env.reset(td)  # the clocks part: episode 1 is one step from T_s
    for _ in range(2):
        td = _one_step_with(env, td, action)  # the second steps episode 1 past T_s (flagged on the device)
    with pytest.raises(ArgumentError, match=r"actions: episodes \[1\].*past T_s"):
        env.reset()
    env.reset()
    assert env.engine.steps is None and env.engine.k == 0 and not env.engine.invalid.any()


@pytest.mark.parametrize(
    "mask",
    [
        torch.tensor([[1.0], [0.0], [1.0], [0.0]]),
        torch.tensor([[1], [0], [1], [0]]),
        torch.tensor([True, False, True]),
    ],
    ids=["float", "int", "wrong-shape"],
)
def test_a_bad_reset_mask_is_refused_by_name_and_changes_nothing(mask):
    env = ConsensusTorchEnv(scenario="generalist", batch_size=4, seed=0)
    module = reference_policy(env)
    td = env.reset()
    for _ in range(3):
        td = step_mdp(env.step(module(td)))
    state, k, topologies = env.engine.state.clone(), env.engine.k, list(env.engine.topologies)
    graphs = env.engine.graphs
    with pytest.raises(ArgumentError, match=r"_reset: expected a torch\.bool mask of shape \(4, 1\)"):
        env._reset(TensorDict({"_reset": mask}, batch_size=[]))
    assert torch.equal(env.engine.state, state) and env.engine.k == k and env.engine.steps is None
    assert env.engine.graphs is graphs and all(a is b for a, b in zip(env.engine.topologies, topologies, strict=True))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(batch_size=-1), "batch_size: expected an integer"),
        (dict(batch_size=2.0), "batch_size: expected an integer"),
        (dict(batch_size=True), "batch_size: expected an integer"),
        (dict(batch_size="2"), "batch_size: expected an integer"),
        (dict(seed=-1), "seed: expected an integer"),
        (dict(seed=1.5), "seed: expected an integer"),
        (dict(seed=True), "seed: expected an integer"),
        (dict(seed=2**64), "seed: expected an integer"),
        (dict(check_values=1), "check_values: expected True or False"),
        (dict(check_values="yes"), "check_values: expected True or False"),
        (dict(obs_format="dict"), "obs_format: the TorchRL environment gives flat observations"),
        (dict(device="mps"), "device: "),
    ],
    ids=lambda value: repr(value)[:40],
)
def test_the_batch_arguments_are_checked_like_the_pettingzoo_envs(kwargs, message):
    with pytest.raises(ArgumentError, match=message):
        ConsensusTorchEnv(scenario="paper_fig1", **kwargs)


@pytest.mark.parametrize("seed", [-1, 1.5, True, 2**64])
def test_set_seed_refuses_a_bad_seed_and_keeps_the_generators(seed):
    env = ConsensusTorchEnv(scenario="paper_fig1", batch_size=2, seed=0)
    rng, host_rng = env.engine.rng, env._host_rng
    with pytest.raises(ArgumentError, match="seed: expected an integer"):
        env.set_seed(seed)
    assert env.engine.rng is rng and env._host_rng is host_rng


def test_one_agent_and_the_meta_device_are_refused_at_construction():
    # Issue 24: N = 1 crashed at reset, and device="meta" raised NotImplementedError at the first reset.
    with pytest.raises(ArgumentError, match=r"^n_agents: expected an integer in \[2, "):
        ConsensusTorchEnv(topology="complete", n_agents=1)
    with pytest.raises(ArgumentError, match=r"^device: expected a device that holds values \(cpu, cuda\), got 'meta'"):
        ConsensusTorchEnv(scenario="paper_fig1", device="meta")


@pytest.mark.parametrize(
    "kwargs",
    [{"options": {"x0": np.zeros(6)}}, {"options": {"bogus": 1}}, {"x0": np.zeros(6)}],
    ids=["options x0", "options bogus", "x0"],
)
def test_reset_keywords_are_refused_by_name_and_nothing_changes(kwargs):
    # TorchRL hands reset's keywords to _reset, which read none of them: an intended initial state was
    # silently dropped (issue 24).
    env = ConsensusTorchEnv(scenario="paper_fig1", batch_size=2, seed=0)
    td = env.reset()
    td.set((GROUP, "action"), torch.zeros((2, env.n_agents, 2), dtype=torch.float64))
    env.step(td)
    state, k = env.engine.state.clone(), env.engine.k
    name = next(iter(kwargs))
    with pytest.raises(ArgumentError, match=rf"^{name}: ConsensusTorchEnv.reset takes no keyword options"):
        env.reset(**kwargs)
    assert torch.equal(env.engine.state, state) and env.engine.k == k == 1


@pytest.mark.parametrize("key", ["X0", "x0", "initial_state"])
def test_a_reset_tensordict_with_an_entry_the_env_does_not_read_is_refused_by_name(key):
    # Issue 33: reset(TensorDict({"X0": ...})) dropped the intended initial state silently, where the
    # parallel env's reset refuses an unknown option key.
    env = ConsensusTorchEnv(scenario="paper_fig1", batch_size=2, seed=0)
    td = env.reset()
    td.set((GROUP, "action"), torch.zeros((2, env.n_agents, 2), dtype=torch.float64))
    td = env.step(td)  # a step's own output, "next" included, is a reset tensordict the env accepts
    state, k = env.engine.state.clone(), env.engine.k
    with pytest.raises(ArgumentError, match=rf"^tensordict: .*unknown key\(s\) \['{key}'\]"):
        env.reset(TensorDict({key: torch.zeros((2, env.n_agents, 2))}, batch_size=[2]))
    assert torch.equal(env.engine.state, state) and env.engine.k == k == 1
    td.set("_reset", torch.tensor([[True], [False]]))
    env.reset(td)
    assert env._cycles.tolist() == [0, 1]  # the partial reset of a step's output still runs
