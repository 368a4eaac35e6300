"""The saved-policy formats are one table (fxc_env.policies.learned.POLICY_FORMATS): each recognised from its path,
read as data, its records checked by a named function; loading any file then runs one fit check, and reading the
load takes few returns to a module already left."""

from __future__ import annotations

import importlib
import sys
import warnings

import pytest

from fxc_env.config import make_config
from fxc_env.config.tasks import task_kwargs
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.learned import POLICY_FORMATS, load_learned_policy, policy_format, pretrained_path, saved_format


def test_each_format_is_recognised_from_its_path_alone(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "policy.pt").write_bytes(b"")
    checkpoint = tmp_path / "checkpoint"
    checkpoint.mkdir()
    cases = {
        tmp_path / "table.npz": "gain schedule",
        tmp_path / "policy.pt": "torch policy",
        run: "torch policy",
        checkpoint: "RLlib checkpoint",
        tmp_path / "model.zip": "SB3 model",
        tmp_path / "model": "SB3 model",  # no suffix: read as SB3's zip, whose reader names what is missing
    }
    assert {path.name: saved_format(path) for path in cases} == {path.name: name for path, name in cases.items()}
    assert [f.name for f in POLICY_FORMATS] == ["gain schedule", "torch policy", "RLlib checkpoint", "SB3 model"]


def test_each_format_names_the_function_that_checks_its_records():
    for entry in POLICY_FORMATS:
        module, _, name = entry.record.rpartition(".")
        assert callable(getattr(importlib.import_module(module), name)), entry.name


def test_a_file_of_another_format_is_refused_by_its_reader_naming_policy(tmp_path):
    path = tmp_path / "table.npz"
    path.write_bytes(b"not an npz")
    with pytest.raises(ArgumentError, match=r"^policy: .*table\.npz is not a gain-schedule file"):
        load_learned_policy(path)
    assert policy_format(path).name == "gain schedule"


def test_allow_out_of_domain_is_checked_before_the_file_is_read(tmp_path):
    with pytest.raises(ArgumentError, match=r"^allow_out_of_domain: expected True or False, got 'yes'"):
        load_learned_policy(tmp_path / "missing.zip", allow_out_of_domain="yes")


def _walk(path, config) -> list[str]:
    """The modules of fxc_env.policies that loading ``path`` for ``config`` enters, each function at its first
    call, in order, a module repeated back to back counted once."""
    entered, seen = [], set()

    def profile(frame, event, _arg):
        module = frame.f_globals.get("__name__", "")
        if event == "call" and module.startswith("fxc_env.policies") and frame.f_code not in seen:
            seen.add(frame.f_code)
            if not entered or entered[-1] != module:
                entered.append(module)

    sys.setprofile(profile)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            load_learned_policy(path, config)
    finally:
        sys.setprofile(None)
    return [module.rsplit(".", 1)[-1] for module in entered]


def test_loading_a_policy_file_returns_to_a_module_already_left_at_most_five_times():
    from fxc_env.training import rings

    cases = {
        "generalist": make_config(scenario="generalist"),  # SB3 .zip, a gain network
        "paper_fig1": make_config(scenario="paper_fig1"),  # SB3 .zip, slots adapted
        "rings": rings.task_config(),  # gain schedule .npz
        "ppo_rings20": make_config(**task_kwargs("rings20-v2")),  # torch .pt
    }
    for name, config in cases.items():
        walk = _walk(pretrained_path(name), config)
        returns = [module for i, module in enumerate(walk) if module in walk[:i]]
        assert walk[0] == "learned" and "domain" in walk  # the loader, then one fit check ends in the domain
        assert len(returns) <= 5, (name, " -> ".join(walk))
