"""What a checkpoint must hold before ``fxc train --resume`` goes on from it: one check that every back end calls.

The back ends read a checkpoint as data (``fxc_env.training.run_dir``: nothing is unpickled without
``--trust-policy-file``) into the run's freshly built model and optimiser, then pass what they loaded to
:func:`check_resumed_state` before training, writing or logging anything. Refused by name, naming the file
and the field, the run directory unchanged:

* a step counter outside ``[0, --timesteps]`` (a negative one would train for ever, a huge one train nothing
  and succeed), or other than the timesteps in the checkpoint's name; any other counter below 0;
* a weight (network, ``log_std``, SAC's entropy coefficient) or an optimiser moment holding a NaN or an
  infinity, and an optimiser setting (``lr``, ``betas``, ``eps``, ``weight_decay``) that is not a finite
  number in its range; the first update would turn every weight into NaN;
* a checkpoint written by another back end than the run's (``torch`` and ``diff`` share the file name and
  format, not their step size or what their weights were trained for): :func:`check_written_by`, called
  before the weights are loaded.

Docs: training.md, "Training learned policies" (resuming), and bad-input.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from fxc_env.core.validation import ArgumentError, integer, probability, real
from fxc_env.training.run_dir import RunDir

#: Largest accepted count of updates or iterations (int64, as TensorBoard and torch keep them).
MAX_COUNT = 2**63 - 1
#: Adam's entries that hold a non-negative running quantity (a negative one gives a NaN square root or bias).
NON_NEGATIVE_STATE = ("step", "exp_avg_sq", "max_exp_avg_sq")


def check_resumed_state(
    run: RunDir,
    path: Path,
    target: int,
    *,
    steps: tuple[str, Any],
    counters: Mapping[str, Any],
    weights: Mapping[str, torch.Tensor],
    optimizers: Mapping[str, Any],
) -> None:
    """Refuse the checkpoint ``path`` of ``run`` (raising :class:`ArgumentError`) unless what was loaded from it is sound.

    Args:
        run: the run directory resumed (its back end, and the timesteps each checkpoint name says).
        path: the checkpoint, named in every refusal.
        target: the run's ``--timesteps`` (agent-steps).
        steps: the step counter's name in the file and its value (agent-steps).
        counters: other counters (iterations, updates) by name in the file.
        weights: every tensor of the model by name (a weight's or parameter's key).
        optimizers: the optimisers' state dicts (``torch.optim.Optimizer.state_dict()``) by name.
    """
    where = f"resume: {path}"
    label, value = steps
    number = integer(f"{where}: {label}", value, 0, target)
    named = run.checkpoint_steps(path)
    if named is not None and number != named:
        raise ArgumentError(f"{where}: {label} is {number}, expected {named} (the timesteps in the file's name)")
    for label, value in counters.items():
        integer(f"{where}: {label}", value, 0, MAX_COUNT)
    for label, tensor in weights.items():
        check_finite(f"{where}: weight {label!r}", tensor)
    for label, state in optimizers.items():
        check_optimizer(f"{where}: {label}", state)


def check_written_by(run: RunDir, path: Path, written_by: Any) -> None:
    """Refuse the checkpoint ``path`` unless the back end it records (``written_by``) is ``run``'s.

    None (a checkpoint from before back ends were recorded) passes: ``config.json``'s record of the back
    end is checked instead (:meth:`fxc_env.training.run_dir.RunDir.resume_checkpoint`).
    """
    if written_by is not None and written_by != run.backend:
        raise ArgumentError(
            f"resume: {path}: backend is {written_by!r}, this run is --backend {run.backend}; a checkpoint goes on "
            f"only with the back end that wrote it (resume with --backend {written_by}, or start a new --run-dir)"
        )


def check_finite(name: str, tensor: Any) -> None:
    """Refuse (naming ``name``) a floating-point tensor holding a NaN or an infinity; other tensors pass."""
    if isinstance(tensor, torch.Tensor) and tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
        bad = tensor[~torch.isfinite(tensor)].flatten()[0].item()
        raise ArgumentError(f"{name}: expected finite numbers, got {bad} among its {tensor.numel()} entries")


def check_optimizer(name: str, state: Any) -> None:
    """Refuse an optimiser state dict whose settings or moments are not finite numbers in their ranges.

    Settings of each parameter group: ``lr`` >= 0 (a schedule may end at 0), ``eps`` > 0, ``weight_decay``
    >= 0, each of ``betas`` in [0, 1); per-weight state: finite, and ``step`` and the squared moments >= 0.
    A state dict of another shape is left to the optimiser's own loader.
    """
    if not isinstance(state, Mapping):
        return
    groups = state.get("param_groups")
    groups = groups if isinstance(groups, list) else []
    for index, group in enumerate(groups):
        if not isinstance(group, Mapping):
            continue
        label = name if len(groups) == 1 else f"{name} group {index}"
        for key, minimum, positive in (("lr", 0.0, False), ("eps", None, True), ("weight_decay", 0.0, False)):
            if key in group:
                real(f"{label} {key}", _number(group[key]), minimum, positive=positive)
        if "betas" in group:
            betas = group["betas"]
            if not isinstance(betas, tuple | list) or len(betas) != 2:
                raise ArgumentError(f"{label} betas: expected two numbers in [0, 1), got {betas!r}")
            for beta in betas:
                probability(f"{label} betas", _number(beta))
    moments = state.get("state")
    for weight, entries in moments.items() if isinstance(moments, Mapping) else ():
        for key, value in entries.items() if isinstance(entries, Mapping) else ():
            entry = f"{name} state {key!r} of weight {weight}"
            check_finite(entry, value)
            if key in NON_NEGATIVE_STATE and isinstance(value, torch.Tensor) and bool((value < 0).any()):
                raise ArgumentError(f"{entry}: expected numbers >= 0, got {value.min().item()}")


def _number(value: Any) -> Any:
    """A one-element tensor (torch keeps ``lr`` and ``betas`` as tensors with ``capturable``) as its number."""
    return value.item() if isinstance(value, torch.Tensor) and value.numel() == 1 else value
