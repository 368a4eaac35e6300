"""ConsensusVecEnv: batched episodes equal separate environments, SB3's VecEnv contract, training."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import VecCheckNan, VecMonitor, VecNormalize

import fxc_env
from fxc_env import ConsensusVecEnv, ReferencePolicy
from fxc_env.core.validation import ArgumentError
from fxc_env.envs.parallel import ConsensusParallelEnv

TOL = 1e-12
SHORT = {"n_intervals": 12}


def random_actions(venv: ConsensusVecEnv, rng: np.random.Generator) -> np.ndarray:
    """Seeded actions inside the action Box, as SB3 hands them over (float32)."""
    bound = venv.action_space.high
    return rng.uniform(-bound, bound, size=(venv.num_envs, *venv.action_space.shape)).astype(np.float32)


def stacked(env: ConsensusParallelEnv, per_agent: dict[str, np.ndarray]) -> np.ndarray:
    return np.stack([per_agent[agent] for agent in env.possible_agents])


def rollout(venv: ConsensusVecEnv, n_steps: int, action_seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Observations ``(n_steps + 1, num_envs, obs_size)`` and rewards of seeded random actions."""
    rng = np.random.default_rng(action_seed)
    observations, rewards = [venv.reset()], []
    for _ in range(n_steps):
        obs, reward, _, _ = venv.step(random_actions(venv, rng))
        observations.append(obs)
        rewards.append(reward)
    return np.array(observations), np.array(rewards)


# ----------------------------------------------------- batch = separate environments
CASES = {
    "plan-normalized": {"n_intervals": 20},
    "accel-normalized": {"n_intervals": 20, "action_mode": "accel"},
    "plan-raw": {"n_intervals": 20, "obs_mode": "raw"},
    "accel-raw": {"n_intervals": 20, "action_mode": "accel", "obs_mode": "raw"},
    "ring-planar": {"n_intervals": 20, "n_agents": 5, "topology": "ring", "dim": 2},
}


@pytest.mark.parametrize("policy", ["reference", "random"])
@pytest.mark.parametrize("case", list(CASES))
def test_batched_episodes_equal_separate_parallel_envs(case: str, policy: str) -> None:
    """Episode b of the VecEnv seeded s replays a ParallelEnv reset with seed s + b N, step by step."""
    kwargs, n_envs, seed = CASES[case], 3, 11
    venv = ConsensusVecEnv(n_envs, **kwargs)
    envs = [ConsensusParallelEnv(**kwargs) for _ in range(n_envs)]
    n, k_total = venv.n_agents, venv.config.n_intervals
    reference = ReferencePolicy(venv)
    rng = np.random.default_rng(3)
    venv.seed(seed)
    obs = venv.reset()
    env_obs = [stacked(env, env.reset(seed=seed + b * n)[0]) for b, env in enumerate(envs)]
    for step in range(2 * k_total):  # two episodes: the second one follows the auto-reset
        np.testing.assert_allclose(obs, np.concatenate(env_obs), rtol=TOL, atol=TOL)
        np.testing.assert_allclose(venv.state(), [env.state() for env in envs], rtol=TOL, atol=TOL)
        actions = reference(obs) if policy == "reference" else random_actions(venv, rng)
        obs, rewards, dones, infos = venv.step(actions)
        assert dones.tolist() == [(step + 1) % k_total == 0] * venv.num_envs
        for b, env in enumerate(envs):
            names = env.possible_agents
            out, env_rewards, terminations, _, env_infos = env.step(
                dict(zip(names, actions[b * n : (b + 1) * n], strict=True))
            )
            np.testing.assert_allclose(rewards[b * n : (b + 1) * n], np.float32(env_rewards[names[0]]), rtol=1e-6)
            env_obs[b] = stacked(env, out)
            if terminations[names[0]]:
                terminal = np.array([infos[b * n + a]["terminal_observation"] for a in range(n)])
                np.testing.assert_allclose(terminal, env_obs[b], rtol=TOL, atol=TOL)
                expected = env_infos[names[0]]["episode"]
                for a in range(n):
                    achieved = infos[b * n + a]["episode_metrics"]
                    assert achieved.keys() == expected.keys()
                    for key, value in expected.items():
                        assert achieved[key] is not None and type(achieved[key]) is type(value), key
                        assert achieved[key] == pytest.approx(value, rel=TOL, abs=0.0, nan_ok=True), key
                env_obs[b] = stacked(env, env.reset()[0])  # unseeded: continues the episode's generator


# ------------------------------------------------------------------ episode end
def test_auto_reset_returns_fresh_episode_and_terminal_observation() -> None:
    venv = ConsensusVecEnv(2, **SHORT)
    policy = ReferencePolicy(venv)
    obs = venv.reset()
    for _ in range(SHORT["n_intervals"]):
        last = obs
        obs, _, dones, infos = venv.step(policy(obs))
        if not dones.all():
            assert not dones.any()
            assert all(info == {} for info in infos)
    assert dones.all()
    terminal = np.array([info["terminal_observation"] for info in infos])
    assert terminal[:, -1] == pytest.approx(1.0)  # clock k / K = 1 at the deadline
    assert terminal[:, -3] == pytest.approx(1.0)  # t_K / T_s = 1
    assert not np.allclose(terminal, last)
    assert all(info["TimeLimit.truncated"] is False for info in infos)  # the deadline is a termination
    assert obs[:, -3:-2].max() == 0.0 and obs[:, -1].max() == 0.0  # new episodes start at t_0 = 0
    assert venv.engine.k == 0
    assert [info == {} for info in venv.reset_infos] == [True] * venv.num_envs


def test_max_cycles_truncates_and_flags_time_limit() -> None:
    venv = ConsensusVecEnv(2, max_cycles=4, **SHORT)
    obs = venv.reset()
    policy = ReferencePolicy(venv)
    done_steps = []
    for step in range(1, 9):
        obs, _, dones, infos = venv.step(policy(obs))
        if dones.any():
            assert dones.all()
            done_steps.append(step)
            assert [info["TimeLimit.truncated"] for info in infos] == [True] * venv.num_envs
            assert {info["episode_metrics"]["sampling_instants"] for info in infos} == {4}
    assert done_steps == [4, 8]


def test_max_cycles_at_deadline_is_a_termination() -> None:
    venv = ConsensusVecEnv(1, max_cycles=SHORT["n_intervals"], **SHORT)
    obs = venv.reset()
    for _ in range(SHORT["n_intervals"]):
        obs, _, dones, infos = venv.step(ReferencePolicy(venv)(obs))
    assert dones.all()
    assert [info["TimeLimit.truncated"] for info in infos] == [False] * venv.num_envs


def test_step_returns_have_sb3_shapes_and_dtypes() -> None:
    venv = ConsensusVecEnv(3, **SHORT)
    obs = venv.reset()
    n = venv.n_agents
    assert venv.num_envs == 3 * n
    assert obs.shape == (venv.num_envs, *venv.observation_space.shape)
    obs, rewards, dones, infos = venv.step(random_actions(venv, np.random.default_rng(0)))
    assert obs.shape == (venv.num_envs, *venv.observation_space.shape)
    assert rewards.shape == (venv.num_envs,) and rewards.dtype == np.float32
    assert dones.shape == (venv.num_envs,) and dones.dtype == np.bool_
    assert isinstance(infos, list) and len(infos) == venv.num_envs
    assert len({id(info) for info in infos}) == venv.num_envs  # no shared dicts
    team = rewards.reshape(3, n)
    assert np.all(team == team[:, :1])  # the team reward, repeated per agent
    assert venv.last_outcome is not None and venv.last_outcome.energy.shape == (3, n)


# -------------------------------------------------------------------- seeding
def test_same_seed_same_rollout_different_seed_differs() -> None:
    steps = 2 * SHORT["n_intervals"] + 3  # across two auto-resets

    def seeded(seed: int) -> tuple[np.ndarray, np.ndarray]:
        venv = ConsensusVecEnv(2, **SHORT)
        assert venv.seed(seed) == [seed + i for i in range(venv.num_envs)]
        return rollout(venv, steps)

    obs_a, rewards_a = seeded(5)
    obs_b, rewards_b = seeded(5)
    obs_c, _ = seeded(6)
    np.testing.assert_array_equal(obs_a, obs_b)
    np.testing.assert_array_equal(rewards_a, rewards_b)
    assert not np.allclose(obs_a[0], obs_c[0])


def test_seed_is_consumed_by_the_next_reset_only() -> None:
    venv = ConsensusVecEnv(2, **SHORT)
    venv.seed(3)
    first = venv.reset()
    second = venv.reset()  # continues each episode's generator
    venv.seed(3)
    np.testing.assert_array_equal(venv.reset(), first)
    assert not np.allclose(first, second)
    env = ConsensusParallelEnv(**SHORT)
    env.reset(seed=3 + venv.n_agents)
    np.testing.assert_array_equal(second[venv.n_agents : 2 * venv.n_agents], stacked(env, env.reset()[0]))


def test_unseeded_episodes_are_independent() -> None:
    venv = ConsensusVecEnv(4, **SHORT)
    venv.reset()
    x0 = venv.engine.x0[:, :, 0]
    assert len({tuple(row) for row in x0.tolist()}) == 4
    other = ConsensusVecEnv(4, **SHORT)
    other.reset()
    assert not np.allclose(other.engine.x0, venv.engine.x0)


def test_copies_made_before_the_first_reset_draw_their_own_episodes() -> None:
    venv = ConsensusVecEnv(2, **SHORT)
    copies = [pickle.loads(pickle.dumps(venv)) for _ in range(2)]
    first, second = (copy.reset() for copy in copies)
    assert not np.allclose(first, second)
    venv.reset()
    twin = pickle.loads(pickle.dumps(venv))  # after a reset the copy continues the same generators
    np.testing.assert_array_equal(venv.reset(), twin.reset())


def test_options_set_the_initial_state_of_each_episode() -> None:
    venv = ConsensusVecEnv(2, **SHORT)
    n = venv.n_agents
    x0 = np.arange(n, dtype=float)
    options = [{} for _ in range(venv.num_envs)]
    options[n] = {"x0": x0, "v0": -x0}  # episode 1 reads the options of its first sub-env
    options[1] = {"x0": np.zeros(3)}  # not the first sub-env of its episode: ignored
    venv.set_options(options)
    venv.reset()
    np.testing.assert_array_equal(venv.engine.x0[1, :, 0], x0)
    np.testing.assert_array_equal(venv.engine.v0[1, :, 0], -x0)
    assert not np.allclose(venv.engine.x0[0, :, 0], x0)
    venv.reset()  # options are used once
    assert not np.allclose(venv.engine.x0[1, :, 0], x0)
    # A bad option is refused when given, nothing is stored, and later resets work.
    state = venv.state()
    with pytest.raises(ValueError, match=r"options\['x0'\]"):
        venv.set_options({"x0": np.zeros(3)})
    np.testing.assert_array_equal(venv.state(), state)
    for _ in range(2):
        venv.reset()
    with pytest.raises(ValueError, match=r"options\['x0'\]"):
        venv.set_options([{"x0": [[0.0], [1.0, 2.0]]}] * venv.num_envs)  # ragged
    with pytest.raises(ValueError, match="options"):
        venv.set_options([{}] * (venv.num_envs - 1))
    with pytest.raises(TypeError, match="options"):
        venv.set_options([5] + [{}] * (venv.num_envs - 1))
    venv.reset()
    assert venv.engine.k == 0


def test_bad_options_written_behind_set_options_fail_one_reset_only() -> None:
    venv = ConsensusVecEnv(2, **SHORT)
    venv._options = [{"x0": np.zeros(3)}] * venv.num_envs  # bypasses set_options' check
    with pytest.raises(ValueError, match=r"options\['x0'\]"):
        venv.reset()
    venv.reset()


# --------------------------------------------------------------- attributes
def test_get_attr_reads_the_shared_env_and_its_config() -> None:
    venv = ConsensusVecEnv(2, max_cycles=7, **SHORT)
    assert venv.get_attr("config") == [venv.config] * venv.num_envs
    assert venv.get_attr("max_cycles", indices=[0, 5]) == [7, 7]
    assert venv.get_attr("settling_time", indices=3) == [20.0]  # from the EnvConfig
    assert venv.get_attr("render_mode") == [None] * venv.num_envs
    with pytest.raises(AttributeError, match="no_such_thing"):
        venv.get_attr("no_such_thing")
    with pytest.raises(IndexError, match="indices"):
        venv.get_attr("config", indices=[venv.num_envs])


def test_set_attr_applies_to_every_sub_env() -> None:
    venv = ConsensusVecEnv(2, **SHORT)
    venv.set_attr("max_cycles", 3)
    assert venv.get_attr("max_cycles") == [3] * venv.num_envs
    obs = venv.reset()
    for _ in range(3):
        obs, _, dones, infos = venv.step(ReferencePolicy(venv)(obs))
    assert dones.all() and infos[0]["TimeLimit.truncated"] is True
    with pytest.raises(ValueError, match="indices"):
        venv.set_attr("max_cycles", 5, indices=[0])
    with pytest.raises(ValueError, match="max_cycles"):
        venv.set_attr("max_cycles", 0)
    assert venv.max_cycles == 3 and venv.config.settling_time == 20.0


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("settling_time", 3.0),
        ("n_agents", 3),
        ("n_intervals", 5),
        ("config", None),
        ("engine", None),
        ("num_envs", 2),
        ("n_envs", 1),
        ("render_mode", "rgb_array"),
        ("reset", None),
        ("_steps", 0),
    ],
)
def test_set_attr_refuses_what_the_config_fixes_and_changes_nothing(name: str, value: object) -> None:
    venv = ConsensusVecEnv(2, **SHORT)
    obs = venv.reset()
    before = {key: getattr(venv, key) for key in ("n_agents", "config", "engine", "num_envs", "n_envs", "render_mode")}
    with pytest.raises(ArgumentError, match=name):
        venv.set_attr(name, value)
    assert {key: getattr(venv, key) for key in before} == before
    venv.step(ReferencePolicy(venv)(obs))
    assert venv.engine.k == 1


def test_env_method_and_env_is_wrapped() -> None:
    venv = ConsensusVecEnv(2, **SHORT)
    venv.reset()
    states = venv.env_method("state", indices=[1, 4])
    assert len(states) == 2
    np.testing.assert_array_equal(states[0], venv.state())
    assert states[0].shape == (2, venv.n_agents, 2)
    assert venv.env_is_wrapped(Monitor) == [False] * venv.num_envs
    assert venv.env_is_wrapped(Monitor, indices=[0, 1]) == [False, False]


# ---------------------------------------------------------------- validation
def test_bad_arguments_are_named() -> None:
    with pytest.raises(ValueError, match="obs_format"):
        ConsensusVecEnv(2, obs_format="dict")
    with pytest.raises(ValueError, match="n_envs"):
        ConsensusVecEnv(0)
    with pytest.raises(ValueError, match="max_cycles"):
        ConsensusVecEnv(1, max_cycles=0)
    with pytest.raises(ValueError, match="render_mode"):
        ConsensusVecEnv(1, render_mode="ascii")
    for seed in (-1, 1.5, "abc", 2**128):
        with pytest.raises(ValueError, match="seed"):
            ConsensusVecEnv(1).seed(seed)


def test_bad_actions_are_named_and_leave_the_env_unchanged() -> None:
    venv = ConsensusVecEnv(2, **SHORT)
    with pytest.raises(RuntimeError, match="reset"):
        venv.step(np.zeros((venv.num_envs, 2), dtype=np.float32))
    venv.reset()
    state = venv.state()
    with pytest.raises(ValueError, match="actions"):
        venv.step(np.zeros((venv.num_envs, 3)))
    nan = np.zeros((venv.num_envs, 2))
    nan[4, 1] = np.nan
    with pytest.raises(ValueError, match="actions"):
        venv.step(nan)
    with pytest.raises(TypeError, match="actions"):
        venv.step(np.full((venv.num_envs, 2), "a"))
    with pytest.raises(TypeError, match="actions"):
        venv.step(np.zeros((venv.num_envs, 2), dtype=complex))
    assert venv.engine.k == 0
    np.testing.assert_array_equal(venv.state(), state)


# ---------------------------------------------------------- spaces and SB3
@pytest.mark.parametrize("kwargs", [{}, {"obs_mode": "raw", "action_mode": "accel"}, {"dim": 2, "topology": "ring"}])
def test_spaces_match_one_agent_of_the_parallel_env(kwargs: dict) -> None:
    venv = ConsensusVecEnv(2, n_intervals=6, **kwargs)
    env = ConsensusParallelEnv(n_intervals=6, **kwargs)
    assert venv.observation_space == env.observation_space("agent_0")
    assert venv.action_space == env.action_space("agent_0")
    assert isinstance(venv.observation_space, spaces.Box) and len(venv.observation_space.shape) == 1
    assert isinstance(venv.action_space, spaces.Box) and len(venv.action_space.shape) == 1
    assert np.all(np.isfinite(venv.action_space.low)) and np.all(venv.action_space.low == -venv.action_space.high)
    venv.action_space.seed(0)
    obs = venv.reset()
    seen = [obs]
    for _ in range(6):
        actions = np.stack([venv.action_space.sample() for _ in range(venv.num_envs)])
        obs, _, dones, infos = venv.step(actions)
        seen.append(obs)
    assert dones.all()
    seen.append(np.array([info["terminal_observation"] for info in infos]))
    assert all(venv.observation_space.contains(row) for batch in seen for row in batch)


def test_works_under_vec_monitor_normalize_and_check_nan() -> None:
    base = ConsensusVecEnv(2, **SHORT)
    venv = VecCheckNan(VecNormalize(VecMonitor(base)), raise_exception=True)
    venv.seed(0)
    obs = venv.reset()
    policy = ReferencePolicy(venv)  # finds the config through the wrappers
    total = np.zeros(venv.num_envs)
    for _ in range(SHORT["n_intervals"]):
        obs, _, dones, infos = venv.step(policy(venv.get_original_obs()))
        total += venv.get_original_reward()
        assert obs.shape == (venv.num_envs, *base.observation_space.shape) and np.all(np.isfinite(obs))
    assert dones.all()
    episode = infos[0]["episode"]  # VecMonitor's statistics, next to our episode_metrics
    assert episode["l"] == SHORT["n_intervals"]
    assert episode["r"] == pytest.approx(total[0], rel=1e-5)
    assert infos[0]["episode_metrics"]["sampling_instants"] == SHORT["n_intervals"]
    assert np.all(np.abs(infos[0]["terminal_observation"]) <= venv.clip_obs)


def test_ppo_learns_briefly_and_predicts_actions_of_the_right_shape() -> None:
    venv = VecMonitor(ConsensusVecEnv(2, n_intervals=16))
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=192, n_epochs=2, seed=0, device="cpu")
    model.learn(total_timesteps=2000)
    assert model.num_timesteps >= 2000
    assert {info["l"] for info in model.ep_info_buffer} == {16}
    obs = venv.reset()
    actions, _ = model.predict(obs, deterministic=True)
    assert actions.shape == (venv.num_envs, 2)
    assert np.all(np.abs(actions) <= venv.action_space.high)


# ------------------------------------------------------------------ the paper
def test_reference_policy_through_the_vec_env_reaches_the_paper_numbers() -> None:
    venv = ConsensusVecEnv(3, scenario="paper_fig1")
    policy = fxc_env.ReferencePolicy(venv)
    obs = venv.reset()
    for _ in range(venv.config.n_intervals):
        actions = policy(obs)
        assert actions.shape == (venv.num_envs, 2)
        obs, _, dones, infos = venv.step(actions)
    assert dones.all()
    for info in infos:
        metrics = info["episode_metrics"]
        assert metrics["achieved_final_position"] == pytest.approx(-1.875, abs=1e-9)
        assert metrics["achieved_final_velocity"] == pytest.approx(-0.125, abs=1e-9)
        assert metrics["predicted_final_position"] == pytest.approx(-1.875, abs=1e-12)
        assert metrics["predicted_final_velocity"] == pytest.approx(-0.125, abs=1e-12)


def test_rgb_array_render_tiles_the_episodes_and_get_images_gives_each_agent_its_episode() -> None:
    venv = ConsensusVecEnv(2, render_mode="rgb_array", **SHORT)
    obs = venv.reset()
    for _ in range(3):
        obs, *_ = venv.step(ReferencePolicy(venv)(obs))
    frame = venv.render()
    assert frame is not None and frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert len(venv._view.history) == 4  # t_0 and three sampling instants
    images = venv.get_images()
    assert len(images) == venv.num_envs
    n = venv.n_agents
    assert all(image is images[0] for image in images[:n])  # episode 0's frame, drawn once for its agents
    assert all(image is images[n] for image in images[n:])
    height, width, _ = images[0].shape
    assert frame.shape == (2 * height, width, 3)  # two episodes, one above the other (ceil(sqrt(2)) rows)
    np.testing.assert_array_equal(frame[:height], images[0])
    np.testing.assert_array_equal(frame[height:], images[n])
    venv.close()


def test_get_images_and_render_before_reset_or_without_rgb_array() -> None:
    venv = ConsensusVecEnv(2, render_mode="rgb_array", **SHORT)
    with pytest.raises(RuntimeError, match="reset"):
        venv.render()
    with pytest.raises(RuntimeError, match="reset"):
        venv.get_images()
    plain = ConsensusVecEnv(2, **SHORT)
    plain.reset()
    with pytest.warns(UserWarning, match="rgb_array"):
        assert plain.get_images() == [None] * plain.num_envs


# ------------------------------------------------------ dtypes and global state
def test_float32_observations_are_the_float64_ones_cast() -> None:
    wide = ConsensusVecEnv(2, **SHORT)
    narrow = ConsensusVecEnv(2, obs_dtype="float32", **SHORT)
    assert narrow.observation_space.dtype == np.float32
    for venv in (wide, narrow):
        venv.seed(4)
    obs_wide, obs_narrow = wide.reset(), narrow.reset()
    assert obs_narrow.dtype == np.float32
    np.testing.assert_array_equal(obs_narrow, obs_wide.astype(np.float32))
    actions = ReferencePolicy(wide)(obs_wide)
    for _ in range(SHORT["n_intervals"]):
        obs_wide, _, _, infos_wide = wide.step(actions)
        obs_narrow, _, dones, infos = narrow.step(actions)
        actions = ReferencePolicy(wide)(obs_wide)
    assert dones.all() and obs_narrow.dtype == np.float32
    assert infos[0]["terminal_observation"].dtype == np.float32
    np.testing.assert_array_equal(
        infos[0]["terminal_observation"], infos_wide[0]["terminal_observation"].astype(np.float32)
    )
    assert all(narrow.observation_space.contains(row) for row in obs_narrow)


def test_normalized_state_of_each_episode_is_the_parallel_envs() -> None:
    venv = ConsensusVecEnv(3, global_state="normalized", obs_dtype="float32", **SHORT)
    env = ConsensusParallelEnv(global_state="normalized", obs_dtype="float32", **SHORT)
    venv.seed(7)
    venv.reset()
    state = venv.state()
    assert state.shape == (3, env.state_space.shape[0]) and state.dtype == np.float32
    env.reset(seed=7 + venv.n_agents)
    np.testing.assert_array_equal(state[1], env.state())
    assert all(env.state_space.contains(row) for row in state)


def test_episode_metrics_are_numbers_and_one_dict_per_sub_env() -> None:
    venv = ConsensusVecEnv(2, switching="random", **SHORT)  # Theorem 2's prediction does not apply
    venv.reset()
    for _ in range(SHORT["n_intervals"]):
        _, _, dones, infos = venv.step(np.zeros((venv.num_envs, 2)))
    assert dones.all()
    metrics = [info["episode_metrics"] for info in infos]
    assert len({id(m) for m in metrics}) == venv.num_envs
    for m in metrics:
        assert None not in m.values()
        assert "predicted_final_position" not in m and m["t_eps_1e_6"] == np.inf  # zero input: never settles
        assert not any(np.isnan(v) for v in m.values())  # metrics that do not apply are left out
    metrics[0]["energy"] = -1.0
    assert metrics[1]["energy"] == 0.0
