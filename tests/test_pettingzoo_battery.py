"""PettingZoo's own test battery over the configurations users train on.

Every test of ``pettingzoo.test`` (``parallel_api_test``, ``api_test``, ``seed_test``,
``parallel_seed_test``, ``max_cycles_test``, ``render_test``, ``state_test``) on the default
environment, random switching, a topology family (``scenario="generalist"``), an input limit,
link dropout and measurement noise (README, "Realism options"). The episodes are short
(K = 10 intervals, six agents) so that each test runs whole episodes to their deadline: the
seed tests compare two identically seeded runs step for step (noise, dropout, switching and
the family's draws all come from the episode's seed), and ``max_cycles_test`` checks that
``max_cycles`` truncates the parallel and AEC forms after exactly that many cycles.
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
}
BATTERY = ("parallel_api", "api", "seed", "parallel_seed", "max_cycles", "render", "state")
#: matplotlib frames of both render modes (2-3 s each at load 4.5, 7-9 s at load 8 on the 2 shared
#: cores): `make test` runs them all, `make check` the default configuration's (tests/test_rendering.py
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
    default = envs["default"].config
    assert (default.switching, default.family, default.u_max_choices) == ("periodic", None, None)
    assert default.link_dropout == default.obs_noise == 0.0


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
