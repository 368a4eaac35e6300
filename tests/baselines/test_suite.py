"""The benchmark suite: cases, contenders and their settings, and loading policies by name or file."""

from __future__ import annotations

import numpy as np
import pytest

from fxc_env import ReferencePolicy, make_config
from fxc_env.baselines.harness.suite import (
    BUILTIN_SETTINGS,
    builtin_contenders,
    contender_config,
    full_suite,
    learned_contender,
    load_policy,
    quick_suite,
)
from fxc_env.baselines.laws.finite_time import FiniteTimePolicy
from fxc_env.baselines.registry import LAWS
from fxc_env.policies.learned import LearnedPolicy, SlotAdaptedPolicy


def test_full_suite_covers_every_family_size_and_budget():
    suite = full_suite()
    families = {s.family for s in suite.cases}
    assert families == {"paper_fig1", "ring", "path", "star", "random (fixed)", "random (switching)"}
    assert {s.n_agents for s in suite.cases} == {6, 20, 100}
    assert len(suite.cases) == 1 + 5 * 3
    assert len(suite.seeds) >= 20
    assert suite.budgets == (25, 50, 100, 200, 400)
    assert len({s.key for s in suite.cases}) == len(suite.cases)


def test_quick_suite_keeps_every_family_and_the_headline_budget():
    quick, full = quick_suite(), full_suite()
    assert {s.family for s in quick.cases} == {s.family for s in full.cases}
    assert quick.headline_budget in quick.budgets
    assert quick.trace_case in quick.cases


def test_contender_settings_reach_the_environment():
    case = full_suite().cases[0]
    for contender in builtin_contenders():
        config = contender_config(contender, case, 50, 20.0)
        assert (config.schedule.name, config.action_mode, config.obs_mode) == BUILTIN_SETTINGS[contender.name][1:]
        assert config.n_intervals == 50
    sampled = {c.name for c in builtin_contenders() if c.sampled}
    assert sampled == {name for name, law in LAWS.items() if law.sampled}  # the budget sweep
    assert {"linear", "finite_time", "prescribed_time"}.isdisjoint(sampled)  # continuous laws run once, at fine K


def test_load_policy_by_name():
    assert isinstance(load_policy("reference", make_config()), ReferencePolicy)
    assert isinstance(load_policy("finite_time", make_config(action_mode="accel", obs_mode="raw")), FiniteTimePolicy)
    with pytest.raises(ValueError, match="policy"):
        load_policy("pid", make_config())
    with pytest.raises(ValueError, match="policy"):
        load_policy("missing/model.zip", make_config())
    with pytest.raises(ValueError, match="policies"):
        builtin_contenders(["reference", "pid"])


def test_learned_policy_plugs_in_with_its_observation_width():
    contender = learned_contender("pretrained")
    assert contender.sampled and contender.obs_slots is None  # a gain network: each case's own slots
    assert learned_contender("paper_fig1").obs_slots == 4  # an MLP: its fixed width
    config = contender_config(contender, full_suite().cases[0], 200, 20.0)  # paper_fig1: N = 6, trained on 20
    with pytest.raises(ValueError, match="n_agents: trained on 20, this environment has 6"):
        load_policy(contender.spec, config)
    with pytest.warns(UserWarning, match="runs outside its training domain"):
        policy = load_policy(contender.spec, config, allow_out_of_domain=True)
    assert isinstance(policy, SlotAdaptedPolicy) and isinstance(policy.policy, LearnedPolicy)
    obs = np.zeros((3, config.n_agents, config.layout.size))
    assert policy(obs).shape == (3, config.n_agents, 2)
    padded = contender_config(learned_contender("paper_fig1"), full_suite().cases[0], 200, 20.0)
    assert isinstance(load_policy(learned_contender("paper_fig1").spec, padded), LearnedPolicy)
