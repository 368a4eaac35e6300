"""One import name: the wheel installs ``fxc_env`` only, and the layers import only downward.

The folders ``baselines/`` and ``training/`` install as ``fxc_env.baselines`` and
``fxc_env.training`` (setuptools ``package-dir``). A wheel that put them at the top level
would let another distribution named ``baselines`` overwrite ours.
"""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(out), str(ROOT)],
        check=True,
        capture_output=True,
    )
    (found,) = out.glob("fxc_env-*.whl")
    return found


@pytest.mark.slow
def test_the_wheel_installs_fxc_env_as_its_only_top_level_name(wheel):
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        (top_level,) = [n for n in names if n.endswith(".dist-info/top_level.txt")]
        assert archive.read(top_level).decode().split() == ["fxc_env"]
    tops = {name.split("/")[0] for name in names if not name.split("/")[0].endswith(".dist-info")}
    assert tops == {"fxc_env"}
    for module in (
        "fxc_env/baselines/harness/benchmark.py",
        "fxc_env/baselines/laws/linear.py",
        "fxc_env/training/backends/sb3_train.py",
        "fxc_env/training/evaluation/statistics.py",
        "fxc_env/training/recipes/rings.py",
        "fxc_env/training/hyperparams.yml",
    ):
        assert module in names
    assert "fxc_env/pretrained/paper_fig1_ppo.zip" in names
    # The documentation's sources (fxc_env/docs/, no __init__.py) build the site; they are not installed.
    assert not [name for name in names if name.startswith("fxc_env/docs/")]


@pytest.mark.slow
def test_a_wheel_install_imports_its_subpackages_next_to_a_foreign_baselines_package(wheel, tmp_path):
    """Installed into a bare directory beside a package called ``baselines``, ours is untouched."""
    target = tmp_path / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target), str(wheel)],
        check=True,
        capture_output=True,
    )
    foreign = target / "baselines"
    foreign.mkdir()
    (foreign / "__init__.py").write_text("raise ImportError('the foreign baselines package')\n")
    code = (
        "import fxc_env.baselines, fxc_env.training.args, sys; "
        "print(fxc_env.baselines.__file__); print(fxc_env.training.args.HYPERPARAMS.exists())"
    )
    # The wheel first on the path, the test environment's dependencies after it; run away from the checkout.
    env = dict(os.environ, PYTHONPATH=str(target))
    result = subprocess.run(
        [sys.executable, "-I", "-c", f"import sys; sys.path.insert(0, {str(target)!r}); {code}"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=env,
    )
    assert result.returncode == 0, result.stderr
    path, hyperparams = result.stdout.split()
    assert Path(path).is_relative_to(target / "fxc_env")
    assert hyperparams == "True"


def test_the_layer_contract_holds(tmp_path):
    """import-linter's contracts in pyproject.toml, checked on the installed layout.

    import-linter reads a package from its folder, so the three source folders are linked
    into one ``fxc_env`` tree the way the wheel lays them out.
    """
    tree = tmp_path / "fxc_env"
    tree.mkdir()
    for entry in (ROOT / "fxc_env").iterdir():
        (tree / entry.name).symlink_to(entry)
    (tree / "baselines").symlink_to(ROOT / "baselines")
    (tree / "training").symlink_to(ROOT / "training")
    lint = Path(sys.executable).with_name("lint-imports")
    result = subprocess.run(
        [str(lint), "--config", str(ROOT / "pyproject.toml"), "--no-cache"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=dict(os.environ, PYTHONPATH=str(tmp_path)),
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


def test_every_package_folder_is_installed():
    """A sub-folder with an ``__init__.py`` (``baselines/laws/``, ``training/backends/`` ...) is in the wheel's list."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    folders = {"fxc_env": "fxc_env", "baselines": "fxc_env.baselines", "training": "fxc_env.training"}
    found = {
        ".".join((package, *init.parent.relative_to(ROOT / folder).parts))
        for folder, package in folders.items()
        for init in (ROOT / folder).rglob("__init__.py")
    }
    assert found == listed, f"not installed: {sorted(found - listed)}; listed but absent: {sorted(listed - found)}"
