"""The engine on torch tensors: equal to numpy step by step, partial resets, and never waiting on the host."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers import MODES, PAPER_V0, PAPER_X0

from fxc_env import ConsensusEngine, ReferencePolicy, make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import to_host

#: Float64 agreement demanded of the two backends, relative to the largest state entry.
TOLERANCE = 1e-12


class SharedDraws:
    """The same uniform and normal draws for two engines (noise, dropout, switching), numpy-made."""

    def __init__(self, seed: int) -> None:
        self.uniform_rng = np.random.default_rng(seed)
        self.normal_rng = np.random.default_rng(seed + 1)

    def install(self, numpy_engine: ConsensusEngine, torch_engine: ConsensusEngine) -> None:
        queue: dict[str, list] = {"uniform": [], "normal": []}

        def draw(kind, make):
            def numpy_side(shape):
                values = make(shape)
                queue[kind].append(values)
                return values

            def torch_side(shape):
                values = queue[kind].pop(0)
                assert tuple(values.shape) == tuple(shape)
                return torch.as_tensor(values)

            return numpy_side, torch_side

        numpy_engine._uniform, torch_engine._uniform = draw("uniform", self.uniform_rng.random)
        numpy_engine._normal, torch_engine._normal = draw("normal", self.normal_rng.standard_normal)

        # Random switching: both engines take the same graph indices.
        def switching(periods):
            local = np.floor(numpy_engine._uniform((numpy_engine.n_episodes,)) * np.asarray(periods)).astype(np.int64)
            return local

        def torch_switching(periods):
            return torch.floor(torch_engine._uniform((torch_engine.n_episodes,)) * periods.double()).long()

        numpy_engine._switching_draw, torch_engine._switching_draw = switching, torch_switching


def twin_engines(n_episodes=3, seed=0, **kwargs):
    """A numpy engine and a torch (CPU) engine reset to the same episodes (topologies and u_max included)."""
    config = make_config(**kwargs)
    numpy_engine = ConsensusEngine(config, n_episodes)
    torch_engine = ConsensusEngine(config, n_episodes, device="cpu")
    SharedDraws(seed).install(numpy_engine, torch_engine)
    rng = np.random.default_rng(seed)
    draws = [numpy_engine.draw_episode(rng) for _ in range(n_episodes)]
    x0 = np.stack([d.x0 for d in draws])
    v0 = np.stack([d.v0 for d in draws])
    topologies = [d.topology for d in draws]
    u_max = [d.u_max for d in draws] if config.u_max_choices is not None else None
    numpy_engine.reset(x0, v0, topologies=topologies, u_max=u_max)
    torch_engine.reset(torch.as_tensor(x0), torch.as_tensor(v0), topologies=topologies, u_max=u_max)
    return config, numpy_engine, torch_engine


TINY = np.finfo(float).tiny


def assert_close(numpy_value, torch_value, what, k, floor=TINY):
    expected = np.asarray(numpy_value, dtype=np.float64)
    got = to_host(torch_value)
    scale = max(float(np.max(np.abs(expected), initial=0.0)), floor)
    assert got.shape == expected.shape, (what, k)
    assert np.max(np.abs(got - expected), initial=0.0) <= TOLERANCE * scale, (what, k)


CASES = [
    *[dict(scenario="paper_fig1", action_mode=a, obs_mode=o) for a, o in MODES],
    *[dict(scenario="paper_fig1", dim=2, action_mode=a, obs_mode=o) for a, o in MODES],
    dict(scenario="paper_fig1", dim=3),
    dict(scenario="paper_fig1", u_max=(10.0, 100.0, 1000.0)),
    dict(scenario="paper_fig1", u_max=30.0, dim=2, action_mode="accel"),
    dict(scenario="paper_fig1", switching="random"),
    dict(scenario="generalist"),
    dict(scenario="saturated"),
    dict(scenario="paper_fig1", obs_noise=0.01, link_dropout=0.2),
    dict(scenario="paper_fig1", obs_noise=0.01, link_dropout=0.2, switching="random", dim=2),
]


@pytest.mark.parametrize("kwargs", CASES, ids=lambda kw: ",".join(f"{k}={v}" for k, v in kw.items()))
def test_torch_equals_numpy_step_by_step_in_float64(kwargs):
    # Same episodes, same draws of noise, dropout and switching (handed to both engines):
    # observations, rewards, energies, peaks and states agree to 1e-12 relative at every step.
    config, numpy_engine, torch_engine = twin_engines(**kwargs)
    policy = ReferencePolicy(config)
    k = 0
    while not numpy_engine.done:
        observations = numpy_engine.observations()
        assert_close(observations, torch_engine.observations(), "observations", k)
        actions = policy.act(observations)
        expected = numpy_engine.step(actions)
        got = torch_engine.step(torch.as_tensor(actions))
        # The reward is a difference of two logarithms (each rounded by its own libm): relative to them.
        assert_close(expected.reward, got.reward, "reward", k, floor=1.0)
        for name in ("energy", "peak_input", "saturated_fraction"):
            assert_close(getattr(expected, name), getattr(got, name), name, k)
        assert_close(numpy_engine.state, torch_engine.state, "state", k)
        k += 1
    assert torch_engine.done and k == config.n_intervals
    expected_metrics, got_metrics = numpy_engine.batch_metrics(), torch_engine.batch_metrics()
    for name, column in expected_metrics.items():
        np.testing.assert_allclose(got_metrics[name], column, rtol=1e-9, atol=0, equal_nan=True, err_msg=name)
    torch_engine.raise_if_invalid()  # nothing flagged


def test_the_torch_reference_reaches_the_papers_deadline_error():
    config = make_config("paper_fig1")
    engine = ConsensusEngine(config, 2, device="cpu")
    engine.reset(
        torch.as_tensor(np.tile(PAPER_X0[None, :, None], (2, 1, 1))),
        torch.as_tensor(np.tile(PAPER_V0[None, :, None], (2, 1, 1))),
    )
    policy = ReferencePolicy(config)
    while not engine.done:
        engine.step(policy.act(engine.observations()))
    metrics = engine.batch_metrics()
    assert np.all(metrics["relative_deadline_error"] < 3e-12)  # docs: agent-models.md: 2.9e-12 at K = 200
    np.testing.assert_allclose(metrics["achieved_final_position"], metrics["predicted_final_position"], rtol=1e-9)


def test_float32_reaches_its_stated_floor():
    # The TorchRL env's card: in float32 the agents still agree at T_s (D(T_s)/D(0) <= 1e-6 at K = 200),
    # but the value they agree on is off Theorem 1's by float32 round-off (about 1e-5 relative).
    config = make_config("paper_fig1", initial_state="random")
    engine = ConsensusEngine(config, 16, device="cpu", dtype="float32")
    engine.seed(0)
    engine.reset(*engine.draw_batch()[:2])
    policy = ReferencePolicy(config)
    while not engine.done:
        engine.step(policy.act(engine.observations()))
    assert engine.state.dtype == torch.float32
    metrics = engine.batch_metrics()
    assert np.all(metrics["relative_deadline_error"] <= 1e-6)
    drift = np.abs(metrics["achieved_final_position"] - metrics["predicted_final_position"])
    relative_drift = drift / np.abs(to_host(engine.x0)).max(axis=(1, 2))
    assert np.all(relative_drift < 1e-4) and np.any(relative_drift > 1e-8)


def test_a_partial_reset_restarts_only_the_chosen_episodes():
    config, numpy_engine, torch_engine = twin_engines(n_episodes=4, scenario="paper_fig1")
    policy = ReferencePolicy(config)
    for _ in range(7):
        torch_engine.step(policy.act(torch_engine.observations()))
        numpy_engine.step(policy.act(numpy_engine.observations()))
    chosen = torch.tensor([True, False, True, False])
    x_new = torch.full((4, 6, 1), 3.0)
    v_new = torch.full((4, 6, 1), -1.0)
    x_new[:, 0] = 5.0
    torch_engine.reset(x_new, v_new, episodes=chosen)
    np.testing.assert_array_equal(to_host(torch_engine.steps), [0, 7, 0, 7])
    np.testing.assert_array_equal(to_host(torch_engine.x[chosen]), to_host(x_new[chosen]))
    np.testing.assert_array_equal(to_host(torch_engine.x[~chosen]), numpy_engine.x[[1, 3]])
    # Each episode now follows its own clock: the restarted ones as a fresh engine, the others as before.
    fresh = ConsensusEngine(config, 2, device="cpu")
    fresh.reset(x_new[chosen], v_new[chosen])
    for _ in range(config.n_intervals - 7):
        torch_engine.step(policy.act(torch_engine.observations()))
        fresh.step(policy.act(fresh.observations()))
        numpy_engine.step(policy.act(numpy_engine.observations()))
    assert numpy_engine.done
    np.testing.assert_array_equal(to_host(torch_engine.episode_done()), [False, True, False, True])
    np.testing.assert_allclose(
        to_host(torch_engine.state[~chosen]), numpy_engine.state[[1, 3]], rtol=0, atol=1e-12 * 10
    )
    np.testing.assert_allclose(to_host(torch_engine.state[chosen]), to_host(fresh.state), rtol=0, atol=1e-12 * 10)
    metrics = torch_engine.batch_metrics()
    np.testing.assert_array_equal(metrics["sampling_instants"], [193, 200, 193, 200])


def test_non_finite_actions_are_flagged_on_the_device_and_reported_on_request():
    config = make_config("paper_fig1")
    engine = ConsensusEngine(config, 3, device="cpu")
    engine.reset(*engine.draw_batch()[:2])
    actions = torch.zeros((3, 6, 2), dtype=torch.float64)
    actions[1, 2, 0] = float("nan")
    engine.step(engine.validate_actions(actions))  # no read of a value: the step goes on
    np.testing.assert_array_equal(to_host(engine.invalid), [False, True, False])
    with pytest.raises(ArgumentError, match=r"actions: episodes \[1\]"):
        engine.raise_if_invalid()
    engine.reset(*engine.draw_batch()[:2])
    engine.raise_if_invalid()  # a reset clears the flags


def test_shapes_are_checked_at_once_and_leave_the_state_unchanged():
    config = make_config("paper_fig1")
    engine = ConsensusEngine(config, 2, device="cpu")
    engine.reset(*engine.draw_batch()[:2])
    before = engine.state.clone()
    with pytest.raises(ArgumentError, match=r"actions: expected shape \(2, 6, 2\), got \(2, 6, 3\)"):
        engine.validate_actions(torch.zeros((2, 6, 3)))
    with pytest.raises(ArgumentError, match="actions: expected a torch tensor"):
        engine.validate_actions([[0.0]])
    assert torch.equal(engine.state, before) and engine.k == 0


@pytest.mark.parametrize(
    ("device", "message"),
    [("cuda:0" if not torch.cuda.is_available() else "no-such-device", "device: "), ("no-such-device", "device: ")],
)
def test_an_unusable_device_is_a_usage_error_naming_device(device, message):
    with pytest.raises(ArgumentError, match=message):
        ConsensusEngine(make_config("paper_fig1"), 1, device=device)


def test_dtype_is_checked():
    with pytest.raises(ArgumentError, match="dtype"):
        ConsensusEngine(make_config("paper_fig1"), 1, device="cpu", dtype="float16")


# -------------------------------------------------------------- never waits on the host
META_CASES = [
    dict(scenario="paper_fig1"),
    dict(scenario="paper_fig1", dim=2, action_mode="accel", obs_mode="raw"),
    dict(scenario="paper_fig1", u_max=(10.0, 100.0), obs_noise=0.01, link_dropout=0.1),
    dict(scenario="paper_fig1", dim=3, switching="random", global_state="normalized"),
    dict(scenario="generalist"),  # a family: graphs drawn on the host at a full reset, once per episode
]


@pytest.mark.parametrize("kwargs", META_CASES, ids=lambda kw: ",".join(f"{k}={v}" for k, v in kw.items()))
def test_step_reset_and_reference_run_on_the_meta_device(kwargs):
    # torch's meta device holds shapes only: any .item(), .tolist(), numpy conversion or branch on
    # a value raises there. The engine's draw, reset, observation, validation and step, and the
    # reference, run through: no step waits on the device (CUDA included).
    config = make_config(**kwargs)
    engine = ConsensusEngine(config, 8, device="meta")
    policy = ReferencePolicy(config)
    x0, v0, u_max, topologies = engine.draw_batch()
    engine.reset(x0, v0, topologies=topologies, u_max=u_max)
    for _ in range(3):
        engine.step(engine.validate_actions(policy.act(engine.observations())))
    assert engine.state.device.type == "meta"
    assert engine.normalized_state().shape == (8, config.n_agents * 2 * config.dim + 3)  # centralised critics
    if config.family is None:  # a partial reset too (a family's would read the mask, once per reset)
        engine.reset(x0, v0, u_max=u_max, episodes=torch.ones(8, dtype=torch.bool, device="meta"))
        for _ in range(3):
            outcome = engine.step(engine.validate_actions(policy.act(engine.observations())))
        assert outcome.reward.shape == (8,) and outcome.terminated.device.type == "meta"


# -------------------------------------------------------------- arguments checked like numpy's
@pytest.mark.parametrize("n_episodes", [0, -1, 2.0, True, "2"])
def test_n_episodes_is_a_positive_integer(n_episodes):
    with pytest.raises(ArgumentError, match="n_episodes: expected an integer"):
        ConsensusEngine(make_config("paper_fig1"), n_episodes, device="cpu")


@pytest.mark.parametrize("seed", [-1, 1.5, True, 2**64])
def test_a_torch_seed_is_an_integer_in_0_to_2_to_the_64(seed):
    engine = ConsensusEngine(make_config("paper_fig1"), 1, device="cpu")
    rng = engine.rng
    with pytest.raises(ArgumentError, match=r"seed: expected an integer in \[0, 2\*\*64 - 1\]"):
        engine.seed(seed)
    assert engine.rng is rng
    engine.seed(2**64 - 1)  # the largest torch.Generator seed is taken


def test_an_unsupported_torch_device_type_is_refused_by_name():
    with pytest.raises(ArgumentError, match=r"device: expected None .* of type cpu / cuda / meta, got 'mps'"):
        ConsensusEngine(make_config("paper_fig1"), 1, device="mps")


def test_numpy_actions_are_checked_in_full_and_converted_to_the_device():
    engine = ConsensusEngine(make_config("paper_fig1"), 2, device="cpu")
    engine.reset(*engine.draw_batch()[:2])
    actions = np.zeros((2, 6, 2))
    checked = engine.validate_actions(actions)
    assert isinstance(checked, torch.Tensor) and checked.dtype == torch.float64
    actions[0, 0, 0] = np.nan
    with pytest.raises(ArgumentError, match="actions: every entry must be finite"):
        engine.validate_actions(actions)  # on the host already: refused at once, like numpy's


def _bad_states(x0):
    nan, inf, big = x0.clone(), x0.clone(), x0.clone()
    nan[0, 0, 0], inf[1, 2, 0], big[0, 1, 0] = float("nan"), float("inf"), 1e101
    return [
        (nan, "finite entries"),
        (inf, "finite entries"),
        (big, "finite entries within"),
        (x0.to(torch.complex128), "real numbers"),
        (x0[:, :3], r"expected shape \(2, 6, 1\), got \(2, 3, 1\)"),
        (np.full((2, 6, 1), np.nan), "every entry must be finite"),  # a host array: the numpy engine's check
        ("x", "expected a torch tensor"),
    ]


@pytest.mark.parametrize("which", ["x0", "v0"])
def test_a_torch_reset_checks_x0_and_v0_and_changes_nothing_on_refusal(which):
    engine = ConsensusEngine(make_config("paper_fig1"), 2, device="cpu")
    x0, v0 = engine.draw_batch()[:2]
    engine.reset(x0, v0)
    engine.step(engine.validate_actions(torch.zeros((2, 6, 2), dtype=torch.float64)))
    state = engine.state.clone()
    for bad, message in _bad_states(x0 if which == "x0" else v0):
        args = (bad, v0) if which == "x0" else (x0, bad)
        with pytest.raises(ArgumentError, match=f"{which}: .*{message}"):
            engine.reset(*args)
        assert torch.equal(engine.state, state) and engine.k == 1
