"""Frames: rgb_array frames are HxWx3 uint8 pictures; human mode returns None; nothing before reset."""

from __future__ import annotations

import pickle
import warnings

import numpy as np
import pytest
from helpers import reference_actions
from matplotlib.figure import Figure

import fxc_env
from fxc_env import ReferencePolicy, make_topology
from fxc_env.envs.rendering import DRAW_GRAPH_LIMIT, circle_layout, draw_graph


def assert_picture(frame):
    assert isinstance(frame, np.ndarray)
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    assert frame.shape[0] > 50 and frame.shape[1] > 50
    colours = np.unique(frame.reshape(-1, 3), axis=0)
    assert len(colours) > 10  # curves, text and arrows, not a blank canvas
    assert np.mean(np.all(frame == 255, axis=-1)) < 0.995  # not (almost) all white


@pytest.mark.parametrize("scenario", ["paper_fig1", pytest.param("random_20_planar", marks=pytest.mark.slow)])
def test_rgb_array_frames(scenario):
    env = fxc_env.parallel_env(scenario=scenario, render_mode="rgb_array", n_intervals=20)
    policy = ReferencePolicy(env)
    obs, _ = env.reset(seed=0)
    first = env.render()
    assert_picture(first)
    for _ in range(6):
        obs, *_ = env.step(reference_actions(policy, obs))
    later = env.render()
    assert_picture(later)
    assert later.shape == first.shape
    assert not np.array_equal(later, first)  # the frame shows the episode so far
    env.close()


def test_rgb_array_frame_at_the_end_of_the_episode():
    env = fxc_env.parallel_env(scenario="paper_fig1", render_mode="rgb_array", n_intervals=10)
    policy = ReferencePolicy(env)
    obs, _ = env.reset(seed=0)
    while env.agents:
        obs, *_ = env.step(reference_actions(policy, obs))
    assert_picture(env.render())
    env.close()


def test_human_mode_returns_none():
    env = fxc_env.parallel_env(scenario="paper_fig1", render_mode="human", n_intervals=5)
    policy = ReferencePolicy(env)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the headless backend cannot show windows
        obs, _ = env.reset(seed=0)
        assert env.render() is None
        obs, *_ = env.step(reference_actions(policy, obs))
        assert env.render() is None
    env.close()


def test_rendering_env_pickles_and_renders_again():
    env = fxc_env.parallel_env(scenario="paper_fig1", render_mode="rgb_array", n_intervals=10)
    policy = ReferencePolicy(env)
    obs, _ = env.reset(seed=0)
    obs, *_ = env.step(reference_actions(policy, obs))
    before = env.render()
    copy = pickle.loads(pickle.dumps(env))
    np.testing.assert_array_equal(copy.render(), before)


def test_circle_layout_is_on_the_unit_circle_with_agent_0_on_top():
    where = circle_layout(7)
    assert where.shape == (7, 2)
    np.testing.assert_allclose(np.hypot(where[:, 0], where[:, 1]), 1.0, rtol=1e-15)
    np.testing.assert_allclose(where[0], [0.0, 1.0], atol=1e-15)
    assert len({tuple(np.round(p, 12)) for p in where}) == 7


@pytest.mark.parametrize("n", [6, DRAW_GRAPH_LIMIT + 5])
def test_draw_graph_draws_one_arrow_per_edge_or_a_summary(n):
    topo = make_topology("ring", n)
    fig = Figure()
    ax = fig.subplots()
    draw_graph(ax, topo, 0, title="G")
    if n <= DRAW_GRAPH_LIMIT:
        assert len(ax.patches) == n  # one arrow per edge
        assert sorted(t.get_text() for t in ax.texts) == sorted(str(i) for i in range(n))
    else:
        assert not ax.patches
        assert f"{n} agents" in ax.texts[0].get_text()


def test_render_before_reset_is_a_clear_error_in_every_front_end():
    for env in (
        fxc_env.parallel_env(render_mode="rgb_array"),
        fxc_env.raw_env(render_mode="rgb_array"),
        fxc_env.ConsensusVecEnv(1, render_mode="rgb_array"),
    ):
        with pytest.raises(RuntimeError, match=r"reset\(\)"):
            env.render()
    view_env = fxc_env.parallel_env(render_mode="rgb_array")
    with pytest.raises(RuntimeError, match="reset"):
        view_env._view.frame()
