"""Measurements rounded to a quantum (``obs_resolution``) and the resolution floor (docs: optimality.md, "The floors, derived")."""

from __future__ import annotations

import numpy as np
import pytest

import fxc_env
from fxc_env import ConsensusTorchEnv, ConsensusVecEnv, ReferencePolicy
from fxc_env.baselines.harness import report
from fxc_env.baselines.harness.jobs import Job, run_job
from fxc_env.baselines.harness.resolution import resolution_rows, resolution_section, with_resolution
from fxc_env.baselines.harness.suite import (
    BenchmarkCase,
    Contender,
    contender_config,
    load_policy,
    quick_optimality_suite,
)
from fxc_env.baselines.registry import LAWS
from fxc_env.config import make_config
from fxc_env.core.floors import resolution_floor, resolution_floor_bounds, resolution_worst_state
from fxc_env.core.validation import ArgumentError
from fxc_env.engine.consensus_engine import ConsensusEngine
from fxc_env.engine.draws import with_initial_state
from fxc_env.envs.torch_env import GROUP

T_S = 20.0
Q = 0.05


def rows_of(obs: np.ndarray, config) -> np.ndarray:
    return np.asarray(obs)[..., : config.layout.rows_end]


def is_multiple(values: np.ndarray, q: float) -> bool:
    return bool(np.allclose(values / q, np.round(values / q), rtol=0, atol=1e-9))


def test_every_front_end_rounds_each_row_to_the_quantum():
    kwargs = dict(topology="ring", n_agents=5, obs_mode="raw", obs_resolution=Q)
    parallel = fxc_env.parallel_env(**kwargs)
    obs, _ = parallel.reset(seed=0)
    rows = rows_of(np.stack(list(obs.values())), parallel.config)
    assert is_multiple(rows, Q) and np.any(rows != 0)
    aec = fxc_env.env(**kwargs)
    aec.reset(seed=0)
    assert is_multiple(rows_of(aec.observe("agent_0"), aec.config), Q)
    vec = ConsensusVecEnv(n_envs=2, **kwargs)
    vec.seed(0)
    assert vec.config.obs_resolution == Q and is_multiple(rows_of(vec.reset(), vec.config), Q)
    torch_env = ConsensusTorchEnv(batch_size=2, seed=0, **kwargs)
    observed = torch_env.reset()[GROUP, "observation"].numpy()
    assert torch_env.config.obs_resolution == Q and is_multiple(rows_of(observed, torch_env.config), Q)


def test_no_quantum_keeps_every_observation_bit_for_bit():
    def episode(**kwargs) -> list[np.ndarray]:
        env = fxc_env.parallel_env(scenario="paper_fig1", n_intervals=30, **kwargs)
        obs, _ = env.reset(seed=4)
        policy, seen = ReferencePolicy(env), []
        while env.agents:
            seen.append(np.stack(list(obs.values())))
            obs, *_ = env.step({a: policy(obs[a]) for a in env.agents})
        return seen

    plain = episode()
    for quantum in (None, 0, 0.0):
        assert all(np.array_equal(a, b) for a, b in zip(plain, episode(obs_resolution=quantum), strict=True))
    assert make_config().obs_resolution == 0.0
    assert not all(np.array_equal(a, b) for a, b in zip(plain, episode(obs_resolution=1e-3), strict=True))


@pytest.mark.parametrize("bad", [-1e-3, float("nan"), float("inf"), "fine", True, [0.1]])
def test_a_bad_quantum_is_refused_by_name_on_every_front_end(bad):
    for make in (fxc_env.parallel_env, make_config, lambda **kw: ConsensusTorchEnv(batch_size=1, **kw)):
        with pytest.raises(ArgumentError, match=r"^obs_resolution: expected a finite number"):
            make(obs_resolution=bad)
    with pytest.raises(ArgumentError, match=r"^obs_resolution"):
        with_resolution(quick_optimality_suite(1), bad)


def test_the_resolution_floor_of_a_ring_of_20_is_the_exact_worst_case_15_q():
    config = make_config(topology="ring", n_agents=20, n_intervals=200, settling_time=T_S, schedule="uniform")
    lower, upper = resolution_floor_bounds(config.topology, config.schedule.times)
    assert lower == pytest.approx(15.1005, rel=1e-5) and upper == pytest.approx(lower, rel=1e-9)
    floors = resolution_floor(config.topology, config.schedule.times, [0.0, 1e-3, 0.1], dim=2)
    np.testing.assert_allclose(floors, np.sqrt(2) * lower * np.array([0.0, 1e-3, 0.1]), rtol=1e-12)
    state, value = resolution_worst_state(config.topology, config.schedule.times)
    x, v = state
    t = config.schedule.times[:-1, None]
    edges = config.topology.edges[0]
    rows = (x[edges[:, 0]] - x[edges[:, 1]]) + t * (v[edges[:, 0]] - v[edges[:, 1]])
    assert np.max(np.abs(rows)) <= 0.5 + 1e-12 and np.max(np.abs(v[edges[:, 0]] - v[edges[:, 1]])) <= 0.5 + 1e-12
    assert value == pytest.approx(np.ptp(x + T_S * v) + T_S * np.ptp(v)) == pytest.approx(lower)


def run_states(law, case: BenchmarkCase, states: list) -> np.ndarray:
    """``D(T_s)`` (metres) of ``law`` from each ``(x0, v0)`` (1-D, ``(N,)``); the engine's own loop."""
    k = 200 if law.sampled else 1000
    config = contender_config(Contender(law.name, law.name, law.sampled, *law.settings[1:]), case, k, T_S)
    policy = load_policy(law.name, config)
    engine = ConsensusEngine(config, n_episodes=len(states))
    draws = [
        with_initial_state(engine.draw_episode(np.random.default_rng(0)), x[:, None], v[:, None]) for x, v in states
    ]
    engine.reset_from_draws(draws, rng=np.random.default_rng(0))
    with np.errstate(all="ignore"):
        while not engine.done:
            engine.step(np.asarray(policy(engine.observations()), dtype=np.float64))
    metrics = engine.batch_metrics()
    return metrics["relative_deadline_error"] * np.asarray(engine.initial_disagreement)


@pytest.mark.parametrize("quantum", [1e-3, 0.1])
@pytest.mark.parametrize("case", [BenchmarkCase("ring", 20), BenchmarkCase("random", 20)], ids=lambda c: c.key)
def test_every_law_runs_under_a_quantum_or_refuses_it_and_none_ends_its_worst_case_below_the_floor(case, quantum):
    """The floor is a worst case over the states that read all zeros: every law meets it there, exactly."""
    quantised = BenchmarkCase(case.topology, case.n_agents, conditions=(("obs_resolution", quantum),))
    ran = 0
    for law in LAWS.values():
        contender = Contender(law.name, law.name, *law.settings)
        config = contender_config(contender, quantised, 200 if law.sampled else 1000, T_S)
        try:
            load_policy(law.name, config)
        except ArgumentError as exc:  # by name: the quantum (or, first, a graph it cannot use)
            assert str(exc).startswith(("obs_resolution:", "topology:")), (law.name, str(exc))
            continue
        z, unit = resolution_worst_state(config.topology, config.schedule.times)
        floor = float(resolution_floor(config.topology, config.schedule.times, quantum))
        assert floor == pytest.approx(unit * quantum)
        worst = (z[0] * quantum * (1 - 1e-9), z[1] * quantum * (1 - 1e-9))
        rng = np.random.default_rng(1)
        others = [(rng.uniform(-5, 5, case.n_agents), rng.uniform(-2, 2, case.n_agents)) for _ in range(2)]
        final = run_states(law, quantised, [worst, *others])
        assert final[0] == pytest.approx(floor, rel=1e-6), law.name  # silent: the worst state coasts
        assert np.max(final) >= floor * (1 - 1e-6), law.name
        ran += 1
    assert ran >= 7


def test_the_laws_that_read_numbers_off_motions_refuse_a_quantum_by_name():
    config = make_config(topology="ring", n_agents=6, schedule="uniform", obs_mode="raw", obs_resolution=1e-6)
    for name in ("signalling", "graph_agnostic", "bounded_steer"):
        with pytest.raises(ArgumentError, match=rf"^obs_resolution: {LAWS[name].policy.__name__} reads numbers"):
            LAWS[name].policy(config)


def test_the_episode_infos_carry_the_resolution_floor_only_with_a_quantum():
    def episode_end(**kwargs) -> tuple[dict, float]:
        env = fxc_env.parallel_env(topology="ring", n_agents=20, n_intervals=20, settling_time=T_S, **kwargs)
        env.reset(seed=1)
        x, v = env.state().T
        while env.agents:
            _, _, _, _, infos = env.step({a: np.zeros(env.action_space(a).shape) for a in env.agents})
        return next(iter(infos.values()))["episode"], float(np.ptp(x) + T_S * np.ptp(v))

    config = make_config(topology="ring", n_agents=20, n_intervals=20, settling_time=T_S)
    floor = float(resolution_floor(config.topology, config.schedule.times, 1e-2))
    metrics, d0 = episode_end(obs_resolution=1e-2)
    assert metrics["resolution_floor"] == pytest.approx(floor / d0)
    assert "resolution_floor" not in episode_end()[0]
    assert "resolution_floor" not in episode_end(obs_resolution=1e-2, obs_noise=1e-3)[0]


def test_fxc_simulate_prints_the_resolution_floor(tmp_path, capsys):
    from fxc_env.cli.main import main

    args = ["simulate", "--scenario", "paper_fig1", "--n-intervals", "20", "--out", str(tmp_path)]
    assert main([*args, "--obs-resolution", "1e-3"]) == 0
    assert "D(T_s)/D(0), worst silent state" in capsys.readouterr().out
    assert main(args) == 0
    assert "worst silent state" not in capsys.readouterr().out


def test_the_benchmark_report_gives_each_quantised_case_its_floor_and_best_law():
    suite = with_resolution(quick_optimality_suite(2), 1e-2)
    case = suite.cases[-1]
    assert dict(case.conditions) == {"obs_resolution": 1e-2} and not suite.cases[0].conditions
    contenders = [Contender(name, name, *LAWS[name].settings) for name in ("reference", "leader_follower")]
    results = [run_job(Job(c, case, 200, (0, 1), T_S, False)) for c in contenders]
    assert all(r.error is None for r in results)
    (row,) = resolution_rows(results)
    errors = {r.job.contender.name: np.median(r.metrics["relative_deadline_error"]) for r in results}
    assert row["best"] == min(errors, key=errors.get) and row["error"] == pytest.approx(min(errors.values()))
    assert row["floor"] == pytest.approx(np.median(results[0].metrics["resolution_floor"]))
    assert "worst D/D(0) ≥" in report.floor_text(results[0].metrics)
    assert "### Resolution floor" in "\n".join(resolution_section(results))
    assert resolution_section([r for r in results if r.job.case != case]) == []
