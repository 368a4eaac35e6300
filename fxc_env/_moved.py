"""Module paths that moved (the layers into folders, then crowded folders into sub-folders): importable for one release more.

Each old path in :data:`MOVED` imports as a small module that re-exports its new module's names (the
same objects) and raises a :class:`DeprecationWarning` naming the new path, pointed at the line that
imports it. :data:`RENAMED` lists attributes renamed in the move; the old name keeps working, with a
warning naming the new one. Everything here goes away in the next release (docs: architecture.md, "Moved modules").

One finder on :data:`sys.meta_path`, appended after the ordinary ones, answers only the paths in
:data:`MOVED`; no file stands at an old path, so the layer folders keep their import contract.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import os
import sys
import types
import warnings
from typing import Any

#: Old module path -> the module(s) that hold its names now (the first one first).
MOVED: dict[str, tuple[str, ...]] = {
    "fxc_env.cli_checks": ("fxc_env.utils.cli_checks",),
    "fxc_env.cluster": ("fxc_env.utils.cluster",),
    "fxc_env.consensus_aec": ("fxc_env.envs.aec",),
    "fxc_env.consensus_env": ("fxc_env.envs.parallel",),
    "fxc_env.env_arguments": ("fxc_env.config.flags",),
    "fxc_env.gain_policy": ("fxc_env.policies.gain_network",),
    "fxc_env.interop": ("fxc_env.envs.interop",),
    "fxc_env.layout": ("fxc_env.config.layout",),
    "fxc_env.learned": ("fxc_env.policies.learned",),
    "fxc_env.plots": ("fxc_env.analysis.plots",),
    "fxc_env.reference": ("fxc_env.policies.reference",),
    "fxc_env.registration": ("fxc_env.envs.registration",),
    "fxc_env.rendering": ("fxc_env.envs.rendering",),
    "fxc_env.scenarios": ("fxc_env.config.scenarios",),
    "fxc_env.simulation": ("fxc_env.analysis.simulation",),
    "fxc_env.spaces": ("fxc_env.envs.spaces",),
    "fxc_env.threads": ("fxc_env.utils.threads",),
    "fxc_env.torch_policy": ("fxc_env.policies.torch_policy",),
    # The TorchRL env kept the env; the reference as a TorchRL module moved beside the other policies.
    "fxc_env.torchrl_env": ("fxc_env.envs.torch_env", "fxc_env.policies.torchrl_reference"),
    "fxc_env.vec_env": ("fxc_env.envs.vec_env",),
    "fxc_env.training.train": ("fxc_env.training.backends.sb3_train",),
}

#: Issue 36: modules that moved one folder down, into the sub-folder that says what they are.
INTO_FOLDERS = {
    "fxc_env.baselines.laws": "bounded_steer design filtering finite_time graph_agnostic leader_follower linear minimum_time motion_signals policy prescribed_time sampled saturation_aware signalling",
    "fxc_env.baselines.harness": "benchmark dropout figures filtering_goals graph_agnostic_goals jobs ray_jobs report resolution suite",
    "fxc_env.training.backends": "checkpoint_checks diff_train imitation rllib_train sb3_train torch_common torch_ppo",
    "fxc_env.training.evaluation": "evaluate leaderboard leaderboard_files leaderboard_runs seed_evaluation seed_scores seeds",
    "fxc_env.training.recipes": "agnostic noise_gains recurrent_imitation residual_sensitivity rings rings_scratch",
}
MOVED.update(
    {
        f"{folder.rpartition('.')[0]}.{name}": (f"{folder}.{name}",)
        for folder, names in INTO_FOLDERS.items()
        for name in names.split()
    }
)
MOVED["fxc_env.core.statistics"] = ("fxc_env.training.evaluation.statistics",)  # with the evaluation that uses it

#: Old module path -> {old attribute name: new attribute name} for names renamed in the move.
RENAMED: dict[str, dict[str, str]] = {"fxc_env.interop": {"torchrl_env": "torchrl_wrapper"}}

_HERE = os.path.normcase(os.path.abspath(__file__))
_PACKAGE_INIT = os.path.normcase(os.path.join(os.path.dirname(_HERE), "__init__.py"))
_IMPORTLIB = os.path.normcase(os.path.dirname(os.path.abspath(importlib.__file__)))


def _is_bootstrap(filename: str) -> bool:
    """The frames :func:`warnings.warn` skips by itself when counting ``stacklevel`` (CPython's rule)."""
    return "importlib" in filename and "_bootstrap" in filename


def _is_ours(filename: str) -> bool:
    """This module, the package's ``__getattr__`` and :func:`importlib.import_module`: not the user's line."""
    path = os.path.normcase(os.path.abspath(filename)) if not filename.startswith("<") else filename
    return path in (_HERE, _PACKAGE_INIT) or os.path.dirname(path) == _IMPORTLIB


def warn(message: str) -> None:
    """A :class:`DeprecationWarning` attributed to the first frame outside the import machinery and this module."""
    frame, level = sys._getframe(1), 2  # the caller of this function: stacklevel 2
    while _is_ours(frame.f_code.co_filename):
        outer = frame.f_back
        while outer is not None and _is_bootstrap(outer.f_code.co_filename):
            outer = outer.f_back
        if outer is None:
            break
        frame, level = outer, level + 1
    warnings.warn(message, DeprecationWarning, stacklevel=level)


def public_names(module: types.ModuleType) -> list[str]:
    """``__all__`` when the module has one, else its names without a leading underscore."""
    names = getattr(module, "__all__", None)
    if names is not None:
        return list(names)
    return [name for name in vars(module) if not name.startswith("_")]


class _CallableModule(types.ModuleType):
    """An old path whose package holds a function of its name (``fxc_env.training.train``, now the function
    ``train(args)``): importing the path binds the module on the package in the function's place, so the
    module calls the function and ``fxc_env.training.train(args)`` keeps working."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self.__wrapped__(*args, **kwargs)


class _Loader(importlib.abc.Loader):
    """Builds the module at an old path: the new modules' public names, a warning naming where they are."""

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> None:
        return None  # the default module object

    def exec_module(self, module: types.ModuleType) -> None:
        old = module.__name__
        new = MOVED[old]
        parent, _, child = old.rpartition(".")
        shadowed = vars(sys.modules[parent]).get(child)
        if callable(shadowed) and not isinstance(shadowed, types.ModuleType):
            module.__class__, module.__wrapped__ = _CallableModule, shadowed
        warn(f"{old} moved to {' and '.join(new)}: import from there; the old path goes away in the next release")
        targets = [importlib.import_module(name) for name in new]
        exported: list[str] = []
        for target in reversed(targets):  # the first module wins a name both define
            for name in public_names(target):
                setattr(module, name, getattr(target, name))
                if name not in exported:
                    exported.append(name)
        module.__all__ = sorted(exported)
        module.__doc__ = f"Deprecated: {old} is now {' and '.join(new)} (this path goes away in the next release)."
        module.__getattr__ = _forwarder(old, targets)

    def get_code(self, fullname: str) -> types.CodeType | None:
        """``python -m <old path>`` runs the new module's code (a recipe's command line), with the warning."""
        new = MOVED[fullname][0]
        warn(f"{fullname} moved to {new}: run python -m {new}; the old path goes away in the next release")
        return importlib.util.find_spec(new).loader.get_code(new)


def _forwarder(old: str, targets: list[types.ModuleType]) -> Any:
    """The old module's ``__getattr__``: renamed names with a warning, private names from the new modules."""
    renamed = RENAMED.get(old, {})

    def __getattr__(name: str) -> object:
        if name in renamed:
            new_name = renamed[name]
            owner = next(t for t in targets if hasattr(t, new_name))
            warn(
                f"{old}.{name} is now {owner.__name__}.{new_name}: use that name; "
                "the old one goes away in the next release"
            )
            return getattr(owner, new_name)
        for target in targets:
            if hasattr(target, name):
                return getattr(target, name)
        raise AttributeError(f"module {old!r} has no attribute {name!r}")

    return __getattr__


class _Finder(importlib.abc.MetaPathFinder):
    """Answers only the old paths in :data:`MOVED`; every other import is left to the ordinary finders."""

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        return importlib.util.spec_from_loader(fullname, _Loader()) if fullname in MOVED else None


def install() -> None:
    """Put the finder on :data:`sys.meta_path` once (after the ordinary finders)."""
    if not any(isinstance(finder, _Finder) for finder in sys.meta_path):
        sys.meta_path.append(_Finder())
