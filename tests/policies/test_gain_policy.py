"""The gain-scheduled policy network: linear in the rows, exact for the paper's controller, saved and loaded by SB3."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO

import fxc_env
from fxc_env.policies.gain_network import GainScheduledExtractor, GainScheduledPolicy
from fxc_env.policies.learned import LearnedPolicy


def observations(config, seed=0, steps=5):
    """Real observations of a random digraph episode under the reference, ``(steps * N, obs_size)``."""
    env = fxc_env.parallel_env(**config)
    obs, _ = env.reset(seed=seed)
    policy = fxc_env.ReferencePolicy(env)
    collected = []
    for _ in range(steps):
        collected.append(np.stack(list(obs.values())))
        obs = env.step({agent: policy(o) for agent, o in obs.items()})[0]
    return np.concatenate(collected)


class ReferenceGains(torch.nn.Module):
    """The gains of eq. (11) from the context: ``[[1, 1], [0, 1]] / (d + 1)`` on every slot."""

    def __init__(self, slots):
        super().__init__()
        self.slots = slots

    def forward(self, context):
        degree = context[..., : self.slots].sum(dim=-1, keepdim=True)
        gains = torch.tensor([1.0, 1.0, 0.0, 1.0]).repeat(self.slots) / (degree + 1.0)
        return gains


CONFIG = {"topology": "random", "n_agents": 12, "mean_in_degree": 2.5, "obs_slots": 4}


def test_the_network_represents_the_paper_controller_exactly():
    obs = observations(CONFIG)
    extractor = GainScheduledExtractor(obs.shape[-1])
    extractor.gains = ReferenceGains(extractor.slots)
    actions = extractor.forward_actor(torch.as_tensor(obs)).detach().numpy()
    expected = fxc_env.ReferencePolicy(fxc_env.parallel_env(**CONFIG))(obs)
    np.testing.assert_allclose(actions, expected, rtol=1e-12, atol=1e-14)


def test_actions_are_linear_in_the_rows_and_padding_contributes_nothing():
    obs = torch.as_tensor(observations(CONFIG))
    torch.manual_seed(0)
    extractor = GainScheduledExtractor(obs.shape[-1]).double()
    for layer in extractor.gains:
        if isinstance(layer, torch.nn.Linear):
            torch.nn.init.normal_(layer.weight)
    scaled = obs.clone()
    scaled[:, : extractor.rows_end] *= -3.5
    np.testing.assert_allclose(
        extractor.forward_actor(scaled).detach().numpy(),
        -3.5 * extractor.forward_actor(obs).detach().numpy(),
        rtol=1e-10,
    )
    # Rows of padded slots are zero in every observation, so whatever gains they get, they add nothing.
    masked = obs[:, extractor.rows_end : extractor.rows_end + extractor.slots] == 0
    rows = obs[:, : extractor.rows_end].reshape(-1, extractor.slots, 2)
    assert torch.all(rows[masked] == 0)


class FixedGains(torch.nn.Module):
    """Slot 0 gets ``[[0.3, 0.7], [0.5, 0]]``, the other slots nothing, whatever the context."""

    def forward(self, context):
        gains = torch.zeros(*context.shape[:-1], 16)
        gains[..., :4] = torch.tensor([0.3, 0.7, 0.5, 0.0])
        return gains


def test_the_position_to_velocity_gain_is_in_units_of_the_interval():
    extractor = GainScheduledExtractor(15)  # 4 slots, one axis
    extractor.gains = FixedGains()
    obs = torch.zeros(2, 15)
    obs[:, 0] = 1.0  # slot 0 holds a position difference only
    obs[:, extractor.rows_end] = 1.0  # its mask
    obs[:, extractor.rows_end + 4 + 1] = torch.tensor([0.01, 0.5])  # T_{k+1} / T_s
    action = extractor.forward_actor(obs).detach().numpy()
    np.testing.assert_allclose(action, [[0.3, 0.5 * 0.01], [0.3, 0.5 * 0.5]])


@pytest.mark.slow
def test_ppo_with_the_gain_policy_saves_and_loads_as_a_learned_policy(tmp_path):
    venv = fxc_env.ConsensusVecEnv(2, **CONFIG, n_intervals=10)
    model = PPO(GainScheduledPolicy, venv, n_steps=10, batch_size=60, n_epochs=1, seed=0, device="cpu")
    model.learn(240)
    model.save(tmp_path / "gain.zip")
    obs = observations({**CONFIG, "n_intervals": 10}, steps=2)
    loaded = LearnedPolicy(tmp_path / "gain.zip", fxc_env.parallel_env(**CONFIG, n_intervals=10))
    expected, _ = model.predict(obs, deterministic=True)
    np.testing.assert_allclose(loaded(obs), expected, rtol=1e-6)


def test_a_fresh_gain_policy_starts_at_zero_action():
    venv = fxc_env.ConsensusVecEnv(1, **CONFIG, n_intervals=10)
    model = PPO(GainScheduledPolicy, venv, seed=0, device="cpu")
    obs = observations({**CONFIG, "n_intervals": 10}, steps=1)
    actions, _ = model.predict(obs, deterministic=True)
    assert np.all(actions == 0)


def test_a_layout_for_the_plane_is_refused_with_a_clear_message():
    with pytest.raises(ValueError, match="one-axis layout"):
        GainScheduledExtractor(4 * (2 * 2) + 4 + 3)  # 4 slots in the plane


class HoldGains(torch.nn.Module):
    """The saturation-aware law's held input in plan units: ``g T^2 (S_x + (gamma / T) S_v) (1/2, 1)``.

    With the position -> velocity entry in units of ``T / T_s`` (the extractor scales it back).
    """

    def __init__(self, slots, settling_time, gain=1.0, gamma=3.0):
        super().__init__()
        self.slots, self.settling_time, self.gain, self.gamma = slots, settling_time, gain, gamma

    def forward(self, context):
        interval = context[..., self.slots + 1 : self.slots + 2] * self.settling_time  # T
        fraction = context[..., self.slots + 1 : self.slots + 2]  # T / T_s
        g = self.gain * interval * interval
        per_slot = torch.cat([g / 2, g * self.gamma / interval / 2, g / fraction, g * self.gamma / interval], dim=-1)
        mask = context[..., : self.slots].unsqueeze(-1)
        return (mask * per_slot.unsqueeze(-2)).reshape(*context.shape[:-1], 4 * self.slots)


def test_the_gated_network_represents_the_saturation_aware_law_exactly():
    from fxc_env.baselines.laws.saturation_aware import SaturationAwarePolicy
    from fxc_env.policies.gain_network import GatedGainExtractor

    config = {"scenario": "paper_fig1", "obs_slots": 4, "u_max": 10.0, "schedule": "uniform"}
    obs = observations(config, steps=40)
    extractor = GatedGainExtractor(obs.shape[-1]).double()
    extractor.gains = ReferenceGains(extractor.slots)
    extractor.hold_gains = HoldGains(extractor.slots, 20.0)
    with torch.no_grad():
        extractor.sharpness.fill_(1e6)  # a hard switch
    actions = extractor.forward_actor(torch.as_tensor(obs)).detach().numpy()
    expected = SaturationAwarePolicy(fxc_env.parallel_env(**config))(obs)
    both_laws_used = np.unique(
        np.isclose(actions, fxc_env.ReferencePolicy(fxc_env.parallel_env(**config))(obs)).all(-1)
    )
    assert set(both_laws_used) == {True, False}
    np.testing.assert_allclose(actions, expected, rtol=1e-9, atol=1e-12)
