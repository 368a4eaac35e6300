"""fxc_env.utils.cluster: the scale-out commands say how to get Ray where it is missing, and refuse bad combinations."""

from __future__ import annotations

import sys

import pytest

from fxc_env import cli
from fxc_env.training import TrainArgs, train
from fxc_env.utils.cluster import import_ray


@pytest.fixture
def without_ray(monkeypatch):
    """This interpreter as if Ray were not installed (the main .venv has none; .venv-rllib does)."""
    monkeypatch.setitem(sys.modules, "ray", None)


def test_import_ray_names_the_option_and_the_extra(without_ray):
    with pytest.raises(ValueError, match=r"--ray: Ray is not installed .*fxc-env\[rllib\]"):
        import_ray("--ray")


def test_train_with_the_rllib_backend_without_ray_says_how_to_install_it(without_ray, tmp_path, capsys):
    with pytest.raises(ValueError, match=r"--backend rllib: Ray is not installed"):
        train(TrainArgs(backend="rllib", run_dir=str(tmp_path / "run")))
    assert cli.main(["train", "--backend", "rllib", "--run-dir", str(tmp_path / "run")]) == 2
    assert 'pip install "fxc-env[rllib]"' in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_benchmark_on_ray_without_ray_and_bad_address_combinations_are_refused(without_ray, tmp_path, capsys):
    assert cli.main(["benchmark", "--quick", "--ray", "--out", str(tmp_path), "--no-progress"]) == 2
    assert "--ray: Ray is not installed" in capsys.readouterr().err
    assert cli.main(["benchmark", "--quick", "--address", "auto", "--out", str(tmp_path)]) == 2
    assert "--address: joins a Ray cluster for --ray" in capsys.readouterr().err
    assert cli.main(["benchmark", "--ray", "--address", "auto", "--workers", "2", "--out", str(tmp_path)]) == 2
    assert "--workers: sets the cores of a local Ray" in capsys.readouterr().err


def test_an_unknown_backend_is_refused():
    with pytest.raises(ValueError, match=r"backend: expected one of \('sb3', 'rllib', 'torch', 'diff'\), got 'jax'"):
        train(TrainArgs(backend="jax"))
