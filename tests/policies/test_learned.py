"""fxc_env.policies.learned: a saved SB3 model as a policy, and the shipped pretrained policy's result.

Loading without unpickling and the training-settings checks: tests/policies/test_policy_files.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from fxc_env import ReferencePolicy, make_config
from fxc_env.engine import ConsensusEngine
from fxc_env.policies.learned import LearnedPolicy, load_model, pretrained_path


def deadline_errors(policy, config, seeds) -> np.ndarray:
    """log10 D(T_s)/D(0) of each seeded random initial state under ``policy``."""
    engine = ConsensusEngine(config, n_episodes=len(seeds))
    x0, v0 = zip(*(engine.sample_initial_state(np.random.default_rng(s)) for s in seeds), strict=True)
    engine.reset(np.stack(x0), np.stack(v0))
    while not engine.done:
        engine.step(engine.validate_actions(policy(engine.observations())))
    return np.log10(engine.batch_metrics()["relative_deadline_error"])


@pytest.mark.slow
def test_pretrained_policy_is_small_and_meets_the_deadline_goal_on_paper_fig1():
    """The learned policy's bar: median log10 deadline error within 1.0 of the reference's, 20 seeded states."""
    assert pretrained_path().stat().st_size < 2 * 2**20
    config = make_config("paper_fig1", obs_slots=4, initial_state="random")
    seeds = range(20)
    learned = np.median(deadline_errors(LearnedPolicy(pretrained_path(), config), config, seeds))
    reference = np.median(deadline_errors(ReferencePolicy(config), config, seeds))
    assert learned <= reference + 1.0


def test_batched_call_equals_row_by_row():
    config = make_config("paper_fig1", obs_slots=4)
    policy = LearnedPolicy(pretrained_path(), config)
    obs = np.random.default_rng(0).uniform(-1, 1, size=(3, 6, config.layout.size))
    batched = policy(obs)
    assert batched.shape == (3, 6, 2)
    np.testing.assert_allclose(batched[1, 4], policy(obs[1, 4]), rtol=1e-6)


def test_a_model_for_another_layout_is_refused_with_both_sizes():
    config = make_config("paper_fig1")  # obs_slots 1: 6 numbers, the model expects 15
    with pytest.raises(ValueError, match=r"policy: the model takes observations of size 15 .* this environment has 6"):
        LearnedPolicy(pretrained_path(), config)
    with pytest.raises(ValueError, match=r"obs_slots: trained with 4, this environment has 1"):
        LearnedPolicy(pretrained_path(), config)  # the file records the slots it was trained with


def test_missing_file_is_named():
    for trusted in (False, True):
        with pytest.raises(FileNotFoundError, match="policy: no saved model at"):
            load_model("no/such/model.zip", trusted=trusted)
