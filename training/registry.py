"""Every training back end, registered once: ``fxc train --backend``, the argument checks, the run
directory's checkpoint names and the dispatch of :func:`fxc_env.training.backends.train` read
:data:`BACKENDS` and nothing else.

To add a back end, write its module with a ``train_<name>(args) -> Path`` that calls
:func:`~fxc_env.training.args.check_train_args` first and writes a :class:`~fxc_env.training.run_dir.RunDir`,
then :func:`register` it here. The module is imported only when its back end is chosen.
"""

from __future__ import annotations

from dataclasses import dataclass

from fxc_env.core.validation import ArgumentError


@dataclass(frozen=True)
class Backend:
    """A registered back end.

    Attributes:
        name: ``--backend``'s value.
        trainer: ``module:function`` of :mod:`fxc_env.training.backends` that trains a run (imported when chosen).
        algorithms: the ``--algo`` values it trains, the default first.
        checkpoint: its checkpoint's name in ``checkpoints/`` (``{}``: the timesteps).
        hyperparams_key: the algorithm's entry in the hyperparameter file (``{backend}``, ``{algo}``).
        settings: the class of :mod:`fxc_env.training.settings` that checks that entry, if any.
        torch_actor: its actor is one of ``--policy-arch``'s, on ``--device``, saved as ``policy.pt``
            (``--init-from`` starts it from a policy file).
        critics: it has a choice of ``--critic``.
        complete: the file a checkpoint directory holds once it is whole (written last).
        algorithm_note, requires: what its algorithms are and need, in error messages.
    """

    name: str
    trainer: str
    algorithms: tuple[str, ...]
    checkpoint: str
    hyperparams_key: str = "{backend}_{algo}"
    settings: str | None = None
    torch_actor: bool = False
    critics: bool = False
    complete: str | None = None
    algorithm_note: str = ""
    requires: str = ""


#: Every back end by name, the default first.
BACKENDS: dict[str, Backend] = {}
#: Old back-end names, still accepted: ``torchrl`` was the torch loop's name (it never used TorchRL).
ALIASES = {"torchrl": "torch"}


def register(backend: Backend) -> Backend:
    """Add ``backend`` to :data:`BACKENDS` (refused when its name is taken)."""
    if backend.name in BACKENDS or backend.name in ALIASES:
        raise ArgumentError(f"name: a back end named {backend.name!r} is registered already")
    BACKENDS[backend.name] = backend
    return backend


PT, TORCH = "model_{}_steps.pt", {"torch_actor": True}
APG = {"algorithm_note": " (analytic policy gradients)", "requires": "the engine's gradients"}
register(Backend("sb3", "sb3_train:train_sb3", ("ppo", "sac"), "model_{}_steps.zip", "{algo}"))
register(Backend("rllib", "rllib_train:train_rllib", ("ppo",), "rllib_{}_steps", complete="rllib_checkpoint.json"))
register(Backend("torch", "torch_ppo:train_torch", ("ppo",), PT, settings="PPOSettings", critics=True, **TORCH))
register(Backend("diff", "diff_train:train_diff", ("apg",), PT, settings="DiffSettings", **TORCH, **APG))


def algorithms() -> tuple[str, ...]:
    """Every ``--algo`` value, in registration order."""
    return tuple(dict.fromkeys(algo for backend in BACKENDS.values() for algo in backend.algorithms))


def with_flag(flag: str) -> tuple[str, ...]:
    """The back ends with ``flag`` (``torch_actor``, ``critics``) set."""
    return tuple(name for name, backend in BACKENDS.items() if getattr(backend, flag))
