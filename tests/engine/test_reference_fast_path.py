"""The reference's fast path (:mod:`fxc_env.engine.reference`): the paper's plan from the neighbour sums alone.

Where the agents observe exactly, ``ReferencePolicy.step(engine)`` plays the same episode as
``engine.step(policy(engine.observations()))`` to rounding (bit for bit with raw observations),
without building observations; with any option that makes observations differ from the true
relative states, or without the compiled kernel (``fxc_env/engine/_reference_kernel.c``), it is
not taken.
"""

from __future__ import annotations

import numpy as np
import pytest

from fxc_env import ReferencePolicy, make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine, reference

EXACT = [
    {"scenario": "paper_fig1"},
    {"topology": "random", "n_agents": 300, "mean_in_degree": 4.0, "dim": 2},
    {"topology": "random", "n_agents": 200, "mean_in_degree": 3.0, "topology_period": 3, "action_mode": "residual"},
    {"topology": "random", "n_agents": 200, "mean_in_degree": 3.0, "topology_period": 3, "switching": "random"},
    {"topology": "random", "n_agents": 100, "mean_in_degree": 3.0, "action_mode": "plan_balanced", "u_max": [1.0, 3.0]},
    {"topology": "ring", "n_agents": 6, "dim": 2, "formation_offsets": np.eye(6, 2), "action_mode": "accel"},
    # Beyond the kernel's prefetch distance and the observation path's blocks of 16384 agents.
    {"topology": "random", "n_agents": 20000, "mean_in_degree": 4.0, "n_intervals": 4},
]
INEXACT = [
    {"obs_noise": 0.01},
    {"obs_resolution": 0.01},
    {"link_dropout": 0.2},
    {"obs_dtype": "float32"},
    {"agent_model": "single_integrator"},
]


def test_the_install_built_the_compiled_kernel():
    # Without it ReferencePolicy.step builds the observations (the same values, slower) and step_reference refuses.
    assert reference.KERNEL is not None, "pip install -e . built no fxc_env.engine._reference_kernel (a C compiler?)"


def episode(config, fast: bool, n_episodes: int = 3):
    """Every step's state and outcome of one batch of seeded episodes, by the fast path or the observation path."""
    engine = ConsensusEngine(config, n_episodes=n_episodes)
    draws = [engine.draw_episode(np.random.default_rng(seed)) for seed in range(n_episodes)]
    engine.reset_from_draws(draws, rng=np.random.default_rng(7))  # random switching draws from it
    policy, states, outcomes = ReferencePolicy(config), [], []
    while not engine.done:
        outcome = engine.step_reference() if fast else engine.step(policy(engine.observations()))
        states.append(engine.state.copy())
        outcomes.append([outcome.u_start.copy(), outcome.u_end.copy(), outcome.energy.copy()])
    return np.array(states), outcomes, engine.batch_metrics()


def make(settings: dict):
    settings = dict(settings)
    return make_config(settings.pop("scenario", None), **settings)


@pytest.mark.parametrize("settings", EXACT, ids=lambda s: ",".join(f"{k}" for k in s))
def test_step_reference_plays_the_observation_path_to_rounding(settings):
    config = make(settings)
    assert ConsensusEngine(config).neighbour_plans.exact
    states, outcomes, metrics = episode(config, fast=False)
    fast_states, fast_outcomes, fast_metrics = episode(config, fast=True)
    scale = np.abs(states).max()
    np.testing.assert_allclose(fast_states, states, rtol=1e-12, atol=1e-14 * scale)
    for index, name in enumerate(("u_start", "u_end", "energy")):
        slow, fast = np.array([o[index] for o in outcomes]), np.array([o[index] for o in fast_outcomes])
        # Late in the episode the agents' differences are tiny and the states' rounding is most of
        # them: the inputs agree to rounding of the episode's largest input, not each to its own.
        np.testing.assert_allclose(fast, slow, rtol=1e-9, atol=1e-10 * np.abs(slow).max(), err_msg=name)
    np.testing.assert_allclose(fast_metrics["energy"], metrics["energy"], rtol=1e-12)
    # The deadline error agrees to rounding of D(0) (both are rounding there when the deadline is met).
    np.testing.assert_allclose(
        fast_metrics["relative_deadline_error"], metrics["relative_deadline_error"], rtol=1e-6, atol=1e-13
    )


@pytest.mark.parametrize(("dim", "action_mode"), [(1, "accel"), (2, "plan"), (3, "residual")])
def test_raw_observations_give_the_observation_path_bit_for_bit(dim, action_mode):
    config = make_config(
        topology="random", n_agents=3000, mean_in_degree=4.0, obs_mode="raw", action_mode=action_mode, dim=dim
    )
    states, outcomes, _ = episode(config, fast=False)
    fast_states, fast_outcomes, _ = episode(config, fast=True)
    np.testing.assert_array_equal(fast_states, states)
    for index in range(3):  # u_start, u_end, energy
        np.testing.assert_array_equal(
            np.array([o[index] for o in fast_outcomes]), np.array([o[index] for o in outcomes])
        )


@pytest.mark.parametrize("dim", [1, 2])
def test_an_interval_that_would_overflow_is_refused_with_the_state_kept(dim):
    engine = ConsensusEngine(make_config(topology="ring", n_agents=8, dim=dim))
    engine.reset_from_draws([engine.draw_episode(np.random.default_rng(0))])
    engine.state[0, ::2] *= 1e307  # past what a reset accepts: the plans' inputs overflow float64
    before = engine.state.copy()
    with pytest.raises(ArgumentError, match="would overflow float64"):
        engine.step_reference()
    np.testing.assert_array_equal(engine.state, before)
    assert engine.k == 0


def test_the_reference_policy_steps_without_observations_where_they_are_exact(monkeypatch):
    config = make_config("paper_fig1")
    engine = ConsensusEngine(config)
    engine.reset_from_draws([engine.draw_episode(np.random.default_rng(0))])

    def no_observations(*args, **kwargs):
        raise AssertionError("observations were built")

    monkeypatch.setattr(engine, "observations", no_observations)
    policy = ReferencePolicy(config)
    while not engine.done:
        policy.step(engine)
    assert engine.batch_metrics()["relative_deadline_error"][0] < 1e-10


@pytest.mark.parametrize(
    "option", [*INEXACT, "float32 engine", "no kernel"], ids=lambda s: s if isinstance(s, str) else next(iter(s))
)
def test_inexact_observations_or_no_kernel_refuse_the_fast_path_and_the_policy_steps_on_observations(
    option, monkeypatch
):
    if option == "no kernel":  # an install without a C compiler
        monkeypatch.setattr(reference, "KERNEL", None)
    config = make_config("paper_fig1", **({} if isinstance(option, str) else option))
    dtype = "float32" if option == "float32 engine" else "float64"
    engine, expected = ConsensusEngine(config, dtype=dtype), ConsensusEngine(config, dtype=dtype)
    assert not engine.neighbour_plans.exact
    for e in (engine, expected):
        e.reset_from_draws([e.draw_episode(np.random.default_rng(0))], rng=np.random.default_rng(3))
    before = engine.state.copy()
    reason = "did not build" if option == "no kernel" else "needs exact observations"
    with pytest.raises(ArgumentError, match=f"step_reference: .*{reason}"):
        engine.step_reference()
    np.testing.assert_array_equal(engine.state, before)
    policy = ReferencePolicy(config)
    for _ in range(3):
        policy.step(engine)
        expected.step(policy(expected.observations()))
    np.testing.assert_array_equal(engine.state, expected.state)


def test_the_torch_engine_takes_the_observation_path():
    config = make_config("paper_fig1")
    engine = ConsensusEngine(config, device="cpu")
    assert not engine.neighbour_plans.exact
    x0, v0 = engine.sample_initial_state(np.random.default_rng(0))
    engine.reset(x0[None], v0[None])
    ReferencePolicy(config).step(engine)
    assert engine.k == 1


def test_raw_plans_are_refused_for_general_linear_agents():
    engine = ConsensusEngine(make_config("paper_fig1", agent_model="single_integrator"))
    engine.reset_from_draws([engine.draw_episode(np.random.default_rng(0))])
    before = engine.state.copy()
    with pytest.raises(ArgumentError, match="raw_plans"):
        engine.step(np.zeros((1, 6, engine.config.action_size)), raw_plans=True)
    np.testing.assert_array_equal(engine.state, before)


def test_simulate_and_the_speed_interval_run_the_reference_without_observations(monkeypatch):
    from fxc_env import simulate
    from fxc_env.speed import scaling

    def no_observations(*args, **kwargs):
        raise AssertionError("observations were built")

    monkeypatch.setattr(ConsensusEngine, "observations", no_observations)
    assert simulate("reference", "paper_fig1", seed=0).metrics.relative_deadline_error < 1e-10
    interval, product = scaling.interval_and_product(2000, rounds=1, steps=1)
    assert interval > 0 and product > 0


def test_after_a_partial_reset_each_episode_plays_its_own_interval_and_graph():
    config = make_config(topology="random", n_agents=50, mean_in_degree=3.0, topology_period=2, n_intervals=8)
    policy, states = ReferencePolicy(config), []
    for fast in (False, True):
        engine = ConsensusEngine(config, n_episodes=3)
        draws = [engine.draw_episode(np.random.default_rng(seed)) for seed in range(3)]
        engine.reset_from_draws(draws, rng=np.random.default_rng(1))
        x0, v0 = engine.sample_initial_state(np.random.default_rng(9))
        for k in range(7):
            if k == 3:  # episode 0 starts again: the episodes' clocks and graphs differ from here on
                engine.reset(np.stack([x0] * 3), np.stack([v0] * 3), episodes=np.array([True, False, False]))
            engine.step_reference() if fast else engine.step(policy(engine.observations()))
        np.testing.assert_array_equal(engine.steps, [4, 7, 7])
        states.append(engine.state.copy())
    np.testing.assert_allclose(states[1], states[0], rtol=1e-12, atol=1e-14 * np.abs(states[0]).max())
