"""Every refusal of the command-line value checks (``fxc_env.utils.cli_checks``).

Each check must name the flag it was given, say what it expected and write nothing: a
subcommand checks all of its values before it creates a directory (docs: bad-input.md, "Bad input and saved policies").
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from fxc_env.core.validation import MAX_INTERVALS, ArgumentError
from fxc_env.utils import cli_checks
from fxc_env.utils.cli_checks import budgets, output_directory, yaml_mapping_file

#: A flag name no subcommand uses: the message must carry the one it was given.
FLAG = "--some-flag"


def tree(root: Path) -> dict[str, bytes | None]:
    """Every path below ``root`` with its bytes (``None`` for directories and links): what was written."""
    found: dict[str, bytes | None] = {}
    for path in sorted(root.rglob("*")):
        plain = path.is_file() and not path.is_symlink()
        found[str(path.relative_to(root))] = path.read_bytes() if plain else None
    return found


def refused(check, *args) -> str:
    """The message of the :class:`ArgumentError` that ``check(FLAG, *args)`` raises, which starts with the flag."""
    with pytest.raises(ArgumentError) as caught:
        check(FLAG, *args)
    message = str(caught.value)
    assert message.startswith(f"{FLAG}: "), message
    assert isinstance(caught.value, ValueError)  # a usage error, also a ValueError
    return message


# --- output_directory -------------------------------------------------------------------


def test_output_directory_accepts_existing_and_creatable_directories_without_creating_them(tmp_path):
    before = tree(tmp_path)
    assert output_directory(FLAG, tmp_path) == tmp_path
    assert output_directory(FLAG, str(tmp_path / "new" / "deeper")) == tmp_path / "new" / "deeper"
    assert tree(tmp_path) == before  # mkdir -p is the command's job, once every value is checked


@pytest.mark.parametrize("text", ["", "   "])
def test_output_directory_refuses_an_empty_path(text, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    message = refused(output_directory, text)
    assert message == f"{FLAG}: expected a directory path, got {text!r}"
    assert tree(tmp_path) == {}


def test_output_directory_refuses_an_existing_file(tmp_path):
    (tmp_path / "notes.txt").write_text("keep me")
    before = tree(tmp_path)
    message = refused(output_directory, str(tmp_path / "notes.txt"))
    assert message == f"{FLAG}: expected a directory, got {str(tmp_path / 'notes.txt')!r}, which is an existing file"
    assert tree(tmp_path) == before


def test_output_directory_refuses_a_path_below_a_file(tmp_path):
    (tmp_path / "notes.txt").write_text("keep me")
    before = tree(tmp_path)
    target = str(tmp_path / "notes.txt" / "out" / "deeper")
    message = refused(output_directory, target)
    assert message == f"{FLAG}: cannot create {target!r}: {str(tmp_path / 'notes.txt')!r} is a file, not a directory"
    assert tree(tmp_path) == before


def test_output_directory_refuses_a_path_through_a_dangling_link(tmp_path):
    (tmp_path / "link").symlink_to(tmp_path / "nowhere")
    before = tree(tmp_path)
    target = str(tmp_path / "link" / "out")
    message = refused(output_directory, target)
    assert message == f"{FLAG}: cannot create {target!r}: {str(tmp_path / 'link')!r} is a dangling symbolic link"
    assert tree(tmp_path) == before and not (tmp_path / "nowhere").exists()


def deny_writes_in(monkeypatch, denied: Path) -> None:
    """``os.access`` says no write permission in ``denied`` (as for a non-root user on a read-only directory)."""
    real_access = os.access

    def access(path, mode, *args, **kwargs):
        if Path(path) == denied and mode & os.W_OK:
            return False
        return real_access(path, mode, *args, **kwargs)

    monkeypatch.setattr(cli_checks.os, "access", access)


def test_output_directory_refuses_an_existing_directory_it_may_not_write_into(tmp_path, monkeypatch):
    locked = tmp_path / "locked"
    locked.mkdir()
    deny_writes_in(monkeypatch, locked)
    before = tree(tmp_path)
    message = refused(output_directory, str(locked))
    assert message == f"{FLAG}: cannot write into {str(locked)!r} (permission denied)"
    assert tree(tmp_path) == before


def test_output_directory_refuses_a_new_directory_below_one_it_may_not_write_into(tmp_path, monkeypatch):
    locked = tmp_path / "locked"
    locked.mkdir()
    deny_writes_in(monkeypatch, locked)
    before = tree(tmp_path)
    message = refused(output_directory, str(locked / "new" / "out"))
    assert message == f"{FLAG}: cannot create directories in {str(locked)!r} (permission denied)"
    assert tree(tmp_path) == before


# --- yaml_mapping_file ------------------------------------------------------------------


def test_yaml_mapping_file_returns_the_mapping(tmp_path):
    path = tmp_path / "hyperparams.yml"
    path.write_text("default:\n  ppo: {learning_rate: 0.0003}\n")
    before = tree(tmp_path)
    assert yaml_mapping_file(FLAG, path) == {"default": {"ppo": {"learning_rate": 0.0003}}}
    assert yaml_mapping_file(FLAG, str(path)) == {"default": {"ppo": {"learning_rate": 0.0003}}}
    assert tree(tmp_path) == before


def test_yaml_mapping_file_refuses_a_missing_file(tmp_path):
    missing = str(tmp_path / "absent.yml")
    message = refused(yaml_mapping_file, missing)
    assert message == f"{FLAG}: expected a YAML file, got {missing!r}, which does not exist"
    assert tree(tmp_path) == {}


def test_yaml_mapping_file_refuses_a_directory(tmp_path):
    (tmp_path / "configs").mkdir()
    message = refused(yaml_mapping_file, str(tmp_path / "configs"))
    assert message == f"{FLAG}: expected a YAML file, got {str(tmp_path / 'configs')!r}, which is a directory"
    assert tree(tmp_path) == {"configs": None}


def test_yaml_mapping_file_refuses_a_file_that_is_not_text(tmp_path):
    path = tmp_path / "policy.zip"
    path.write_bytes(b"PK\x03\x04\xff\xfe\x00binary")
    before = tree(tmp_path)
    message = refused(yaml_mapping_file, str(path))
    assert message.startswith(f"{FLAG}: cannot read {str(path)!r} (")
    assert "utf-8" in message.lower()  # the reason is given
    assert tree(tmp_path) == before


def test_yaml_mapping_file_refuses_a_file_it_cannot_open(tmp_path, monkeypatch):
    path = tmp_path / "hyperparams.yml"
    path.write_text("default: {}\n")

    def unreadable(self, *args, **kwargs):
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "read_text", unreadable)
    message = refused(yaml_mapping_file, str(path))
    assert message.startswith(f"{FLAG}: cannot read {str(path)!r} (") and "Permission denied" in message


def test_yaml_mapping_file_refuses_malformed_yaml_with_the_parser_s_first_line(tmp_path):
    path = tmp_path / "broken.yml"
    path.write_text("default:\n  ppo: [1, 2\n")
    before = tree(tmp_path)
    message = refused(yaml_mapping_file, str(path))
    assert re.fullmatch(rf"{re.escape(FLAG)}: {re.escape(repr(str(path)))} is not valid YAML \([^\n]+\)", message)
    assert tree(tmp_path) == before


@pytest.mark.parametrize(
    ("text", "kind"),
    [("- ppo\n- a2c\n", "list"), ("just words\n", "str"), ("42\n", "int"), ("", "NoneType")],
    ids=["list", "scalar", "number", "empty"],
)
def test_yaml_mapping_file_refuses_yaml_that_is_not_a_mapping(text, kind, tmp_path):
    path = tmp_path / "hyperparams.yml"
    path.write_text(text)
    before = tree(tmp_path)
    message = refused(yaml_mapping_file, str(path))
    assert message == f"{FLAG}: expected a YAML mapping in {str(path)!r}, got {kind}"
    assert tree(tmp_path) == before


# --- budgets ----------------------------------------------------------------------------


def test_budgets_parse_comma_separated_integers_in_order():
    assert budgets(FLAG, "25, 200") == (25, 200)
    assert budgets(FLAG, " 400 ,25") == (400, 25)
    assert budgets(FLAG, f"1,{MAX_INTERVALS}") == (1, MAX_INTERVALS)


@pytest.mark.parametrize("text", ["abc", "", "25,", "two hundred", "1e3", "2.5", "25;200"])
def test_budgets_refuse_what_is_not_a_list_of_integers(text):
    message = refused(budgets, text)
    assert message == f"{FLAG}: expected comma-separated integers in [1, {MAX_INTERVALS:g}], got {text!r}"


@pytest.mark.parametrize("text", ["0", "-5", "25,0", f"{MAX_INTERVALS + 1}", f"200,{10 * MAX_INTERVALS}"])
def test_budgets_refuse_a_budget_outside_one_to_the_interval_cap(text):
    message = refused(budgets, text)
    assert message == f"{FLAG}: expected comma-separated integers in [1, {MAX_INTERVALS:g}], got {text!r}"


@pytest.mark.parametrize("text", ["200,200", "25, 200, 25"])
def test_budgets_refuse_repeats(text):
    assert refused(budgets, text) == f"{FLAG}: expected distinct budgets, got {text!r}"


# --- through the command line -----------------------------------------------------------


def test_fxc_prints_the_refusal_as_one_usage_line_and_writes_nothing(tmp_path, capsys):
    from fxc_env.cli import main

    (tmp_path / "notes.txt").write_text("keep me")
    before = tree(tmp_path)
    assert main(["simulate", "--out", str(tmp_path / "notes.txt" / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fxc simulate: error: --out: cannot create ") and err.count("\n") == 1
    assert main(["evaluate", "--policy", "reference", "--budgets", "25,25", "--out", str(tmp_path / "eval")]) == 2
    assert capsys.readouterr().err == "fxc evaluate: error: --budgets: expected distinct budgets, got '25,25'\n"
    assert tree(tmp_path) == before


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            "evaluate --policy reference --agent-model integrator_chain --order 3 --action-mode accel".split(),
            "action_mode: 'integrator_chain' agents take plans only",
        ),
        (["evaluate", "--policy", "reference", "--action-mode", "accel"], "--action-mode: sets a learned policy's"),
        (["simulate", "--scenario", "none", "--topology", "complete", "--n-agents", "1"], "n_agents: expected"),
        (["simulate", "--family", "ring", "--mean-in-degree", "3"], "--mean-in-degree: shapes --family random only"),
    ],
    ids=[
        "a combination the Python API refuses",
        "a learned policy's flag with the reference",
        "one agent",
        "a key the family does not use",
    ],
)
def test_fxc_refuses_environment_flags_as_the_python_api_does_and_writes_nothing(tmp_path, capsys, argv, message):
    # fxc evaluate ran (exit 0) on a combination make_config refuses, or ignored the flag (issue 24).
    from fxc_env.cli import main

    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"fxc {argv[0]}: error: {message}") and err.count("\n") == 1, err
    assert tree(tmp_path) == {}
