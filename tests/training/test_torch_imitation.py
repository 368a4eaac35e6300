"""fxc_env.training.recipes.recurrent_imitation: cloning the minimum-time law into a schedule-reading gru policy."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from fxc_env import make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine
from fxc_env.policies.torch_memory import RecurrentActor
from fxc_env.policies.torch_policy import load_torch_policy
from fxc_env.training.recipes import recurrent_imitation


def ring_observations(n_agents: int = 5, n_intervals: int = 12) -> torch.Tensor:
    """Observations ``[K, N, obs]`` of one seeded episode on a ring (one slot), agents coasting."""
    config = make_config(None, topology="ring", n_agents=n_agents, obs_slots=1, n_intervals=n_intervals)
    engine = ConsensusEngine(config, n_episodes=1)
    engine.reset_from_draws([engine.draw_episode(np.random.default_rng(7))])
    observations = []
    while not engine.done:
        observations.append(np.asarray(engine.observations()[0]))
        engine.step(np.zeros((1, n_agents, 2)))
    return torch.as_tensor(np.array(observations), dtype=torch.float32)


def test_polish_recovers_a_last_layer_the_features_can_express():
    obs = ring_observations()
    layout = make_config(None, topology="ring", n_agents=5, obs_slots=1).layout
    torch.manual_seed(0)
    teacher = RecurrentActor(
        layout.size, 2, (16,), "tanh", 8, layout.clock_end - 1, gru_input="schedule", rows_end=layout.rows_end
    )
    torch.nn.init.normal_(teacher.head.net[-1].weight, std=1.0)
    with torch.no_grad():
        targets, _ = teacher.sequence(obs, teacher.initial_state((5,)))
    student = copy.deepcopy(teacher)
    torch.nn.init.normal_(student.head.net[-1].weight, std=1.0)  # a wrong last layer, the same features
    torch.nn.init.normal_(student.head.net[-1].bias, std=1.0)
    with torch.no_grad():
        before = student.sequence(obs, student.initial_state((5,)))[0]
    assert not torch.allclose(before, targets, atol=1e-2)
    residual = recurrent_imitation.polish(student, obs, targets)
    assert residual < 1e-5
    with torch.no_grad():
        after = student.sequence(obs, student.initial_state((5,)))[0]
    assert torch.allclose(after, targets, atol=1e-4)
    observing = RecurrentActor(layout.size, 2, (16,), "tanh", 8, layout.clock_end - 1)
    with pytest.raises(ArgumentError, match=r"^polish: only the schedule form"):
        recurrent_imitation.polish(observing, obs, targets)


@pytest.mark.slow
def test_the_trained_record_is_a_gru_policy_file_that_knows_its_task(tmp_path):
    record, made = recurrent_imitation.train(
        sizes=(4,), rounds=0, episodes=1, steps=1, batch=4, gru_size=8, hidden=(8,), log=lambda _: None
    )
    assert made["sizes"] == [4] and "round_0" in made
    torch.save(record, tmp_path / "policy.pt")
    with pytest.warns(UserWarning, match="n_agents: trained on 4, this environment has 20"):  # N is not read
        policy = load_torch_policy(tmp_path, recurrent_imitation.task_config(20), allow_out_of_domain=True)
    assert policy.training_domain["n_agents"] == [4, 4]  # the trainer records its domain
    assert policy.arch == "gru" and policy.training_settings["obs_slots"] == 1
    assert policy.training_settings["schedule"] == "paper" and policy.action_bound == 20.0
    with pytest.raises(ArgumentError, match=r"schedule"):
        load_torch_policy(tmp_path, make_config(None, topology="ring", n_agents=20, obs_slots=1, schedule="uniform"))


def test_the_shipped_rings_gru_beats_the_reference_tenfold_on_rings_of_20():
    from pathlib import Path

    import fxc_env

    path = Path(fxc_env.__file__).parent / "pretrained" / "rings_gru.pt"
    assert path.stat().st_size < 2**20
    policy = load_torch_policy(path, recurrent_imitation.task_config(20))
    assert policy.arch == "gru" and policy.module.gru_input == "schedule"
    result = recurrent_imitation.evaluate(policy, 20, range(3))
    assert result["median"] * 10 < result["reference_median"]


def test_rings_gru_loads_by_name_into_a_plain_ring_of_20_and_beats_the_reference_there():
    import fxc_env
    from fxc_env.policies.learned import load_learned_policy
    from fxc_env.policies.reference import ReferencePolicy

    def deadline_error(make_policy, act) -> float:
        env = fxc_env.parallel_env(topology="ring", n_agents=20, n_intervals=200, settling_time=20.0)
        observations, infos = env.reset(seed=3)
        policy = make_policy(env)
        while env.agents:
            observations, _, _, _, infos = env.step(act(policy, observations))
        return infos["agent_0"]["episode"]["relative_deadline_error"]

    def per_agent(policy, observations):
        return {agent: policy(o) for agent, o in observations.items()}

    ours = deadline_error(lambda env: load_learned_policy("rings_gru", env), lambda policy, obs: policy(obs))
    assert ours * 10 < deadline_error(ReferencePolicy, per_agent)
    policy = load_learned_policy("rings_gru")
    with pytest.raises(
        ArgumentError, match=r"^observations: TorchPolicy from .*rings_gru.pt acts for every agent at once"
    ):
        policy(np.zeros(policy.obs_size))
