"""Topology families drawn per episode, per-episode input limits, and the input-limit feature."""

from __future__ import annotations

import re

import numpy as np
import pytest

from fxc_env import ReferencePolicy
from fxc_env.config import make_config
from fxc_env.core.families import FAMILY_KINDS, TopologyFamily, edge_lists, make_family
from fxc_env.core.graphs import check_spanning_tree, make_topology
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine, limit_feature

MIXTURE = {
    "mixture": [
        ({"family": "ring", "period": (1, 3)}, 1.0),
        ({"family": "path"}, 1.0),
        ({"family": "star", "period": 2}, 1.0),
        ({"family": "random", "mean_in_degree": (1.0, 3.0), "period": (1, 4)}, 2.0),
        ({"family": "complete"}, 0.5),
    ],
    "name": "everything",
}


@pytest.mark.parametrize("kind", FAMILY_KINDS)
@pytest.mark.parametrize("period", [(1, 1), (2, 4)])
def test_every_draw_spans_jointly_within_the_family_bounds(kind, period):
    degree = {"mean_in_degree": (1.5, 3.5)} if kind == "random" else {}
    family = make_family({"family": kind, "period": period, **degree})
    rng = np.random.default_rng(0)
    for n in (2, 7, 30):
        for _ in range(25):
            topology = family.draw(n, rng)
            check_spanning_tree(topology)  # raises if the union of the period does not span
            assert period[0] <= topology.period <= period[1]
            assert topology.max_in_degree <= family.max_in_degree(n)
            assert topology.n_agents == n


def test_a_period_is_usually_not_spanning_graph_by_graph():
    """Edges are dealt to the m graphs, so single graphs rarely span: Theorem 2's setting, not Theorem 1's."""
    family = TopologyFamily("ring", period=(3, 3))
    rng = np.random.default_rng(1)
    single_graph_spans = 0
    for _ in range(50):
        topology = family.draw(12, rng)
        for graph in topology.edges:
            try:
                check_spanning_tree(make_topology(graph, 12, check=False))
                single_graph_spans += 1
            except ArgumentError:
                pass
    assert single_graph_spans == 0


def test_draws_are_reproducible_from_the_seed_and_differ_between_seeds():
    family = make_family(MIXTURE)
    first = [edge_lists(family.draw(15, np.random.default_rng(seed))) for seed in range(10)]
    again = [edge_lists(family.draw(15, np.random.default_rng(seed))) for seed in range(10)]
    assert first == again
    assert len({repr(edges) for edges in first}) == 10


def test_structured_families_relabel_the_agents():
    family = TopologyFamily("star")
    rng = np.random.default_rng(2)
    leaders = {int(family.draw(10, rng).edges[0][0, 0]) for _ in range(60)}
    assert len(leaders) >= 8
    fixed = TopologyFamily("star", relabel=False)
    assert {int(fixed.draw(10, rng).edges[0][0, 0]) for _ in range(10)} == {0}


def test_mixture_weights_set_the_frequencies():
    family = make_family({"mixture": [({"family": "ring"}, 1.0), ({"family": "complete"}, 3.0)]})
    rng = np.random.default_rng(3)
    complete = sum(family.draw(5, rng).max_in_degree == 4 for _ in range(800))
    assert 0.70 < complete / 800 < 0.80


@pytest.mark.parametrize(
    ("spec", "name"),
    [
        ({"family": "hypercube"}, "topology['family']"),
        ({"family": "random", "mean_in_degree": (3.0, 1.0)}, "topology['mean_in_degree']"),
        ({"family": "random", "mean_in_degree": -1.0}, "topology['mean_in_degree']"),
        ({"family": "ring", "period": 0}, "topology['period']"),
        ({"family": "ring", "period": (1, 2, 3)}, "topology['period']"),
        ({"family": "ring", "relabel": "yes"}, "topology['relabel']"),
        ({"family": "ring", "colour": "red"}, "topology"),
        ({"mixture": []}, "topology"),
        ({"mixture": [({"family": "ring"}, 0.0)]}, "topology mixture weight"),
        ({"mixture": [({"family": "ring"},)]}, "topology"),
    ],
)
def test_bad_family_specs_name_the_argument(spec, name):
    with pytest.raises(ArgumentError) as caught:
        make_config(topology=spec, n_agents=8)
    assert str(caught.value).startswith(name), str(caught.value)


def test_obs_slots_cover_every_draw_and_a_smaller_request_is_refused():
    config = make_config(topology={"family": "random", "mean_in_degree": (1.0, 3.2)}, n_agents=20)
    assert config.obs_slots == 4
    with pytest.raises(ArgumentError, match=r"^obs_slots: the family's draws have in-degree up to 4"):
        make_config(topology={"family": "random", "mean_in_degree": (1.0, 3.2)}, n_agents=20, obs_slots=3)


def run_reference(engine, policy):
    obs = np.empty((engine.n_episodes, engine.config.n_agents, engine.config.layout.size))
    while not engine.done:
        engine.step(policy(engine.observations(out=obs)))
    return engine.batch_metrics()


@pytest.mark.parametrize("switching", ["periodic", "random"])
def test_a_batch_of_family_draws_equals_each_episode_replayed_as_a_fixed_topology(switching):
    kwargs = {"n_agents": 9, "n_intervals": 40, "obs_slots": 9, "switching": switching}
    config = make_config(topology=MIXTURE, **kwargs)
    engine = ConsensusEngine(config, n_episodes=4)
    draws = [engine.draw_episode(np.random.default_rng(seed)) for seed in range(4)]
    engine.reset(
        np.stack([d.x0 for d in draws]),
        np.stack([d.v0 for d in draws]),
        rng=np.random.default_rng(99),
        topologies=[d.topology for d in draws],
    )
    batch = run_reference(engine, ReferencePolicy(config))
    for b, draw in enumerate(draws):
        replay = make_config(topology=edge_lists(draw.topology), **kwargs)
        alone = ConsensusEngine(replay, n_episodes=1)
        alone.reset(draw.x0[None], draw.v0[None], rng=np.random.default_rng(99))
        if switching == "random":  # the batch's shared stream drew differently; compare the periodic case only
            continue
        single = run_reference(alone, ReferencePolicy(replay))
        np.testing.assert_array_equal(engine.x[b], alone.x[0])
        assert batch["relative_deadline_error"][b] == pytest.approx(single["relative_deadline_error"][0], rel=1e-14)
        assert batch["predicted_final_position"][b] == pytest.approx(single["predicted_final_position"][0], rel=1e-12)
    assert np.all(np.isfinite(batch["relative_deadline_error"]))


def test_an_input_limit_set_is_drawn_per_episode_and_applied_per_episode():
    config = make_config(scenario="paper_fig1", u_max=(10, 100, 1000), initial_state="random")
    engine = ConsensusEngine(config, n_episodes=12)
    draws = [engine.draw_episode(np.random.default_rng(seed)) for seed in range(12)]
    limits = [d.u_max for d in draws]
    assert set(limits) <= {10.0, 100.0, 1000.0} and len(set(limits)) == 3
    engine.reset(np.stack([d.x0 for d in draws]), np.stack([d.v0 for d in draws]), u_max=limits)
    metrics = run_reference(engine, ReferencePolicy(config))
    limits = np.array(limits)
    assert np.all(metrics["peak_input"] <= limits)
    # The tighter the limit, the longer the reference spends at it.
    saturated = metrics["saturated_fraction"]
    assert saturated[limits == 10].min() > saturated[limits == 1000].max() > 0


def test_the_limit_feature_is_scale_free_and_bounded():
    config = make_config(scenario="paper_fig1", u_max=100.0)
    layout = config.layout
    assert layout.size == layout.clock_end + 1
    observations = []
    for c in (1.0, 1e-3, 1e4):
        engine = ConsensusEngine(config, n_episodes=1)
        engine.u_max = np.array([100.0 * c])
        x0, v0 = config.initial_state
        engine.reset(c * x0[None], c * v0[None])
        observations.append(engine.observations()[0])
    np.testing.assert_allclose(observations[1], observations[0], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(observations[2], observations[0], rtol=1e-12, atol=1e-15)
    feature = observations[0][:, -1]
    assert np.all(np.abs(feature) <= 1)
    assert limit_feature(100.0, 0.1, np.array(0.0)) == 1.0
    # rho = 1 at zero, one decade either side at +-0.5.
    np.testing.assert_allclose(limit_feature(1.0, 1.0, np.array([1.0, 0.1, 10.0])), [0.0, 0.5, -0.5])


def test_without_a_limit_the_observation_is_unchanged():
    config = make_config(scenario="paper_fig1")
    assert not config.layout.limit_feature and config.layout.size == config.layout.clock_end


def test_initial_scales_span_decades_and_normalized_observations_ignore_them():
    config = make_config(scenario="paper_fig1", initial_state="random", position_range=(1e-3, 1e3))
    engine = ConsensusEngine(config, n_episodes=1)
    spans = [np.ptp(engine.sample_initial_state(np.random.default_rng(s))[0]) for s in range(200)]
    assert min(spans) < 1e-2 and max(spans) > 1e2
    # The same configuration scaled by c observes exactly the same thing (rows / s_i).
    x0, v0 = engine.sample_initial_state(np.random.default_rng(0))
    seen = []
    for c in (1.0, 1e-6, 1e6):
        engine.reset(c * x0[None], c * v0[None])
        seen.append(engine.observations()[0])
    np.testing.assert_allclose(seen[1], seen[0], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(seen[2], seen[0], rtol=1e-12, atol=1e-15)


def test_episode_edges_and_the_infos_u_max_report_the_draw_and_replaying_them_gives_the_same_episode():
    import fxc_env

    env = fxc_env.parallel_env(scenario="generalist", u_max=(10.0, 100.0))
    observations, infos = env.reset(seed=5)
    edges, limit = env.episode_edges(), infos["agent_0"]["u_max"]
    replay = fxc_env.parallel_env(scenario="generalist", topology=edges, u_max=limit)
    replayed, _ = replay.reset(seed=5, options={"x0": env.unwrapped.engine.x0[0], "v0": env.unwrapped.engine.v0[0]})
    assert "edges" not in _["agent_0"]
    policy = ReferencePolicy(env)
    for _step in range(30):
        for agent in env.agents:
            np.testing.assert_array_equal(observations[agent], replayed[agent])
        actions = {agent: policy(obs) for agent, obs in observations.items()}
        observations = env.step(actions)[0]
        replayed = replay.step(actions)[0]
    np.testing.assert_array_equal(env.state(), replay.state())


def test_each_vecenv_episode_draws_its_own_graph_from_its_seed():
    from fxc_env import ConsensusVecEnv

    venv = ConsensusVecEnv(3, scenario="generalist")
    venv.seed(7)
    venv.reset()
    n = 20
    drawn = [venv.episode_edges(b) for b in range(3)]
    assert len({repr(e) for e in drawn}) == 3 and n == venv.n_agents
    again = ConsensusVecEnv(3, scenario="generalist")
    again.seed(7)
    again.reset()
    assert [again.episode_edges(b) for b in range(3)] == drawn


@pytest.mark.parametrize(
    ("spec", "unused"),
    [
        ({"family": "ring", "mean_in_degree": 3.0}, "['mean_in_degree']; its keys are 'family', 'period', 'relabel'"),
        ({"family": "star", "mean_in_degree": (1.0, 2.0)}, "['mean_in_degree']"),
        ({"family": "random", "relabel": False}, "['relabel']; its keys are 'family', 'mean_in_degree', 'period'"),
        ({"family": "complete", "relabel": True}, "['relabel']; its keys are 'family', 'period'"),
        ({"mixture": [({"family": "path", "mean_in_degree": 2.0}, 1.0)]}, "['mean_in_degree']"),
    ],
)
def test_a_key_the_family_does_not_use_is_refused_naming_the_keys_it_does(spec, unused):
    # A ring's mean_in_degree was silently ignored (issue 24): a setting that is not honoured is refused.
    kind = spec["family"] if "family" in spec else spec["mixture"][0][0]["family"]
    with pytest.raises(ArgumentError, match=rf"^topology: the '{kind}' family does not use {re.escape(unused)}"):
        make_config(topology=spec, n_agents=8)


def test_a_mixture_member_may_be_a_bare_family_name():
    # docs: environment.md: {"mixture": [(family, weight), ...]} read as if ("random", 2.0) were allowed (issue 24).
    bare = make_family({"mixture": [("random", 2.0), ("ring", 1.0)], "name": "bare"})
    spelled = make_family({"mixture": [({"family": "random"}, 2.0), ({"family": "ring"}, 1.0)], "name": "bare"})
    assert bare == spelled
    with pytest.raises(ArgumentError, match=r"^topology\['family'\]: "):
        make_family({"mixture": [("hypercube", 1.0)]})
