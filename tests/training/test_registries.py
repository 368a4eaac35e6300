"""Laws and training back ends register once (issue 28): what the registries promise the suite, the CLI and users."""

from __future__ import annotations

import numpy as np
import pytest

from fxc_env.baselines import registry as laws
from fxc_env.baselines.harness.suite import builtin_contenders, load_policy, optimality_contenders
from fxc_env.config import make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine
from fxc_env.training import registry as backends
from fxc_env.training.args import ALGORITHMS, BACKENDS
from fxc_env.training.run_dir import RunDir


def test_every_registered_law_loads_and_acts_under_its_own_settings():
    for name, law in laws.LAWS.items():
        config = make_config(
            scenario=None,
            topology="ring",
            n_agents=6,
            n_intervals=200,
            schedule=law.schedule,
            action_mode=law.action_mode,
            obs_mode=law.obs_mode,
        )
        policy = load_policy(name, config)
        engine = ConsensusEngine(config, n_episodes=1)
        engine.reset_from_draws([engine.draw_episode(np.random.default_rng(0))])
        actions = policy(engine.observations())
        assert np.shape(actions) == (1, 6, config.action_size), name
    assert [c.name for c in builtin_contenders()] == list(laws.LAWS)
    assert set(laws.LAWS) <= {c.spec for c in optimality_contenders()}


def test_a_name_registered_twice_is_refused_naming_it():
    with pytest.raises(ArgumentError, match=r"^name: a law named 'linear' is registered already"):
        laws.register(laws.LAWS["linear"])
    with pytest.raises(ArgumentError, match=r"^name: a back end named 'torch' is registered already"):
        backends.register(backends.BACKENDS["torch"])
    assert list(backends.BACKENDS) == list(BACKENDS)  # nothing was added


def test_every_back_end_is_reachable_from_its_registry_entry():
    for name, backend in backends.BACKENDS.items():
        module, function = backend.trainer.split(":")
        assert function == f"train_{name}" and module.endswith(("_train", "_ppo")), backend
        assert set(backend.algorithms) <= set(ALGORITHMS)
        run = RunDir("runs/x", name)
        assert run.checkpoint_steps(run.checkpoint_path(1200)) == 1200
