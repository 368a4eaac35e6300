"""``action_mode="residual"``: the action is a correction added to the paper's plan (eq. 11).

The zero action replays the reference's episode (the PettingZoo env, the VecEnv and the
TorchRL env share the engine), a nonzero one adds exactly to the plan, and whatever emits
whole plans or inputs refuses the mode by name (docs: results.md, "PPO from scratch").
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import fxc_env
from fxc_env import make_config
from fxc_env.baselines.laws.leader_follower import LeaderFollowerPolicy
from fxc_env.baselines.laws.minimum_time import MinimumTimePolicy
from fxc_env.baselines.laws.policy import HoldPolicy
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine
from fxc_env.envs.torch_env import ConsensusTorchEnv
from fxc_env.policies.reference import ReferencePolicy

RING = {"n_agents": 20, "topology": {"family": "ring"}, "initial_state": "random", "obs_slots": 1}


def _parallel_states(mode: str, scenario: str | None, **kwargs: object) -> np.ndarray:
    """Every state of one seeded PettingZoo episode under the reference policy."""
    env = fxc_env.parallel_env(scenario, action_mode=mode, **kwargs)
    policy = ReferencePolicy(env)
    observations, _ = env.reset(seed=3)
    states = []
    while env.agents:
        observations, *_ = env.step({agent: policy(obs) for agent, obs in observations.items()})
        states.append(env.unwrapped.engine.state.copy())
    return np.array(states)


@pytest.mark.parametrize(
    ("scenario", "kwargs"),
    [("paper_fig1", {}), ("paper_fig1", {"obs_mode": "raw"}), (None, {**RING, "obs_noise": 0.01, "link_dropout": 0.1})],
)
def test_zero_residual_replays_the_reference_episode(scenario: str | None, kwargs: dict) -> None:
    plan = _parallel_states("plan", scenario, **kwargs)
    residual = _parallel_states("residual", scenario, **kwargs)
    np.testing.assert_allclose(residual, plan, rtol=0, atol=1e-12 * np.abs(plan).max())


def test_zero_residual_replays_the_reference_on_torch() -> None:
    final = {}
    for mode in ("plan", "residual"):
        env = ConsensusTorchEnv(scenario=None, batch_size=3, action_mode=mode, seed=5, **RING)
        policy = ReferencePolicy(env.config)
        td = env.reset()
        while True:
            td.set(("agents", "action"), policy.act(td["agents", "observation"]))
            td = env.step(td)["next"]
            if td["done"].all():
                break
        final[mode] = env.engine.state.clone()
    assert torch.allclose(final["residual"], final["plan"], rtol=0, atol=1e-12 * float(final["plan"].abs().max()))


def test_the_reference_emits_zeros_in_residual_mode() -> None:
    env = fxc_env.parallel_env("paper_fig1", action_mode="residual")
    observations, _ = env.reset(seed=0)
    assert all(not ReferencePolicy(env)(obs).any() for obs in observations.values())


@pytest.mark.parametrize("obs_mode", ["normalized", "raw"])
def test_a_residual_adds_exactly_to_the_plan(obs_mode: str) -> None:
    """One interval of (residual r) equals one of (plan = eq. 11's plan + r'), and the inputs agree.

    Normalized: ``r' = (r_x, r_v T / T_s)``, a velocity correction of ``s r_v / T_s`` on every interval
    of the paper's shrinking schedule (the card's Action Space); raw: ``r' = r``.
    """
    engines = {}
    for mode in ("plan", "residual"):
        engine = ConsensusEngine(make_config(None, action_mode=mode, obs_mode=obs_mode, schedule="paper", **RING), 4)
        rng = np.random.default_rng(7)
        engine.reset_from_draws([engine.draw_episode(rng) for _ in range(4)])
        for _ in range(5):  # a few intervals in, the rows are not the initial ones
            engine.step(
                np.zeros((4, 20, 2))
                if mode == "residual"
                else ReferencePolicy(engine.config).act(engine.observations())
            )
        engines[mode] = engine
    residual = 0.3 * np.random.default_rng(1).standard_normal((4, 20, 2))
    engine = engines["plan"]
    as_plan = residual.copy()
    if obs_mode == "normalized":
        as_plan[..., 1] *= engine.current_interval() / engine.config.settling_time
        assert engine.current_interval() / engine.config.settling_time < 0.05  # the scaling matters here
    plan = ReferencePolicy(engine.config).act(engine.observations()) + as_plan
    u_plan = engines["plan"].inputs_from_actions(plan)
    u_residual = engines["residual"].inputs_from_actions(residual)
    for a, b in zip(u_plan, u_residual, strict=True):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * np.abs(a).max())
    engines["plan"].step(plan)
    engines["residual"].step(residual)
    expected = engines["plan"].state
    np.testing.assert_allclose(engines["residual"].state, expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def test_residual_is_refused_where_it_cannot_be_honoured() -> None:
    with pytest.raises(ArgumentError, match=r"action_mode: 'single_integrator' agents take plans only.*'residual'"):
        make_config("paper_fig1", agent_model="single_integrator", action_mode="residual")
    config = make_config("paper_fig1", action_mode="residual")
    for law in (MinimumTimePolicy, LeaderFollowerPolicy):
        with pytest.raises(ArgumentError, match=r"action_mode: .* not 'residual' corrections"):
            law(config)
    with pytest.raises(ArgumentError, match=r"action_mode: HoldPolicy .* needs action_mode='accel', got 'residual'"):
        HoldPolicy(config)


def test_ppo_can_start_as_the_reference_in_residual_mode() -> None:
    """``actor_out_gain: 0`` starts the actor's output at exactly zero: the untrained policy is eq. (11)."""
    from fxc_env.training.backends.torch_ppo import ActorCritic, PPOSettings

    config = make_config(None, action_mode="residual", **RING)
    settings = PPOSettings.from_mapping({"actor_out_gain": 0.0}, config)
    model = ActorCritic(config.layout.size, config.action_size, config.layout.size, settings)
    assert not model.actor(torch.randn(7, config.layout.size)).any()
    with pytest.raises(ArgumentError, match=r"hyperparams: torch_ppo.actor_out_gain"):
        PPOSettings.from_mapping({"actor_out_gain": -1.0}, config)


def test_zero_residual_replays_the_reference_in_the_vec_env() -> None:
    states = {}
    for mode in ("plan", "residual"):
        venv = fxc_env.ConsensusVecEnv(2, scenario=None, action_mode=mode, **RING)
        venv.seed(3)
        policy = ReferencePolicy(venv)
        obs = venv.reset()
        for _ in range(100):
            obs, *_ = venv.step(policy(obs))
        states[mode] = venv.engine.state.copy()
    scale = np.abs(states["plan"]).max()
    np.testing.assert_allclose(states["residual"], states["plan"], rtol=0, atol=1e-12 * scale)
