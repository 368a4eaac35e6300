"""The noise-fitted gain tables (issue 25, item 5): the closed form, the rank-one floor, refusals by name."""

import numpy as np
import pytest

from fxc_env.core.validation import ArgumentError
from fxc_env.training.recipes import noise_gains

torch = pytest.importorskip("torch")


@pytest.fixture(scope="module")
def config():
    return noise_gains.task_config(1e-3)


def _metrics(config, gains, seeds):
    """The engine's episode metrics of the table on ``seeds`` (its own noise stream)."""
    from fxc_env.engine import ConsensusEngine

    policy = noise_gains.policy_of(config, gains)
    engine = ConsensusEngine(config, n_episodes=len(seeds))
    engine.reset_from_draws(
        [engine.draw_episode(np.random.default_rng(s)) for s in seeds], rng=np.random.default_rng(7)
    )
    obs = np.empty((engine.n_episodes, config.n_agents, config.layout.size))
    while not engine.done:
        engine.observations(out=obs)
        engine.step(policy(obs))
    return engine.batch_metrics()


def test_closed_form_predicts_the_environment(config):
    """The expected energy and E* of the closed form match the engine's means (64 seeds, sampling error ~3%)."""
    gains = noise_gains.start_table(config, "deadbeat")
    _, energy, _, e_star = noise_gains.ring_moments(config, torch.tensor(gains))
    metrics = _metrics(config, gains, range(64))
    assert float(energy) == pytest.approx(np.mean(metrics["energy_ratio"] * metrics["energy_bound"]), rel=0.1)
    assert e_star == pytest.approx(np.mean(metrics["energy_bound"]), rel=0.1)


def test_measure_scores_the_deadbeat_table_as_the_suite_scores_minimum_time_noisy(config):
    """``measure`` of ``minimum_time``'s table is the optimality suite's ``minimum_time/noisy`` row, to the digit."""
    from fxc_env.baselines.harness.jobs import Job, run_job
    from fxc_env.baselines.harness.suite import BenchmarkCase, Contender

    result = noise_gains.measure(config, noise_gains.policy_of(config, noise_gains.start_table(config, "deadbeat")))
    contender = Contender("minimum_time/noisy", "minimum_time/noisy", True, "uniform", "plan", "normalized")
    case = BenchmarkCase("ring", 20, conditions=(("obs_noise", 1e-3),))
    suite = run_job(Job(contender, case, 200, tuple(range(20)), 20.0, False)).metrics
    assert result["error"] == pytest.approx(np.median(suite["relative_deadline_error"]), rel=1e-9)
    assert result["energy_ratio"] == pytest.approx(np.median(suite["energy_ratio"]), rel=1e-9)
    assert result["error"] == pytest.approx(2.32e-3, rel=0.01)  # the best law before these tables
    assert result["noise_floor"] == pytest.approx(2.06e-5, rel=0.01)


def test_no_rank_one_table_beats_the_rank_one_floor(config):
    """Any table of rank-one gains (one input shape per interval) stays above 0.0165 rms on ring N = 20, K = 200."""
    floor = noise_gains.rank_one_floor(config)
    assert floor == pytest.approx(0.0165, rel=0.01)
    rng = np.random.default_rng(0)
    for _ in range(3):
        left, right = rng.normal(size=(200, 2, 1)), rng.normal(size=(200, 1, 2))
        gains = 0.3 * left @ right * np.array([0.1, 1.0])[None, :, None]
        final, _, initial, _ = noise_gains.ring_moments(config, torch.tensor(gains), sigma=0.0)
        assert float(final / initial) ** 0.5 >= floor
    final, _, initial, _ = noise_gains.ring_moments(config, torch.tensor(noise_gains.start_table(config, "accel")))
    assert float(final / initial) ** 0.5 >= floor


def test_refusals_name_the_argument(config, tmp_path):
    with pytest.raises(ArgumentError, match="topology"):
        noise_gains.ring_moments(noise_gains.task_config(1e-3, topology="path"), torch.zeros(200, 2, 2))
    with pytest.raises(ArgumentError, match="gains"):
        noise_gains.policy_of(config, np.zeros((199, 2, 2)))
    with pytest.raises(ArgumentError, match="policy"):
        noise_gains.measure(config, np.zeros((200, 2, 2)))
    with pytest.raises(ArgumentError, match="start"):
        noise_gains.start_table(config, "zero")
    np.save(tmp_path / "short.npy", np.zeros((10, 2, 2)))
    with pytest.raises(ArgumentError, match="start"):
        noise_gains.start_table(config, str(tmp_path / "short.npy"))
    with pytest.raises(ArgumentError, match="cap"):
        noise_gains.fit(config, cap=0.0)
    with pytest.raises(ArgumentError, match="sigma"):
        noise_gains.task_config(-1.0)


@pytest.mark.slow
def test_a_fit_round_lowers_the_predicted_error_and_saves_the_table(config, tmp_path):
    """One L-BFGS round from the accelerations lowers the predicted rms (9.2 before) and writes the table it returns."""
    start = noise_gains.start_table(config, "accel")
    final, _, initial, _ = noise_gains.ring_moments(config, torch.tensor(start))
    gains, history = noise_gains.fit(config, cap=1e3, start="accel", steps=1, out=str(tmp_path / "t.npy"))
    assert float(final / initial) ** 0.5 == pytest.approx(9.23, rel=0.01)
    assert history[0][1] < 0.1
    np.testing.assert_array_equal(np.load(tmp_path / "t.npy"), gains)


def test_a_saved_table_runs_in_the_benchmark_only_at_its_noise(config, tmp_path):
    """``--policy`` files load through the benchmark's ``load_policy``; another σ is refused by name."""
    from fxc_env.baselines.harness.suite import load_policy

    path = noise_gains.policy_of(config, noise_gains.start_table(config, "deadbeat")).save(tmp_path / "t.npz")
    policy = load_policy(str(path), config)
    result = noise_gains.measure(config, policy)
    assert result["error"] == pytest.approx(2.32e-3, rel=0.01)
    with pytest.raises(ArgumentError, match="obs_noise"):
        load_policy(str(path), noise_gains.task_config(1e-4))
