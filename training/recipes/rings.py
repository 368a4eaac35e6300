"""Train the shipped ``rings`` policy: a learned gain schedule for directed rings of 20 agents.

The task: directed rings of N = 20 relabelled every episode, initial scales over two decades, K = 200
intervals of the paper's schedule (eq. 27), T_s = 20 s, plans in normalized units. The network is
:class:`fxc_env.policies.interval_gains.IntervalGainPolicy` (``G_k r_i`` from a ``(K, 2, 2)`` table indexed
by ``k / K``), learned in float64 by

1. **Imitation** of the minimum-time law (:mod:`fxc_env.baselines.laws.minimum_time`): ``G_k`` is the
   least-squares solution of ``plan = G_k r`` over every agent and seeded episode at interval k;
2. **Direct refinement** (optional, ``--refine-steps``): gradient steps on the mean ``log D(T_s)/D(0)``
   through the exact closed-form interval map; ``--init paper`` starts from eq. 11's table.

Commands and results: (docs: results.md, "What learning reached").
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from fxc_env.baselines.registry import LAWS
from fxc_env.config import EnvConfig, make_config
from fxc_env.config.argument_types import FlagParser
from fxc_env.core.families import TopologyFamily
from fxc_env.core.validation import ArgumentError, integer
from fxc_env.engine.consensus_engine import ConsensusEngine
from fxc_env.policies.domain import training_domain
from fxc_env.policies.interval_gains import IntervalGainPolicy, load_interval_gains, spectrum, spectrum_matrix
from fxc_env.policies.policy_files import training_settings
from fxc_env.policies.protocol import seeded_engine
from fxc_env.policies.reference import ReferencePolicy

#: The task of the shipped policy (keywords of :func:`fxc_env.make_config`).
TASK: dict[str, Any] = {
    "n_agents": 20,
    "settling_time": 20.0,
    "n_intervals": 200,
    "schedule": "paper",
    "action_mode": "plan",
    "obs_mode": "normalized",
    "obs_slots": 1,
    "position_range": (0.5, 50.0),
    "velocity_range": (0.2, 20.0),
}
#: Seeds of the demonstration episodes, and of the evaluation episodes (disjoint).
DEMONSTRATION_SEED = 1_000
#: The paper's plan (eq. 11) as a gain in normalized units: ``G_k = P_k`` physically, ``S P_k S^{-1}``
#: with ``S = diag(1, T_{k+1})``.
PAPER_GAIN = np.array([[1.0, 1.0], [0.0, 1.0]])
EVALUATION_SEED = 0


def task_config(n_agents: int = 20, topology: Any = None) -> EnvConfig:
    """The task's environment on ``n_agents`` agents: directed rings relabelled per episode, or ``topology``."""
    family = TopologyFamily("ring") if topology is None else topology
    return make_config(None, **{**TASK, "n_agents": n_agents, "topology": family})


# ------------------------------------------------------------------------------------ episodes
def run_episodes(config: EnvConfig, policy_of: Any, seeds: Sequence[int], record: bool = False) -> dict[str, Any]:
    """Seeded episodes of ``config``, every agent acting by ``policy_of(drawn_config)`` (one policy per episode).

    Episode b is ``reset(seed=seeds[b])``'s. Returns ``deadline_error`` ``(B,)`` and, with ``record``, the
    observations ``(K, B, N, obs_size)`` and actions ``(K, B, N, 2)``.
    """
    engine, draws = seeded_engine(config, seeds)
    policies = [
        policy_of(make_config(None, **{**dict(TASK, n_agents=config.n_agents), "topology": d.topology})) for d in draws
    ]
    observations, actions = [], []
    while not engine.done:
        obs = np.asarray(engine.observations())
        act = np.stack([policy(obs[b]) for b, policy in enumerate(policies)])
        if record:
            observations.append(obs.copy())
            actions.append(act)
        engine.step(act)
    out: dict[str, Any] = {"deadline_error": np.asarray(engine.batch_metrics()["relative_deadline_error"])}
    if record:
        out["observations"], out["actions"] = np.array(observations), np.array(actions)
    return out


# ----------------------------------------------------------------------------------- imitation
def aggregated_rows(config: EnvConfig, observations: np.ndarray) -> np.ndarray:
    """The aggregated relative rows ``r_i`` ``(..., 2)`` (normalized units) of observations ``(..., obs_size)``.

    Read through the observation layout, masked rows ignored (as :class:`IntervalGainPolicy` reads them).
    """
    rows, mask, _ = config.layout.split(observations)
    real = mask[..., None, None] > 0.5
    sums = np.sum(np.where(real, rows, 0.0), axis=-3)[..., 0]  # dim 1
    return sums / (np.sum(mask > 0.5, axis=-1)[..., None] + 1.0)


def regress_gains(config: EnvConfig, observations: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per interval k, the least-squares ``G_k`` of ``action = G_k r``: the table ``(K, 2, 2)`` and the RMS residuals ``(K,)``."""
    rows = aggregated_rows(config, observations)  # (K, B, N, 2)
    K = rows.shape[0]
    gains, residuals = np.zeros((K, 2, 2)), np.zeros(K)
    for k in range(K):
        r, a = rows[k].reshape(-1, 2), actions[k].reshape(-1, 2)
        solution, *_ = np.linalg.lstsq(r, a, rcond=None)  # a = r @ G^T
        gains[k] = solution.T
        residuals[k] = float(np.sqrt(np.mean((r @ solution - a) ** 2)))
    return gains, residuals


# ----------------------------------------------------------------------------- refinement
def gain_scale(config: EnvConfig) -> np.ndarray:
    """``[[1, T_{k+1}], [1/T_{k+1}, 1]]`` per interval ``(K, 2, 2)``: a table in normalized units times it
    (entrywise) is the table in physical units, and a physical one divided by it the normalized one."""
    tau = np.asarray(config.schedule.intervals, dtype=np.float64)
    scale = np.ones((len(tau), 2, 2))
    scale[:, 0, 1], scale[:, 1, 0] = tau, 1.0 / tau
    return scale


def physical_map(config: EnvConfig, gains: Any) -> Any:
    """The table in physical units ``S^{-1} G_k S``, ``S = diag(1, T_{k+1})`` (torch, ``(K, 2, 2)``)."""
    import torch

    return gains * torch.as_tensor(gain_scale(config))


def episode_log_errors(config: EnvConfig, gains: Any, x0: np.ndarray, v0: np.ndarray, w_hat: np.ndarray) -> Any:
    """``log D(T_s)/D(0)`` ``(B,)`` of the plan ``z_i(t_{k+1}) = P_k z_i + G_k r_i``, exactly (torch float64).

    ``r = -Ŵ z`` for ``Ŵ = (D + I)^{-1} L`` ``(N, N)``; ``x0, v0`` ``(B, N)``. ``D = spread(x) +
    T_s spread(v)`` (docs: environment.md, "The environment"). Differentiable in ``gains`` (normalized units, ``(K, 2, 2)``).
    """
    import torch

    g = physical_map(config, gains)
    tau = torch.as_tensor(np.array(config.schedule.intervals, dtype=np.float64))
    w = torch.as_tensor(w_hat)
    z = torch.stack([torch.as_tensor(x0), torch.as_tensor(v0)], dim=-1)  # (B, N, 2)

    def spread(z: Any) -> Any:
        return (z.amax(-2) - z.amin(-2)) @ torch.tensor([1.0, config.settling_time], dtype=torch.float64)

    d0 = spread(z)
    for k in range(len(tau)):
        coast = torch.stack([z[..., 0] + tau[k] * z[..., 1], z[..., 1]], dim=-1)
        z = coast - torch.einsum("nm,bmc,dc->bnd", w, z, g[k])
        z = z - z.mean(dim=-2, keepdim=True)  # D is translation invariant; keeps the numbers small
    return torch.log(spread(z) + 1e-300) - torch.log(d0)


def refine(
    config: EnvConfig, gains: np.ndarray, steps: int, seed: int, batch: int = 16, lr: float = 1e-3
) -> tuple[np.ndarray, list[float]]:
    """Adam steps on the mean ``log D(T_s)/D(0)`` of fresh seeded batches; the best table seen and the loss curve."""
    import torch

    table = torch.tensor(gains, dtype=torch.float64, requires_grad=True)
    optimiser = torch.optim.Adam([table], lr=lr)
    engine = ConsensusEngine(config, n_episodes=1)
    rng = np.random.default_rng(seed)
    best, best_loss, curve = gains.copy(), np.inf, []
    for _ in range(steps):
        x0, v0, w_hat = drawn_rings(engine, rng, batch)
        loss = episode_log_errors(config, table, x0, v0, w_hat).mean()
        curve.append(float(loss.detach()))
        if curve[-1] < best_loss:  # the table this batch was scored with, before the step
            best_loss, best = curve[-1], table.detach().numpy().copy()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    return best, curve


def drawn_rings(engine: Any, rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``x0, v0`` ``(count, N)`` of ``count`` episodes ``engine`` draws from ``rng``, and ``Ŵ`` of the first one's
    ring (one relabelled ring serves them all: D is invariant to the labels)."""
    draws = [engine.draw_episode(rng) for _ in range(count)]
    x0, v0 = (np.stack([getattr(d, key)[:, 0] for d in draws]) for key in ("x0", "v0"))
    return x0, v0, spectrum_matrix(draws[0].topology)


# ---------------------------------------------------------------------------------- training
def train(
    episodes: int = 8, refine_steps: int = 0, init: str = "teacher", seed: int = DEMONSTRATION_SEED, lr: float = 1e-4
) -> tuple[IntervalGainPolicy, dict[str, Any]]:
    """The ``rings`` policy and a record of how it was made (see the module)."""
    config = task_config()
    record: dict[str, Any] = {"init": init, "demonstration_episodes": episodes, "refine_steps": refine_steps, "lr": lr}
    began = time.perf_counter()
    if init == "teacher":
        demos = run_episodes(config, LAWS["minimum_time"].policy, range(seed, seed + episodes), record=True)
        gains, residuals = regress_gains(config, demos["observations"], demos["actions"])
        record["teacher"] = "minimum_time"
        record["teacher_median_deadline_error"] = float(np.median(demos["deadline_error"]))
        record["regression_max_rms_residual"] = float(residuals.max())
    elif init == "paper":
        gains = np.broadcast_to(PAPER_GAIN, (config.n_intervals, 2, 2)).copy()
    else:
        raise ArgumentError(f"init: expected 'teacher' or 'paper', got {init!r}")
    if refine_steps:
        gains, curve = refine(config, gains, refine_steps, seed + episodes, lr=lr)
        record["refine_first_loss"], record["refine_best_loss"] = curve[0], min(curve)
    record["wall_s"] = round(time.perf_counter() - began, 2)
    header = ring_header(
        "rings",
        config,
        config.family.draw(config.n_agents, np.random.default_rng(0)),
        task_ranges=True,
        training=record,
    )
    return IntervalGainPolicy(gains, header), record


def ring_header(name: str, config: EnvConfig, ring: Any, *, task_ranges: bool = False, **fields: Any) -> dict[str, Any]:
    """A ring policy file's header: ``name``, the training settings and domain of ``config``, the relabelled rings,
    the eigenvalues of ``ring`` (for the graph check at load time only: training never reads them), with
    ``task_ranges`` the :data:`TASK`'s initial ranges, then ``fields``."""
    eigenvalues = spectrum(ring)
    ranges = {key: list(TASK[key]) for key in ("position_range", "velocity_range")} if task_ranges else {}
    return {
        "name": name,
        "env": training_settings(config),
        "domain": training_domain(config),
        "topology": {"family": "ring", "relabel": True, "period": 1},
        **ranges,
        "eigenvalues": np.stack([eigenvalues.real, eigenvalues.imag], axis=-1).tolist(),
        **fields,
    }


def record_run(
    policy: Any, recipe: str, argv: Sequence[str] | None, seed: int, out: str | None, hidden: Sequence[str] = ()
) -> None:
    """Record in ``policy``'s header the command of ``python -m fxc_env.training.recipes.<recipe>`` and the training
    seed, print its training record (but the keys ``hidden``) and save it to ``out`` when given."""
    record = policy.header["training"]
    record["command"] = f"python -m fxc_env.training.recipes.{recipe} " + " ".join(
        sys.argv[1:] if argv is None else argv
    )
    record["training_seed"] = seed
    print("trained:", json.dumps({key: value for key, value in record.items() if key not in hidden}))
    if out:
        print("wrote", policy.save(out))


def evaluate(policy: IntervalGainPolicy, n_agents: int = 20, seeds: Sequence[int] = range(20)) -> dict[str, float]:
    """Median ``D(T_s)/D(0)`` of ``policy`` and of the reference on the same seeded rings of ``n_agents``."""
    config = task_config(n_agents)
    ours = run_episodes(config, lambda _config: policy, seeds)["deadline_error"]
    reference = run_episodes(config, ReferencePolicy, seeds)["deadline_error"]
    return comparison(n_agents, ours, reference)


def comparison(n_agents: int, ours: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    """Medians of a policy's and the reference's ``D(T_s)/D(0)`` (one value per seed each), their ratio."""
    return {
        "n_agents": n_agents,
        "seeds": len(ours),
        "median": float(np.median(ours)),
        "max": float(np.max(ours)),
        "reference_median": float(np.median(reference)),
        "ratio": float(np.median(reference) / max(np.median(ours), 1e-300)),
    }


def comparison_line(label: str, result: dict[str, float], seeds: str = "seeds") -> str:
    """One line of :func:`comparison`: the policy's median (and max) beside the reference's, and their ratio
    (``seeds``: what the episodes are called, e.g. ``held-out seeds``)."""
    return (
        f"{label} N = {result['n_agents']}, K = 200, T_s = 20, {result['seeds']} {seeds}: median D(T_s)/D(0) "
        f"{result['median']:.3g} (max {result['max']:.3g}), reference {result['reference_median']:.3g}, "
        f"{result['ratio']:.3g}x below the reference"
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = FlagParser(prog="python -m fxc_env.training.recipes.rings", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="where to save the policy (.npz)")
    parser.add_argument("--episodes", type=int, default=8, help="demonstration episodes of the teacher")
    parser.add_argument("--refine-steps", type=int, default=0, help="direct-minimisation steps after the start")
    parser.add_argument("--lr", type=float, default=1e-4, help="Adam's learning rate of the refinement")
    parser.add_argument("--init", default="teacher", choices=("teacher", "paper"), help="the table to start from")
    parser.add_argument("--evaluate", default=None, help="only measure the policy saved at this path")
    parser.add_argument("--n-agents", type=int, default=20, help="ring size to measure on")
    parser.add_argument("--seeds", type=int, default=20, help="evaluation episodes (seeds 0 ..)")
    parser.add_argument(
        "--seed", type=int, default=0, help="training seed k: demonstrations from episode seeds 1000 + k * episodes"
    )
    args = parser.parse_args(argv)
    integer("--episodes", args.episodes, 1)
    integer("--seed", args.seed, 0)
    integer("--seeds", args.seeds, 1)
    if args.evaluate is not None:
        policy = load_interval_gains(args.evaluate)
    else:
        first = DEMONSTRATION_SEED + args.seed * args.episodes  # seed 0: the shipped file's episodes
        policy, _ = train(args.episodes, args.refine_steps, args.init, seed=first, lr=args.lr)
        record_run(policy, "rings", argv, args.seed, args.out)
    result = evaluate(policy, args.n_agents, range(EVALUATION_SEED, EVALUATION_SEED + args.seeds))
    print(comparison_line("rings", result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
