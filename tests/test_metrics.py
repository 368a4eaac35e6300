"""Disagreement measures (SPEC 4.4) and the per-episode record (SPEC 5)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import brute_spread

from fxc_env.core.metrics import EpisodeMetrics, disagreement, reward_floor, spread


@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("n", [1, 2, 7, 40])
def test_spread_equals_the_brute_force_diameter(dim, n):
    rng = np.random.default_rng(10 * dim + n)
    z = rng.normal(scale=4.0, size=(n, dim))
    assert spread(z) == pytest.approx(brute_spread(z), rel=1e-12, abs=1e-15)


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_spread_over_leading_dimensions(dim):
    rng = np.random.default_rng(dim)
    z = rng.normal(size=(3, 4, 9, dim))
    result = spread(z)
    assert result.shape == (3, 4)
    for a in range(3):
        for b in range(4):
            assert result[a, b] == pytest.approx(brute_spread(z[a, b]), rel=1e-12)


def test_spread_with_more_agents_than_one_chunk():
    rng = np.random.default_rng(0)
    z = rng.normal(size=(300, 2))
    z[123] = [50.0, 0.0]
    z[299] = [-50.0, 1.0]
    assert spread(z) == pytest.approx(math.hypot(100.0, 1.0), rel=1e-12)


@pytest.mark.parametrize("dim", [1, 2])
def test_spread_is_zero_at_consensus_and_translation_invariant(dim):
    assert spread(np.full((5, dim), 3.25)) == 0.0
    rng = np.random.default_rng(1)
    z = rng.normal(size=(6, dim))
    assert spread(z + 1000.0) == pytest.approx(spread(z), rel=1e-9)


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_disagreement_is_position_spread_plus_ts_velocity_spread(dim):
    rng = np.random.default_rng(dim)
    x, v = rng.normal(size=(8, dim)), rng.normal(size=(8, dim))
    expected = brute_spread(x) + 20.0 * brute_spread(v)
    assert disagreement(x, v, 20.0) == pytest.approx(expected, rel=1e-12)


def test_disagreement_of_the_paper_initial_state():
    x0 = np.array([1.0, -1.0, 2.0, 4.0, -4.0, -2.0])[:, None]
    v0 = np.array([1.0, 2.0, 3.0, -3.0, -2.0, 0.0])[:, None]
    assert disagreement(x0, v0, 20.0) == pytest.approx(8.0 + 20.0 * 6.0)


def test_reward_floor_is_relative_to_the_initial_disagreement():
    np.testing.assert_allclose(reward_floor(np.array([2.0, 0.0]), 1e-12), [2e-12, 1.0])


def test_episode_metrics_as_dict_is_json_safe():
    m = EpisodeMetrics(
        final_position_spread=1e-10,
        final_velocity_spread=0.0,
        relative_deadline_error=1e-12,
        t_eps_1e_2=19.0,
        t_eps_1e_6=math.inf,
        energy=1.0,
        peak_input=2.0,
        sampling_instants=200,
        predicted_final_position=math.nan,
        achieved_final_position=-1.875,
        predicted_final_velocity=-0.125,
        achieved_final_velocity=-0.125,
        saturated_fraction=0.0,
    )
    d = m.as_dict()
    assert d["t_eps_1e_6"] is None and d["predicted_final_position"] is None
    assert d["sampling_instants"] == 200 and d["achieved_final_position"] == -1.875
    import json

    assert json.loads(json.dumps(d)) == d
