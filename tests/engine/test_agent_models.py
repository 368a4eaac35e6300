"""General linear agents and formations in the environment: exact episodes, the generalised theorems, errors."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import scipy.linalg
from pettingzoo.test import parallel_api_test
from scipy.integrate import solve_ivp

import fxc_env
from fxc_env import ConsensusEngine, ReferencePolicy, make_config
from fxc_env.config.scenarios import HEXAGON
from fxc_env.core.linear import model_matrices
from fxc_env.core.validation import ArgumentError

#: The named models (with their parameters) every test runs over.
MODELS = [
    dict(agent_model="single_integrator"),
    dict(agent_model={"name": "integrator_chain", "order": 3}),
    dict(agent_model={"name": "integrator_chain", "order": 4}),
    dict(agent_model={"name": "damped", "damping": 0.5}),
    dict(agent_model={"name": "oscillator", "frequency": 1.0}),
]
DOUBLE_INTEGRATOR = model_matrices("double_integrator")


def model_id(kwargs):
    spec = kwargs["agent_model"]
    return "-".join(str(v) for v in spec.values()) if isinstance(spec, dict) else spec


def reference_episode(config, x0, v0):
    """Play the reference; return the engine, the states ``(K + 1, N, n, dim)`` and the plans ``(K, N, dim, n)``."""
    engine = ConsensusEngine(config)
    engine.reset(x0[None], v0[None])
    policy = ReferencePolicy(config)
    states, plans = [engine.state[0].copy()], []
    while not engine.done:
        outcome = engine.step(engine.validate_actions(policy.act(engine.observations())))
        states.append(engine.state[0].copy())
        plans.append(outcome.plan[0])
    return engine, np.array(states), np.array(plans)


@pytest.mark.parametrize("kwargs", MODELS, ids=model_id)
@pytest.mark.slow
def test_a_whole_reference_episode_matches_solve_ivp(kwargs):
    # Each interval integrated by scipy's DOP853 from the same start under the minimum-energy
    # input u(s) = B^T e^{A^T (T - s)} lambda (lambda = G(T)^{-1} Delta by the package); the
    # states the environment reports agree to 1e-9 relative over the whole episode (K = 200).
    config = make_config("paper_fig1", **kwargs)
    _, states, plans = reference_episode(config, *config.initial_state)
    A, B = config.model.A, config.model.B
    maps = config.interval_maps
    n = config.n_states
    worst = 0.0
    for k in range(config.n_intervals):
        T = config.schedule.intervals[k]
        costate = maps.costate(k, plans[k][:, 0])  # (N, n), first axis

        def rhs(s, z, costate=costate, T=T):
            z = z.reshape(-1, n)
            u = costate @ scipy.linalg.expm(A * (T - s)) @ B  # (N, m)
            return (z @ A.T + u @ B.T).ravel()

        start = states[k][:, :, 0]
        atol = 1e-15 * np.max(np.abs(start * config.row_scales[k]) / config.row_scales[k])
        solution = solve_ivp(rhs, (0.0, T), start.ravel(), method="DOP853", rtol=1e-13, atol=atol)
        assert solution.success, solution.message
        expected = solution.y[:, -1].reshape(-1, n)
        got = states[k + 1][:, :, 0]
        # Relative to the state's size in position units (x, T v, T^2 a, ...), as the plan is solved.
        scales = config.row_scales[k]
        size = np.max(np.abs(start * scales)) + np.max(np.abs(expected * scales))
        worst = max(worst, np.max(np.abs((got - expected) * scales)) / size)
    assert worst <= 1e-9


def test_the_general_path_with_the_double_integrators_matrices_equals_the_closed_forms():
    closed = make_config("paper_fig1")
    general = make_config("paper_fig1", agent_model=DOUBLE_INTEGRATOR)
    assert general.model is not None and general.agent_model == "linear"
    x0, v0 = closed.initial_state
    closed_engine, general_engine = ConsensusEngine(closed), ConsensusEngine(general)
    closed_engine.reset(x0[None], v0[None])
    general_engine.reset(x0[None], v0[None])
    policy = ReferencePolicy(closed)
    general_policy = ReferencePolicy(general)
    while not closed_engine.done:
        obs = closed_engine.observations()
        # The measured rows (metres, m/s) agree to 1e-12 of the state's size. (Normalized rows late
        # in the episode divide round-off-sized differences by each other and are not compared.)
        scale = np.max(np.abs(closed_engine.state))
        rows = closed_engine.measurements()[0]
        np.testing.assert_allclose(general_engine.measurements()[0], rows, rtol=0, atol=1e-12 * scale)
        closed_engine.step(policy.act(obs))
        general_engine.step(general_policy.act(general_engine.observations()))
        assert np.max(np.abs(general_engine.state - closed_engine.state)) <= 1e-12 * scale
    # Energies and peaks are quadratic and linear in the plans, which late in the episode are
    # differences of nearly equal states: compared over the episode, where users read them.
    closed_metrics, general_metrics = closed_engine.episode_metrics(), general_engine.episode_metrics()
    assert general_metrics.energy == pytest.approx(closed_metrics.energy, rel=1e-12)
    assert general_metrics.peak_input == pytest.approx(closed_metrics.peak_input, rel=1e-12)
    assert general_metrics.relative_deadline_error < 3e-12


@pytest.mark.parametrize("kwargs", MODELS, ids=model_id)
@pytest.mark.parametrize("period", [1, 3])
@pytest.mark.slow
def test_the_generalised_final_value_on_held_out_random_digraphs(kwargs, period):
    # Theorems 1-2 generalised: z_i(T_s) = e^{A T_s} sum_j xi_j z_j(0) for every agent, on
    # random digraphs the package never saw in its tests (seeds 101..), fixed and switching.
    for seed in (101, 202):
        config = make_config(
            n_agents=8, topology="random", topology_seed=seed, topology_period=period, mean_in_degree=2.0, **kwargs
        )
        rng = np.random.default_rng(seed)
        x0, v0 = rng.uniform(-5, 5, (8, 1)), rng.uniform(-2, 2, (8, 1))
        _, states, _ = reference_episode(config, x0, v0)
        xi = config.topology.consensus_weights()
        weighted = np.einsum("j,jnd->nd", xi, states[0])  # (n, dim)
        final = config.model.free_motion_matrix(config.settling_time) @ weighted
        scale = np.max(np.abs(states[0])) + np.max(np.abs(final))
        assert np.max(np.abs(states[-1] - final[None])) <= 1e-8 * scale, seed


@pytest.mark.slow
def test_deadline_errors_of_every_model_at_K_200_and_400():
    # Every named model on paper_fig1 reaches round-off level by T_s (docs: agent-models.md's table).
    for kwargs in MODELS:
        for K, bound in ((200, 1e-11), (400, 1e-15)):
            config = make_config("paper_fig1", n_intervals=K, **kwargs)
            engine, _, _ = reference_episode(config, *config.initial_state)
            assert engine.episode_metrics().relative_deadline_error <= bound, (kwargs, K)


def test_normalized_observations_of_a_chain_are_scale_free():
    config = make_config("paper_fig1", agent_model={"name": "integrator_chain", "order": 3})
    x0, v0 = config.initial_state
    observed = []
    for factor in (1.0, 1e-6, 1e6):
        engine = ConsensusEngine(config)
        engine.reset(factor * x0[None], factor * v0[None])
        policy = ReferencePolicy(config)
        for _ in range(5):
            engine.step(policy.act(engine.observations()))
        observed.append(engine.observations())
        assert np.all(np.abs(observed[-1][..., : config.layout.rows_end]) <= 1.0)
    np.testing.assert_allclose(observed[1], observed[0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(observed[2], observed[0], rtol=1e-9, atol=1e-12)


def test_the_parallel_env_with_a_chain_passes_pettingzoos_api_test():
    env = fxc_env.parallel_env(scenario="paper_fig1", agent_model={"name": "integrator_chain", "order": 3}, dim=2)
    parallel_api_test(env, num_cycles=20)
    env.reset(seed=0)
    assert env.observation_space("agent_0").shape == (env.config.layout.size,)
    assert env.action_space("agent_0").shape == (3 * 2,)
    assert env.state().shape == (6, 3 * 2)


# ------------------------------------------------------------------------ formations
@pytest.mark.slow
def test_the_hexagon_scenario_reaches_its_formation_by_the_deadline():
    trajectory = fxc_env.simulate("reference", "formation_hexagon", seed=3)
    final = trajectory.x[-1]  # (6, 2) absolute positions at T_s
    shape = final - np.array(HEXAGON)
    spread_before = np.ptp(trajectory.x[0] - np.array(HEXAGON), axis=0).max()
    assert np.ptp(shape, axis=0).max() <= 1e-9 * spread_before  # every x_i - h_i equal: the hexagon
    # The formation keeps its shape after T_s: all agents share one velocity.
    assert np.ptp(trajectory.v[-1], axis=0).max() <= 1e-9 * np.abs(trajectory.v[0]).max()
    assert trajectory.metrics.relative_deadline_error < 1e-11


def test_position_offsets_of_a_chain_stay_constant_and_are_reached():
    offsets = np.linspace(-3.0, 3.0, 6)[:, None]
    config = make_config("paper_fig1", agent_model={"name": "integrator_chain", "order": 3}, formation_offsets=offsets)
    np.testing.assert_array_equal(
        config.formation_motion[:, None] @ config.formation, np.broadcast_to(config.formation, (201, 6, 3, 1))
    )
    engine, _, _ = reference_episode(config, *config.initial_state)
    absolute = engine.absolute_state()[0]  # (N, n, dim)
    gaps = absolute[:, 0, 0] - offsets[:, 0]
    assert np.ptp(gaps) <= 1e-9 * np.ptp(config.initial_state[0])


@pytest.mark.slow
def test_full_state_offsets_of_an_oscillator_move_with_the_free_motion():
    # Agents agree on z_i - e^{A t} h_i: with velocity offsets the targets rotate with the oscillator.
    offsets = np.zeros((6, 1, 2))
    offsets[:, 0, 1] = np.arange(6) * 0.1
    config = make_config("paper_fig1", agent_model="oscillator", formation_offsets=offsets)
    engine, _, _ = reference_episode(config, *config.initial_state)
    rotated = config.model.free_motion_matrix(config.settling_time) @ config.formation  # (N, n, dim)
    error = engine.absolute_state()[0] - rotated
    assert np.ptp(error, axis=0).max() <= 1e-9 * np.abs(config.initial_state[0]).max()


# ---------------------------------------------------------------------------- errors
@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(agent_model=(np.diag([1.0, 2.0]), np.array([[1.0], [0.0]]))), r"A, B: .*rank 1 < n = 2"),
        (dict(agent_model=(np.eye(2), np.ones((3, 1)))), "B: "),
        (dict(agent_model=(np.array([[0.0, np.nan], [0.0, 0.0]]), np.array([[0.0], [1.0]]))), "A: "),
        (dict(agent_model="triple_integrator"), "agent_model: "),
        (dict(agent_model={"name": "integrator_chain", "order": 5}), "order: "),
        (dict(agent_model={"name": "damped", "damping": -1.0}), "damping: "),
        (dict(agent_model={"damping": 0.5}), r"agent_model: expected a dict with a 'name' key"),
        (dict(agent_model={"name": "damped", "order": 3}), r"agent_model: 'damped' takes only 'damping'.*\['order'\]"),
        (dict(agent_model={"name": "single_integrator", "order": 3}), r"agent_model: .*takes no parameters"),
        (dict(agent_model={"name": "warp"}), r"agent_model\['name'\]: "),
        (dict(agent_model=5), r"agent_model: expected a model name, a dict .* or a pair \(A, B\), got int"),
        (dict(agent_model={"name": "integrator_chain", "order": 3}, action_mode="accel"), "action_mode: "),
        (dict(agent_model="oscillator", u_max=10.0), "u_max: "),
        (dict(formation_offsets=np.zeros((5, 1))), "formation_offsets: "),
        (dict(formation_offsets=np.full((6, 1), np.inf)), "formation_offsets: "),
        (dict(formation_offsets="hexagon"), "formation_offsets: "),
    ],
)
def test_bad_models_and_offsets_are_refused_naming_the_argument(kwargs, message):
    with pytest.raises((ArgumentError, TypeError), match=message):
        make_config("paper_fig1", **kwargs)


@pytest.mark.parametrize(
    "kwargs",
    [dict(agent_model={"name": "integrator_chain", "order": 3}), dict(agent_model="oscillator")],
    ids=["chain3", "oscillator"],
)
def test_a_general_model_on_torch_plays_the_numpy_engine_to_rounding(kwargs):
    torch = pytest.importorskip("torch")
    config = make_config("formation_hexagon", n_intervals=20, **kwargs)
    host, device = ConsensusEngine(config, 2), ConsensusEngine(config, 2, device="cpu")
    draws = [host.draw_episode(np.random.default_rng(seed)) for seed in range(2)]
    host.reset_from_draws(draws)
    device.reset_from_draws(draws)
    policy = ReferencePolicy(config)
    for _ in range(config.n_intervals):
        actions = policy.act(host.observations())
        expected, got = host.step(actions), device.step(torch.as_tensor(actions))
        for name in ("reward", "energy", "peak_input", "u_start", "u_end"):
            want = getattr(expected, name)
            assert np.allclose(getattr(got, name).numpy(), want, rtol=1e-12, atol=1e-12 * np.abs(want).max()), name
    host_metrics, device_metrics = host.batch_metrics(), device.batch_metrics()
    for name, column in host_metrics.items():
        assert np.allclose(device_metrics[name], column, rtol=1e-12, atol=1e-12, equal_nan=True), name


def test_a_general_model_steps_on_the_meta_device_without_reading_the_host():
    torch = pytest.importorskip("torch")
    config = make_config("formation_hexagon", agent_model={"name": "integrator_chain", "order": 3}, n_intervals=5)
    engine = ConsensusEngine(config, 4, device="meta")  # any read of a value would raise here
    x0, v0, u_max, topologies = engine.draw_batch()
    engine.reset(x0, v0, u_max=u_max, topologies=topologies)
    for _ in range(config.n_intervals):
        engine.observations()
        engine.step(torch.zeros((4, 6, config.action_size), dtype=torch.float64, device="meta"))
    assert engine.metric_tensors()["energy"].shape == (4,)


@pytest.mark.slow
def test_fxc_simulate_writes_the_figures_of_a_chain_and_of_a_formation(tmp_path):
    for arguments, extra in (
        (["--agent-model", "integrator_chain", "--order", "3"], []),
        (["--scenario", "formation_hexagon"], ["formation.png"]),
    ):
        out = tmp_path / arguments[1]
        result = subprocess.run(
            [sys.executable, "-m", "fxc_env.cli", "simulate", *arguments, "--out", str(out)],
            capture_output=True,
            text=True,
            env={"MPLBACKEND": "Agg", "PATH": ""},
        )
        assert result.returncode == 0, result.stderr
        for name in ("positions.png", "velocities.png", "inputs.png", "disagreement.png", *extra):
            assert (out / name).stat().st_size > 1000, name


@pytest.mark.slow
def test_the_models_benchmark_suite_scores_the_reference_on_every_model(tmp_path):
    import csv

    from fxc_env.baselines.harness.benchmark import run_benchmark
    from fxc_env.baselines.harness.suite import builtin_contenders, models_suite

    suite = models_suite(n_seeds=2)
    output = run_benchmark(
        suite, builtin_contenders(["reference", "linear_sampled"]), tmp_path, workers=1, progress=False
    )
    rows = list(csv.DictReader((tmp_path / "results.csv").open()))
    reference = [r for r in rows if r["policy"] == "reference"]
    assert len(reference) == 2 * 6 * 2  # two graphs, six models, K = 200 and 400
    for row in reference:
        assert float(row["relative_deadline_error_median"]) < 1e-10, row["case"]
    # The double integrator's analytic baselines do not run on other models, and the report says why.
    assert "action_mode" in output.markdown


# ---------------------------------------------------------------------------- the agent_model spec
SPECS = [
    ({"name": "integrator_chain", "order": 3}, {"order": 3}),
    ({"name": "damped", "damping": 0.7}, {"damping": 0.7}),
    ({"name": "oscillator", "frequency": 1.3}, {"frequency": 1.3}),
]


@pytest.mark.parametrize(("spec", "flat"), SPECS, ids=lambda x: str(x))
def test_the_flat_model_parameters_warn_naming_the_spec_and_give_its_model(spec, flat):
    # agent_model={"name": "damped", "damping": 0.7} is the spelling; damping=0.7 beside agent_model="damped"
    # still works for one release, with a DeprecationWarning that writes the new spelling out.
    ((key, value),) = flat.items()
    expected = model_matrices(spec["name"], **flat)
    new = make_config("paper_fig1", agent_model=spec)
    np.testing.assert_array_equal(new.model.A, expected[0])
    with pytest.warns(DeprecationWarning, match=rf"^{key}={value!r} is deprecated .*write agent_model=\{{'name'"):
        old = make_config("paper_fig1", agent_model=spec["name"], **flat)
    np.testing.assert_array_equal(old.model.A, new.model.A)
    assert old.agent_model == new.agent_model == spec["name"]


def test_a_flat_parameter_given_twice_or_without_a_model_is_refused():
    with pytest.warns(DeprecationWarning), pytest.raises(ArgumentError, match=r"^damping: given twice"):
        make_config(agent_model={"name": "damped", "damping": 0.7}, damping=0.2)
    with pytest.warns(DeprecationWarning), pytest.raises(ArgumentError, match=r"^order: the double integrator"):
        make_config(order=3)


def test_every_front_end_takes_the_model_spec():
    torchrl = pytest.importorskip("fxc_env.envs.torch_env")
    spec = {"name": "damped", "damping": 0.7}
    expected = make_config("formation_hexagon", agent_model=spec).model.A
    fronts = [
        fxc_env.parallel_env(scenario="formation_hexagon", agent_model=spec).unwrapped.config,
        fxc_env.env(scenario="formation_hexagon", agent_model=spec).unwrapped.config,
        fxc_env.ConsensusVecEnv(2, scenario="formation_hexagon", agent_model=spec).config,
        torchrl.ConsensusTorchEnv(batch_size=2, scenario="formation_hexagon", agent_model=spec).config,
        ConsensusEngine(make_config("formation_hexagon", agent_model=spec)).config,
    ]
    for config in fronts:
        np.testing.assert_array_equal(config.model.A, expected)
        assert config.agent_model == "damped"


def test_every_front_end_takes_the_flat_alias_with_a_warning():
    torchrl = pytest.importorskip("fxc_env.envs.torch_env")
    flat = {"scenario": "formation_hexagon", "agent_model": "damped", "damping": 0.7}
    makers = [
        lambda: fxc_env.parallel_env(**flat).unwrapped.config,
        lambda: fxc_env.env(**flat).unwrapped.config,
        lambda: fxc_env.ConsensusVecEnv(2, **flat).config,
        lambda: torchrl.ConsensusTorchEnv(**flat).config,
    ]
    for make in makers:
        with pytest.warns(DeprecationWarning, match=r"^damping=0.7 is deprecated") as caught:
            assert make().model.A[1, 1] == -0.7
        assert caught[0].filename == __file__  # the user's line, not PettingZoo's or TorchRL's machinery
