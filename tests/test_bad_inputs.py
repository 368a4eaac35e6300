"""Bad input gets a clear error and loses nothing (docs: bad-input.md, "Bad input and saved policies").

One table of distinct bad inputs across every front end: the constructor, ``reset`` and
``step`` of the parallel env, the AEC form, the SB3 VecEnv, ``simulate`` and the command
line. Each row asserts that the exception is the package's usage error
(:class:`~fxc_env.core.validation.ArgumentError`), that its message starts with the
argument's name, and, for a live environment, that nothing changed: the state, the clock,
the live agents and the generator, and that the environment then steps exactly like an
untouched twin.
"""

from __future__ import annotations

import pickle

import networkx as nx
import numpy as np
import pytest

import fxc_env
from fxc_env import ReferencePolicy
from fxc_env.core.validation import ArgumentError

N = 6

# --------------------------------------------------------------- constructor
CONSTRUCTOR_CASES = [
    ({"n_agents": 0, "topology": "ring"}, "n_agents"),
    ({"n_agents": 2.5, "topology": "ring"}, "n_agents"),
    ({"n_agents": True, "topology": "ring"}, "n_agents"),
    ({"n_agents": 10**12, "topology": "ring"}, "n_agents"),
    ({"settling_time": 0.0}, "settling_time"),
    ({"settling_time": -3.0}, "settling_time"),
    ({"settling_time": float("nan")}, "settling_time"),
    ({"settling_time": "20"}, "settling_time"),
    ({"settling_time": 1e155}, "settling_time"),
    ({"settling_time": 1e-200}, "n_intervals"),
    ({"n_intervals": 0}, "n_intervals"),
    ({"n_intervals": 2**63}, "n_intervals"),
    ({"n_intervals": 3.0}, "n_intervals"),
    ({"schedule": [1e-300, 20.0], "settling_time": 20.0 + 1e-300}, "schedule"),
    ({"schedule": [5.0, 5.0], "settling_time": 20.0}, "schedule"),
    ({"schedule": "geometric"}, "schedule"),
    ({"schedule": [[1.0, 2.0]]}, "schedule"),
    ({"schedule": ["a", "b"]}, "schedule"),
    ({"dim": 0}, "dim"),
    ({"dim": 10**6}, "dim"),
    ({"action_mode": "force"}, "action_mode"),
    ({"obs_mode": "scaled"}, "obs_mode"),
    ({"obs_format": "tuple"}, "obs_format"),
    ({"obs_dtype": "float16"}, "obs_dtype"),
    ({"global_state": "pixels"}, "global_state"),
    ({"action_bound": -1.0}, "action_bound"),
    ({"reward_floor": 0.0}, "reward_floor"),
    ({"position_range": float("inf")}, "position_range"),
    ({"velocity_range": 1e200}, "velocity_range"),
    ({"u_max": 0.0}, "u_max"),
    ({"u_max": 1e300}, "u_max"),
    ({"obs_noise": -0.1}, "obs_noise"),
    ({"obs_noise": 1e300}, "obs_noise"),
    ({"obs_resolution": -1e-3}, "obs_resolution"),
    ({"obs_resolution": float("nan")}, "obs_resolution"),
    ({"obs_resolution": "fine"}, "obs_resolution"),
    ({"link_dropout": 1.0}, "link_dropout"),
    ({"link_dropout": "often"}, "link_dropout"),
    ({"switching": "sometimes"}, "switching"),
    ({"scenario": ["paper_fig1"]}, "scenario"),
    ({"scenario": "paper_fig2"}, "scenario"),
    ({"topology": "hypercube"}, "topology"),
    ({"topology": [(0, 1), (1, 1)], "n_agents": 3}, "topology"),
    ({"topology": [(0, 1), (0.5, 2)], "n_agents": 3}, "topology"),
    ({"topology": [(0, 1), (1, float("nan"))], "n_agents": 3}, "topology"),
    ({"topology": [(0, 1), (1, 1e30)]}, "topology"),
    ({"topology": [[(0, 1), (1, 2)], None]}, "topology"),
    ({"topology": [("a", "b")]}, "topology"),
    ({"topology": nx.DiGraph([(0.5, 1.0), (1.0, 2.0)])}, "topology"),
    ({"topology": nx.DiGraph([("a", "b"), ("b", "c")])}, "topology"),
    ({"topology": [(0, 1)], "n_agents": 3}, "topology"),
    ({"topology": "random", "n_agents": 20, "topology_seed": -1}, "topology_seed"),
    ({"topology": "random", "n_agents": 20, "topology_seed": 1.5}, "topology_seed"),
    ({"topology": "random", "n_agents": 20, "mean_in_degree": -1.0}, "mean_in_degree"),
    ({"topology": "random", "n_agents": 20, "topology_period": 0}, "topology_period"),
    ({"obs_slots": 0}, "obs_slots"),
    ({"initial_state": "zeros"}, "initial_state"),
    ({"initial_state": ([1.0] * N,)}, "initial_state"),
    ({"initial_state": ([[1.0, 2.0], [3.0]] + [[0.0, 0.0]] * 4, [[0.0, 0.0]] * N), "dim": 2}, "initial_state"),
    ({"initial_state": ([1e308] * N, [0.0] * N)}, "initial_state"),
    ({"initial_state": ([float("nan")] * N, [0.0] * N)}, "initial_state"),
    ({"render_mode": "ansi"}, "render_mode"),
    ({"max_cycles": 0}, "max_cycles"),
    # float32 holds at most 3.4e38: a raw float32 observation of a larger state would be inf
    ({"obs_dtype": "float32", "obs_mode": "raw", "position_range": 1e100}, "position_range"),
    ({"obs_dtype": "float32", "obs_mode": "raw", "velocity_range": (1.0, 1e50)}, "velocity_range"),
    ({"obs_dtype": "float32", "obs_mode": "raw", "initial_state": ([1e50] * N, [0.0] * N)}, "initial_state"),
    ({"agent_model": {"name": "oscillator", "frequency": 1e300}}, "frequency"),
    ({"agent_model": {"name": "damped", "damping": 1e300}}, "damping"),
    ({"n_agents": np.array([1, 2]), "topology": "ring"}, "n_agents"),
    ({"topology": np.array(4)}, "topology"),
    ({"schedule": [10.0, 10.0, 1e-15]}, "schedule"),  # the last interval is lost to rounding at t = 20 s
    ({"schedule": [True] * 20}, "schedule"),
    ({"topology": "ring", "topology_period": 3}, "topology_period"),
    ({"topology": "ring", "mean_in_degree": 3.0}, "mean_in_degree"),
    ({"reward_floor": 1e308}, "reward_floor"),  # f = 1e308 D(0) overflows: every reward would be NaN
    ({"topology": {"mixture": [({"family": "ring"}, 1e308), ({"family": "path"}, 1e308)]}}, "topology"),
]


def test_float32_raw_observations_refuse_states_beyond_float32_naming_both():
    with pytest.raises(ArgumentError, match=r'^position_range: .*obs_dtype="float32", obs_mode="raw"'):
        fxc_env.parallel_env(obs_dtype="float32", obs_mode="raw", position_range=1e100)
    env = fxc_env.parallel_env(obs_dtype="float32", obs_mode="raw")
    with pytest.raises(ArgumentError, match=r"^options\['x0'\]: .*obs_dtype=\"float32\", obs_mode=\"raw\""):
        env.reset(seed=0, options={"x0": np.full(N, 1e100)})
    observations, _ = env.reset(seed=0, options={"x0": np.full(N, 1e30), "v0": np.full(N, -1e30)})
    assert all(np.isfinite(o).all() for o in observations.values())
    # float64 observations (or normalized ones) keep the float64 range
    env64 = fxc_env.parallel_env(obs_mode="raw", position_range=1e100)
    assert all(np.isfinite(o).all() for o in env64.reset(seed=0)[0].values())


def test_intervals_of_exactly_the_documented_minimum_are_accepted():
    for k in (3, 59, 100):  # T_s = K * 1e-30 s: rounding leaves some intervals a few ulps below 1e-30 s
        env = fxc_env.parallel_env(settling_time=k * 1e-30, n_intervals=k, schedule="uniform")
        assert env.unwrapped.config.schedule.intervals.min() == pytest.approx(1e-30, rel=1e-9)
    env = fxc_env.parallel_env(schedule=[1e-30, 20.0 - 1e-30], settling_time=20.0)
    assert env.unwrapped.config.n_intervals == 2


@pytest.mark.parametrize(("kwargs", "name"), CONSTRUCTOR_CASES, ids=[str(c[0])[:60] for c in CONSTRUCTOR_CASES])
def test_constructor_names_the_bad_argument(kwargs, name):
    with pytest.raises(ArgumentError) as caught:
        fxc_env.parallel_env(**kwargs)
    assert str(caught.value).startswith(name), str(caught.value)


def test_the_constructor_cases_are_distinct_and_many():
    assert len({repr(kwargs) for kwargs, _ in CONSTRUCTOR_CASES}) == len(CONSTRUCTOR_CASES) >= 50


# ------------------------------------------------------------- live parallel env
def snapshot(env):
    """Everything a refused call must leave as it was."""
    engine = env.unwrapped.engine
    return (
        engine.state.copy(),
        engine.k,
        list(env.unwrapped.agents),
        pickle.dumps(engine.rng.bit_generator.state),
    )


def assert_unchanged(before, after):
    np.testing.assert_array_equal(before[0], after[0])
    assert before[1:] == after[1:]


def started(**kwargs):
    env = fxc_env.parallel_env(scenario="paper_fig1", **kwargs)
    obs, _ = env.reset(seed=3)
    policy = ReferencePolicy(env)
    for _ in range(2):
        obs = env.step({a: policy(o) for a, o in obs.items()})[0]
    return env, obs, policy


def good_actions(env, obs, policy):
    return {agent: policy(o) for agent, o in obs.items()}


STEP_CASES = [
    ("nan action", lambda acts: {**acts, "agent_2": np.array([np.nan, 0.0])}, "actions"),
    ("inf action", lambda acts: {**acts, "agent_0": np.array([0.0, np.inf])}, "actions"),
    ("short action", lambda acts: {**acts, "agent_1": np.array([0.0])}, "actions"),
    ("string action", lambda acts: {**acts, "agent_1": "left"}, "actions"),
    ("ragged action", lambda acts: {**acts, "agent_1": [0.0, [1.0]]}, "actions"),
    ("unknown agent", lambda acts: {**acts, "agent_9": np.zeros(2)}, "actions"),
    ("missing agent", lambda acts: {k: v for k, v in acts.items() if k != "agent_5"}, "actions"),
    ("not a dict", lambda acts: list(acts.values()), "actions"),
]


@pytest.mark.parametrize(("label", "change", "name"), STEP_CASES, ids=[c[0] for c in STEP_CASES])
def test_parallel_step_refuses_and_keeps_the_state(label, change, name):
    env, obs, policy = started()
    before = snapshot(env)
    with pytest.raises(ArgumentError) as caught:
        env.step(change(good_actions(env, obs, policy)))
    assert str(caught.value).startswith(name), str(caught.value)
    assert_unchanged(before, snapshot(env))
    env.step(good_actions(env, obs, policy))  # still usable


@pytest.mark.parametrize("action_mode", ["plan", "accel"])
@pytest.mark.parametrize("size", [1e160, 1e308])
def test_a_finite_raw_action_that_would_overflow_is_refused(action_mode, size):
    env = fxc_env.parallel_env(scenario="paper_fig1", obs_mode="raw", action_mode=action_mode)
    obs, _ = env.reset(seed=0)
    before = snapshot(env)
    actions = {agent: np.zeros(2) for agent in env.agents}
    actions["agent_3"] = np.array([size, size])
    with pytest.raises(ArgumentError, match=r"^actions: .*overflow.*agents \[3\]") as caught:
        env.step(actions)
    assert "unchanged" in str(caught.value)
    assert_unchanged(before, snapshot(env))
    twin = fxc_env.parallel_env(scenario="paper_fig1", obs_mode="raw", action_mode=action_mode)
    twin.reset(seed=0)
    policy = ReferencePolicy(env)
    mine, theirs = env.step(good_actions(env, obs, policy)), twin.step(good_actions(twin, obs, policy))
    np.testing.assert_array_equal(env.state(), twin.state())
    assert mine[1] == theirs[1]


RESET_CASES = [
    ({"seed": "abc"}, "seed"),
    ({"seed": -1}, "seed"),
    ({"seed": 1.5}, "seed"),
    ({"options": "x0"}, "options"),
    ({"options": {"x0": [1.0, 2.0]}}, "options['x0']"),
    ({"options": {"x0": [[1.0], [2.0, 3.0]] + [[0.0]] * 4}}, "options['x0']"),
    ({"options": {"x0": ["a"] * N}}, "options['x0']"),
    ({"options": {"v0": [np.nan] * N}}, "options['v0']"),
    ({"options": {"v0": [1e101] * N}}, "options['v0']"),
    ({"options": {"x0": [-1e308] * N}}, "options['x0']"),
]


@pytest.mark.parametrize(("kwargs", "name"), RESET_CASES, ids=[str(c[0])[:50] for c in RESET_CASES])
def test_parallel_reset_refuses_and_keeps_the_state(kwargs, name):
    env, obs, policy = started()
    before = snapshot(env)
    with pytest.raises(ArgumentError) as caught:
        env.reset(**kwargs)
    assert str(caught.value).startswith(name), str(caught.value)
    assert_unchanged(before, snapshot(env))
    env.step(good_actions(env, obs, policy))


# ------------------------------------------------------------------ simulate
SIMULATE_CASES = [
    ({"settling_time": 1e300}, "settling_time"),
    ({"x0": [1.0] * 5}, "x0"),
    ({"v0": [np.inf] * N}, "v0"),
    ({"points_per_interval": 0}, "points_per_interval"),
    ({"seed": -5}, "seed"),
]


@pytest.mark.parametrize(("kwargs", "name"), SIMULATE_CASES, ids=[str(c[0])[:50] for c in SIMULATE_CASES])
def test_simulate_names_the_bad_argument(kwargs, name):
    with pytest.raises(ArgumentError) as caught:
        fxc_env.simulate("reference", "paper_fig1", **kwargs)
    assert str(caught.value).startswith(name), str(caught.value)


def test_simulate_refuses_a_policy_that_is_not_callable():
    for policy in ("pid", None, 3):
        with pytest.raises(ArgumentError, match=r"^policy: expected 'reference' or a callable"):
            fxc_env.simulate(policy, "paper_fig1")


# ------------------------------------------------------------------ AEC form
AEC_CASES = [
    ("nan", np.array([np.nan, 0.0])),
    ("inf", np.array([0.0, -np.inf])),
    ("short", np.array([0.0])),
    ("text", "left"),
    ("ragged", [0.0, [1.0]]),
]


@pytest.mark.parametrize(("label", "action"), AEC_CASES, ids=[c[0] for c in AEC_CASES])
def test_aec_checks_each_action_when_its_agent_acts(label, action):
    env = fxc_env.raw_env(scenario="paper_fig1")
    env.reset(seed=1)
    policy = ReferencePolicy(env)
    for _ in range(2):  # agent_0 and agent_1 act
        env.step(policy(env.observe(env.agent_selection)))
    before = snapshot(env.parallel)
    assert env.agent_selection == "agent_2"
    with pytest.raises(ArgumentError) as caught:
        env.step(action)
    assert str(caught.value).startswith("action of agent_2"), str(caught.value)
    assert env.agent_selection == "agent_2"
    assert_unchanged(before, snapshot(env.parallel))
    while env.agent_selection != "agent_0":  # the same agent acts again; the cycle completes
        env.step(policy(env.observe(env.agent_selection)))
    assert env.parallel.unwrapped.engine.k == 1


# ------------------------------------------------------------------ SB3 VecEnv
def started_vecenv():
    venv = fxc_env.ConsensusVecEnv(2, scenario="paper_fig1")
    venv.seed(4)
    obs = venv.reset()
    venv.step(ReferencePolicy(venv)(obs))
    return venv


VECENV_CASES = [
    ("actions of the wrong shape", lambda v: v.step(np.zeros((v.num_envs, 3))), "actions"),
    ("nan actions", lambda v: v.step(np.full((v.num_envs, 2), np.nan)), "actions"),
    ("text actions", lambda v: v.step(np.array([["a", "b"]] * v.num_envs)), "actions"),
    ("set_attr n_agents", lambda v: v.set_attr("n_agents", 3), "n_agents"),
    ("set_attr config", lambda v: v.set_attr("config", None), "config"),
    ("negative seed", lambda v: v.seed(-1), "seed"),
    ("text seed", lambda v: v.seed("abc"), "seed"),
    ("bad x0 option", lambda v: v.set_options({"x0": [1.0, 2.0]}), "options['x0']"),
]


@pytest.mark.parametrize(("label", "call", "name"), VECENV_CASES, ids=[c[0] for c in VECENV_CASES])
def test_vecenv_refuses_and_keeps_the_state(label, call, name):
    venv = started_vecenv()
    engine = venv.engine
    state, k = engine.state.copy(), engine.k
    with pytest.raises(ArgumentError) as caught:
        call(venv)
    assert str(caught.value).startswith(name), str(caught.value)
    np.testing.assert_array_equal(engine.state, state)
    assert engine.k == k
    obs = venv.reset()  # still usable: a reset and a step work
    venv.step(ReferencePolicy(venv)(obs))


def test_the_table_covers_every_front_end_with_sixty_distinct_inputs_or_more():
    rows = len(CONSTRUCTOR_CASES) + len(STEP_CASES) + len(RESET_CASES) + len(SIMULATE_CASES)
    rows += len(AEC_CASES) + len(VECENV_CASES)
    assert rows >= 60  # and tests/cli/test_cli.py holds the command line's table


# ------------------------------------------------------------------ numpy engine
def started_engine(**kwargs):
    from fxc_env.config import make_config
    from fxc_env.engine import ConsensusEngine

    engine = ConsensusEngine(make_config("paper_fig1", **kwargs), n_episodes=2)
    engine.seed(5)
    rng = np.random.default_rng(0)
    engine.reset_from_draws([engine.draw_episode(rng) for _ in range(2)])
    engine.step(engine.validate_actions(np.zeros((2, N, 2))))
    return engine


def engine_snapshot(engine):
    return (
        engine.state.copy(),
        engine.x0.copy(),
        engine.current_disagreement.copy(),
        engine.k,
        pickle.dumps(engine.rng.bit_generator.state),
    )


def assert_engine_unchanged(before, after):
    for a, b in zip(before[:3], after[:3], strict=True):
        np.testing.assert_array_equal(a, b)
    assert before[3:] == after[3:]


GOOD_STATE = np.zeros((2, N, 1))
ENGINE_RESET_CASES = [
    ("nan x0", {"x0": np.full((2, N, 1), np.nan)}, "x0", "finite"),
    ("inf v0", {"v0": np.full((2, N, 1), -np.inf)}, "v0", "finite"),
    ("complex x0", {"x0": GOOD_STATE.astype(complex)}, "x0", "real numbers"),
    ("text v0", {"v0": np.full((2, N, 1), "a")}, "v0", "real numbers"),
    ("beyond 1e100", {"x0": np.full((2, N, 1), 1e101)}, "x0", r"within ±1e\+100"),
    ("one episode's shape", {"x0": np.zeros((N, 1))}, "x0", r"expected shape \(2, 6, 1\), got \(6, 1\)"),
    ("ragged", {"v0": [[[0.0]] * N, [[0.0]] * (N - 1)]}, "v0", "real numbers"),
]


@pytest.mark.parametrize(
    ("label", "given", "name", "message"), ENGINE_RESET_CASES, ids=[c[0] for c in ENGINE_RESET_CASES]
)
def test_the_numpy_engine_reset_checks_x0_and_v0_and_changes_nothing(label, given, name, message):
    """The numpy engine checks a reset's states itself, as the torch engine does (one check for both)."""
    engine = started_engine()
    before = engine_snapshot(engine)
    arguments = {"x0": GOOD_STATE + 1.0, "v0": GOOD_STATE, **given}
    with pytest.raises(ArgumentError, match=f"^{name}: .*{message}"):
        engine.reset(arguments["x0"], arguments["v0"])
    assert_engine_unchanged(before, engine_snapshot(engine))
    engine.step(engine.validate_actions(np.zeros((2, N, 2))))  # still usable
    assert engine.k == 2


def test_the_numpy_engine_reset_keeps_raw_float32_states_within_float32():
    engine = started_engine(obs_dtype="float32", obs_mode="raw")
    before = engine_snapshot(engine)
    with pytest.raises(
        ArgumentError, match=r'^x0: entries must lie within ±1e\+37 \(float32 range, obs_dtype="float32"'
    ):
        engine.reset(np.full((2, N, 1), 1e38), GOOD_STATE)
    assert_engine_unchanged(before, engine_snapshot(engine))
    engine.reset(np.full((2, N, 1), 1e36), GOOD_STATE)  # within range: taken
    assert engine.k == 0


def test_the_torch_and_numpy_engines_share_one_state_check():
    """Both back ends refuse a host array with the same message (fxc_env.core.validation.state_batch)."""
    from fxc_env.config import make_config
    from fxc_env.engine import ConsensusEngine

    messages = []
    for device in (None, "cpu"):
        engine = ConsensusEngine(make_config("paper_fig1"), n_episodes=2, device=device)
        with pytest.raises(ArgumentError) as caught:
            engine.reset(np.full((2, N, 1), np.nan), GOOD_STATE)
        messages.append(str(caught.value))
    assert messages[0] == messages[1] == "x0: every entry must be finite (no NaN or inf)"


ENGINE_SEEDS = [-1, 1.5, True, 2**128, "abc", np.float64(3.0)]


@pytest.mark.parametrize("seed", ENGINE_SEEDS, ids=[repr(s) for s in ENGINE_SEEDS])
def test_the_numpy_engine_seed_is_refused_by_name_and_the_generator_kept(seed):
    engine = started_engine()
    before = engine_snapshot(engine)
    with pytest.raises(ArgumentError, match=r"^seed: expected an integer in \[0, 2\*\*128 - 1\]"):
        engine.seed(seed)
    assert_engine_unchanged(before, engine_snapshot(engine))
    engine.seed(2**128 - 1)  # the largest numpy seed is taken
    engine.seed(None)


# ------------------------------------------------------- raw float32 observations
def raw32_env(small_n_path=True, **kwargs):
    env = fxc_env.parallel_env(
        obs_dtype="float32", obs_mode="raw", action_mode="accel", topology="complete", n_agents=4, **kwargs
    )
    env.small_n_path = small_n_path
    return env


@pytest.mark.parametrize("small_n_path", [True, False], ids=["small-N path", "engine"])
def test_a_raw_float32_episode_that_grows_past_float32_is_refused_not_observed_as_inf(small_n_path):
    """States admitted at reset (within ±1e37) that a step would take more than float32's range apart
    (3.4e38: their raw row would be inf) are refused naming the actions; state unchanged, env usable."""
    env = raw32_env(small_n_path)
    env.reset(seed=0)
    before = snapshot(env)
    spread = {agent: np.full(2, 1e39 if agent != "agent_0" else -1e39) for agent in env.agents}
    with pytest.raises(
        ArgumentError, match=r'^actions: .*beyond ±3\.40282e\+38.*obs_dtype="float32", obs_mode="raw"'
    ) as c:
        env.step(spread)
    assert "unchanged" in str(c.value)
    assert_unchanged(before, snapshot(env))
    observations, *_ = env.step({agent: np.zeros(2) for agent in env.agents})  # still usable
    assert all(np.isfinite(o).all() for o in observations.values())
    observations, _ = env.reset(seed=1)  # and the next reset starts clean
    assert env.unwrapped.engine.k == 0 and all(np.isfinite(o).all() for o in observations.values())
    # A common push moves every agent alike: no row grows, so nothing is refused.
    observations, *_ = env.step({agent: np.full(2, 1e39) for agent in env.agents})
    assert all(np.isfinite(o).all() for o in observations.values())


def test_the_reference_from_the_edge_of_the_raw_float32_range_finishes_with_finite_observations():
    env = fxc_env.parallel_env(obs_dtype="float32", obs_mode="raw")
    policy = ReferencePolicy(env)
    x0, v0 = np.array([1e37, -1e37, 1e37, -1e37, 0, 0]), np.array([1e37, -1e37, 0, 0, 0, 0])
    observations, _ = env.reset(seed=0, options={"x0": x0, "v0": v0})
    while env.agents:
        observations, *_ = env.step({a: policy(o) for a, o in observations.items()})
        assert all(np.isfinite(o).all() for o in observations.values())
    assert env.unwrapped.engine.k == env.unwrapped.config.n_intervals


def test_raw_float32_refuses_noise_beyond_float32s_range():
    with pytest.raises(ArgumentError, match=r'^obs_noise: .*obs_dtype="float32", obs_mode="raw"'):
        fxc_env.parallel_env(obs_dtype="float32", obs_mode="raw", obs_noise=1e50)
    fxc_env.parallel_env(obs_dtype="float32", obs_noise=1e50)  # normalized observations stay in [-1, 1]


def test_the_vecenv_refuses_a_raw_float32_step_past_float32_and_keeps_the_state():
    venv = fxc_env.ConsensusVecEnv(
        2, obs_dtype="float32", obs_mode="raw", action_mode="accel", topology="complete", n_agents=4
    )
    venv.seed(0)
    venv.reset()
    state, k = venv.engine.state.copy(), venv.engine.k
    actions = np.full((venv.num_envs, 2), 1e39)
    actions[0] = -1e39
    with pytest.raises(ArgumentError, match=r"^actions: .*float32"):
        venv.step(actions)
    np.testing.assert_array_equal(venv.engine.state, state)
    assert venv.engine.k == k
    observations, *_ = venv.step(np.zeros((venv.num_envs, 2)))
    assert np.isfinite(observations).all()


def test_the_torch_engine_flags_a_raw_float32_step_past_float32_and_reports_it_once():
    import torch

    from fxc_env.config import make_config
    from fxc_env.engine import ConsensusEngine

    config = make_config(obs_dtype="float32", obs_mode="raw", action_mode="accel", topology="complete", n_agents=4)
    engine = ConsensusEngine(config, n_episodes=2, device="cpu")
    engine.reset(*engine.draw_batch()[:2])
    actions = torch.zeros((2, 4, 2), dtype=torch.float64)
    actions[1, 0] = 1e39  # episode 1 only: agent 0 pushed away from the others
    engine.step(engine.validate_actions(actions))
    with pytest.raises(ArgumentError, match=r"^actions: episodes \[1\] .*float32"):
        engine.raise_if_invalid()
    engine.raise_if_invalid()  # reported once: the flags were cleared


# --------------------------------------------------- damaged torch checkpoints and policies
@pytest.fixture(scope="module")
def torch_run(tmp_path_factory):
    """One tiny torch run (one rollout of one episode): its checkpoint and policy.pt, damaged below."""
    from fxc_env.training import TrainArgs, train

    root = tmp_path_factory.mktemp("torch_run")
    args = {"scenario": "paper_fig1", "backend": "torch", "n_envs": 1, "checkpoint_every": 1, "torch_threads": 1}
    run = train(TrainArgs(**args, timesteps=1, run_dir=str(root / "run"), progress_bar=False))
    return run, args


def _shape_of(record, key, shape):
    import torch

    record[key] = torch.zeros(shape)


CHECKPOINT_DAMAGE = [
    ("no model", lambda r: r.pop("model"), r"lacks model \(damaged"),
    ("no host generator", lambda r: r["rng"].pop("host"), r"lacks rng\.host"),
    (
        "an extra weight",
        lambda r: _shape_of(r["model"], "actor.9.weight", (2, 2)),
        r"other network settings: .*actor\.9",
    ),
    ("a missing weight", lambda r: r["model"].pop("critic.0.bias"), r"other network settings: .*critic\.0\.bias"),
    (
        "a misshapen weight",
        lambda r: _shape_of(r["model"], "actor.0.weight", (3, 3)),
        r"other network settings: .*actor\.0",
    ),
    (
        "misshapen Adam moments",
        lambda r: [state.update(exp_avg=state["exp_avg"][..., :1]) for state in r["optimizer"]["state"].values()],
        r"damaged optimizer, counter or generator state: optimizer state 'exp_avg'",
    ),
    ("a counter that is text", lambda r: r.update(timesteps="many"), r"damaged optimizer, counter or generator state"),
]


@pytest.mark.slow  # the module's tiny torch run takes about 6 s
@pytest.mark.parametrize(("label", "damage", "message"), CHECKPOINT_DAMAGE, ids=[c[0] for c in CHECKPOINT_DAMAGE])
def test_a_damaged_torch_checkpoint_is_a_one_line_usage_error_naming_it(torch_run, tmp_path, label, damage, message):
    import shutil

    import torch

    from fxc_env.training import TrainArgs, train
    from fxc_env.training.backends.torch_ppo import latest_torch_checkpoint

    run, args = torch_run
    copy = shutil.copytree(run, tmp_path / "run")
    checkpoint = latest_torch_checkpoint(copy)
    record = torch.load(checkpoint, weights_only=True)
    damage(record)
    torch.save(record, checkpoint)
    with pytest.raises(ArgumentError, match=f"^resume: .*{message}") as caught:
        train(TrainArgs(**args, timesteps=10**6, resume=True, run_dir=str(copy), progress_bar=False))
    assert "\n" not in str(caught.value) and checkpoint.name in str(caught.value)


POLICY_DAMAGE = [
    ("no actor", lambda r: r.pop("actor"), r"lacks the key 'actor'"),
    ("an extra weight", lambda r: _shape_of(r["actor"], "9.weight", (2, 2)), r"does not load .*9\.weight"),
    ("a misshapen weight", lambda r: _shape_of(r["actor"], "0.weight", (3, 3)), r"does not load .*0\.weight"),
    ("a missing weight", lambda r: r["actor"].pop("4.bias"), r"does not load .*4\.bias"),
    ("a size that is text", lambda r: r.update(obs_size="wide"), r"obs_size: expected an integer >= 1, got .wide."),
]


@pytest.mark.slow
@pytest.mark.parametrize(("label", "damage", "message"), POLICY_DAMAGE, ids=[c[0] for c in POLICY_DAMAGE])
def test_a_damaged_torch_policy_is_a_one_line_usage_error_naming_it(torch_run, tmp_path, label, damage, message):
    import torch

    from fxc_env.policies.torch_policy import load_torch_policy

    run, _ = torch_run
    assert load_torch_policy(run)(np.zeros((2, 15))).shape == (2, 2)  # the undamaged file loads
    record = torch.load(run / "policy.pt", weights_only=True)
    damage(record)
    path = tmp_path / "policy.pt"
    torch.save(record, path)
    with pytest.raises(ArgumentError, match=f"^policy: .*{message}") as caught:
        load_torch_policy(path)
    assert "\n" not in str(caught.value) and str(path) in str(caught.value)


@pytest.mark.slow
def test_a_torch_checkpoint_without_its_policy_record_is_refused_by_name(torch_run, tmp_path):
    import torch

    from fxc_env.policies.torch_policy import load_torch_policy
    from fxc_env.training.backends.torch_ppo import latest_torch_checkpoint

    record = torch.load(latest_torch_checkpoint(torch_run[0]), weights_only=True)
    del record["policy"]
    path = tmp_path / "model_1_steps.pt"
    torch.save(record, path)
    with pytest.raises(ArgumentError, match=r"^policy: the checkpoint .*lacks the key 'policy'"):
        load_torch_policy(path)


# ------------------------------------------------- more refusals found by probing the front ends
def test_booleans_are_not_states_or_actions():
    env, *_ = started()
    before = snapshot(env)
    with pytest.raises(ArgumentError, match=r"^options\['x0'\]: .*got booleans"):
        env.reset(options={"x0": np.ones(N, bool)})
    with pytest.raises(ArgumentError, match=r"^actions\['agent_0'\]: .*got booleans"):
        env.step({agent: np.array([True, False]) for agent in env.agents})
    assert_unchanged(before, snapshot(env))
    aec = fxc_env.raw_env(scenario="paper_fig1")
    aec.reset(seed=0)
    with pytest.raises(ArgumentError, match=r"^action of agent_0: .*got booleans"):
        aec.step(np.array([True, True]))
    venv = started_vecenv()
    with pytest.raises(ArgumentError, match=r"^actions: expected real numbers, got dtype bool"):
        venv.step(np.ones((venv.num_envs, 2), bool))
    with pytest.raises(ArgumentError, match=r"^x0: .*got booleans"):
        fxc_env.simulate("reference", "paper_fig1", x0=np.ones(N, bool))


def test_state_and_last_before_the_first_reset_raise_like_render_and_observe():
    with pytest.raises(RuntimeError, match=r"^state: .*reset"):
        fxc_env.parallel_env().state()
    with pytest.raises(RuntimeError, match=r"^state: .*reset"):
        fxc_env.raw_env().state()
    with pytest.raises(RuntimeError, match=r"^last: call reset"):
        fxc_env.raw_env().last()
    env = fxc_env.raw_env(n_intervals=3)
    env.reset(seed=0)
    assert env.last()[1] == 0.0 and env.state().shape == (N, 2)


def engine_with_limit():
    from fxc_env.config import make_config
    from fxc_env.engine import ConsensusEngine

    engine = ConsensusEngine(make_config("paper_fig1", u_max=(5.0, 50.0)), n_episodes=2)
    engine.reset_from_draws([engine.draw_episode(np.random.default_rng(s)) for s in range(2)])
    return engine


ENGINE_EXTRA_CASES = [
    ("u_max NaN", lambda e: e.reset(GOOD_STATE, GOOD_STATE, u_max=[np.nan, 5.0]), "u_max"),
    ("u_max negative", lambda e: e.reset(GOOD_STATE, GOOD_STATE, u_max=[-1.0, 5.0]), "u_max"),
    ("u_max per agent", lambda e: e.reset(GOOD_STATE, GOOD_STATE, u_max=[5.0] * 3), "u_max"),
    ("u_max text", lambda e: e.reset(GOOD_STATE, GOOD_STATE, u_max=["fast", "slow"]), "u_max"),
    ("one topology for two episodes", lambda e: e.reset(GOOD_STATE, GOOD_STATE, topologies=[None]), "topologies"),
    ("a topology by name", lambda e: e.reset(GOOD_STATE, GOOD_STATE, topologies=["ring", "ring"]), "topologies"),
    ("an integer generator", lambda e: e.reset(GOOD_STATE, GOOD_STATE, rng=5), "rng"),
    ("an integer mask", lambda e: e.reset(GOOD_STATE, GOOD_STATE, episodes=np.array([1, 0])), "episodes"),
    ("a list mask", lambda e: e.reset(GOOD_STATE, GOOD_STATE, episodes=[True, False]), "episodes"),
    ("a metrics index out of range", lambda e: e.episode_metrics(2), "episode"),
    ("a negative metrics index", lambda e: e.episode_metrics(-1), "episode"),
    ("a misshapen out buffer", lambda e: e.observations(out=np.zeros((1, N, 3))), "out"),
    ("a seed for a generator", lambda e: e.draw_episode(5), "rng"),
]


@pytest.mark.parametrize(("label", "call", "name"), ENGINE_EXTRA_CASES, ids=[c[0] for c in ENGINE_EXTRA_CASES])
def test_the_engine_refuses_reset_extras_by_name_and_changes_nothing(label, call, name):
    engine = engine_with_limit()
    engine.step(engine.validate_actions(np.zeros((2, N, 2))))
    before, limits = engine_snapshot(engine), engine.u_max.copy()
    with pytest.raises(ArgumentError) as caught:
        call(engine)
    assert str(caught.value).startswith(name), str(caught.value)
    assert_engine_unchanged(before, engine_snapshot(engine))
    np.testing.assert_array_equal(engine.u_max, limits)
    engine.step(engine.validate_actions(np.zeros((2, N, 2))))  # still usable


def test_the_engine_refuses_an_input_limit_its_config_does_not_have():
    engine = started_engine()
    with pytest.raises(ArgumentError, match=r"^u_max: this engine's config has no input limit"):
        engine.reset(GOOD_STATE, GOOD_STATE, u_max=[5.0, 5.0])
    assert engine.u_max is None and engine.k == 1


def test_an_engine_that_was_never_reset_refuses_to_step():
    from fxc_env.config import make_config
    from fxc_env.engine import ConsensusEngine

    engine = ConsensusEngine(make_config("paper_fig1"), n_episodes=2)
    with pytest.raises(RuntimeError, match=r"^step: call reset\(\) before the first step"):
        engine.step(engine.validate_actions(np.zeros((2, N, 2))))
    assert engine.k == 0 and not engine.state.any()
    engine.reset(GOOD_STATE + np.arange(N)[None, :, None], GOOD_STATE)
    engine.step(engine.validate_actions(np.zeros((2, N, 2))))
    assert engine.k == 1


# ------------------------------------------------------------------ issue 24
def _one_node_graph():
    graph = nx.DiGraph()
    graph.add_node(0)
    return graph


ONE_AGENT_FRONT_ENDS = [
    ("parallel_env", lambda **kwargs: fxc_env.parallel_env(**kwargs)),
    ("env (AEC)", lambda **kwargs: fxc_env.env(**kwargs)),
    ("ConsensusVecEnv", lambda **kwargs: fxc_env.ConsensusVecEnv(2, **kwargs)),
    ("ConsensusEngine", lambda **kwargs: fxc_env.ConsensusEngine(fxc_env.make_config(**kwargs))),
    ("simulate", lambda **kwargs: fxc_env.simulate("reference", **kwargs)),
]


@pytest.mark.parametrize(("label", "build"), ONE_AGENT_FRONT_ENDS, ids=[c[0] for c in ONE_AGENT_FRONT_ENDS])
def test_one_agent_is_refused_by_name_at_construction_on_every_front_end(label, build):
    # One agent crashed at reset in the small-N path (issue 24). Consensus is agreement between
    # agents: N = 1 is refused where it is given (the torch env and fxc simulate: their test files).
    with pytest.raises(ArgumentError, match=r"^n_agents: expected an integer in \[2, "):
        build(scenario=None, topology="complete", n_agents=1)
    with pytest.raises(ArgumentError, match=r"^n_agents: expected an integer in \[2, "):
        build(scenario=None, topology={"family": "ring"}, n_agents=1)
    with pytest.raises(ArgumentError, match=r"^topology: expected at least 2 agents .*got a graph of 1"):
        build(scenario=None, topology=_one_node_graph())
    build(scenario=None, topology="complete", n_agents=2)  # two agents: the smallest consensus


UNKNOWN_RESET_OPTIONS = [
    {"X0": np.arange(N, dtype=float)},
    {"x0": np.arange(N, dtype=float), "v00": np.ones(N)},
    {"bogus": 1},
]
UNKNOWN_OPTION_MESSAGE = r"^options: unknown key\(s\) \[.*\]; expected only 'x0', 'v0'"


@pytest.mark.parametrize("options", UNKNOWN_RESET_OPTIONS, ids=[str(sorted(o)) for o in UNKNOWN_RESET_OPTIONS])
def test_an_unknown_reset_option_is_refused_naming_the_known_keys_and_nothing_changes(options):
    # The intended initial state was silently not used (issue 24): every env front end refuses the key.
    env, obs, policy = started()
    before = snapshot(env)
    with pytest.raises(ArgumentError, match=UNKNOWN_OPTION_MESSAGE):
        env.reset(seed=0, options=options)
    assert_unchanged(before, snapshot(env))
    env.step(good_actions(env, obs, policy))

    aec = fxc_env.env(scenario="paper_fig1")
    aec.reset(seed=3)
    aec.step(ReferencePolicy(aec)(aec.observe(aec.agent_selection)))
    before, selected = snapshot(aec.unwrapped.parallel), aec.agent_selection
    with pytest.raises(ArgumentError, match=UNKNOWN_OPTION_MESSAGE):
        aec.reset(seed=0, options=options)
    assert_unchanged(before, snapshot(aec.unwrapped.parallel))
    assert aec.agent_selection == selected == "agent_1"

    venv = started_vecenv()
    state, k = venv.engine.state.copy(), venv.engine.k
    for given in (options, [options] * venv.num_envs, [{}] * (venv.num_envs - 1) + [options]):
        with pytest.raises(ArgumentError, match=UNKNOWN_OPTION_MESSAGE):
            venv.set_options(given)
    np.testing.assert_array_equal(venv.engine.state, state)
    assert venv.engine.k == k
    venv.reset()  # nothing was stored: the next reset draws as usual
    assert not np.array_equal(venv.engine.state[0, :, 0, 0], options.get("x0", np.full(N, np.nan)))


def test_a_weighted_networkx_graph_is_refused_by_name():
    # The weights were silently dropped (issue 24); the paper's graphs are unweighted.
    weighted = nx.DiGraph()
    weighted.add_weighted_edges_from([(j, (j + 1) % N, 1.0 if j else 2.5) for j in range(N)])
    with pytest.raises(ArgumentError, match=r"^topology: expected an unweighted networkx graph .*weight 2\.5"):
        fxc_env.parallel_env(scenario=None, topology=weighted)
    unit = nx.DiGraph()
    unit.add_weighted_edges_from([(j, (j + 1) % N, 1.0) for j in range(N)])
    plain = fxc_env.make_config(None, topology=nx.DiGraph([(j, (j + 1) % N) for j in range(N)])).topology
    assert fxc_env.make_config(None, topology=unit).topology.edges[0].tolist() == plain.edges[0].tolist()


def test_a_model_parameter_that_breaks_the_interval_maps_is_blamed_by_name():
    # frequency = 2**70 was blamed on "intervals", which the user never gave (issue 24).
    with pytest.raises(ArgumentError, match=r"^frequency: expected a value with which 'oscillator' agents can be"):
        fxc_env.parallel_env(scenario=None, agent_model={"name": "oscillator", "frequency": 2**70})


def test_the_engine_refuses_a_scenario_name_in_place_of_its_config():
    # ConsensusEngine("paper_fig1") raised AttributeError (issue 24): one way in, the validated config.
    with pytest.raises(
        TypeError, match=r"^config: expected an EnvConfig \(make_config\('paper_fig1'\)\), got the name"
    ):
        fxc_env.ConsensusEngine("paper_fig1")
    with pytest.raises(ArgumentError, match=r"^config: expected an EnvConfig .*got a dict"):
        fxc_env.ConsensusEngine({"scenario": "paper_fig1"})
