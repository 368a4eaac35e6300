"""PettingZoo's own test battery over the configurations users train on.

Every test of ``pettingzoo.test`` (``parallel_api_test``, ``api_test``, ``seed_test``,
``parallel_seed_test``, ``max_cycles_test``, ``render_test``, ``state_test``) on the default
environment, random switching, a topology family (``scenario="generalist"``), an input limit,
link dropout, measurement noise (docs: realism.md, "Realism options") and graph tensors in the infos, on
the default topology and on a family (docs: graph-tensors.md, "Graph tensors"). The episodes are short
(K = 10 intervals, six agents) so that each test runs whole episodes to their deadline: the
seed tests compare two identically seeded runs step for step (noise, dropout, switching and
the family's draws all come from the episode's seed), and ``max_cycles_test`` checks that
``max_cycles`` truncates the parallel and AEC forms after exactly that many cycles.

Replay buffers (Tianshou's, TorchRL's) store every info key with one type and shape: the infos
of every configuration, and of a drawn input limit, have the same keys, types and shapes at
reset and after every step, in the parallel and the AEC form (``episode`` joins at the end).
"""

from __future__ import annotations

import functools
import types
import warnings

import numpy as np
import pytest
from pettingzoo.test import (
    api_test,
    max_cycles_test,
    parallel_api_test,
    parallel_seed_test,
    render_test,
    seed_test,
    state_test,
)

import fxc_env

#: Intervals per episode: every test below plays past the deadline (``K + 5`` cycles).
K = 10
#: The configurations, by name: each is run through the whole battery.
CONFIGURATIONS = {
    "default": {},
    "random_switching": {"switching": "random"},
    "generalist_family": {"scenario": "generalist", "n_agents": 6},
    "u_max": {"u_max": 5.0},
    "link_dropout": {"link_dropout": 0.3},
    "obs_noise": {"obs_noise": 0.05},
    "graph_tensors": {"graph_tensors": True},
    "family_graph_tensors": {"scenario": "generalist", "n_agents": 6, "graph_tensors": True},
}
BATTERY = ("parallel_api", "api", "seed", "parallel_seed", "max_cycles", "render", "state")
#: matplotlib frames of both render modes (2-3 s each at load 4.5, 7-9 s at load 8 on the 2 shared
#: cores): `make test` runs them all, `make check` the default configuration's (tests/envs/test_rendering.py
#: covers the frames).
SLOW = {(name, "render") for name in CONFIGURATIONS if name != "default"}


@pytest.fixture(autouse=True)
def _quiet_pettingzoo_warnings():
    # The battery warns about unbounded raw states (state_space is R^(N x 2 dim)) and negative
    # entries in a 2-D state; its asserts are what this module checks.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def _factories(name: str) -> tuple[functools.partial, functools.partial]:
    kwargs = {**CONFIGURATIONS[name], "n_intervals": K}
    return functools.partial(fxc_env.parallel_env, **kwargs), functools.partial(fxc_env.env, **kwargs)


def _not_blank(frame: np.ndarray) -> bool:
    return len(np.unique(frame.reshape(-1, 3), axis=0)) > 2


def _run(test: str, parallel_fn: functools.partial, aec_fn: functools.partial) -> None:
    if test == "parallel_api":
        parallel_api_test(parallel_fn(), num_cycles=K + 5)
    elif test == "api":
        api_test(aec_fn(), num_cycles=K + 5)
    elif test == "seed":
        seed_test(aec_fn, num_cycles=K + 5)
    elif test == "parallel_seed":
        parallel_seed_test(parallel_fn, num_cycles=K + 5)
    elif test == "max_cycles":
        max_cycles_test(types.SimpleNamespace(env=aec_fn, parallel_env=parallel_fn))
    elif test == "render":
        render_test(lambda render_mode=None: aec_fn(render_mode=render_mode), custom_tests={"rgb_array": _not_blank})
    elif test == "state":
        state_test(aec_fn(), parallel_fn(), num_cycles=K + 5)
    else:  # pragma: no cover - a typo in BATTERY
        raise AssertionError(test)


@pytest.mark.parametrize(
    ("name", "test"),
    [
        pytest.param(name, test, id=f"{name}-{test}", marks=(pytest.mark.slow,) if (name, test) in SLOW else ())
        for name in CONFIGURATIONS
        for test in BATTERY
    ],
)
def test_pettingzoo_battery(name, test):
    parallel_fn, aec_fn = _factories(name)
    _run(test, parallel_fn, aec_fn)


def test_the_configurations_are_what_they_say():
    """Each configuration really turns its option on (so the battery covers what the names claim)."""
    envs = {name: _factories(name)[0]() for name in CONFIGURATIONS}
    assert envs["random_switching"].config.switching == "random"
    assert envs["generalist_family"].config.family is not None
    assert envs["u_max"].config.u_max_choices == (5.0,)
    assert envs["link_dropout"].config.link_dropout == 0.3
    assert envs["obs_noise"].config.obs_noise == 0.05
    assert envs["graph_tensors"].graph_tensors and envs["family_graph_tensors"].graph_tensors
    assert envs["family_graph_tensors"].config.family is not None
    default = envs["default"].config
    assert (default.switching, default.family, default.u_max_choices) == ("periodic", None, None)
    assert default.link_dropout == default.obs_noise == 0.0 and not envs["default"].graph_tensors


def test_the_seeded_draws_differ_between_seeds_in_every_random_configuration():
    """The seed tests would pass vacuously if nothing were random: two seeds give different episodes."""
    for name in ("random_switching", "generalist_family", "link_dropout", "obs_noise"):
        env = _factories(name)[0]()
        runs = []
        for seed in (1, 2):
            observations, _ = env.reset(seed=seed)
            trace = [np.stack(list(observations.values()))]
            while env.agents:
                observations, *_ = env.step({agent: np.zeros(2) for agent in env.agents})
                trace.append(np.stack(list(observations.values())))
            runs.append(np.stack(trace))
        assert runs[0].shape == runs[1].shape and not np.array_equal(runs[0], runs[1]), name


#: The battery's configurations and an input limit drawn from a set at every reset.
INFO_CONFIGURATIONS = {**CONFIGURATIONS, "u_max_drawn": {"u_max": (2.0, 5.0)}}


def _info_shape(info: dict) -> dict:
    """Each info key's type, and shape and dtype (arrays), but ``episode``, which joins at the end only."""
    return {
        key: (type(value), np.shape(value), getattr(value, "dtype", None))
        for key, value in info.items()
        if key != "episode"
    }


@pytest.mark.parametrize("name", INFO_CONFIGURATIONS)
def test_infos_have_the_same_keys_types_and_shapes_at_reset_and_every_step(name):
    kwargs = {**INFO_CONFIGURATIONS[name], "n_intervals": K}
    env = fxc_env.parallel_env(**kwargs)
    policy = fxc_env.ReferencePolicy(env)
    _, infos = env.reset(seed=0)
    expected = _info_shape(infos["agent_0"])
    for small_n_path, seed in ((True, 1), (False, 2)):  # both step paths; a family draws new graphs each reset
        env.small_n_path = small_n_path
        observations, infos = env.reset(seed=seed)
        assert all(_info_shape(info) == expected for info in infos.values())
        while env.agents:
            observations, _, terminations, truncations, infos = env.step(
                {agent: policy(observation) for agent, observation in observations.items()}
            )
            end = terminations["agent_0"] or truncations["agent_0"]
            for info in infos.values():
                assert _info_shape(info) == expected and ("episode" in info) == end
    # The AEC form: what last() gives each agent at its every turn (reset infos until the cycle's end).
    aec = fxc_env.env(**kwargs)
    aec.reset(seed=3)
    for agent in aec.agent_iter():
        observation, _, termination, truncation, info = aec.last()
        assert _info_shape(info) == expected, agent
        aec.step(None if termination or truncation else policy(observation))


@pytest.mark.parametrize("name", ["generalist_family", "family_graph_tensors"])
def test_a_family_s_drawn_graphs_are_behind_episode_edges_and_replay_the_episode(name):
    """The graphs a family draws are no info (their length changes): ``episode_edges()`` gives them."""
    parallel_fn, aec_fn = _factories(name)
    env = parallel_fn()
    _, infos = env.reset(seed=4)
    edges = env.episode_edges()
    assert "edges" not in infos["agent_0"] and len(edges) == len(env.engine.topologies[0].edges)
    replay = parallel_fn(topology=edges, scenario=None)  # the drawn graphs as a fixed topology
    replay.reset(seed=4)
    assert replay.episode_edges() == edges and replay.config.family is None
    aec = aec_fn()
    aec.reset(seed=4)
    assert aec.episode_edges() == edges


def test_the_vec_env_gives_each_episode_s_drawn_graphs_by_method_not_in_reset_infos():
    from fxc_env.core.validation import ArgumentError
    from fxc_env.envs.vec_env import ConsensusVecEnv

    vec = ConsensusVecEnv(2, scenario="generalist", n_agents=6, n_intervals=K)
    vec.seed(10)
    vec.reset()
    assert not any("edges" in info for info in vec.reset_infos)
    env = fxc_env.parallel_env(scenario="generalist", n_agents=6, n_intervals=K)
    env.reset(seed=10 + 6)  # episode 1 replays the parallel env seeded with its first sub-environment's seed
    assert vec.episode_edges(1) == env.episode_edges()
    with pytest.raises(ArgumentError, match="episode"):
        vec.episode_edges(2)
