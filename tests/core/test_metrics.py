"""Disagreement measures and the per-episode record (docs: environment.md, "The environment" and the deadline benchmark)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import brute_spread

from fxc_env.core import metrics
from fxc_env.core.metrics import EpisodeMetrics, disagreement, reward_floor, spread


def all_pairs(z: np.ndarray, centred: bool = True) -> np.ndarray:
    """Diameter over every pair by numpy broadcasting, in blocks of rows; ``(..., N, dim)`` -> ``(...)``.

    ``centred``: in the arithmetic :func:`spread` documents (coordinates minus the centroid
    summed in agent order, squares of the differences added component by component), so the
    values must agree bit for bit; else plainly on the raw coordinates.
    """
    z = np.asarray(z, dtype=np.float64)
    n, dim = z.shape[-2:]
    if centred:
        z = z - np.cumsum(z, axis=-2)[..., -1:, :] / n
    best = np.zeros(z.shape[:-2])
    for start in range(0, n, 128):
        diff = z[..., start : start + 128, None, :] - z[..., None, :, :]
        squares = diff * diff
        total = squares[..., 0]
        for component in range(1, dim):
            total = total + squares[..., component]
        best = np.maximum(best, total.max(axis=(-2, -1)))
    return np.sqrt(best)


def assert_exact_diameter(z: np.ndarray) -> None:
    """``spread(z)`` is the all-pairs value bit for bit, and the plain diameter to 1e-12."""
    result = np.asarray(spread(z))
    np.testing.assert_array_equal(result, all_pairs(z))
    np.testing.assert_allclose(result, all_pairs(z, centred=False), rtol=1e-12, atol=0)


def on_sphere(rng: np.random.Generator, n: int, dim: int) -> np.ndarray:
    """``n`` random points on the unit circle (dim 2) or sphere (dim 3): every one on the hull."""
    u = rng.normal(size=(n, dim))
    return u / np.linalg.norm(u, axis=-1, keepdims=True)


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
        energy_bound=0.5,
        energy_ratio=2.0,
        settled_interval=math.inf,
        radius_bound=math.nan,
        all_roots_bound=math.nan,
        propagation_bound=math.nan,
    )
    d = m.as_dict()
    assert d["t_eps_1e_6"] is None and d["predicted_final_position"] is None
    assert d["settled_interval"] is None and d["propagation_bound"] is None and d["energy_ratio"] == 2.0
    assert d["sampling_instants"] == 200 and d["achieved_final_position"] == -1.875
    import json

    assert json.loads(json.dumps(d)) == d


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("n", [3, 50, 200, pytest.param(2000, marks=pytest.mark.slow)])
def test_spread_in_the_plane_and_space_is_the_all_pairs_diameter(dim, n):
    rng = np.random.default_rng(100 * dim + n)
    assert_exact_diameter(rng.normal(scale=3.0, size=(n, dim)) + 2.0)
    assert_exact_diameter(rng.uniform(-5.0, 5.0, size=(3, n, dim)))  # the engine's initial states


@pytest.mark.slow
@pytest.mark.parametrize("dim", [2, 3])
def test_spread_of_large_batches_and_state_views(dim):
    rng = np.random.default_rng(dim)
    assert_exact_diameter(rng.normal(size=(40, 300, dim)) * rng.uniform(0.1, 10.0, size=(40, 1, dim)))
    state = rng.uniform(-1.0, 1.0, size=(2, 2000, 2, dim))  # the engine's (B, N, 2, dim) layout
    assert_exact_diameter(state[:, :, 0])
    assert_exact_diameter(state[:, :, 1])
    assert spread(rng.normal(size=(2, 3, 400, dim))).shape == (2, 3)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("n", [200, 2000])
def test_spread_of_points_all_on_a_circle_or_sphere(dim, n, monkeypatch):
    searches = []
    search = metrics._farthest_pair
    monkeypatch.setattr(metrics, "_farthest_pair", lambda *args: searches.append(1) or search(*args))
    points = 7.0 * on_sphere(np.random.default_rng(dim + n), n, dim) + 0.5
    assert_exact_diameter(points)
    assert spread(points) == pytest.approx(14.0, rel=1e-2 if n == 200 else 1e-4)
    if n == 2000:
        assert searches  # every point survives the filters: the pruned search runs


@pytest.mark.parametrize("n", [3, 500, pytest.param(3000, marks=pytest.mark.slow)])
def test_spread_of_collinear_and_coplanar_points(n):
    rng = np.random.default_rng(n)
    t = rng.normal(size=(n, 1))
    for dim in (2, 3):
        line = 1.0 + t * rng.normal(size=dim)
        assert_exact_diameter(line)
        assert spread(line) == pytest.approx(np.ptp(t) * np.linalg.norm(line[1] - line[0]) / abs(t[1, 0] - t[0, 0]))
    plane = rng.normal(size=(n, 2)) @ rng.normal(size=(2, 3)) - 3.0
    assert_exact_diameter(plane)
    assert_exact_diameter(np.round(rng.uniform(0, 4, size=(n, 3))))  # a small grid, many ties


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("n", [5, 100, 4000])
def test_spread_of_identical_points_is_zero(dim, n):
    # 0.1 is not a binary fraction: the centroid is off by rounding, the points still coincide.
    assert spread(np.full((n, dim), 0.1)) == 0.0
    assert spread(np.full((2, n, dim), -7.3)).tolist() == [0.0, 0.0]


@pytest.mark.parametrize("dim", [2, pytest.param(3, marks=pytest.mark.slow)])
def test_spread_near_consensus_a_few_ulps_wide(dim):
    # A swarm that has converged: coordinates a few units in the last place apart, far from
    # the origin, so the rounded centroid sits off the cloud by more than its width.
    rng = np.random.default_rng(dim)
    base = np.array([0.064, 0.044, -3.0][:dim])
    for width in (1, 5, 300):
        steps = rng.integers(-width, width + 1, size=(3000, dim))
        cloud = base + steps * np.spacing(base)
        assert_exact_diameter(cloud)
        assert spread(cloud) > 0


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("scale", [1e-12, 1e12])
def test_spread_at_tiny_and_huge_scales(dim, scale):
    rng = np.random.default_rng(dim)
    for n in (50, 3000):
        z = scale * (rng.normal(size=(n, dim)) + 10.0)
        assert_exact_diameter(z)
        assert spread(z) == pytest.approx(scale * spread(z / scale), rel=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("n", [10, pytest.param(3000, marks=pytest.mark.slow)])
def test_spread_of_non_finite_entries_is_nan_like_all_pairs(dim, n):
    rng = np.random.default_rng(n)
    z = rng.normal(size=(3, n, dim))
    z[0, n // 2, 0] = np.nan
    z[1, n // 3, dim - 1] = np.inf
    with np.errstate(invalid="ignore"):
        result = spread(z)
        expected = all_pairs(z)
    assert np.isnan(result[0]) and np.isnan(result[1]) and np.isnan(expected[:2]).all()
    assert result[2] == expected[2]


def test_spread_beyond_three_dimensions_compares_every_pair():
    rng = np.random.default_rng(4)
    assert_exact_diameter(rng.normal(size=(2, 700, 4)))


@pytest.mark.slow
def test_spread_of_a_cloud_with_an_outlier_and_of_two_clusters():
    rng = np.random.default_rng(7)
    cloud = rng.normal(size=(5000, 3))
    cloud[17] = [60.0, 0.0, 0.0]
    assert_exact_diameter(cloud)
    clusters = np.concatenate([rng.normal(size=(2000, 2)), rng.normal(size=(2000, 2)) + 1e3])
    assert_exact_diameter(clusters)
