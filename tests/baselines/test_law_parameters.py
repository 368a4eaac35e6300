"""Every registered law refuses a numeric parameter outside the range where its promise holds, by name."""

from __future__ import annotations

import numpy as np
import pytest

from fxc_env.baselines.laws.bounded_steer import BoundedSteerPolicy
from fxc_env.baselines.registry import LAWS
from fxc_env.config import make_config
from fxc_env.core.validation import ArgumentError, ArgumentTypeError
from fxc_env.engine import ConsensusEngine


def law_config(name, **kwargs):
    law = LAWS[name]
    settings = {"topology": "ring", "n_agents": 6, "schedule": law.schedule}
    return make_config(scenario=None, action_mode=law.action_mode, obs_mode=law.obs_mode, **{**settings, **kwargs})


# (law, parameter, a value outside its range, the range as the message writes it)
OUTSIDE = [
    ("signalling", "amplitude", 2.0, "1e-12 <= amplitude <= 1"),
    ("graph_agnostic", "amplitude", 1e100, "1e-12 <= amplitude <= 1"),
    ("graph_agnostic", "amplitude", 1e-300, "1e-12 <= amplitude <= 1"),
    ("graph_agnostic", "rank_tolerance", 1e-2, "1e-16 <= rank_tolerance <= 1e-06"),
    ("graph_agnostic", "rank_tolerance", 1e-300, "1e-16 <= rank_tolerance <= 1e-06"),
    ("bounded_steer", "amplitude", 596.0, "1e-12 <= amplitude <= 1"),
    ("bounded_steer", "amplitude", 1e-300, "1e-12 <= amplitude <= 1"),
    ("linear", "gain", 1e100, "0 < gain <= 1e12"),
    ("linear", "gamma", 0.0, "0 < gamma <= 1e12"),
    ("linear_sampled", "gamma", 1e13, "0 < gamma <= 1e12"),
    ("finite_time", "alpha", 1.0, "0 < alpha < 1"),
    ("finite_time", "gain", 1e100, "0 < gain <= 1e12"),
    ("prescribed_time", "exponent", 1e4, "1 < exponent <= 100"),
    ("prescribed_time", "cutoff", 20.0, "0 < cutoff < 20"),
    ("saturation_aware", "gain", 1e100, "0 < gain <= 1e12"),
    ("saturation_aware", "gamma", -1.0, "0 < gamma <= 1e12"),
]


@pytest.mark.parametrize(("law", "parameter", "value", "expected"), OUTSIDE)
def test_a_parameter_outside_its_range_is_refused_naming_it_and_the_range(law, parameter, value, expected):
    with pytest.raises(ArgumentError, match=rf"^{parameter}: expected {expected}; .*got "):
        LAWS[law].policy(law_config(law), **{parameter: value})


@pytest.mark.parametrize(("law", "parameter"), [("graph_agnostic", "amplitude"), ("finite_time", "alpha")])
def test_a_parameter_that_is_no_number_is_a_type_error_naming_it(law, parameter):
    with pytest.raises(ArgumentTypeError, match=rf"^{parameter}: expected a number"):
        LAWS[law].policy(law_config(law), **{parameter: "0.5"})


def test_linear_sampled_refuses_a_gain_it_would_replace_by_its_design():
    with pytest.raises(ArgumentError, match=r"^gain: .*give gamma too"):
        LAWS["linear_sampled"].policy(law_config("linear_sampled"), gain=1e12)
    assert LAWS["linear_sampled"].policy(law_config("linear_sampled"), gamma=2.0, gain=0.5).gain == 0.5


def test_bounded_steer_under_a_limit_does_not_promise_exactness_where_its_gathering_passes_the_limit():
    config = law_config("bounded_steer", u_max=0.5)
    loud, quiet = BoundedSteerPolicy(config, amplitude=1.0), BoundedSteerPolicy(config)
    assert loud.guarantee().startswith("not exact where the gathering's inputs pass u_max = 0.5")
    assert loud.parameters()["gathering_peak"] > 0.5 >= quiet.parameters()["gathering_peak"]
    assert quiet.guarantee().startswith("exact")
    engine = ConsensusEngine(config, n_episodes=3)
    engine.reset_from_draws([engine.draw_episode(np.random.default_rng(seed)) for seed in range(3)])
    while not engine.done:
        engine.step(np.asarray(loud(engine.observations()), dtype=np.float64))
    assert np.min(engine.batch_metrics()["relative_deadline_error"]) > 1e-3  # not exact, as it says


def test_every_registered_law_runs_at_the_ends_of_its_ranges():
    ends = {
        "signalling": {"amplitude": 1e-12},
        "graph_agnostic": {"amplitude": 1.0, "rank_tolerance": 1e-16},
        "bounded_steer": {"amplitude": 1.0},
        "linear": {"gain": 1e12, "gamma": 1e12},
        "finite_time": {"alpha": 1e-300},
        "prescribed_time": {"exponent": 100.0},
        "saturation_aware": {"gain": 1e12},
    }
    for name, parameters in ends.items():
        policy = LAWS[name].policy(law_config(name), **parameters)
        assert all(policy.parameters()[key] == value for key, value in parameters.items() if key in policy.parameters())
