"""Property-based tests (hypothesis) over random graphs, sizes, dims, modes and initial states."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

import fxc_env
from fxc_env import ReferencePolicy, make_config
from fxc_env.engine import ConsensusEngine

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@st.composite
def scenarios(draw, fixed_graph: bool = False):
    """Random seeded topologies and settings, as keyword arguments of make_config."""
    n_agents = draw(st.integers(2, 9))
    kwargs = {
        "topology": "random",
        "n_agents": n_agents,
        "topology_seed": draw(st.integers(0, 10_000)),
        "mean_in_degree": draw(st.sampled_from([1.0, 1.5, 2.0, 3.0])),
        "topology_period": 1 if fixed_graph else draw(st.integers(1, 3)),
        "dim": draw(st.integers(1, 3)),
        "n_intervals": draw(st.integers(3, 40)),
        "settling_time": draw(st.floats(0.5, 50.0)),
        "schedule": draw(st.sampled_from(["paper", "uniform"])),
        "action_mode": draw(st.sampled_from(["plan", "accel"])),
        "obs_mode": draw(st.sampled_from(["normalized", "raw"])),
    }
    return kwargs


@st.composite
def initial_states(draw, n_agents: int, dim: int):
    scale = 10.0 ** draw(st.integers(-4, 4))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    return scale * rng.normal(size=(n_agents, dim)), scale * rng.normal(size=(n_agents, dim))


def run(config, x0, v0, policy=None):
    engine = ConsensusEngine(config)
    engine.reset(x0[None], v0[None])
    policy = policy or ReferencePolicy(config)
    states, outcomes, observations = [engine.state[0].copy()], [], []
    while not engine.done:
        obs = engine.observations()
        observations.append(obs)
        outcomes.append(engine.step(engine.validate_actions(policy(obs))))
        states.append(engine.state[0].copy())
    return engine, np.array(states), outcomes, observations


@pytest.mark.slow
@SETTINGS
@given(data=st.data(), kwargs=scenarios(), u_max=st.sampled_from([None, 0.5, 5.0]))
def test_each_interval_matches_solve_ivp(data, kwargs, u_max):
    config = make_config(**kwargs, u_max=u_max)
    x0, v0 = data.draw(initial_states(config.n_agents, config.dim))
    _, states, outcomes, _ = run(config, x0, v0)
    times = config.schedule.times
    for k in (0, len(outcomes) // 2, len(outcomes) - 1):
        u0, u1 = outcomes[k].u_start[0].ravel(), outcomes[k].u_end[0].ravel()
        T = times[k + 1] - times[k]

        def field(s, y, u0=u0, u1=u1, T=T):
            u = u0 + (u1 - u0) * s / T
            u = u if u_max is None else np.clip(u, -u_max, u_max)
            return np.concatenate([y[u0.size :], u])

        start = np.concatenate([states[k][:, 0].ravel(), states[k][:, 1].ravel()])
        end = solve_ivp(field, (0.0, T), start, rtol=1e-11, atol=1e-13, max_step=T / 64).y[:, -1]
        expected = np.concatenate([states[k + 1][:, 0].ravel(), states[k + 1][:, 1].ravel()])
        assert np.abs(end - expected).max() <= 1e-7 * (1.0 + np.abs(expected).max())


@SETTINGS
@given(data=st.data(), kwargs=scenarios(fixed_graph=True))
def test_xi_weighted_invariants_on_fixed_graphs(data, kwargs):
    """Under the reference on a fixed graph, xi^T V(t_k) and xi^T (X(t_k) - t_k V(t_k)) stay constant."""
    config = make_config(**kwargs)
    x0, v0 = data.draw(initial_states(config.n_agents, config.dim))
    _, states, _, _ = run(config, x0, v0)
    xi = config.topology.consensus_weights()
    times = config.schedule.times[:, None]
    velocity_mean = np.einsum("i,kid->kd", xi, states[:, :, 1])
    position_mean = np.einsum("i,kid->kd", xi, states[:, :, 0]) - times * velocity_mean
    scale = 1.0 + np.abs(states).max() * (1.0 + config.settling_time)
    assert np.abs(velocity_mean - velocity_mean[0]).max() <= 1e-9 * scale
    assert np.abs(position_mean - position_mean[0]).max() <= 1e-9 * scale


@SETTINGS
@given(
    data=st.data(),
    kwargs=scenarios(),
    noise=st.sampled_from([0.0, 0.1]),
    dropout=st.sampled_from([0.0, 0.4]),
    switching=st.sampled_from(["periodic", "random"]),
)
def test_no_nan_or_inf_in_any_output_even_under_random_actions(data, kwargs, noise, dropout, switching):
    env = fxc_env.parallel_env(**kwargs, obs_noise=noise, link_dropout=dropout, switching=switching, u_max=1e3)
    seed = data.draw(st.integers(0, 2**31 - 1))
    observations, infos = env.reset(seed=seed)
    space = env.action_space(env.possible_agents[0])
    space.seed(seed)
    while env.agents:
        assert all(np.isfinite(o).all() for o in observations.values())
        observations, rewards, _, _, infos = env.step({a: space.sample() for a in env.agents})
        assert all(np.isfinite(r) for r in rewards.values())
        assert all(np.isfinite(v) for info in infos.values() for v in info.values() if isinstance(v, float))
        assert np.isfinite(env.state()).all()
    episode = infos[env.possible_agents[0]]["episode"]
    # Numbers only (no None, no NaN): "never settled" is inf, a prediction or bound that does not apply
    # is left out (Theorem 2's prediction and the propagation bound need a fixed sequence of graphs).
    for name, value in episode.items():
        assert isinstance(value, float | int), name
        assert not np.isnan(value), name
        if not (name.startswith("t_eps") or name == "settled_interval"):
            assert np.isfinite(value), name
    assert ("propagation_bound" in episode) == (switching == "periodic")
