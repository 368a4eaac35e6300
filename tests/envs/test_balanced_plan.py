"""``action_mode="plan_balanced"``: plans whose two parts move the deadline's disagreement alike per unit.

The velocity part is in units of ``s_i / T_s`` and the local scale weighs velocities by ``T_s``
(``s_i = max(|x_j - x_i|, T_s |v_j - v_i|)``), so Gaussian noise of 5 % of the box on either part
costs less than a decade over an episode, where ``plan``'s velocity part blows up; the reference
emits the same plans in these units and scores what it scores under ``plan`` (docs: environment.md,
"Action space", "Conditioning of the action").
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import fxc_env
from fxc_env import make_config
from fxc_env.analysis.conditioning import NoiseRow, final_ratios
from fxc_env.baselines.laws.leader_follower import LeaderFollowerPolicy
from fxc_env.baselines.laws.minimum_time import MinimumTimePolicy
from fxc_env.config.tasks import task_kwargs
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine
from fxc_env.envs.torch_env import ConsensusTorchEnv
from fxc_env.policies.reference import ReferencePolicy

SEEDS = (1000, 1001, 1002, 1003)


def _reference_ratios(mode: str, n_episodes: int = 3, **kwargs: object) -> np.ndarray:
    """``D(T_s)/D(0)`` of the reference on the engine (numpy), seeds 0 .. n - 1."""
    config = make_config(kwargs.pop("scenario", None), action_mode=mode, initial_state="random", **kwargs)
    engine, policy = ConsensusEngine(config, n_episodes), ReferencePolicy(config)
    engine.reset_from_draws([engine.draw_episode(np.random.default_rng(seed)) for seed in range(n_episodes)])
    for _ in range(config.n_intervals):
        engine.step(policy.act(engine.observations()))
    return engine.current_disagreement / engine.initial_disagreement


@pytest.mark.parametrize(
    "kwargs",
    [
        {"scenario": "paper_fig1", "n_intervals": 50},
        {"scenario": "paper_fig1", "n_intervals": 50, "obs_mode": "raw"},
        {"scenario": "saturated", "n_intervals": 50},
        {"n_agents": 20, "topology": "ring", "schedule": "uniform", "n_intervals": 50, "dim": 2},
        {"n_agents": 2048, "topology": "ring", "n_intervals": 6},  # the observations' blocked numpy path
    ],
    ids=["paper_fig1", "raw", "saturated", "uniform-planar", "blocked"],
)
def test_the_reference_scores_under_plan_balanced_what_it_scores_under_plan(kwargs):
    plan = _reference_ratios("plan", **kwargs)
    balanced = _reference_ratios("plan_balanced", **kwargs)
    np.testing.assert_allclose(balanced, plan, rtol=1e-6)  # round-off, amplified by the input limit's clipping


def test_the_reference_scores_the_same_on_torch():
    final = {}
    for mode in ("plan", "plan_balanced"):
        env = ConsensusTorchEnv(batch_size=3, seed=5, **{**task_kwargs("rings20-v2"), "action_mode": mode})
        policy = ReferencePolicy(env.config)
        td = env.reset()
        while True:
            td.set(("agents", "action"), policy.act(td["agents", "observation"]))
            td = env.step(td)["next"]
            if td["done"].all():
                break
        final[mode] = env.engine.current_disagreement / env.engine.initial_disagreement
    assert torch.allclose(final["plan_balanced"], final["plan"], rtol=1e-9, atol=0)


def test_velocities_are_observed_and_scaled_as_the_deadline_weighs_them():
    """Rows ``(x_j - x_i) / s_i`` and ``T_s (v_j - v_i) / s_i`` with ``s_i = max(|x_j - x_i|, T_s |v_j - v_i|)``."""
    x0, v0 = np.array([0.0, 1.0, 3.0]), np.array([0.0, 0.5, -0.01])
    env = fxc_env.parallel_env(n_agents=3, topology="ring", action_mode="plan_balanced")  # i receives from i - 1
    observations, _ = env.reset(options={"x0": x0, "v0": v0})
    T_s = env.unwrapped.config.settling_time
    for i in range(3):
        dx, dv = x0[i - 1] - x0[i], v0[i - 1] - v0[i]
        scale = max(abs(dx), T_s * abs(dv))
        np.testing.assert_allclose(observations[f"agent_{i}"][:2], [dx / scale, T_s * dv / scale], rtol=1e-15)


def test_one_unit_of_either_part_moves_an_agent_by_its_scale_in_the_deadlines_units():
    """``alpha_x = 1`` moves x(t_{k+1}) by ``s_i``; ``alpha_v = 1`` moves ``T_s v(t_{k+1})`` by ``s_i``, on any interval."""
    config = make_config(None, n_agents=3, topology="ring", action_mode="plan_balanced", n_intervals=50)
    x0, v0 = np.array([[0.0], [1.0], [3.0]]), np.array([[0.0], [0.5], [-0.01]])
    for k in (0, 49):
        moved = []
        for action in ([0.0, 0.0], [1.0, 0.0], [0.0, 1.0]):
            engine = ConsensusEngine(config, 1)
            engine.reset(x0[None], v0[None])
            for _ in range(k):
                engine.step(np.zeros((1, 3, 2)))
            scale = float(engine.local_scale()[0, 0])
            engine.step(np.array([[action, [0.0, 0.0], [0.0, 0.0]]]))
            moved.append((engine.state[0, 0, :, 0] * [1.0, config.settling_time], scale))
        (coast, scale), (x_moved, _), (v_moved, _) = moved
        np.testing.assert_allclose([x_moved[0] - coast[0], v_moved[1] - coast[1]], [scale, scale], rtol=1e-9)
        # Each part moves its own component only: a planned velocity change keeps x(t_{k+1}) where coasting puts it.
        np.testing.assert_allclose([x_moved[1], v_moved[0]], [coast[1], coast[0]], rtol=0, atol=1e-9 * scale)


@pytest.mark.parametrize("task", ["rings20-v2", "paper_fig1-v2"])
def test_five_percent_of_the_box_on_either_part_costs_less_than_a_decade(task):
    settings = task_kwargs(task)
    medians = {
        (centre, part): float(np.median(final_ratios(settings, centre, part, SEEDS)))
        for centre in ("zero", "reference")
        for part in (None, 0, 1)
    }
    medians[("uniform", None)] = 1.0
    assert NoiseRow(task, "plan_balanced", 50, 1.0, medians).well_conditioned(), medians


def test_plans_in_v1_units_are_not_so_conditioned():
    settings = {**task_kwargs("rings20-v1"), "n_intervals": 50}
    noisy = np.median(final_ratios(settings, "reference", 1, SEEDS))
    assert noisy > 10 * np.median(final_ratios(settings, "reference", None, SEEDS))


@pytest.mark.parametrize("law", [MinimumTimePolicy, LeaderFollowerPolicy])
def test_a_law_that_emits_plan_units_refuses_plan_balanced_by_name(law):
    with pytest.raises(ArgumentError, match=r"action_mode: .* not 'plan_balanced' units"):
        law(make_config(None, n_agents=6, topology="ring", action_mode="plan_balanced"))


def test_plan_balanced_is_refused_for_agents_it_does_not_describe():
    with pytest.raises(ArgumentError, match="action_mode: 'single_integrator' agents take plans only"):
        make_config(None, agent_model="single_integrator", action_mode="plan_balanced")
