"""Scale-free exactness: a law that claims exact consensus keeps it in any units of the initial state.

Observations and actions are homogeneous of degree one in the state, so a law's D(T_s)/D(0) must not depend on
``x(0), v(0) -> c x(0), c v(0)`` (docs: optimality.md, "Exact consensus without knowing the graph").
"""

from __future__ import annotations

import numpy as np
import pytest

from fxc_env.baselines.harness.graph_agnostic_goals import strongly_connected_random
from fxc_env.baselines.laws.policy import claims_exactness
from fxc_env.baselines.registry import LAWS
from fxc_env.config import make_config
from fxc_env.engine import ConsensusEngine

GRAPHS = {
    "ring-18": {"topology": "ring", "n_agents": 18},
    "random-25": {"topology": strongly_connected_random(25, 2.0)[0], "n_agents": 25},
}
SCALES = (1e-3, 1e3, 1e6)


def law_config(name: str, graph: dict):
    law = LAWS[name]
    return make_config(
        scenario=None,
        n_intervals=200,
        settling_time=20.0,
        schedule=law.schedule,
        action_mode=law.action_mode,
        obs_mode=law.obs_mode,
        **graph,
    )


def deadline_errors(policy, config, scale: float, seeds=(0, 1, 2)) -> np.ndarray:
    """D(T_s)/D(0) of the seeded episodes with the initial state multiplied by ``scale``."""
    engine = ConsensusEngine(config, n_episodes=len(seeds))
    draws = [engine.draw_episode(np.random.default_rng(seed)) for seed in seeds]
    engine.reset(scale * np.stack([d.x0 for d in draws]), scale * np.stack([d.v0 for d in draws]))
    while not engine.done:
        engine.step(np.asarray(policy(engine.observations()), dtype=np.float64))
    return engine.batch_metrics()["relative_deadline_error"]


EXACT_LAWS = [name for name in LAWS if claims_exactness(LAWS[name].policy(law_config(name, GRAPHS["ring-18"])))]


def test_the_laws_that_claim_exactness_are_the_ones_the_scale_test_covers():
    assert set(EXACT_LAWS) == {
        "minimum_time",
        "leader_follower",
        "signalling",
        "graph_agnostic",
        "bounded_steer",
        "filtering",
    }


@pytest.mark.parametrize("graph", sorted(GRAPHS))
@pytest.mark.parametrize("name", EXACT_LAWS)
def test_an_exact_law_keeps_its_deadline_error_in_any_units(name, graph):
    config = law_config(name, GRAPHS[graph])
    policy = LAWS[name].policy(config)
    assert claims_exactness(policy)
    at_one = np.max(deadline_errors(policy, config, 1.0))
    assert at_one <= 2e-9
    for scale in SCALES:  # millimetres to thousands of kilometres, same numbers
        assert np.max(deadline_errors(policy, config, scale)) <= max(1e-9, 4 * at_one), scale
