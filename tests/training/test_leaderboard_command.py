"""``fxc leaderboard`` in an environment without BenchMARL: refused by name, or the laws and shipped policies only."""

from __future__ import annotations

import pytest

from fxc_env.cli.main import main
from fxc_env.training.evaluation.leaderboard import has_benchmarl

pytestmark = pytest.mark.skipif(has_benchmarl(), reason="BenchMARL is installed: tests/benchmarl/test_leaderboard.py")


def test_benchmarl_algorithms_are_refused_naming_the_environment_that_has_them(tmp_path, capsys):
    assert main(["leaderboard", "--frames", "400", "--seeds", "1", "--out", str(tmp_path)]) == 2
    error = capsys.readouterr().err
    assert ".venv-benchmarl" in error and 'pip install "fxc-env[benchmarl]"' in error
    assert error.count("\n") == 1  # one line
    assert not any(tmp_path.iterdir())  # refused before any work


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--algorithms", "qmix"], "--algorithms: expected some of"),
        (["--tasks", "rings20"], "--tasks: a task name carries its version"),
        (["--frames", "0"], "--frames"),
    ],
)
def test_bad_flags_are_refused_by_name(argv, message, tmp_path, capsys):
    assert main(["leaderboard", "--out", str(tmp_path), *argv]) == 2
    assert message in capsys.readouterr().err
