"""What every training back end writes into its run directory besides the policy.

``versions.json`` (:func:`versions`) and ``training_curve.png`` (:func:`write_training_curve`,
read from ``progress.csv``, whose SB3 column names the RLlib back end writes too).
"""

from __future__ import annotations

import platform
from importlib import metadata
from pathlib import Path


def versions() -> dict[str, str]:
    """Python and the versions of the libraries a run depends on."""
    found = {"python": platform.python_version()}
    for name in ("fxc-env", "numpy", "gymnasium", "pettingzoo", "stable-baselines3", "torch", "ray"):
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "not installed"
    return found


def write_training_curve(run_dir: Path) -> Path | None:
    """Plot ``rollout/ep_rew_mean`` against ``time/total_timesteps`` from ``progress.csv``."""
    import csv

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    progress = run_dir / "progress.csv"
    if not progress.exists():
        return None
    steps, returns = [], []
    with progress.open() as handle:
        for row in csv.DictReader(handle):
            if row.get("rollout/ep_rew_mean") and row.get("time/total_timesteps"):
                steps.append(float(row["time/total_timesteps"]))
                returns.append(float(row["rollout/ep_rew_mean"]))
    if not steps:
        return None
    fig = Figure(figsize=(6.5, 3.8), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    ax.plot(steps, returns, lw=0.8, color="#9ecae1", label="per rollout")
    window = 10
    if len(returns) >= window:
        import numpy as np

        smooth = np.convolve(returns, np.ones(window) / window, mode="valid")
        ax.plot(steps[window - 1 :], smooth, lw=1.6, color="#08519c", label=f"mean of {window} rollouts")
        ax.legend(fontsize=8, loc="lower right")
    ax.set_xlabel("timesteps (agent-steps)")
    ax.set_ylabel("mean episode return = ln D(0)/D(T_s)")
    ax.set_title(f"training curve: {run_dir.name}", fontsize=9)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = run_dir / "training_curve.png"
    fig.savefig(path)
    return path
