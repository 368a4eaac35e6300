"""How well an action interface is conditioned for exploration: D(T_s)/D(0) under Gaussian action noise.

A Gaussian policy explores with noise of a few per cent of its action box on every component.
Every action is relative to the agent's current local disagreement, so errors compound over
the K intervals of an episode: an interface is well conditioned when such noise, on either
component alone, costs at most a factor of a few. :func:`noise_table` measures it around the
zero action (coasting) and around the reference (paper eq. 11), and for uniform random actions
over the box (docs: environment.md, "Conditioning of the action"):

    .venv/bin/python -m fxc_env.analysis.conditioning [generalist saturated]

prints the table for the ``plan`` interface (``rings20-v1``, ``paper_fig1-v1``) beside ``plan_balanced``
(``rings20-v2``, ``paper_fig1-v2``), each also at the other's K.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fxc_env.config import make_config
from fxc_env.config.tasks import get_task
from fxc_env.policies.protocol import seeded_engine
from fxc_env.policies.reference import ReferencePolicy

#: The noise's standard deviation as a share of the box's half-width.
NOISE_FRACTION = 0.05
#: The columns of :func:`noise_table`: (what is played around, which action component is noisy).
COLUMNS = (
    ("zero", None),
    ("zero", 0),
    ("zero", 1),
    ("reference", None),
    ("reference", 0),
    ("reference", 1),
    ("uniform", None),
)


@dataclass(frozen=True)
class NoiseRow:
    """One environment's medians of ``D(T_s)/D(0)`` over the episodes, one per :data:`COLUMNS` entry.

    Attributes:
        label: the row's name (a task id, or a task at another K).
        action_mode: the interface measured.
        n_intervals: K.
        bound: the box's half-width ``b``; the noise is ``NOISE_FRACTION * b`` per component.
        medians: ``{(centre, component): median}``; component 0 is ``alpha_x``, 1 ``alpha_v``, None noise-free
            (``uniform``: actions uniform over the box).
    """

    label: str
    action_mode: str
    n_intervals: int
    bound: float
    medians: Mapping[tuple[str, int | None], float]

    def well_conditioned(self) -> bool:
        """Each noisy median within a decade of its noise-free one, and the noisy reference never worse than zero action."""
        m = self.medians
        within = all(
            abs(np.log10(m[(centre, part)] / m[(centre, None)])) <= 1.0
            for centre in ("zero", "reference")
            for part in (0, 1)
        )
        return within and all(m[("reference", part)] <= m[("zero", None)] for part in (None, 0, 1))


def final_ratios(
    settings: Mapping[str, Any],
    centre: str,
    component: int | None,
    seeds: Sequence[int],
    fraction: float = NOISE_FRACTION,
    noise_seed: int = 0,
) -> np.ndarray:
    """``D(T_s)/D(0)`` per seed ``(len(seeds),)`` with noise on one action component, or uniform actions.

    ``settings``: :func:`fxc_env.make_config` keywords (a fixed initial state is dropped: seed b draws
    its own from ``np.random.default_rng(seeds[b])``, as ``fxc evaluate --task`` scores it).
    ``centre``: ``"zero"`` or ``"reference"`` (with ``N(0, (fraction b)^2)`` on ``component``, 0 or
    1 for ``dim = 1``; None: no noise), or ``"uniform"`` (actions ``U(-b, b)``, ``component`` unused).
    """
    kwargs = dict(settings)
    config = make_config(kwargs.pop("scenario", None), **{**kwargs, "initial_state": "random"})
    engine, _ = seeded_engine(config, seeds)
    policy, rng, bound = ReferencePolicy(config), np.random.default_rng(noise_seed), config.action_bound
    shape = (len(seeds), config.n_agents, config.action_size)
    with np.errstate(over="ignore", invalid="ignore"):
        for _ in range(config.n_intervals):
            if centre == "uniform":
                actions = rng.uniform(-bound, bound, shape)
            else:
                actions = policy.act(engine.observations()) if centre == "reference" else np.zeros(shape)
                if component is not None:
                    actions[..., component] += fraction * bound * rng.standard_normal(shape[:-1])
            engine.step(actions)
    return engine.current_disagreement / engine.initial_disagreement


def noise_row(
    label: str, settings: Mapping[str, Any], seeds: Sequence[int], fraction: float = NOISE_FRACTION
) -> NoiseRow:
    """The :data:`COLUMNS` medians of one environment (see :func:`final_ratios`)."""
    kwargs = dict(settings)
    config = make_config(kwargs.pop("scenario", None), **kwargs)
    medians = {
        (centre, part): float(np.median(final_ratios(settings, centre, part, seeds, fraction)))
        for centre, part in COLUMNS
    }
    return NoiseRow(label, config.action_mode, config.n_intervals, config.action_bound, medians)


def noise_table(task_ids: Sequence[str] = ("rings20", "paper_fig1"), episodes: int = 20) -> list[NoiseRow]:
    """Per task name: ``<name>-v1`` (``plan``) and ``<name>-v2`` (``plan_balanced``), each also at the other's K.

    ``episodes``: the first that many evaluation seeds of each task.
    """
    rows = []
    for name in task_ids:
        old, new = get_task(f"{name}-v1"), get_task(f"{name}-v2")
        seeds = new.eval_seeds[:episodes]
        rows.append(noise_row(old.id, old.settings, seeds))
        rows.append(
            noise_row(f"{old.id} at K = {new.n_intervals}", {**old.settings, "n_intervals": new.n_intervals}, seeds)
        )
        rows.append(noise_row(new.id, new.settings, seeds))
        rows.append(
            noise_row(f"{new.id} at K = {old.n_intervals}", {**new.settings, "n_intervals": old.n_intervals}, seeds)
        )
    return rows


def markdown(rows: Sequence[NoiseRow]) -> str:
    """The rows as a Markdown table (medians to 3 digits)."""
    header = (
        "| task | action_mode | K | box b | zero | zero + σ on α_x | zero + σ on α_v | reference | "
        "reference + σ on α_x | reference + σ on α_v | uniform over the box | well conditioned |"
    )
    lines = [header, "|" + " --- |" * 12]
    for row in rows:
        values = " | ".join(f"{row.medians[column]:.3g}" for column in COLUMNS)
        verdict = "yes" if row.well_conditioned() else "no"
        lines.append(f"| {row.label} | {row.action_mode} | {row.n_intervals} | {row.bound:g} | {values} | {verdict} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> None:
    """Print :func:`noise_table` (20 episodes) as Markdown for the task names given (default rings20 and paper_fig1)."""
    names = list(sys.argv[1:] if argv is None else argv) or ["rings20", "paper_fig1"]
    print(f"median D(T_s)/D(0) over 20 evaluation seeds; σ = {NOISE_FRACTION:g} b on one component")
    print(markdown(noise_table(names)))


if __name__ == "__main__":
    main()
