"""The differentiable engine's contract (ConsensusTorchEnv card; the docs page "Differentiable simulation").

Gradients of observations, rewards and episode metrics with respect to a policy's parameters
are exact (autograd equals central finite differences to 1e-6 relative in float64), over two
consecutive episodes of one environment: a reset lets the previous episode's graph go.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from docs_blocks import DOCS, blocks, run  # noqa: E402

from fxc_env.core.validation import ArgumentTypeError  # noqa: E402
from fxc_env.envs.torch_env import ConsensusTorchEnv  # noqa: E402
from fxc_env.policies.torchrl_reference import ReferenceModule  # noqa: E402

#: Two consecutive episodes of one environment, each from its own seed.
EPISODE_SEEDS = (3, 4)
#: A general (A, B) agent: a damped oscillator per axis (x' = v, v' = -x - 0.3 v + u).
DAMPED = ([[0.0, 1.0], [-1.0, -0.3]], [[0.0], [1.0]])

CASES = {
    # The paper's example: its initial state on the assumed Fig. 1 switching set.
    "paper_fig1": dict(scenario="paper_fig1", n_intervals=12, batch_size=2),
    # A new switching graph every episode (rings, paths, stars, random digraphs, periods up to 4).
    "family_switching": dict(scenario="generalist", n_intervals=10, batch_size=2, obs_noise=1e-3, link_dropout=0.2),
    # An input limit that binds: the clipped input is piecewise smooth (no kink within the differences' step).
    "input_limit": dict(
        scenario=None, n_agents=6, topology="ring", n_intervals=12, initial_state="random", batch_size=2, u_max=0.05
    ),
    # General linear agents, stepped on the device by their interval maps.
    "general_ab": dict(
        scenario=None,
        n_agents=5,
        topology="ring",
        n_intervals=10,
        initial_state="random",
        batch_size=2,
        agent_model=DAMPED,
    ),
}


class LinearPolicy:
    """Actions ``theta_0 * reference(obs) + theta_1 * obs @ R`` (general agents: ``obs @ (theta_0 R_0 + theta_1 R_1)``)."""

    def __init__(self, env: ConsensusTorchEnv) -> None:
        c = env.config
        rng = np.random.default_rng(7)
        size = env.observation_spec["agents", "observation"].shape[-1]
        self.gains = [torch.as_tensor(0.3 * rng.standard_normal((size, c.action_size)) / size**0.5) for _ in range(2)]
        self.reference = ReferenceModule(c) if c.model is None else None

    def __call__(self, obs: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
        if self.reference is None:
            return obs @ (theta[0] * self.gains[0] + theta[1] * self.gains[1])
        return theta[0] * self.reference(obs) + theta[1] * (obs @ self.gains[0])


def episode_loss(env: ConsensusTorchEnv, policy: LinearPolicy, theta: torch.Tensor, seed: int) -> torch.Tensor:
    """One whole episode from ``set_seed(seed)``: a loss on every reward, every observation and the metrics."""
    env.set_seed(seed)
    td = env.reset()
    weights = torch.linspace(-1.0, 1.0, td["agents", "observation"].shape[-1], dtype=torch.float64)
    loss = torch.zeros((), dtype=torch.float64)
    for _ in range(env.config.n_intervals):
        td["agents", "action"] = policy(td["agents", "observation"], theta)
        td = env.step(td)["next"]
        loss = loss + td["agents", "reward"].sum() + 0.1 * (td["agents", "observation"] * weights).sum()
    metrics = env.episode_metrics(as_tensors=True)
    return (
        loss
        + metrics["relative_deadline_error"].log().sum()
        + metrics["energy"].log().sum()
        + metrics["peak_input"].sum()
        + metrics["final_position_spread"].sum()
        + metrics["achieved_final_velocity"].sum()
        + metrics["saturated_fraction"].sum()
    )


def central_differences(env, policy, theta: torch.Tensor, seed: int, step: float = 1e-6) -> np.ndarray:
    gradient = np.zeros(len(theta))
    for i in range(len(theta)):
        shift = torch.zeros_like(theta)
        shift[i] = step
        with torch.no_grad():
            up = episode_loss(env, policy, theta + shift, seed)
            down = episode_loss(env, policy, theta - shift, seed)
        gradient[i] = (up - down).item() / (2 * step)
    return gradient


@pytest.mark.parametrize("case", list(CASES))
def test_autograd_equals_central_differences_over_two_consecutive_episodes(case):
    env = ConsensusTorchEnv(**CASES[case])
    policy = LinearPolicy(env)
    theta = torch.tensor([0.9, 0.2], dtype=torch.float64, requires_grad=True)
    for seed in EPISODE_SEEDS:  # one env: the second episode backpropagates after the first's graph was freed
        (autograd,) = torch.autograd.grad(episode_loss(env, policy, theta, seed), theta)
        finite = central_differences(env, policy, theta.detach(), seed)
        assert np.all(np.isfinite(autograd.numpy())) and np.abs(autograd.numpy()).max() > 1e-3
        np.testing.assert_allclose(autograd.numpy(), finite, rtol=1e-6, atol=1e-6 * np.abs(finite).max())
        if case == "family_switching":  # the episode's graphs did switch
            assert max(topology.period for topology in env.engine.topologies) > 1
    if case == "input_limit":  # the limit did bind: the clip is on the path that was differentiated
        assert env.episode_metrics()["saturated_fraction"].min() > 0.05


def test_a_full_reset_lets_the_previous_episode_graph_go():
    # The report: a linear policy on the observation rows, set_seed then reset each episode.
    env = ConsensusTorchEnv(
        n_agents=20, topology="ring", scenario=None, n_intervals=10, initial_state="random", batch_size=4, obs_slots=1
    )
    size = env.observation_spec["agents", "observation"].shape[-1]
    weights = torch.zeros((size, env.config.action_size), dtype=torch.float64, requires_grad=True)
    for seed in range(3):
        env.set_seed(seed)
        td = env.reset()
        assert env.engine.state.grad_fn is None and env.engine.trackers.energy_total.grad_fn is None
        total = torch.zeros((), dtype=torch.float64)
        for _ in range(10):
            td["agents", "action"] = td["agents", "observation"] @ weights
            td = env.step(td)["next"]
            total = total + td["agents", "reward"].sum()
        total.backward()  # raised "backward through the graph a second time" at the second episode
        assert torch.isfinite(weights.grad).all()


def test_a_partial_reset_cuts_the_restarted_episodes_past_and_cut_graph_cuts_every_episode():
    env = ConsensusTorchEnv(
        scenario=None, n_agents=6, topology="ring", n_intervals=12, initial_state="random", batch_size=3, seed=5
    )
    policy = LinearPolicy(env)
    before = torch.tensor([0.9, 0.2], dtype=torch.float64, requires_grad=True)
    after = torch.tensor([1.0, 0.1], dtype=torch.float64, requires_grad=True)
    td = env.reset()
    for _ in range(4):
        td["agents", "action"] = policy(td["agents", "observation"], before)
        td = env.step(td)["next"]
    restart = torch.tensor([True, False, False])
    td = env.reset(td.set("_reset", restart[:, None]))
    for _ in range(4):
        td["agents", "action"] = policy(td["agents", "observation"], after)
        td = env.step(td)["next"]
    reward = td["agents", "reward"][:, 0, 0]
    restarted = torch.autograd.grad(reward[0], before, retain_graph=True)[0]
    going_on = torch.autograd.grad(reward[1:].sum(), before, retain_graph=True)[0]
    assert torch.equal(restarted, torch.zeros(2, dtype=torch.float64))  # no path to before the reset
    assert going_on.abs().max() > 1e-6  # the others kept theirs
    # Truncated windows: backpropagate, cut, go on, backpropagate again.
    torch.autograd.grad(reward.sum(), after)
    env.cut_graph()
    td = td.detach()
    for _ in range(2):
        td["agents", "action"] = policy(td["agents", "observation"], after)
        td = env.step(td)["next"]
    loss = td["agents", "reward"].sum() + env.episode_metrics(as_tensors=True)["energy"].sum()
    (gradient,) = torch.autograd.grad(loss, after)
    assert torch.isfinite(gradient).all()
    assert torch.autograd.grad(loss, before, allow_unused=True)[0] is None


def test_metric_tensors_equal_the_episode_metrics_and_as_tensors_is_checked():
    env = ConsensusTorchEnv(scenario="random_20_planar", n_intervals=15, batch_size=3, seed=2, u_max=[0.5, 5.0])
    policy = ReferenceModule(env.config)
    td = env.reset()
    for _ in range(15):
        td["agents", "action"] = policy(td["agents", "observation"])
        td = env.step(td)["next"]
    tensors, arrays = env.episode_metrics(as_tensors=True), env.episode_metrics()
    for name, tensor in tensors.items():
        assert tensor.shape == (3,) and tensor.device == env.engine.device
        np.testing.assert_allclose(tensor.numpy(), arrays[name], rtol=1e-12, atol=1e-12, err_msg=name)
    with pytest.raises(ArgumentTypeError, match="as_tensors: expected True or False"):
        env.episode_metrics(as_tensors="yes")


def test_the_docs_example_fits_a_gain_by_gradient_descent(capsys):
    (block,) = [block for block in blocks(DOCS / "differentiable.md") if "autograd.grad" in block.code]
    assert len([line for line in block.code.splitlines() if line.strip()]) <= 15
    run(block)
    printed = re.findall(r"gain ([-\d.]+), mean log D\(T_s\)/D\(0\) ([-\d.]+)", capsys.readouterr().out)
    assert len(printed) == 30
    gains, losses = np.array(printed, dtype=float).T
    # From half the paper's plan the descent raises the gain and lowers the deadline error.
    assert losses[-1] < losses[0] - 0.3 and 0.9 < gains[-1] < 1.3
