"""What a policy file records is checked on load (fxc_env.policies.records): its training-domain record and
every number, in each format (SB3 zip, torch policy.pt, gain-schedule npz, RLlib fxc_policy.json); each refusal
names the file and the field, and ``fxc evaluate`` prints it as one line."""

from __future__ import annotations

import copy
import json
import re
import warnings
import zipfile

import numpy as np
import pytest
import torch

from fxc_env import cli
from fxc_env.config import make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.domain import DOMAIN_FORMAT, OutOfDomainWarning
from fxc_env.policies.learned import load_learned_policy, pretrained_path, rllib_record
from fxc_env.policies.policy_files import METADATA_MEMBER
from fxc_env.policies.records import DOMAIN_SCHEMA, checked_domain
from fxc_env.policies.saving import RLLIB_RECORD_FORMAT
from fxc_env.training.recipes.rings import task_config

#: The shipped file each format is crafted from.
SOURCES = {"zip": "generalist", "pt": "rings_gru", "npz": "rings"}


def crafted(tmp_path, kind: str, change) -> str:
    """A copy of a shipped ``kind`` file whose record (the zip's fxc_policy.json, the pt's dict, the npz's header)
    ``change`` edits in place; its path."""
    source = pretrained_path(SOURCES[kind])
    path = tmp_path / f"crafted.{kind}"
    if kind == "zip":
        with zipfile.ZipFile(source) as archive:
            contents = {name: archive.read(name) for name in archive.namelist()}
        record = json.loads(contents[METADATA_MEMBER])
        change(record)
        contents[METADATA_MEMBER] = json.dumps(record).encode()
        with zipfile.ZipFile(path, "w") as archive:
            for name, data in contents.items():
                archive.writestr(name, data)
    elif kind == "pt":
        record = torch.load(source, map_location="cpu", weights_only=True)
        change(record)
        torch.save(record, path)
    else:
        with np.load(source, allow_pickle=False) as arrays:
            contents = {name: arrays[name] for name in arrays.files}
        header = json.loads(str(contents["header"]))
        change(header)
        contents["header"] = np.array(json.dumps(header))
        np.savez(path, **contents)
    return str(path)


def with_domain(value):
    """A change that records ``value`` as the domain (a callable edits a copy of the file's own record)."""

    def change(record):
        record["domain"] = value(copy.deepcopy(record["domain"])) if callable(value) else value

    return change


def edited(key, value):
    def edit(domain):
        domain[key] = value
        return domain

    return edit


def without(key):
    def edit(domain):
        del domain[key]
        return domain

    return edit


#: Bad domain records, and the field each refusal names (after ``policy: <file>: ``).
BAD_DOMAINS = {
    "empty": ({}, "domain.format"),
    "false": (False, "domain"),
    "zero": (0, "domain"),
    "a list": ([1, 2], "domain"),
    "text": ("ring", "domain"),
    "only format": ({"format": DOMAIN_FORMAT}, "domain: the record lacks graphs, n_agents"),
    "another format": (edited("format", "fxc_env.policy_domain/0"), "domain.format"),
    "missing graphs": (without("graphs"), "domain: the record lacks graphs"),
    "missing u_max": (without("u_max"), "domain: the record lacks u_max"),
    "unknown field": (edited("colour", ["red"]), r"domain: unknown field\(s\) colour"),
    "n_agents text": (edited("n_agents", "20"), "domain.n_agents"),
    "n_agents one number": (edited("n_agents", [20]), "domain.n_agents"),
    "n_agents floats": (edited("n_agents", [20.5, 21]), "domain.n_agents"),
    "n_agents reversed": (edited("n_agents", [30, 20]), "domain.n_agents"),
    "settling_time NaN": (edited("settling_time", [float("nan"), 20.0]), "domain.settling_time"),
    "settling_time zero": (edited("settling_time", [0.0, 20.0]), "domain.settling_time"),
    "u_max negative": (edited("u_max", [-1.0, 2.0]), "domain.u_max"),
    "obs_noise None": (edited("obs_noise", None), "domain.obs_noise"),
    "link_dropout above 1": (edited("link_dropout", [0.0, 2.0]), "domain.link_dropout"),
    "switching a name": (edited("switching", "periodic"), "domain.switching"),
    "schedule empty": (edited("schedule", []), "domain.schedule"),
    "dim zero": (edited("dim", [0]), "domain.dim"),
    "graphs empty": (edited("graphs", []), "domain.graphs"),
    "graph without period": (edited("graphs", [{"family": "ring"}]), r"domain.graphs\[0\]"),
    "graph of no family": (edited("graphs", [{"family": "hexagon", "period": [1, 1]}]), r"domain.graphs\[0\].family"),
    "random without degree": (edited("graphs", [{"family": "random", "period": [1, 1]}]), r"domain.graphs\[0\]"),
    "period reversed": (edited("graphs", [{"family": "ring", "period": [4, 1]}]), r"domain.graphs\[0\].period"),
    "edges not pairs": (edited("graphs", [{"topology": "t", "edges": [[[0]]]}]), r"domain.graphs\[0\].edges"),
    "graph a name": (edited("graphs", ["ring"]), r"domain.graphs\[0\]"),
}


@pytest.mark.parametrize("kind", list(SOURCES))
@pytest.mark.parametrize("case", list(BAD_DOMAINS))
def test_a_malformed_domain_record_is_refused_on_load_naming_the_file_and_the_field(tmp_path, kind, case):
    """Before: {}, False, 0 and a record of its format alone checked nothing (or fell back to the settings);
    the others raised AttributeError, ValueError, KeyError or TypeError deep in the domain check."""
    value, field = BAD_DOMAINS[case]
    path = crafted(tmp_path, kind, with_domain(value))
    with pytest.raises(ArgumentError, match=rf"^policy: {re.escape(path)}: {field}"):
        load_learned_policy(path)


@pytest.mark.parametrize("kind", ["pt", "zip"])
def test_a_file_without_a_domain_record_still_says_that_nothing_checks_the_environment(tmp_path, kind):
    def change(record):
        record["domain"] = None
        record["env"] = {} if kind == "pt" else None

    path = crafted(tmp_path, kind, change)
    env = task_config() if kind == "pt" else make_config("generalist")
    with pytest.warns(OutOfDomainWarning, match=r"records no training domain, so nothing checks"):
        load_learned_policy(path, env)


def test_every_shipped_record_meets_the_schema_and_a_record_is_its_fields():
    for name in SOURCES.values():
        policy = load_learned_policy(name)
        assert set(policy.training_domain) == {"format", *DOMAIN_SCHEMA}
    assert checked_domain(None, "here") is None


def test_an_rllib_record_is_checked_by_the_same_validator(tmp_path):
    """RLlibPolicy reads its checkpoint's fxc_policy.json with rllib_record (Ray is not needed to read it)."""
    (tmp_path / METADATA_MEMBER).write_text(
        json.dumps({"format": RLLIB_RECORD_FORMAT, "module": "shared", "env": None, "domain": {}})
    )
    with pytest.raises(ArgumentError, match=rf"^policy: {re.escape(str(tmp_path / METADATA_MEMBER))}: domain.format"):
        rllib_record(tmp_path)


# ------------------------------------------------------------------------------------ numbers (item 3)
def set_entry(key, value):
    def change(record):
        record[key] = value

    return change


@pytest.mark.parametrize("bound", [-1.0, 0.0, 1e300, float("nan"), float("inf"), True, "2"])
def test_a_torch_policy_refuses_an_action_bound_that_is_not_a_positive_finite_float32(tmp_path, bound):
    """Before: -1 made every action -1 and 0 every action 0 (scored, rc 0), 1e300 a traceback in torch's clamp."""
    path = crafted(tmp_path, "pt", set_entry("action_bound", bound))
    with pytest.raises(ArgumentError, match=rf"^policy: {re.escape(path)}: action_bound: expected a positive finite"):
        load_learned_policy(path)


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("obs_size", 6.5),
        ("action_size", 0),
        ("hidden", [64.7]),
        ("gru_size", -1),
        ("clock_index", 6),
        ("timesteps", -5),
        ("log_std", torch.tensor([float("nan"), -3.0])),
        ("log_std", torch.zeros(3)),
    ],
)
def test_every_number_of_a_torch_policy_is_checked_by_name(tmp_path, key, value):
    path = crafted(tmp_path, "pt", set_entry(key, value))
    with pytest.raises(ArgumentError, match=rf"^policy: {re.escape(path)}: {key}"):
        load_learned_policy(path)


def test_a_non_finite_weight_is_refused_by_name_not_blamed_on_the_actions(tmp_path):
    def poison(record):
        name = next(iter(record["actor"]))
        record["actor"][name] = torch.full_like(record["actor"][name], float("nan"))

    path = crafted(tmp_path, "pt", poison)
    with pytest.raises(ArgumentError, match=rf"^policy: {re.escape(path)}: actor\.\S+: every entry must be finite"):
        load_learned_policy(path)


def bounds(key, entry, value):
    def change(record):
        record[key][entry] = value

    return change


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (bounds("action", "high", [float("nan"), 2.0]), "action.high"),
        (bounds("action", "low", [-1e300, -2.0]), "action.low"),
        (bounds("action", "low", [-2.0]), "action.low"),
        (bounds("observation", "shape", [0]), "observation.shape"),
        (bounds("observation", "low", [float("nan")] * 15), "observation.low"),
        (set_entry("num_timesteps", -1), "num_timesteps"),
    ],
)
def test_every_number_of_an_sb3_record_is_checked_by_name(tmp_path, change, field):
    path = crafted(tmp_path, "zip", change)
    with pytest.raises(ArgumentError, match=rf"^policy: {re.escape(path)}: {re.escape(field)}"):
        load_learned_policy(path)


def test_an_sb3_action_space_of_one_point_is_refused(tmp_path):
    """Before: low = high = -1 made every action -1, and the model was scored."""

    def collapse(record):
        record["action"]["low"] = record["action"]["high"] = [-1.0, -1.0]

    path = crafted(tmp_path, "zip", collapse)
    with pytest.raises(ArgumentError, match=rf"^policy: {re.escape(path)}: action: expected low < high"):
        load_learned_policy(path)


def test_recorded_normalization_statistics_must_be_finite(tmp_path):
    def stats(record):
        record["normalization"] = {"mean": [0.0] * 15, "var": [float("nan")] * 15, "epsilon": 1e-8, "clip_obs": 10.0}

    with pytest.raises(ArgumentError, match=r"^vecnormalize: .*crafted\.zip: mean and var must be finite"):
        load_learned_policy(crafted(tmp_path, "zip", stats))
    with pytest.raises(ArgumentError, match=r"^vecnormalize: .*crafted\.zip: clip_obs: expected a positive"):
        load_learned_policy(
            crafted(tmp_path, "zip", set_entry("normalization", {"mean": [0.0] * 15, "var": [1.0] * 15, "clip_obs": 0}))
        )


@pytest.mark.parametrize(("key", "value"), [("n_intervals", 200.5), ("obs_slots", "1"), ("dim", 0)])
def test_the_settings_a_gain_schedule_reads_are_checked_by_name(tmp_path, key, value):
    def change(header):
        header["env"][key] = value

    path = crafted(tmp_path, "npz", change)
    with pytest.raises(ArgumentError, match=rf"^policy: {re.escape(path)}: env\.{key}: expected an integer"):
        load_learned_policy(path)


# ------------------------------------------------------------------------------------- the command line
@pytest.mark.parametrize(
    ("kind", "change"),
    [
        ("pt", with_domain({})),
        ("zip", with_domain([1, 2])),
        ("npz", with_domain({"format": DOMAIN_FORMAT})),
        ("pt", set_entry("action_bound", -1.0)),
    ],
)
def test_fxc_evaluate_prints_one_line_naming_the_file_and_exits_non_zero(tmp_path, capsys, kind, change):
    path = crafted(tmp_path, kind, change)
    argv = ["evaluate", "--policy", path, "--scenario", "paper_fig1", "--seeds", "1", "--workers", "1"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        code = cli.main([*argv, "--out", str(tmp_path / "out"), "--no-progress"])
    err = capsys.readouterr().err
    assert code != 0
    assert err.startswith(f"fxc evaluate: error: --policy: {path}: ") and err.count("\n") == 1
    assert "Traceback" not in err
