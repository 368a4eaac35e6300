"""``fxc --help`` and every ``fxc <command> --help`` are plain text: no docstring markup reaches the terminal."""

from __future__ import annotations

import argparse

import pytest

from fxc_env.cli.main import build_parser
from fxc_env.config.argument_types import plain_text

MARKUP = (":data:`", ":mod:`", ":func:`", ":class:`", ":meth:`", ":attr:`", "``")


def _command_parsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    (commands,) = (action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
    return {"fxc": parser, **{f"fxc {name}": sub for name, sub in commands.choices.items()}}


@pytest.mark.parametrize("command", sorted(_command_parsers()))
def test_every_command_help_is_plain_text(command):
    help_text = _command_parsers()[command].format_help()
    assert help_text.strip()
    for role in MARKUP:
        assert role not in help_text, f"{command} --help shows {role!r}"


def test_train_help_names_what_the_roles_pointed_at():
    """The markup goes, the names stay: ``fxc train --help`` still says where the scenario names are."""
    help_text = " ".join(_command_parsers()["fxc train"].format_help().split())
    assert "Named scenario of fxc_env.SCENARIOS" in help_text
    assert "--algo ALGO ppo or sac." in help_text


def test_plain_text_keeps_a_role_title_or_target():
    assert plain_text(":func:`~fxc_env.engine.draws.draw_batch`") == "draw_batch"
    assert plain_text(":meth:`Observer.measure <fxc_env.engine.Observer.measure>` rows") == "Observer.measure rows"
    assert plain_text("``0-4`` of :data:`fxc_env.config.tasks.TASKS`") == "0-4 of fxc_env.config.tasks.TASKS"
