"""The shipped ``agnostic`` policy: two gain schedules and its own probe, learned without being told the graph.

Goals (docs: results.md, "agnostic policy"): at K = 200, T_s = 20 s on the paper's schedule, at least ten
times below the paper's controller on directed rings of sizes it was never trained on (N in
12..40), within a decade of it under switching; its inputs are the agent's own rows, mask, clock and
its memory of them only (no N, no graph, no spectrum).
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from fxc_env.baselines.harness.jobs import Job, run_job
from fxc_env.baselines.harness.suite import BenchmarkCase, builtin_contenders, learned_contender
from fxc_env.config import make_config
from fxc_env.core.families import TopologyFamily
from fxc_env.core.validation import ArgumentError
from fxc_env.engine.consensus_engine import ConsensusEngine
from fxc_env.envs.parallel import ConsensusParallelEnv
from fxc_env.policies.interval_gains import read_interval_gains
from fxc_env.policies.learned import load_learned_policy, pretrained_path
from fxc_env.policies.regime_gains import REGIME_FORMAT, RegimeGainPolicy
from fxc_env.training.recipes.agnostic import (
    HELD_OUT_RINGS,
    PROBES,
    TRAINED_RINGS,
    case_config,
    main,
    probe_keeps_fixed,
)
from fxc_env.training.recipes.rings import TASK


def deadline_errors(contender, n_agents, seeds) -> np.ndarray:
    result = run_job(Job(contender, BenchmarkCase(TopologyFamily("ring"), n_agents), 200, seeds, 20.0, False))
    assert result.error is None, result.error
    return np.asarray(result.metrics["relative_deadline_error"])


def test_the_agnostic_policy_is_ten_times_below_the_reference_on_a_ring_size_it_never_met():
    assert 15 in HELD_OUT_RINGS and 15 not in TRAINED_RINGS
    seeds = (0, 1, 2)
    ours = np.median(deadline_errors(learned_contender("agnostic"), 15, seeds))
    reference = np.median(deadline_errors(builtin_contenders(["reference"])[0], 15, seeds))
    assert reference > 1e-3
    assert ours * 10 <= reference


@pytest.mark.slow
@pytest.mark.parametrize("n_agents", HELD_OUT_RINGS)
def test_the_agnostic_policy_is_ten_times_below_the_reference_on_every_held_out_ring_size_over_20_seeds(n_agents):
    seeds = tuple(range(20))
    ours = np.median(deadline_errors(learned_contender("agnostic"), n_agents, seeds))
    reference = np.median(deadline_errors(builtin_contenders(["reference"])[0], n_agents, seeds))
    assert ours * 10 <= reference


@pytest.mark.slow
def test_under_period_4_switching_the_agnostic_policy_is_within_a_decade_of_the_reference():
    seeds = tuple(range(20))
    case = BenchmarkCase(TopologyFamily("ring", period=(4, 4)), 20)
    errors = []
    for contender in (learned_contender("agnostic"), builtin_contenders(["reference"])[0]):
        result = run_job(Job(contender, case, 200, seeds, 20.0, False))
        assert result.error is None, result.error
        errors.append(np.median(result.metrics["relative_deadline_error"]))
    assert errors[1] > 1e-2 and errors[0] <= 10 * errors[1]


def _episode_observations(env_kwargs, seed, instants):
    """Every agent's observations ``(instants, N, obs_size)`` of one episode, every agent coasting (the probe's plan)."""
    env = ConsensusParallelEnv(None, **env_kwargs)
    observations, _ = env.reset(seed=seed)
    out = []
    for _ in range(instants):
        out.append(np.stack([observations[a] for a in env.agents]))
        observations, *_ = env.step({a: np.zeros(2) for a in env.agents})
    return np.stack(out)


def test_an_agent_plan_reads_only_its_own_rows_mask_clock_and_memory():
    """Scrambling every other agent's observations over an episode, or swapping the graph and N, changes no agent's plan."""
    switching = TopologyFamily("random", mean_in_degree=(1.5, 3.0), period=(2, 4))
    obs = _episode_observations({**TASK, "n_agents": 20, "topology": switching, "obs_slots": 4}, 3, 8)
    policy = load_learned_policy("agnostic", case_config({"kind": "ring"}, 20))
    assert isinstance(policy, RegimeGainPolicy)
    plans = np.stack([policy(o) for o in obs])  # every agent at once, one instant after the other
    rng = np.random.default_rng(0)
    for i in (0, 7):
        alone, scrambled = [], []
        policy.reset()
        alone = np.stack([policy(o[i : i + 1])[0] for o in obs])  # agent i's episode alone
        policy.reset()
        for o in obs:
            others = rng.normal(size=(13, o.shape[1])) * 1e3  # another N, other agents, anything
            others[:, -3:] = o[i, -3:]  # (on the same clock)
            others[5] = o[i]
            scrambled.append(policy(others)[5])
        np.testing.assert_array_equal(np.stack(scrambled), alone)
        np.testing.assert_array_equal(plans[:, i], alone)
    assert "eigenvalues" not in policy.header  # no spectrum in the file either


@pytest.mark.parametrize(("family", "n_agents"), [("ring", 20), ("ring", 6), ("random", 20)])
@pytest.mark.parametrize("period", [1, 2, 3, 4])
def test_the_probe_finds_exactly_the_agents_whose_in_neighbours_change(family, n_agents, period):
    """What the training simulates (:func:`probe_keeps_fixed`) is what every agent's probe finds."""
    config = case_config({"kind": family, "period": (period, period)}, n_agents)
    engine = ConsensusEngine(config, n_episodes=3)
    draws = [engine.draw_episode(np.random.default_rng(seed)) for seed in range(3)]
    engine.reset_from_draws(draws)
    policy = load_learned_policy("agnostic", config, allow_out_of_domain=n_agents < 12)
    for _ in range(PROBES + 1):
        policy(np.asarray(engine.observations()))
        engine.step(np.zeros((3, n_agents, 2)))
    expected = np.stack([~probe_keeps_fixed(d.topology) for d in draws])
    np.testing.assert_array_equal(policy.switched, expected)
    assert expected.any() == (period > 1)


def test_the_policy_refuses_calls_that_break_its_memory_by_name():
    policy = load_learned_policy("agnostic", case_config({"kind": "ring"}, 20))
    obs = _episode_observations({**TASK, "n_agents": 20, "topology": TopologyFamily("ring"), "obs_slots": 4}, 0, 3)
    with pytest.raises(ArgumentError, match=r"^observations: .*from k = 0"):
        policy(obs[1])
    policy(obs[0])
    with pytest.raises(ArgumentError, match=r"^observations: .*skipped or repeated"):
        policy(obs[2])
    policy.reset()
    # Agent by agent (AEC style) every agent would run through one memory: refused at once, naming the policy.
    with pytest.raises(ArgumentError, match=r"^observations: RegimeGainPolicy from .*agnostic.npz acts for every"):
        policy(obs[0][0])


def test_the_agnostic_file_records_a_training_without_teacher_over_graph_families():
    path = pretrained_path("agnostic")
    assert path.suffix == ".npz" and path.stat().st_size < 2**16
    with np.load(path, allow_pickle=False) as arrays:
        gains, switching, header = arrays["gains"], arrays["switching_gains"], json.loads(str(arrays["header"]))
    assert gains.shape == switching.shape == (200, 2, 2) and header["name"] == "agnostic"
    assert header["probes"] == PROBES and not gains[:PROBES].any() and not switching[:PROBES].any()
    assert header["training"]["teacher"] is None
    # The command as it was run, before the recipes moved into training/recipes/ (a record, not an import).
    assert header["training"]["command"].startswith("python -m fxc_env.training.agnostic")
    domain = header["domain"]
    assert domain["n_agents"] == [12, 40] and domain["schedule"] == ["paper"] and domain["n_intervals"] == [200, 200]
    assert {g["family"] for g in domain["graphs"]} == {"ring", "random", "path", "star"}
    config = make_config(None, **{**TASK, "topology": TopologyFamily("ring"), "n_agents": 33})
    assert isinstance(load_learned_policy("agnostic", config), RegimeGainPolicy)


def test_a_damaged_two_table_file_is_refused_by_name(tmp_path):
    policy = read_interval_gains(pretrained_path("agnostic"))
    path = tmp_path / "one_table.npz"
    np.savez(path, gains=policy.gains, header=np.array(json.dumps({**policy.header, "format": REGIME_FORMAT})))
    with pytest.raises(ArgumentError, match=r"^policy: .*one_table.npz is a .* file without switching_gains"):
        read_interval_gains(path)
    moving = policy.switching_gains.copy()
    moving[0] = 1.0
    with pytest.raises(ArgumentError, match=r"^gains: both tables must be zero on the first probes = 4"):
        RegimeGainPolicy(policy.gains, moving, policy.header)
    with pytest.raises(ArgumentError, match=r"^probes: expected an integer in \[1, K\), got 0"):
        RegimeGainPolicy(policy.gains, policy.switching_gains, {**policy.header, "probes": 0})


def test_the_agnostic_policy_refuses_a_ring_outside_its_sizes_by_name():
    config = make_config(None, **{**TASK, "topology": TopologyFamily("ring"), "n_agents": 100})
    with pytest.raises(ArgumentError, match=r"^policy: .*agnostic.npz was trained on another domain.*n_agents"):
        load_learned_policy("agnostic", config)


def test_quick_training_writes_a_policy_that_beats_the_reference_on_a_held_out_ring(tmp_path, capsys):
    out = tmp_path / "agnostic.npz"
    assert main(["--quick", "--out", str(out)]) == 0
    policy = read_interval_gains(out)
    assert policy.header["training"]["teacher"] is None and policy.header["name"] == "agnostic"
    printed = re.search(r"ring N = 15, 2 held-out seeds: .*, ([0-9.e+]+)x below", capsys.readouterr().out)
    assert printed is not None and float(printed.group(1)) >= 10


@pytest.mark.parametrize(("keyword", "value"), [("steps", 0), ("seed", -1)])
def test_bad_training_settings_are_refused_by_name(keyword, value):
    from fxc_env.training.recipes.agnostic import train

    with pytest.raises(ArgumentError, match=f"^{keyword}"):
        train(**{keyword: value})


def test_the_agnostic_policy_plans_every_axis_alike_in_the_plane():
    """The table is linear in the rows: in dim = 2 each axis moves as it does alone, probe included."""
    from dataclasses import replace

    settings = {**TASK, "topology": TopologyFamily("random", mean_in_degree=(1.5, 3.0)), "obs_slots": 4}
    configs = [make_config(None, **{**settings, "dim": dim}) for dim in (2, 1, 1)]
    engines = [ConsensusEngine(config, n_episodes=1) for config in configs]
    plane = engines[0].draw_episode(np.random.default_rng(7))
    draws = [plane] + [replace(plane, x0=plane.x0[:, a : a + 1], v0=plane.v0[:, a : a + 1]) for a in (0, 1)]
    policies = [load_learned_policy("agnostic", config) for config in configs]
    assert policies[0].action_size == 4
    for engine, draw in zip(engines, draws, strict=True):
        engine.reset_from_draws([draw])
    for _ in range(3 * PROBES):
        for engine, policy in zip(engines, policies, strict=True):
            engine.step(policy(np.asarray(engine.observations())))
        for axis in (0, 1):
            np.testing.assert_allclose(engines[0].state[..., axis], engines[1 + axis].state[..., 0], rtol=1e-9)
    assert not policies[0].switched.any() and np.ptp(engines[0].state) > 0
