"""The filtering law's goal table: medians against the noise floor on the optimality suite's graphs of 20.

``python -c "from fxc_env.baselines.harness.filtering_goals import goal_table; print(goal_table())"`` prints,
for the directed ring and the random digraph of N = 20 at ``obs_noise = sigma`` (1e-3 m by default; uniform
K = 200, T_s = 20 s, 20 seeded initial states), the medians of ``D(T_s)/D(0)``, of the noise floor no
controller beats (:mod:`fxc_env.core.floors`), of their ratio and of the energy over the minimum energy E*;
each case runs as ``fxc benchmark`` runs it (same seeds and noise streams). Docs: optimality.md,
"Filtered dead-beat (`filtering`)".
"""

from __future__ import annotations

import numpy as np

from fxc_env.baselines.harness.jobs import Job, run_job
from fxc_env.baselines.harness.suite import BenchmarkCase, builtin_contenders


def goal_table(sigma: float = 1e-3, seeds: tuple[int, ...] = tuple(range(20))) -> str:
    """Medians over ``seeds`` of ``D(T_s)/D(0)``, the noise floor and energy / E* on the optimality suite's directed
    ring and random digraph of 20 at ``obs_noise = sigma`` (uniform K = 200, T_s = 20 s), run as ``fxc benchmark``
    runs them (same seeds and noise streams; docs: optimality.md, "Filtered dead-beat (`filtering`)")."""
    contender = builtin_contenders(["filtering"])[0]
    lines = ["case: error, noise floor, error / floor, energy / E*"]
    for family in ("ring", "random"):
        case = BenchmarkCase(family, 20, conditions=(("obs_noise", sigma),))
        metrics = run_job(Job(contender, case, 200, tuple(seeds), 20.0, False)).metrics
        error, floor = np.median(metrics["relative_deadline_error"]), np.median(metrics["noise_floor"])
        lines.append(
            f"{family}: {error:.3g}, {floor:.3g}, {error / floor:.3g}, {np.median(metrics['energy_ratio']):.3g}"
        )
    return "\n".join(lines)
