"""The agents' part: chosen once from the config, exact closed forms, the state left to the caller."""

from __future__ import annotations

import numpy as np
import pytest

from fxc_env import ConsensusEngine, make_config
from fxc_env.core import dynamics
from fxc_env.core.metrics import disagreement
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import agents
from fxc_env.engine.backend import NumpyBackend
from fxc_env.engine.clock import InstantTables, LockStepClock


@pytest.mark.parametrize(
    ("kwargs", "kind"),
    [
        ({}, agents.DoubleIntegratorAgents),
        ({"u_max": 5.0}, agents.LimitedDoubleIntegratorAgents),
        ({"agent_model": {"name": "integrator_chain", "order": 3}}, agents.LinearAgents),
    ],
)
def test_the_dynamics_are_chosen_from_the_config(kwargs, kind):
    config = make_config("paper_fig1", **kwargs)
    assert type(agents.make_agents(config, NumpyBackend("float64", 1))) is kind


@pytest.mark.parametrize("n_agents", [50, 20_000])  # the generic lines and the blocked fast path
def test_a_double_integrator_interval_is_the_closed_form_and_leaves_the_state(n_agents):
    config = make_config(topology="random", n_agents=n_agents, obs_mode="raw", action_mode="accel", dim=2)
    backend = NumpyBackend("float64", 2)
    part = agents.make_agents(config, backend)
    clock = LockStepClock(InstantTables(config, backend), k=3)
    rng = np.random.default_rng(0)
    state = rng.normal(size=(2, n_agents, 2, 2))
    before = state.copy()
    actions = rng.normal(size=(2, n_agents, 4))
    out = np.empty_like(state)
    result = part.advance(state, actions, clock, lambda: None, out)
    T = config.schedule.intervals[3]
    u0, u1 = actions[..., :2], actions[..., 2:]
    x_next, v_next = dynamics.advance(state[:, :, 0], state[:, :, 1], u0, u1, T)
    np.testing.assert_allclose(result.state[:, :, 0], x_next, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(result.state[:, :, 1], v_next, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(result.energy, dynamics.interval_energy(u0, u1, T), rtol=1e-13)
    np.testing.assert_array_equal(state, before)  # written into `out`, adopted by the engine only if finite
    assert result.state is out
    np.testing.assert_allclose(result.disagreement, disagreement(out[:, :, 0], out[:, :, 1], config.settling_time))


def test_a_limited_input_never_exceeds_u_max_and_reports_its_saturated_share():
    config = make_config("paper_fig1", u_max=0.5, action_mode="accel", obs_mode="raw")
    backend = NumpyBackend("float64", 1)
    part = agents.make_agents(config, backend)
    part.u_max = np.array([0.5])
    clock = LockStepClock(InstantTables(config, backend))
    actions = np.linspace(-3, 3, 12).reshape(1, 6, 2)
    result = part.advance(np.zeros((1, 6, 2, 1)), actions, clock, lambda: None, np.empty((1, 6, 2, 1)))
    assert np.all(result.peak <= 0.5)
    assert np.all((result.saturated_fraction >= 0) & (result.saturated_fraction <= 1))
    assert result.saturated_fraction.max() > 0


def test_formation_offsets_are_added_back_at_the_start():
    offsets = np.arange(6.0)[:, None]
    config = make_config("paper_fig1", formation_offsets=offsets)
    engine = ConsensusEngine(config)
    x0, v0 = np.ones((1, 6, 1)), np.zeros((1, 6, 1))
    engine.reset(x0, v0)
    np.testing.assert_allclose(engine.state[0, :, 0], 1.0 - offsets)  # the formation error zeta = z - h
    np.testing.assert_allclose(engine.absolute_state()[0, :, 0], x0[0])


def test_general_agents_have_no_input_end_values_to_map_from_actions():
    config = make_config("paper_fig1", agent_model={"name": "integrator_chain", "order": 3})
    engine = ConsensusEngine(config)
    engine.reset(np.ones((1, 6, 1)), np.zeros((1, 6, 1)))
    with pytest.raises(ArgumentError, match="plans"):
        engine.inputs_from_actions(np.zeros((1, 6, 3)))
