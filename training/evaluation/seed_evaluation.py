"""``fxc evaluate --runs``: one policy trained with several seeds, scored with confidence intervals.

Each run (a training seed) plays the suite's seeded initial states next to the reference; per case the
deadline errors form a ``(R, S)`` matrix and :mod:`fxc_env.training.evaluation.statistics` gives the **median** of
``D(T_s)/D(0)`` and the **IQM** of ``log10(max(D(T_s)/D(0), 1e-12))``, each with a 95 % stratified bootstrap
interval (fixed bootstrap seed; the reference resamples initial states only). The scores and files are
:mod:`fxc_env.training.evaluation.seed_scores`'s.
"""

from __future__ import annotations

import glob
import re
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.baselines.harness.suite import Contender, learned_contender, model_path
from fxc_env.core.validation import ArgumentError, integer
from fxc_env.policies.learned import SHIPPED, architecture_of, load_learned_policy
from fxc_env.policies.policy_files import CHECKED_SETTINGS, read_metadata
from fxc_env.training.args import canonical_backend
from fxc_env.training.evaluation.seed_scores import (  # noqa: F401
    LOG_FLOOR,
    MARL_EVAL_ENV,
    TrainedRun,
    case_scores,
    write_seed_report,
)
from fxc_env.training.run_dir import recorded_args

#: Training seed of each shipped policy: 0 for every one (its recipe in ``fxc_env/pretrained/README.md``: ``--seed 0``;
#: ``rings``: ``python -m fxc_env.training.recipes.rings --seed 0``, the default).
SHIPPED_SEEDS = dict.fromkeys(SHIPPED, 0)
#: A run directory or file named ``...seed<k>...`` was trained with seed k.
_SEED_IN_NAME = re.compile(r"seed(\d+)")
#: Files that make a directory a run (else it is read as a folder of ``*-seed<k>`` runs).
_RUN_FILES = ("model.zip", "policy.pt", "config.json", "checkpoints")
#: Saved policies by suffix: an SB3 model, a torch policy, a gain schedule (anything else, a log say, is no run).
POLICY_SUFFIXES = (".zip", ".pt", ".npz")
_NOT_A_RUN = "neither a saved policy (" + ", ".join(POLICY_SUFFIXES) + ") nor a run directory"
#: What runs pooled as training seeds of one policy must share, in the order :func:`pooled_identity` compares them.
POOLED_FIELDS = ("format", "trainer", "algorithm", "architecture", "parameter shapes", "scenario", "settings")
#: The step count in a checkpoint's name (``model_4000000_steps.zip``, ``rllib_4000_steps``).
_CHECKPOINT_STEPS = re.compile(r"_(\d+)_steps")


def expand_runs(entries: Sequence[str], name: str = "--runs") -> list[str]:
    """Each entry as the runs it names: a shipped policy name, a file, a run directory, a glob, or a
    folder holding ``*-seed<k>`` runs (those runs, in seed order).

    Refused, naming ``name``: a glob that matches nothing, a path that does not exist, a folder that
    is neither a run nor holds ``*-seed<k>`` runs, and a run named twice.
    """
    found: list[str] = []
    for entry in entries:
        if entry in SHIPPED and not Path(entry).exists():
            found.append(entry)
        elif glob.has_magic(entry):
            matches = sorted(glob.glob(entry), key=_seed_order)
            if not matches:
                raise ArgumentError(f"{name}: no run matches {entry!r}")
            runs = [m for m in matches if _is_policy(Path(m))]
            for other in (m for m in matches if m not in runs):
                print(f"{name}: skipping {other!r}, which {entry!r} matches: {_NOT_A_RUN}", file=sys.stderr)
            if not runs:
                raise ArgumentError(f"{name}: {entry!r} matches no run, only {matches} ({_NOT_A_RUN})")
            found += runs
        elif not Path(entry).exists():
            raise ArgumentError(f"{name}: nothing at {entry!r} (expected a run directory, a saved policy or a glob)")
        elif Path(entry).is_file() and not _is_policy(Path(entry)):
            raise ArgumentError(f"{name}: {entry!r} is {_NOT_A_RUN}")
        elif Path(entry).is_dir() and not _is_run(Path(entry)) and not _is_rllib_run(Path(entry)):
            children = sorted((str(p) for p in Path(entry).glob("*-seed*") if p.is_dir()), key=_seed_order)
            if not children:
                raise ArgumentError(
                    f"{name}: {entry!r} is neither a run directory (model.zip, policy.pt, config.json or "
                    "checkpoints/) nor a folder of *-seed<k> runs"
                )
            found += children
        else:
            found.append(entry)
    twice = [e for i, e in enumerate(found) if e in found[:i]]
    if twice:
        raise ArgumentError(f"{name}: {twice[0]!r} is named twice")
    return found


def _is_policy(path: Path) -> bool:
    """Whether ``path`` is a saved policy (:data:`POLICY_SUFFIXES`) or a run directory."""
    return (_is_run(path) or _is_rllib_run(path)) if path.is_dir() else path.suffix in POLICY_SUFFIXES


def _is_run(path: Path) -> bool:
    return any((path / f).exists() for f in _RUN_FILES)


def _is_rllib_run(path: Path) -> bool:
    return (path / "rllib_checkpoint.json").exists()


def _seed_order(path: str) -> tuple[int, str]:
    match = _SEED_IN_NAME.search(Path(path).name)
    return (int(match.group(1)) if match else -1, path)


def resolve_run(entry: str, name: str = "--runs") -> TrainedRun:
    """The :class:`TrainedRun` at ``entry``: where its policy is, its training seed and timesteps.

    The seed comes from the run's ``config.json`` (what ``fxc train`` recorded), else from
    ``seed<k>`` in its name, else from :data:`SHIPPED_SEEDS`; a run whose seed none of these
    tells is refused, naming ``name``.
    """
    path = Path(entry)
    spec = str(path / "model.zip") if path.is_dir() and (path / "model.zip").is_file() else entry
    run_dir = path if path.is_dir() else path.parent
    config = run_dir / "config.json"
    recorded = recorded_args(config) if entry not in SHIPPED or path.exists() else {}
    seed = recorded.get("seed")
    if seed is not None:  # fxc train checks it as TrainArgs.seed: a damaged config.json is refused by name
        integer(f"{name}: the seed in {str(config)!r}", seed, 0, 2**32 - 1)
    else:
        named = [path.name] if path.is_dir() else [path.stem, path.parent.name]  # runs/x-seed1/model.zip
        match = next((m for m in map(_SEED_IN_NAME.search, named) if m), None)
        seed = int(match.group(1)) if match else SHIPPED_SEEDS.get(entry)
    if seed is None:
        raise ArgumentError(
            f"{name}: cannot tell the training seed of {entry!r} (no config.json from fxc train, no seed<k> in its name)"
        )
    return TrainedRun(entry, spec, int(seed), _timesteps(spec, recorded), _trainer(recorded))


def _trainer(recorded: dict[str, Any]) -> str | None:
    """``--backend B --algo A`` as a run's ``config.json`` records them (None when it records no back end)."""
    backend, algo = recorded.get("backend"), recorded.get("algo")
    if not isinstance(backend, str):
        return None
    return f"--backend {canonical_backend(backend, warn=False)}" + (f" --algo {algo}" if isinstance(algo, str) else "")


def _timesteps(spec: str, recorded: dict[str, Any]) -> int:
    """The agent-steps a policy was trained for: its zip's ``fxc_policy.json``, else its run's newest
    checkpoint (``checkpoints/*_<steps>_steps*``: whole rollouts, past the target), else the target
    in ``config.json``, else 0."""
    target = model_path(spec)
    if target.suffix == ".zip" and target.is_file():
        try:
            record = read_metadata(target) or {}
        except ArgumentError:
            record = {}
        if isinstance(record.get("num_timesteps"), int):
            return int(record["num_timesteps"])
    run_dir = target if target.is_dir() else target.parent
    saved = [int(m.group(1)) for p in run_dir.glob("checkpoints/*") if (m := _CHECKPOINT_STEPS.search(p.name))]
    if saved:
        return max(saved)
    steps = recorded.get("timesteps")
    return int(steps) if isinstance(steps, int) and not isinstance(steps, bool) and steps >= 0 else 0


def default_label(runs: Sequence[TrainedRun]) -> str:
    """The runs' common name without its seed (``generalist-ppo`` for ``runs/generalist-ppo-seed1``), else ``policy``."""
    names = set()
    for run in runs:
        path = Path(run.entry)
        stem = path.name if path.is_dir() or run.entry in SHIPPED else path.stem
        if stem == "model":
            stem = path.parent.name
        names.add(re.sub(r"[-_]?seed\d+", "", stem) or "policy")
    return names.pop() if len(names) == 1 else "policy"


def seed_contenders(
    runs: Sequence[TrainedRun],
    label: str,
    *,
    trusted: bool = False,
    allow_out_of_domain: bool = False,
    schedule: str | None = None,
    action_mode: str | None = None,
    obs_mode: str | None = None,
    name: str = "--runs",
) -> list[Contender]:
    """One learned contender per run, named ``learned:<label>-seed<k>``, with its training settings.

    Settings are the policy's recorded ones unless given; a missing or damaged run, or two with the same seed,
    are refused naming ``name`` before any job runs.
    """
    seeds = [run.seed for run in runs]
    repeated = sorted({s for s in seeds if seeds.count(s) > 1})
    if repeated:
        twins = [run.entry for run in runs if run.seed == repeated[0]]
        raise ArgumentError(f"{name}: {twins[0]!r} and {twins[1]!r} were both trained with seed {repeated[0]}")
    policies = []
    for run in runs:
        try:
            policies.append(load_learned_policy(model_path(run.spec), trusted=trusted))
        except (FileNotFoundError, ArgumentError) as exc:
            raise ArgumentError(f"{name}: {str(exc).removeprefix('policy: ')}") from exc
    check_pooled(runs, policies, name)
    contenders = []
    for run, policy in zip(runs, policies, strict=True):
        trained = getattr(policy, "training_settings", None) or {}
        settings = {
            "schedule": schedule or trained.get("schedule"),
            "action_mode": action_mode or trained.get("action_mode", "plan"),
            "obs_mode": obs_mode or trained.get("obs_mode", "normalized"),
        }
        if settings["schedule"] not in ("paper", "uniform"):
            settings["schedule"] = None  # a custom or unrecorded schedule: the benchmark's default for it
        contender = learned_contender(
            run.spec, name=name, trusted=trusted, allow_out_of_domain=allow_out_of_domain, **settings
        )
        contenders.append(replace(contender, name=f"learned:{label}-seed{run.seed}"))
    return contenders


def pooled_identity(policy: Any, run: TrainedRun | None = None) -> dict[str, Any]:
    """What a loaded policy (of ``run``) must share with the other seeds it is pooled with (:data:`POOLED_FIELDS`).

    ``trainer`` is the back end and algorithm the run's ``config.json`` records (a torch PPO run and an
    analytic-gradient run save the same kind of file); ``algorithm`` what the policy file says of itself.
    """
    model = getattr(policy, "model", None)
    kind = type(policy).__name__
    formats = {
        "LearnedPolicy": "an SB3 model",
        "TorchPolicy": "a torch policy (fxc train --backend torch or diff)",
        "RLlibPolicy": "an RLlib checkpoint",
        "IntervalGainPolicy": "a gain schedule (.npz)",
        "RegimeGainPolicy": "a pair of gain schedules chosen by a probe (.npz)",
    }
    if model is not None:
        algorithm = getattr(model, "algorithm", None) or type(model).__name__
    else:  # RLlib trains PPO; a torch file does not say (PPO or analytic gradients): its run's trainer does
        algorithm = "PPO" if kind == "RLlibPolicy" else None
    module = getattr(policy, "module", None) or getattr(model, "policy", None)
    if hasattr(module, "state_dict"):
        shapes = [f"{key} {tuple(value.shape)}" for key, value in module.state_dict().items()]
    else:
        shapes = [f"gains {np.shape(getattr(policy, 'gains', ()))}"]
    trained = getattr(policy, "training_settings", None) or {}
    return {
        "format": formats.get(kind, kind),
        "trainer": None if run is None else run.trainer,
        "algorithm": algorithm,
        "architecture": architecture_of(policy)[0],
        "parameter shapes": shapes,
        "scenario": trained.get("scenario"),
        "settings": {key: trained.get(key) for key in (*CHECKED_SETTINGS, "model_A", "model_B") if key in trained},
    }


def check_pooled(runs: Sequence[TrainedRun], policies: Sequence[Any], name: str = "--runs") -> None:
    """Refuse runs that are not training seeds of one policy: the first :data:`POOLED_FIELDS` entry that
    differs from the first run's is named, with both runs and both values. What a file does not
    record (a scenario, a setting an older file lacks) is not taken for a difference."""
    first = pooled_identity(policies[0], runs[0]) if policies else {}
    for run, policy in zip(runs[1:], policies[1:], strict=True):
        other = pooled_identity(policy, run)
        for field in POOLED_FIELDS:
            ours, theirs, label = first[field], other[field], field
            if field == "settings":  # the settings both files record (an older file records fewer)
                both = [k for k in (*CHECKED_SETTINGS, "model_A", "model_B") if k in ours and k in theirs]
                label = next((k for k in both if ours[k] != theirs[k]), None)
                if label is None:
                    continue
                label, ours, theirs = f"setting {label}", ours[label], theirs[label]
            elif ours is None or theirs is None or ours == theirs:  # unrecorded (None) is not a difference
                continue
            elif field == "parameter shapes":
                ours, theirs = (", ".join(v[:4]) + (", ..." if len(v) > 4 else "") for v in (ours, theirs))
            raise ArgumentError(
                f"{name}: {runs[0].entry!r} and {run.entry!r} are not training seeds of one policy: {label} "
                f"{ours!r} vs {theirs!r} (runs pooled as seeds share {', '.join(POOLED_FIELDS)})"
            )
