"""The previous release's module paths still import, for one release, with a warning naming the new path.

The layers became folders (docs: architecture.md, "Moved modules"): every module at the package's top level moved into
one, and ``fxc_env.training.train`` became ``sb3_train``. A user's ``import fxc_env.learned`` keeps working
and says where the module is now; the public names users import sit on ``fxc_env`` itself.
"""

from __future__ import annotations

import importlib
import importlib.util
import subprocess
import sys
import types
import warnings

import pytest

import fxc_env
from fxc_env.core.validation import ArgumentError

#: Every module path of the previous release that moved, and where its names are now.
OLD_TO_NEW = {
    "fxc_env.cli_checks": ["fxc_env.utils.cli_checks"],
    "fxc_env.cluster": ["fxc_env.utils.cluster"],
    "fxc_env.consensus_aec": ["fxc_env.envs.aec"],
    "fxc_env.consensus_env": ["fxc_env.envs.parallel"],
    "fxc_env.env_arguments": ["fxc_env.config.flags"],
    "fxc_env.gain_policy": ["fxc_env.policies.gain_network"],
    "fxc_env.interop": ["fxc_env.envs.interop"],
    "fxc_env.layout": ["fxc_env.config.layout"],
    "fxc_env.learned": ["fxc_env.policies.learned"],
    "fxc_env.plots": ["fxc_env.analysis.plots"],
    "fxc_env.reference": ["fxc_env.policies.reference"],
    "fxc_env.registration": ["fxc_env.envs.registration"],
    "fxc_env.rendering": ["fxc_env.envs.rendering"],
    "fxc_env.scenarios": ["fxc_env.config.scenarios"],
    "fxc_env.simulation": ["fxc_env.analysis.simulation"],
    "fxc_env.spaces": ["fxc_env.envs.spaces"],
    "fxc_env.threads": ["fxc_env.utils.threads"],
    "fxc_env.torch_policy": ["fxc_env.policies.torch_policy"],
    "fxc_env.torchrl_env": ["fxc_env.envs.torch_env", "fxc_env.policies.torchrl_reference"],
    "fxc_env.vec_env": ["fxc_env.envs.vec_env"],
    "fxc_env.training.train": ["fxc_env.training.backends.sb3_train"],
}

#: Issue 36: the laws apart from the benchmark harness, training's back ends, evaluation and recipes each in a
#: sub-folder (core.statistics with the evaluation that uses it). No file stands at an old path.
MOVED_IN_FOLDERS = {
    "fxc_env.baselines.benchmark": ["fxc_env.baselines.harness.benchmark"],
    "fxc_env.baselines.bounded_steer": ["fxc_env.baselines.laws.bounded_steer"],
    "fxc_env.baselines.design": ["fxc_env.baselines.laws.design"],
    "fxc_env.baselines.dropout": ["fxc_env.baselines.harness.dropout"],
    "fxc_env.baselines.figures": ["fxc_env.baselines.harness.figures"],
    "fxc_env.baselines.filtering": ["fxc_env.baselines.laws.filtering"],
    "fxc_env.baselines.filtering_goals": ["fxc_env.baselines.harness.filtering_goals"],
    "fxc_env.baselines.finite_time": ["fxc_env.baselines.laws.finite_time"],
    "fxc_env.baselines.graph_agnostic": ["fxc_env.baselines.laws.graph_agnostic"],
    "fxc_env.baselines.graph_agnostic_goals": ["fxc_env.baselines.harness.graph_agnostic_goals"],
    "fxc_env.baselines.jobs": ["fxc_env.baselines.harness.jobs"],
    "fxc_env.baselines.leader_follower": ["fxc_env.baselines.laws.leader_follower"],
    "fxc_env.baselines.linear": ["fxc_env.baselines.laws.linear"],
    "fxc_env.baselines.minimum_time": ["fxc_env.baselines.laws.minimum_time"],
    "fxc_env.baselines.motion_signals": ["fxc_env.baselines.laws.motion_signals"],
    "fxc_env.baselines.policy": ["fxc_env.baselines.laws.policy"],
    "fxc_env.baselines.prescribed_time": ["fxc_env.baselines.laws.prescribed_time"],
    "fxc_env.baselines.ray_jobs": ["fxc_env.baselines.harness.ray_jobs"],
    "fxc_env.baselines.report": ["fxc_env.baselines.harness.report"],
    "fxc_env.baselines.resolution": ["fxc_env.baselines.harness.resolution"],
    "fxc_env.baselines.sampled": ["fxc_env.baselines.laws.sampled"],
    "fxc_env.baselines.saturation_aware": ["fxc_env.baselines.laws.saturation_aware"],
    "fxc_env.baselines.signalling": ["fxc_env.baselines.laws.signalling"],
    "fxc_env.baselines.suite": ["fxc_env.baselines.harness.suite"],
    "fxc_env.core.statistics": ["fxc_env.training.evaluation.statistics"],
    "fxc_env.training.agnostic": ["fxc_env.training.recipes.agnostic"],
    "fxc_env.training.checkpoint_checks": ["fxc_env.training.backends.checkpoint_checks"],
    "fxc_env.training.diff_train": ["fxc_env.training.backends.diff_train"],
    "fxc_env.training.evaluate": ["fxc_env.training.evaluation.evaluate"],
    "fxc_env.training.imitation": ["fxc_env.training.backends.imitation"],
    "fxc_env.training.leaderboard": ["fxc_env.training.evaluation.leaderboard"],
    "fxc_env.training.leaderboard_files": ["fxc_env.training.evaluation.leaderboard_files"],
    "fxc_env.training.leaderboard_runs": ["fxc_env.training.evaluation.leaderboard_runs"],
    "fxc_env.training.noise_gains": ["fxc_env.training.recipes.noise_gains"],
    "fxc_env.training.recurrent_imitation": ["fxc_env.training.recipes.recurrent_imitation"],
    "fxc_env.training.residual_sensitivity": ["fxc_env.training.recipes.residual_sensitivity"],
    "fxc_env.training.rings": ["fxc_env.training.recipes.rings"],
    "fxc_env.training.rings_scratch": ["fxc_env.training.recipes.rings_scratch"],
    "fxc_env.training.rllib_train": ["fxc_env.training.backends.rllib_train"],
    "fxc_env.training.sb3_train": ["fxc_env.training.backends.sb3_train"],
    "fxc_env.training.seed_evaluation": ["fxc_env.training.evaluation.seed_evaluation"],
    "fxc_env.training.seed_scores": ["fxc_env.training.evaluation.seed_scores"],
    "fxc_env.training.seeds": ["fxc_env.training.evaluation.seeds"],
    "fxc_env.training.torch_common": ["fxc_env.training.backends.torch_common"],
    "fxc_env.training.torch_ppo": ["fxc_env.training.backends.torch_ppo"],
}
OLD_TO_NEW.update({old: new for old, new in MOVED_IN_FOLDERS.items() if "rllib" not in old})  # Ray: .venv-rllib

#: Names the previous release's README imported from the old paths.
README_IMPORTS = {
    "fxc_env.torchrl_env": ["ConsensusTorchEnv", "reference_policy"],
    "fxc_env.learned": ["load_learned_policy"],
    "fxc_env.gain_policy": ["GainScheduledPolicy"],
    "fxc_env.torch_policy": ["TorchPolicy", "load_torch_policy"],
}


def forget(path: str) -> None:
    """Drop an old module from this process, so that importing it runs (and warns) again (a package's function of
    the same name stays: ``fxc_env.training.train``)."""
    sys.modules.pop(path, None)
    parent, _, child = path.rpartition(".")
    names = vars(importlib.import_module(parent))
    if isinstance(names.get(child), types.ModuleType):
        module = names.pop(child)
        if callable(module):  # it stood over the package's function: put the function back
            names[child] = module.__wrapped__


def import_old(path: str) -> tuple[object, list[warnings.WarningMessage]]:
    forget(path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = importlib.import_module(path)
    return module, [w for w in caught if issubclass(w.category, DeprecationWarning)]


def test_the_old_module_path_of_train_leaves_fxc_env_training_train_a_working_function():
    """``import fxc_env.training.train`` (the module's old path) binds the module on the package where the
    function ``fxc_env.training.train(args)`` is: the module calls the function, the same error for a bad back end."""
    import fxc_env.training as training
    from fxc_env.training import TrainArgs

    function = training.train
    with pytest.raises(ArgumentError) as direct:
        function(TrainArgs(backend="nope"))
    module, caught = import_old("fxc_env.training.train")
    assert caught and training.train is module
    with pytest.raises(ArgumentError) as through_the_module:
        training.train(TrainArgs(backend="nope"))
    assert str(through_the_module.value) == str(direct.value) and "backend" in str(direct.value)
    forget("fxc_env.training.train")
    assert training.train is function


@pytest.mark.parametrize("old", sorted(OLD_TO_NEW))
def test_an_old_path_imports_the_new_modules_objects_with_a_warning_naming_the_new_path(old):
    if old == "fxc_env.torchrl_env":
        pytest.importorskip("torchrl")
    module, caught = import_old(old)
    (warning,) = [w for w in caught if old in str(w.message)]
    for new in OLD_TO_NEW[old]:
        assert new in str(warning.message)
    assert "next release" in str(warning.message)
    assert warning.filename == __file__  # pointed at the importing line, not at the import machinery
    for new in OLD_TO_NEW[old]:
        target = importlib.import_module(new)
        names = getattr(target, "__all__", None) or [n for n in vars(target) if not n.startswith("_")]
        for name in names:
            assert getattr(module, name) is getattr(target, name), name
    for name in README_IMPORTS.get(old, []):
        assert name in module.__all__


def test_no_file_stands_at_a_path_that_moved_into_a_sub_folder():
    """The old paths answer through the one finder of ``fxc_env._moved``, not one shim module per moved file."""
    from fxc_env import _moved

    for old, (new,) in MOVED_IN_FOLDERS.items():
        assert _moved.MOVED[old] == (new,)
        assert importlib.util.find_spec(new).origin != importlib.util.find_spec(old).origin
        assert importlib.util.find_spec(old).origin is None, old  # no module file at the old path


def test_an_old_law_path_gives_the_same_class_with_a_deprecation_warning():
    from fxc_env.baselines.laws.minimum_time import MinimumTimePolicy

    forget("fxc_env.baselines.minimum_time")
    with pytest.warns(
        DeprecationWarning, match=r"fxc_env\.baselines\.minimum_time moved to fxc_env\.baselines\.laws\.minimum_time"
    ):
        from fxc_env.baselines.minimum_time import MinimumTimePolicy as old

    assert old is MinimumTimePolicy


def test_the_renamed_torchrl_env_function_still_answers_with_a_warning_naming_torchrl_wrapper():
    from fxc_env.envs.interop import torchrl_wrapper

    module, _ = import_old("fxc_env.interop")
    with pytest.warns(
        DeprecationWarning, match=r"fxc_env\.interop\.torchrl_env is now fxc_env\.envs\.interop\.torchrl_wrapper"
    ) as caught:
        function = module.torchrl_env
    assert function is torchrl_wrapper
    assert caught[0].filename == __file__


def test_an_old_submodule_read_as_an_attribute_of_the_package_imports_with_its_warning():
    forget("fxc_env.simulation")
    with pytest.warns(DeprecationWarning, match=r"fxc_env\.analysis\.simulation") as caught:
        simulate = fxc_env.simulation.simulate
    assert simulate is fxc_env.simulate
    assert caught[0].filename == __file__


def test_a_users_script_sees_the_warning_by_default_at_its_own_import_line(tmp_path):
    script = tmp_path / "old_script.py"
    script.write_text(
        "import fxc_env\n"
        "from fxc_env.learned import load_learned_policy\n"
        "assert load_learned_policy is fxc_env.load_learned_policy\n"
    )
    result = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, check=True)
    assert (
        f"{script}:2: DeprecationWarning: fxc_env.learned moved to fxc_env.policies.learned: import from there; "
        "the old path goes away in the next release"
    ) in result.stderr


def test_the_package_imports_no_old_path_and_loads_the_baselines_and_torchrl_on_first_use():
    code = (
        "import sys, fxc_env; "
        "assert 'fxc_env.baselines' not in sys.modules and 'torchrl' not in sys.modules, sorted(sys.modules); "
        "fxc_env.SignallingPolicy; "
        "assert 'fxc_env.baselines' in sys.modules"
    )
    subprocess.run([sys.executable, "-W", "error::DeprecationWarning", "-c", code], check=True)


def test_the_versioned_module_imports_at_its_public_path_without_a_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        module = importlib.import_module("fxc_env.fxc_consensus_v0")
    assert module is fxc_env.fxc_consensus_v0
    assert module.parallel_env is fxc_env.parallel_env


def test_the_names_users_import_sit_on_fxc_env():
    from fxc_env import baselines
    from fxc_env.policies.learned import load_learned_policy

    assert fxc_env.load_learned_policy is load_learned_policy
    for name in baselines.__all__:
        if name.endswith("Policy"):
            assert name in fxc_env.__all__
            assert getattr(fxc_env, name) is getattr(baselines, name)


def test_every_name_in_all_resolves_and_all_lists_the_names_users_import():
    pytest.importorskip("torchrl")  # ConsensusTorchEnv, ReferenceModule, reference_policy
    assert {"ConsensusTorchEnv", "load_learned_policy", "SignallingPolicy", "MinimumTimePolicy"} <= set(fxc_env.__all__)
    for name in fxc_env.__all__:
        namespace: dict[str, object] = {}
        exec(f"from fxc_env import {name}", namespace)
        assert namespace[name] is getattr(fxc_env, name)


def old_release_file(tmp_path, name: str = "generalist"):
    """A shipped gain network as the previous release saved it: its class under ``fxc_env.gain_policy``, no fxc_policy.json."""
    import base64
    import json
    import zipfile

    from fxc_env.policies.learned import pretrained_path

    with zipfile.ZipFile(pretrained_path(name)) as archive:
        contents = {member: archive.read(member) for member in archive.namelist() if member != "fxc_policy.json"}
    data = json.loads(contents["data"])
    entry = data["policy_class"]
    assert entry["__module__"] == "fxc_env.policies.gain_network"
    entry["__module__"] = "fxc_env.gain_policy"
    # The pickled class reference, protocol 5: GLOBAL by module and name (what SB3 wrote then).
    module, cls = b"fxc_env.gain_policy", entry["__init__"].split()[1].split(".")[0].encode()
    body = b"\x8c" + bytes([len(module)]) + module + b"\x94\x8c" + bytes([len(cls)]) + cls + b"\x94\x93\x94."
    entry[":serialized:"] = base64.b64encode(b"\x80\x05\x95" + len(body).to_bytes(8, "little") + body).decode()
    contents["data"] = json.dumps(data).encode()
    path = tmp_path / f"{name}_previous_release.zip"
    with zipfile.ZipFile(path, "w") as archive:
        for member, content in contents.items():
            archive.writestr(member, content)
    return path


@pytest.mark.parametrize("trusted", [False, True])
def test_a_gain_network_saved_by_the_previous_release_loads_and_acts_as_the_shipped_one(tmp_path, trusted):
    import numpy as np

    from fxc_env.config import make_config
    from fxc_env.policies.learned import LearnedPolicy, load_model, pretrained_path

    config = make_config("generalist")  # the shipped file's own training domain
    path = old_release_file(tmp_path)
    forget("fxc_env.gain_policy")
    if trusted:  # SB3 unpickles the class reference: the old module path answers, with its warning
        with pytest.warns(DeprecationWarning, match=r"fxc_env\.gain_policy moved to fxc_env\.policies\.gain_network"):
            model = load_model(path, trusted=True)
        assert type(model.policy) is fxc_env.policies.gain_network.GainScheduledPolicy
        policy = LearnedPolicy(path, config, trusted=True)
    else:  # the safe reader reads the class's name and module without unpickling
        policy = fxc_env.load_learned_policy(path, config)
    shipped = fxc_env.load_learned_policy(pretrained_path("generalist"), config)
    obs = np.random.default_rng(0).uniform(-1, 1, size=(5, config.n_agents, config.layout.size))
    assert np.array_equal(policy(obs), shipped(obs))


def test_the_previous_releases_config_names_still_import_from_fxc_env_config():
    from fxc_env.config import layout

    namespace: dict[str, object] = {}
    exec("from fxc_env.config import CLOCK_SIZE, EnvConfig, ObservationLayout, config_of, make_config", namespace)
    assert namespace["ObservationLayout"] is layout.ObservationLayout and namespace["CLOCK_SIZE"] == layout.CLOCK_SIZE


def test_an_old_recipe_command_runs_the_moved_module_with_a_warning():
    """The shipped files record ``python -m fxc_env.training.rings ...``: that command runs the recipe still."""
    result = subprocess.run(
        [sys.executable, "-W", "always::DeprecationWarning", "-m", "fxc_env.training.rings", "--help"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert result.stdout.startswith("usage: python -m fxc_env.training.recipes.rings")
    assert "fxc_env.training.rings moved to fxc_env.training.recipes.rings" in result.stderr
