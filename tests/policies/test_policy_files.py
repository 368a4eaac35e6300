"""Saved policies load without running code from them, and refuse environments they were not trained for.

docs: training.md, "Training learned policies": an SB3 ``.zip`` is read from its plain JSON and its
``weights_only`` tensors; pickled formats (RLlib checkpoints, VecNormalize's ``.pkl``) need
``trusted=True``; a policy that records its training settings refuses an environment whose
schedule, modes, input-limit feature, agent model, dim or observation slots differ.
"""

from __future__ import annotations

import base64
import json
import pickle
import warnings
import zipfile

import numpy as np
import pytest
import torch
from helpers import torch_mlp_policy_file

from fxc_env import make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.domain import OutOfDomainWarning, training_domain
from fxc_env.policies.learned import (
    LearnedPolicy,
    PerAxisPolicy,
    PolicyAdaptedWarning,
    RLlibPolicy,
    load_learned_policy,
    load_model,
    pretrained_path,
)
from fxc_env.policies.policy_files import METADATA_MEMBER, read_sb3_zip, save_model

SHIPPED = ("generalist", "saturated", "paper_fig1")


class WritesMarker:
    """Unpickling this object creates the file ``marker`` (what a crafted policy file could do instead)."""

    def __init__(self, marker) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def members(path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as archive:
        return {name: archive.read(name) for name in archive.namelist()}


def write_zip(path, contents: dict[str, bytes]):
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in contents.items():
            archive.writestr(name, content)
    return path


# ------------------------------------------------------------------------------ no code runs
@pytest.mark.parametrize("name", SHIPPED)
def test_the_shipped_policies_load_with_unpickling_disabled_and_act_as_sb3_does(name, monkeypatch):
    """Bit for bit SB3's deterministic actions, with every unpickler made to fail while loading."""
    from stable_baselines3 import PPO

    sb3 = PPO.load(pretrained_path(name), device="cpu")
    obs = np.random.default_rng(0).uniform(-1, 1, size=(64, sb3.observation_space.shape[0]))
    expected, _ = sb3.predict(obs, deterministic=True)

    def refuse(*args, **kwargs):
        raise AssertionError("a policy file was unpickled")

    import cloudpickle

    monkeypatch.setattr(pickle, "loads", refuse)
    monkeypatch.setattr(pickle, "load", refuse)
    monkeypatch.setattr(cloudpickle, "loads", refuse)
    policy = LearnedPolicy(pretrained_path(name))
    monkeypatch.undo()
    assert np.array_equal(policy(obs), expected)


def test_the_shipped_files_record_their_training_settings():
    recorded = {name: json.loads(members(pretrained_path(name))[METADATA_MEMBER])["env"] for name in SHIPPED}
    assert recorded["saturated"]["schedule"] == "uniform" and recorded["saturated"]["limit_feature"] is True
    assert recorded["generalist"]["schedule"] == "paper" and recorded["paper_fig1"]["obs_slots"] == 4
    for settings in recorded.values():
        assert (settings["action_mode"], settings["obs_mode"], settings["dim"]) == ("plan", "normalized", 1)


def test_a_crafted_data_entry_is_not_unpickled_and_the_model_still_loads(tmp_path):
    marker = tmp_path / "marker"
    contents = members(pretrained_path("paper_fig1"))
    data = json.loads(contents["data"])
    blob = base64.b64encode(pickle.dumps(WritesMarker(marker))).decode()
    for key in ("policy_class", "lr_schedule", "observation_space", "action_space"):
        data[key][":serialized:"] = blob
    crafted = write_zip(tmp_path / "crafted.zip", {**contents, "data": json.dumps(data).encode()})
    policy = load_learned_policy(crafted, make_config("paper_fig1", obs_slots=4))
    assert policy(np.zeros((2, 15))).shape == (2, 2)
    assert not marker.exists()
    with pytest.raises(Exception):  # noqa: B017 - SB3's loader chokes on the crafted objects after running them
        load_model(crafted, trusted=True)
    assert marker.exists(), "the file is crafted: SB3's own loader (trusted=True) runs its code"


def test_crafted_weights_are_refused_naming_the_file_and_nothing_runs(tmp_path):
    marker = tmp_path / "marker"
    contents = members(pretrained_path("paper_fig1"))
    weights = tmp_path / "weights.pth"
    torch.save({"mlp_extractor.policy_net.0.weight": WritesMarker(marker)}, weights)
    crafted = write_zip(tmp_path / "crafted.zip", {**contents, "policy.pth": weights.read_bytes()})
    with pytest.raises(ArgumentError, match=r"policy: .*crafted\.zip: policy\.pth is not a plain state dict"):
        load_learned_policy(crafted)
    assert not marker.exists()


def test_a_vecnormalize_pickle_is_refused_without_trust_and_plain_statistics_are_used(tmp_path):
    marker = tmp_path / "marker"
    stats = tmp_path / "vecnormalize.pkl"
    stats.write_bytes(pickle.dumps(WritesMarker(marker)))
    with pytest.raises(ArgumentError, match=r"vecnormalize: .*vecnormalize\.pkl is a pickle"):
        LearnedPolicy(pretrained_path("paper_fig1"), vecnormalize=stats)
    assert not marker.exists()
    mean, var = np.linspace(-0.5, 0.5, 15), np.linspace(1.0, 4.0, 15)
    plain = tmp_path / "vecnormalize.json"
    plain.write_text(json.dumps({"mean": mean.tolist(), "var": var.tolist(), "epsilon": 1e-8, "clip_obs": 10.0}))
    normalized = LearnedPolicy(pretrained_path("paper_fig1"), vecnormalize=plain)
    raw = LearnedPolicy(pretrained_path("paper_fig1"))
    obs = np.random.default_rng(1).uniform(-1, 1, size=(8, 15))
    np.testing.assert_array_equal(normalized(obs), raw(np.clip((obs - mean) / np.sqrt(var + 1e-8), -10, 10)))


def test_an_rllib_checkpoint_is_refused_without_trust_naming_it(tmp_path):
    marker = tmp_path / "marker"
    checkpoint = tmp_path / "checkpoint"
    module = checkpoint / "learner_group" / "learner" / "rl_module" / "shared"
    module.mkdir(parents=True)
    (checkpoint / "rllib_checkpoint.json").write_text("{}")
    (module / "class_and_ctor_args.pkl").write_bytes(pickle.dumps(WritesMarker(marker)))
    with pytest.raises(
        ArgumentError, match=r"policy: .*checkpoint is an RLlib checkpoint, which loads only by unpickling"
    ):
        load_learned_policy(checkpoint)
    with pytest.raises(ArgumentError, match="trusted=True"):
        RLlibPolicy(checkpoint)
    assert not marker.exists()


# ------------------------------------------------------------------------- files of any origin
def small_ppo(**policy_kwargs):
    from stable_baselines3 import PPO

    import fxc_env

    venv = fxc_env.ConsensusVecEnv(1, scenario="paper_fig1", obs_slots=4, n_intervals=10)
    return PPO("MlpPolicy", venv, n_steps=10, batch_size=60, seed=0, device="cpu", policy_kwargs=policy_kwargs)


def test_a_plain_sb3_save_loads_from_its_readable_fields_as_sb3_acts(tmp_path):
    model = small_ppo(net_arch=[16, 8])
    model.save(tmp_path / "plain.zip")
    obs = np.random.default_rng(2).uniform(-1, 1, size=(32, 15))
    saved = read_sb3_zip(tmp_path / "plain.zip")
    assert saved.training is None and saved.policy_class == "ActorCriticPolicy"
    assert np.array_equal(saved.predict(obs)[0], model.predict(obs, deterministic=True)[0])


def test_an_activation_known_only_from_a_pickle_needs_the_metadata_that_save_model_writes(tmp_path):
    model = small_ppo(net_arch=[16], activation_fn=torch.nn.ReLU)
    model.save(tmp_path / "plain.zip")
    with pytest.raises(ArgumentError, match=r"policy: .*plain\.zip: its policy_kwargs are recorded only as a pickle"):
        read_sb3_zip(tmp_path / "plain.zip")
    path = save_model(model, tmp_path / "saved.zip")
    record = json.loads(members(path)[METADATA_MEMBER])
    assert record["activation"] == "relu" and record["env"]["scenario"] == "paper_fig1"
    # Its training domain (fxc_env.policies.domain), from the environment under the model.
    assert record["domain"] == training_domain(make_config("paper_fig1", obs_slots=4, n_intervals=10))
    obs = np.random.default_rng(3).uniform(-1, 1, size=(32, 15))
    trained = make_config("paper_fig1", obs_slots=4, n_intervals=record["env"]["n_intervals"])
    policy = LearnedPolicy(path, trained)
    assert np.array_equal(policy(obs), model.predict(obs, deterministic=True)[0])
    with pytest.raises(ArgumentError, match=r"action_mode: trained with 'plan', this environment has 'accel'"):
        LearnedPolicy(path, make_config("paper_fig1", obs_slots=4, action_mode="accel"))


# ------------------------------------------------------------------------- training settings
@pytest.mark.parametrize(
    ("name", "env", "message"),
    [
        ("saturated", {"u_max": 10.0}, r"schedule: trained on 'uniform', this environment has 'paper'"),
        ("paper_fig1", {"action_mode": "accel"}, r"action_mode: trained with 'plan', this environment has 'accel'"),
        ("paper_fig1", {"obs_mode": "raw"}, r"obs_mode: trained with 'normalized', this environment has 'raw'"),
        (
            "paper_fig1",
            {"agent_model": "damped"},
            r"agent_model: trained with 'double_integrator', this environment has 'damped'",
        ),
        (
            "saturated",
            {"schedule": "uniform"},
            r"size 16 .* has 15.*u_max feature \(limit_feature\): trained with True, this environment has False",
        ),
        # An MLP reads a fixed 4 rows: fewer are padded exactly, an in-degree of 5 is refused.
        ("paper_fig1", {"topology": "complete", "obs_slots": 5}, r"obs_slots: trained with 4, this environment has 5"),
        ("generalist", {"dim": 2, "obs_mode": "raw"}, r"dim: trained with 1, this environment has 2"),
    ],
    ids=["schedule", "action_mode", "obs_mode", "agent_model", "u_max_feature", "obs_slots", "dim"],
)
def test_a_policy_refuses_settings_it_was_not_trained_for_naming_the_setting_and_both_values(name, env, message):
    config = make_config("paper_fig1", **{"obs_slots": 4, **env})
    with pytest.raises(ArgumentError, match=rf"^policy: .*{message}"):
        load_learned_policy(pretrained_path(name), config)
    with pytest.raises(ArgumentError, match=message):
        LearnedPolicy(pretrained_path(name), config)


@pytest.mark.parametrize(
    ("name", "env"),
    [
        ("paper_fig1", {}),
        ("generalist", {"topology": "ring", "n_agents": 20}),
        ("saturated", {"schedule": "uniform", "u_max": 10.0}),
    ],
)
def test_matching_settings_load(name, env):
    config = make_config("paper_fig1", **{"obs_slots": 4, **env})
    policy = load_learned_policy(pretrained_path(name), config)
    assert isinstance(policy, LearnedPolicy)
    assert policy(np.zeros((3, config.n_agents, config.layout.size))).shape == (3, config.n_agents, 2)


def test_a_one_axis_policy_in_the_plane_acts_per_axis_and_says_so():
    config = make_config(None, topology="ring", n_agents=20, obs_slots=4, dim=2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        policy = load_learned_policy(pretrained_path("generalist"), config)
    assert isinstance(policy, PerAxisPolicy) and policy.adaptation == "trained in dim 1, acting per axis in dim 2"
    assert [w.category for w in caught] == [PolicyAdaptedWarning]
    with pytest.raises(ArgumentError, match=r"schedule: trained on 'paper', this environment has 'uniform'"):
        load_learned_policy(
            pretrained_path("generalist"),
            make_config(None, topology="ring", n_agents=20, obs_slots=4, dim=2, schedule="uniform"),
        )


def torch_policy_file(tmp_path, env):
    return torch_mlp_policy_file(tmp_path, env)


def test_a_torch_policy_refuses_settings_other_than_its_recorded_env(tmp_path):
    path = torch_policy_file(tmp_path, {"scenario": "paper_fig1", "obs_slots": 4, "action_mode": "plan"})
    assert load_learned_policy(path, make_config("paper_fig1", obs_slots=4)).obs_size == 15
    with pytest.raises(
        ArgumentError, match=r"policy\.pt was trained .*action_mode: trained with 'plan', this environment has 'accel'"
    ):
        load_learned_policy(path, make_config("paper_fig1", obs_slots=4, action_mode="accel"))
    from fxc_env.policies.torch_policy import load_torch_policy

    with pytest.raises(ArgumentError, match=r"schedule: trained on 'paper', this environment has 'uniform'"):
        load_torch_policy(path, make_config("paper_fig1", obs_slots=4, schedule="uniform"))
    assert load_torch_policy(path, make_config("paper_fig1", obs_slots=4)).training_settings["obs_slots"] == 4


def test_vecnormalize_statistics_travel_as_plain_json_in_the_saved_model(tmp_path):
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    import fxc_env

    venv = VecNormalize(
        fxc_env.ConsensusVecEnv(1, scenario="paper_fig1", obs_slots=4, n_intervals=10), norm_reward=False
    )
    model = PPO("MlpPolicy", venv, n_steps=10, batch_size=60, n_epochs=1, seed=0, device="cpu")
    model.learn(120)  # the running statistics move off (0, 1)
    path = save_model(model, tmp_path / "normalized.zip")
    obs = np.random.default_rng(4).uniform(-1, 1, size=(16, 15))
    expected, _ = model.predict(venv.normalize_obs(obs), deterministic=True)
    assert not np.allclose(venv.obs_rms.mean, 0.0)
    np.testing.assert_array_equal(LearnedPolicy(path)(obs), expected)


def test_a_trusted_load_still_checks_the_recorded_settings():
    config = make_config("paper_fig1", obs_slots=4, obs_mode="raw")
    with pytest.raises(ArgumentError, match=r"obs_mode: trained with 'normalized', this environment has 'raw'"):
        LearnedPolicy(pretrained_path("paper_fig1"), config, trusted=True)


def test_a_sac_model_loads_from_its_plain_fields_as_sb3_acts(tmp_path):
    from stable_baselines3 import SAC

    import fxc_env

    venv = fxc_env.ConsensusVecEnv(1, scenario="paper_fig1", obs_slots=4, n_intervals=10)
    model = SAC(
        "MlpPolicy", venv, learning_starts=10, batch_size=16, seed=0, device="cpu", policy_kwargs={"net_arch": [16]}
    )
    model.learn(30)
    model.save(tmp_path / "plain.zip")
    obs = np.random.default_rng(5).uniform(-1, 1, size=(32, 15))
    expected, _ = model.predict(obs, deterministic=True)
    config = make_config("paper_fig1", obs_slots=4, n_intervals=10)
    with pytest.warns(OutOfDomainWarning, match=r"plain\.zip records no training domain, so nothing checks"):
        assert np.array_equal(LearnedPolicy(tmp_path / "plain.zip", config)(obs), expected)  # SB3's own save
    with warnings.catch_warnings():
        warnings.simplefilter("error", OutOfDomainWarning)  # save_model records the domain: nothing to say
        assert np.array_equal(LearnedPolicy(save_model(model, tmp_path / "saved.zip"), config)(obs), expected)


def test_a_malformed_description_is_refused_naming_the_file(tmp_path):
    contents = members(pretrained_path("paper_fig1"))
    record = json.loads(contents[METADATA_MEMBER])
    record["net_arch"] = "wide"
    crafted = write_zip(tmp_path / "odd.zip", {**contents, METADATA_MEMBER: json.dumps(record).encode()})
    with pytest.raises(ArgumentError, match=r"policy: .*odd\.zip"):
        load_learned_policy(crafted)


def test_a_custom_features_extractor_is_not_silently_dropped(tmp_path):
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

    class Scaled(BaseFeaturesExtractor):
        def __init__(self, observation_space):
            super().__init__(observation_space, 15)
            self.linear = torch.nn.Linear(15, 15)

        def forward(self, obs):
            return self.linear(obs)

    model = small_ppo(net_arch=[8], features_extractor_class=Scaled)
    path = save_model(model, tmp_path / "custom.zip")
    with pytest.raises(ArgumentError, match=r"policy: .*custom\.zip: features extractor 'Scaled' is not rebuilt"):
        read_sb3_zip(path)
    record = json.loads(members(path)[METADATA_MEMBER])
    del record["features_extractor"]  # a record that does not name it: the extractor's weights give it away
    crafted = write_zip(tmp_path / "unnamed.zip", {**members(path), METADATA_MEMBER: json.dumps(record).encode()})
    with pytest.raises(ArgumentError, match=r"unnamed\.zip: policy\.pth holds parameters .*features_extractor"):
        read_sb3_zip(crafted)
