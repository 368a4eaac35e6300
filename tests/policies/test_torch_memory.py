"""Memory and message passing in the torch back end: ``--policy-arch gru`` and ``gnn`` (fxc_env.policies.torch_memory)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from fxc_env import make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine
from fxc_env.policies.torch_memory import MessagePassingActor, RecurrentActor, interval_graph
from fxc_env.policies.torch_policy import POLICY_FORMAT, TorchPolicy, load_torch_policy, mlp
from fxc_env.training import TrainArgs, train
from fxc_env.training.args import check_train_args
from fxc_env.training.backends.torch_ppo import latest_torch_checkpoint

# 2 episodes x 6 agents, one whole episode (K = 200) per rollout: 2400 timesteps a rollout.
PER_ROLLOUT = 2400


def short_args(tmp_path, **changes) -> TrainArgs:
    base = {
        "scenario": "paper_fig1",
        "backend": "torch",
        "n_envs": 2,
        "timesteps": PER_ROLLOUT,
        "checkpoint_every": PER_ROLLOUT,
        "run_dir": str(tmp_path / "run"),
        "progress_bar": False,
    }
    return TrainArgs(**{**base, **changes})


def record_of(actor: torch.nn.Module, config, arch: str, **entries) -> dict:
    """A policy record of ``actor`` (random weights), as the trainer writes it."""
    return {
        "format": POLICY_FORMAT,
        "arch": arch,
        "obs_size": config.layout.size,
        "action_size": config.action_size,
        "action_bound": float(config.action_bound),
        "hidden": [16],
        "activation": "tanh",
        **entries,
        "actor": actor.state_dict(),
        "log_std": torch.zeros(config.action_size),
        "env": {},
        "timesteps": 0,
    }


def gru_policy(config, seed: int = 0) -> TorchPolicy:
    torch.manual_seed(seed)
    clock = config.layout.clock_end - 1
    actor = RecurrentActor(config.layout.size, config.action_size, (16,), "tanh", 8, clock)
    for parameter in actor.head.parameters():  # larger than the initial 0.01 gain, so that actions vary
        torch.nn.init.normal_(parameter, std=0.5)
    return TorchPolicy(record_of(actor, config, "gru", gru_size=8, clock_index=clock))


def play(engine: ConsensusEngine, policy, seed: int, graph: bool = False) -> np.ndarray:
    """One seeded batch of episodes; the actions ``(K, B, N, 2)``."""
    draws = [engine.draw_episode(np.random.default_rng([seed, b])) for b in range(engine.n_episodes)]
    engine.reset_from_draws(draws)
    actions = []
    while not engine.done:
        obs = engine.observations()
        act = policy(obs, graph=interval_graph(engine)) if graph else policy(obs)
        actions.append(act)
        engine.step(act)
    return np.array(actions)


# ----------------------------------------------------------------------------------- gru
def test_gru_memory_resets_per_episode_and_is_used_within_one():
    config = make_config("paper_fig1", n_intervals=10)
    policy = gru_policy(config)
    engine = ConsensusEngine(config, n_episodes=2)
    first = play(engine, policy, seed=3)
    second = play(engine, policy, seed=3)  # no reset() call: the clock's k = 0 resets the memory
    assert np.array_equal(first, second)
    # Within an episode the memory matters: a fresh policy on the same observation acts otherwise.
    engine.reset_from_draws([engine.draw_episode(np.random.default_rng([3, b])) for b in range(2)])
    policy.reset()
    policy(engine.observations())
    engine.step(first[0])
    obs = engine.observations()
    assert np.array_equal(policy(obs), first[1])
    fresh = gru_policy(config)
    fresh._hidden = None
    with torch.no_grad():  # the same weights, a zero memory, on the second observation (k = 1, no reset)
        zero = fresh.module.initial_state(obs.shape[:-1])
        memoryless, _ = fresh.module.step(torch.as_tensor(obs, dtype=torch.float32), zero)
    assert not np.allclose(memoryless.clamp(-2, 2).double().numpy(), first[1])


def test_gru_sequence_recomputes_the_steps_with_resets_mid_sequence():
    """The update reruns the GRU over a rollout in stretches; it must give the collection's means,
    also where one sequence's clock restarts (a partial reset) and another's does not."""
    torch.manual_seed(1)
    actor = RecurrentActor(5, 2, (8,), "tanh", 6, clock_index=4)
    obs = torch.randn(7, 3, 5)
    obs[:, :, 4] = torch.rand(7, 3) + 0.1
    obs[0, :, 4] = 0.0  # every sequence starts an episode at t = 0
    obs[4, 1, 4] = 0.0  # sequence 1 restarts at t = 4
    hidden = torch.randn(3, 6)
    means, last = actor.sequence(obs, hidden)
    stepped, h = [], hidden
    for t in range(7):
        mean, h = actor.step(obs[t], h)
        stepped.append(mean)
    assert torch.allclose(means, torch.stack(stepped), atol=1e-6)
    assert torch.allclose(last, h, atol=1e-6)
    # Without the restart, sequence 1 would remember t < 4.
    unrestarted = obs.clone()
    unrestarted[4, 1, 4] = 0.5
    other, _ = actor.sequence(unrestarted, hidden)
    assert not torch.allclose(other[4:, 1], means[4:, 1])
    assert torch.equal(other[:, 0], means[:, 0])


# ----------------------------------------------------------------------------------- gnn
def hops_upstream(topology, agent: int) -> dict[int, int]:
    """Distance from each agent j to ``agent`` along edges j -> i (breadth first over in-neighbours)."""
    index, mask = topology.neighbour_index[0], topology.neighbour_mask[0]
    distance, frontier = {agent: 0}, [agent]
    while frontier:
        nxt = []
        for i in frontier:
            for j in index[i][mask[i]]:
                if int(j) not in distance:
                    distance[int(j)] = distance[i] + 1
                    nxt.append(int(j))
        frontier = nxt
    return distance


@pytest.mark.parametrize("rounds", [1, 2])
def test_gnn_output_depends_on_states_exactly_rounds_plus_one_hops_upstream(rounds):
    config = make_config(None, topology="ring", n_agents=8, n_intervals=10)
    torch.manual_seed(0)
    actor = MessagePassingActor(config.layout.size, config.action_size, (16,), "tanh", 8, rounds)
    for parameter in actor.head.parameters():
        torch.nn.init.normal_(parameter, std=0.5)
    policy = TorchPolicy(record_of(actor, config, "gnn", embed_size=8, rounds=rounds))
    engine = ConsensusEngine(config, n_episodes=1)
    rng = np.random.default_rng(0)
    x0, v0 = rng.uniform(-5, 5, (1, 8, 1)), rng.uniform(-2, 2, (1, 8, 1))
    agent = 7
    distance = hops_upstream(config.topology, agent)

    def action_of_agent(x):
        engine.reset(x, v0)
        return policy(engine.observations(), graph=interval_graph(engine))[0, agent]

    base = action_of_agent(x0)
    for j in range(8):
        moved = x0.copy()
        moved[0, j, 0] += 0.7
        changed = not np.allclose(action_of_agent(moved), base, rtol=0, atol=1e-9)
        # Messages reach `rounds` hops; an observation holds its in-neighbours' states: one hop more.
        assert changed == (distance[j] <= rounds + 1), (j, distance[j])
    with pytest.raises(ArgumentError, match=r"^graph: a 'gnn' policy passes messages along the interval graph"):
        policy(engine.observations())


# --------------------------------------------------------------------------- policy files
def test_a_policy_file_without_arch_loads_as_the_mlp(tmp_path):
    config = make_config("paper_fig1")
    torch.manual_seed(0)
    net = mlp(config.layout.size, config.action_size, (16,), "tanh", 1.0)
    record = record_of(net, config, "mlp")
    del record["arch"]
    torch.save(record, tmp_path / "policy.pt")
    policy = load_torch_policy(tmp_path)
    obs = np.random.default_rng(0).normal(size=(3, config.layout.size))
    assert policy.arch == "mlp"
    expected = net(torch.as_tensor(obs, dtype=torch.float32)).clamp(-2, 2).double().detach().numpy()
    assert np.array_equal(policy(obs), expected)


def test_an_unknown_arch_is_refused_by_name():
    config = make_config("paper_fig1")
    record = record_of(mlp(config.layout.size, 2, (16,), "tanh", 1.0), config, "transformer")
    with pytest.raises(ArgumentError, match=r"^arch: expected one of \('mlp', 'gru', 'gnn'\), got 'transformer'"):
        TorchPolicy(record)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"policy_arch": "lstm"}, r"^policy_arch: expected one of"),
        (
            {"policy_arch": "gru", "backend": "sb3"},
            r"^policy_arch: only the torch and diff backends have a choice of actor",
        ),
    ],
)
def test_bad_policy_arch_is_named(tmp_path, change, message):
    with pytest.raises(ArgumentError, match=message):
        check_train_args(short_args(tmp_path, **change))


# ----------------------------------------------------------------------------- training
@pytest.mark.slow
@pytest.mark.parametrize("arch", ["gru", "gnn"])
def test_resume_gives_the_uninterrupted_run_bit_for_bit_and_the_file_round_trips(tmp_path, arch):
    train(short_args(tmp_path, policy_arch=arch))
    run_dir = train(short_args(tmp_path, policy_arch=arch, resume=True, timesteps=2 * PER_ROLLOUT))
    straight = train(short_args(tmp_path, policy_arch=arch, timesteps=2 * PER_ROLLOUT, run_dir=str(tmp_path / "s")))
    resumed = torch.load(run_dir / "policy.pt", weights_only=True)
    uninterrupted = torch.load(straight / "policy.pt", weights_only=True)
    assert resumed["arch"] == arch
    assert all(torch.equal(resumed["actor"][k], uninterrupted["actor"][k]) for k in uninterrupted["actor"])
    assert torch.equal(resumed["log_std"], uninterrupted["log_std"])
    # The file plays like the checkpoint it came from, on the numpy engine, whole episodes.
    policy, from_checkpoint = load_torch_policy(run_dir), load_torch_policy(latest_torch_checkpoint(run_dir))
    config = make_config("paper_fig1", obs_slots=4, initial_state="random")
    engine = ConsensusEngine(config, n_episodes=2)
    graph = arch == "gnn"
    actions = play(engine, policy, seed=5, graph=graph)
    assert np.array_equal(actions, play(engine, from_checkpoint, seed=5, graph=graph))
    assert np.all(np.isfinite(engine.batch_metrics()["relative_deadline_error"]))


@pytest.mark.slow
def test_gru_with_a_central_critic_and_rollouts_shorter_than_an_episode(tmp_path):
    """T = 100 < K = 200: the memory is carried from one rollout into the next (the update reruns
    from the stored start), and the central critic's episodes are gathered per minibatch."""
    import yaml

    from fxc_env.training.args import HYPERPARAMS

    table = yaml.safe_load(HYPERPARAMS.read_text())
    entry = table["paper_fig1"]
    entry["torch_ppo"] = {**entry["torch_ppo"], "rollout_steps": 100, "gru_size": 8}
    path = tmp_path / "hyperparams.yml"
    path.write_text(yaml.safe_dump({"paper_fig1": entry}))
    run_dir = train(
        short_args(tmp_path, policy_arch="gru", critic="central", hyperparams=str(path), timesteps=PER_ROLLOUT)
    )
    record = torch.load(run_dir / "policy.pt", weights_only=True)
    assert record["gru_size"] == 8 and record["timesteps"] == PER_ROLLOUT
    assert all(torch.all(torch.isfinite(v)) for v in record["actor"].values())


def test_a_schedule_gru_plans_linearly_in_the_rows_with_one_gain_for_one_schedule():
    """``gru_input="schedule"``: the GRU reads mask and clock only, the head is linear in the rows, so
    scaling an agent's rows scales its plan, zero rows give a zero plan, and agents with the same schedule
    history get the same gain (the structure of eq. 11 and of the minimum-time law)."""
    config = make_config(None, topology="ring", n_agents=5, obs_slots=1, n_intervals=8)
    layout = config.layout
    torch.manual_seed(2)
    actor = RecurrentActor(
        layout.size, 2, (16,), "tanh", 8, layout.clock_end - 1, gru_input="schedule", rows_end=layout.rows_end
    )
    for parameter in actor.head.parameters():
        torch.nn.init.normal_(parameter, std=0.5)
    engine = ConsensusEngine(config, n_episodes=1)
    engine.reset_from_draws([engine.draw_episode(np.random.default_rng(4))])
    observations = []
    while not engine.done:
        observations.append(np.asarray(engine.observations()[0]))
        engine.step(np.zeros((1, 5, 2)))
    obs = torch.as_tensor(np.array(observations), dtype=torch.float32)  # [K, N, obs]
    means, _ = actor.sequence(obs, actor.initial_state((5,)))
    scaled = obs.clone()
    scaled[..., : layout.rows_end] *= -3.0
    assert torch.allclose(actor.sequence(scaled, actor.initial_state((5,)))[0], -3.0 * means, atol=1e-5)
    zero = obs.clone()
    zero[..., : layout.rows_end] = 0.0
    assert torch.equal(actor.sequence(zero, actor.initial_state((5,)))[0], torch.zeros_like(means))
    # The observation-reading GRU is not linear in the rows.
    free = RecurrentActor(layout.size, 2, (16,), "tanh", 8, layout.clock_end - 1)
    for parameter in free.parameters():
        torch.nn.init.normal_(parameter, std=0.5)
    plain, _ = free.sequence(obs, free.initial_state((5,)))
    assert not torch.allclose(free.sequence(scaled, free.initial_state((5,)))[0], -3.0 * plain, atol=1e-3)


@pytest.mark.slow
@pytest.mark.parametrize("arch", ["gru", "gnn"])
def test_fxc_evaluate_plays_a_gru_or_gnn_run(tmp_path, capsys, arch):
    """The benchmark carries a gru's memory through each episode and hands a gnn its interval graph."""
    import csv

    from fxc_env.cli import main

    run_dir = train(short_args(tmp_path, policy_arch=arch))
    out = tmp_path / "evaluate"
    # Scored inside the run's training domain (paper_fig1, as the file records).
    arguments = ["evaluate", "--policy", str(run_dir), "--scenario", "paper_fig1", "--seeds", "2"]
    assert main([*arguments, "--out", str(out), "--no-progress", "--workers", "1"]) == 0
    capsys.readouterr()
    with (out / "episodes.csv").open() as handle:
        rows = [row for row in csv.DictReader(handle) if row["policy"] == "learned:run"]
    assert len(rows) == 2 and all(float(row["relative_deadline_error"]) >= 0 for row in rows)  # ran, not refused
