"""The finite-time law (Wang & Hong 2008 family): sig powers, proven class, convergence."""

from __future__ import annotations

import numpy as np
import pytest

from fxc_env import ConsensusEngine, make_config
from fxc_env.baselines.laws.finite_time import FiniteTimePolicy, is_undirected, sig

UNDIRECTED_RING = [(i, (i + 1) % 5) for i in range(5)] + [((i + 1) % 5, i) for i in range(5)]


def test_sig_is_the_signed_power():
    np.testing.assert_allclose(sig(np.array([-4.0, 0.0, 9.0]), 0.5), [-2.0, 0.0, 3.0])


def test_law_matches_a_hand_computed_case():
    # Agent 0 hears agents 1 and 2: x_j - x_0 = [4, -1], v_j - v_0 = [8, -1].
    config = make_config(topology=[(1, 0), (2, 0), (0, 1), (0, 2)], action_mode="accel", obs_mode="raw")
    policy = FiniteTimePolicy(config, alpha=0.5, gain=2.0)
    assert policy.alpha_velocity == pytest.approx(2 / 3)
    engine = ConsensusEngine(config)
    engine.reset(np.array([0.0, 4.0, -1.0])[None, :, None], np.array([0.0, 8.0, -1.0])[None, :, None])
    actions = policy(engine.observations())[0]
    # u_0 = g [sig(4)^(1/2) + sig(-1)^(1/2) + sig(8)^(2/3) + sig(-1)^(2/3)] = 2 [2 - 1 + 4 - 1] = 8
    # u_1 = g [sig(-4)^(1/2) + sig(-8)^(2/3)] = 2 [-2 - 4] = -12;  u_2 = 2 [1 + 1] = 4
    np.testing.assert_allclose(actions, [[8.0, 8.0], [-12.0, -12.0], [4.0, 4.0]], rtol=1e-14)


def test_converges_on_an_undirected_graph_where_it_is_proven():
    config = make_config(
        topology=UNDIRECTED_RING, n_intervals=4000, schedule="uniform", action_mode="accel", obs_mode="raw"
    )
    policy = FiniteTimePolicy(config)
    assert is_undirected(config.topology)
    assert policy.guarantee().startswith("proven")
    engine = ConsensusEngine(config, 3)
    states = [engine.sample_initial_state(np.random.default_rng(s)) for s in range(3)]
    engine.reset(np.stack([x for x, _ in states]), np.stack([v for _, v in states]))
    while not engine.done:
        engine.step(policy(engine.observations()))
    assert np.all(engine.batch_metrics()["relative_deadline_error"] < 1e-3)


def test_directed_graphs_are_flagged_unproven():
    config = make_config(topology="ring", action_mode="accel", obs_mode="raw")
    assert not is_undirected(config.topology)
    assert FiniteTimePolicy(config).guarantee().startswith("unproven")


def test_needs_raw_observations_and_a_valid_exponent():
    with pytest.raises(ValueError, match="obs_mode"):
        FiniteTimePolicy(make_config(action_mode="accel", obs_mode="normalized"))
    with pytest.raises(ValueError, match="alpha"):
        FiniteTimePolicy(make_config(action_mode="accel", obs_mode="raw"), alpha=1.0)
