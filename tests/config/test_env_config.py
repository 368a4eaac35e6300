"""Settings (docs: environment.md, "The environment"): defaults, scenarios, overrides, layout and validation."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import PAPER_GRAPHS, PAPER_V0, PAPER_X0

from fxc_env import SCENARIOS, make_config


def test_defaults_are_the_paper_example():
    c = make_config()
    assert c.n_agents == 6
    assert c.topology.period == 3
    for g, edges in enumerate(PAPER_GRAPHS):
        assert {tuple(e) for e in c.topology.edges[g].tolist()} == set(edges)
    assert c.settling_time == 20.0
    assert c.n_intervals == 200
    assert c.schedule.name == "paper"
    assert c.dim == 1
    assert (c.action_mode, c.obs_mode, c.obs_format) == ("plan", "normalized", "flat")
    assert c.initial_state is None  # random draws
    assert c.scenario is None


def test_paper_scenario_holds_the_paper_example():
    c = make_config("paper_fig1")
    assert c.n_agents == 6 and c.settling_time == 20.0 and c.topology.name == "paper_fig1"
    x0, v0 = c.initial_state
    np.testing.assert_array_equal(x0[:, 0], PAPER_X0)
    np.testing.assert_array_equal(v0[:, 0], PAPER_V0)
    assert x0.shape == v0.shape == (6, 1)


def test_every_named_scenario_builds():
    assert {"paper_fig1", "ring_6", "random_20_planar"} <= set(SCENARIOS)
    for name in SCENARIOS:
        c = make_config(name)
        assert c.scenario == name
        if c.initial_state is not None:
            assert c.initial_state[0].shape == (c.n_agents, c.dim)


def test_explicit_arguments_override_the_scenario():
    c = make_config("paper_fig1", settling_time=10.0, n_intervals=50, schedule="uniform")
    assert c.settling_time == 10.0 and c.n_intervals == 50 and c.schedule.name == "uniform"
    np.testing.assert_array_equal(c.initial_state[0][:, 0], PAPER_X0)


def test_resizing_a_scenario_drops_its_fixed_initial_state():
    c = make_config("ring_6", n_agents=9)
    assert c.n_agents == 9 and c.initial_state is None


@pytest.mark.parametrize("scenario", ["paper_fig1", "ring_6"])
def test_changing_dim_of_a_scenario_drops_its_fixed_initial_state(scenario):
    # make_config's docstring: the scenario's state is dropped when n_agents or dim is
    # overridden, since it has the scenario's shape.
    c = make_config(scenario, dim=2)
    assert c.dim == 2
    assert c.initial_state is None


def test_custom_schedule_array_sets_k():
    c = make_config(schedule=[10.0, 6.0, 4.0])
    assert c.n_intervals == 3 and c.schedule.name == "custom"


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_layout_sizes_and_split(dim):
    c = make_config(topology="complete", n_agents=4, dim=dim)
    layout = c.layout
    assert layout.slots == 3
    assert layout.size == 3 * 2 * dim + 3 + 3
    assert c.action_size == 2 * dim
    obs = np.arange(2 * 5 * layout.size, dtype=float).reshape(2, 5, layout.size)
    rows, mask, clock = layout.split(obs)
    assert rows.shape == (2, 5, 3, 2, dim) and mask.shape == (2, 5, 3) and clock.shape == (2, 5, 3)
    np.testing.assert_array_equal(np.concatenate([rows.reshape(2, 5, -1), mask, clock], axis=-1), obs)
    # Row r is [x_j - x_i (dim), v_j - v_i (dim)].
    np.testing.assert_array_equal(rows[0, 0, 1, 0], obs[0, 0, 2 * dim : 3 * dim])
    np.testing.assert_array_equal(rows[0, 0, 1, 1], obs[0, 0, 3 * dim : 4 * dim])


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"action_mode": "force"}, "action_mode"),
        ({"obs_mode": "global"}, "obs_mode"),
        ({"obs_format": "tuple"}, "obs_format"),
        ({"dim": 0}, "dim"),
        ({"dim": 1.5}, "dim"),
        ({"n_agents": 0, "topology": "ring"}, "n_agents"),
        ({"settling_time": -1.0}, "settling_time"),
        ({"settling_time": float("nan")}, "settling_time"),
        ({"settling_time": float("inf")}, "settling_time"),
        ({"n_intervals": 0}, "n_intervals"),
        ({"action_bound": -1.0}, "action_bound"),
        ({"action_bound": float("nan")}, "action_bound"),
        ({"reward_floor": 0.0}, "reward_floor"),
        ({"position_range": 0.0}, "position_range"),
        ({"velocity_range": float("inf")}, "velocity_range"),
        ({"topology": [(0, 1), (1, 1)]}, "topology"),
        ({"topology": "ring", "n_agents": 4, "initial_state": (np.zeros(3), np.zeros(4))}, "x0"),
        ({"topology": "ring", "n_agents": 4, "initial_state": (np.zeros(4), np.full(4, np.nan))}, "v0"),
        ({"topology": "ring", "n_agents": 4, "initial_state": np.zeros(4)}, "initial_state"),
    ],
)
def test_bad_settings_name_the_argument(kwargs, name):
    with pytest.raises((ValueError, TypeError), match=name):
        make_config(**kwargs)


def test_unknown_scenario_names_the_argument():
    with pytest.raises(ValueError, match="scenario"):
        make_config("paper_fig2")


def test_initial_state_accepts_n_or_n_by_dim():
    x0 = np.arange(4.0)
    c1 = make_config(topology="ring", n_agents=4, initial_state=(x0, -x0))
    c2 = make_config(topology="ring", n_agents=4, initial_state=(x0[:, None], -x0[:, None]))
    np.testing.assert_array_equal(c1.initial_state[0], c2.initial_state[0])
    np.testing.assert_array_equal(c1.initial_state[1], -x0[:, None])


def test_obs_slots_pads_rows_and_refuses_fewer_than_the_in_degree():
    c = make_config("paper_fig1", obs_slots=4)
    assert c.layout.slots == 4 and c.topology.max_in_degree == 1
    with pytest.raises(ValueError, match="obs_slots: the topology has in-degree up to 3"):
        make_config(topology="complete", n_agents=4, obs_slots=2)


def test_initial_state_random_drops_the_scenario_state():
    assert make_config("paper_fig1").initial_state is not None
    assert make_config("paper_fig1", initial_state="random").initial_state is None
    with pytest.raises(ValueError, match="initial_state: expected None, 'random'"):
        make_config("paper_fig1", initial_state="fixed")
