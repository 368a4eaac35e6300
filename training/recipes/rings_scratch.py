"""Train the shipped ``rings_scratch`` policy: a gain schedule for directed rings of 20, learned from scratch.

The task and network are :mod:`fxc_env.training.recipes.rings`'s; nothing is copied (no teacher, no spectrum). L-BFGS
minimises the mean ``log D(T_s)/D(0)`` over seeded episodes through the exact interval map (:func:`log_errors`)
from a random start ``q_m ~ N(0, 1)`` (a real start is a saddle: the loss is even in each ``b_m``).

**Factors.** Intervals go in pairs, each holding ``q_m = a_m + i b_m``: ``G_{2m} = R_m P_{2m}``,
``G_{2m+1} = P_{2m+1} R_m^T``, ``R_m = [[a_m, -b_m], [b_m, a_m]]``, ``P_k = [[1, T_k], [0, 1]]``, so an
episode multiplies every mode mu of ``(D + I)^{-1} L`` by ``prod_m (1 - mu q_m)(1 - mu conj(q_m))``;
``q_m = 1`` is the paper's controller (eq. 11), ``q_m = 0`` coasting. ``--free`` learns the free table
instead (the control). Training episodes are drawn from seed ``2000 + seed``, evaluation seeds from 0.
Commands and results: (docs: results.md, "What learning reached").
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from fxc_env.config.argument_types import FlagParser
from fxc_env.core.validation import ArgumentError, integer
from fxc_env.engine.consensus_engine import ConsensusEngine
from fxc_env.policies.interval_gains import IntervalGainPolicy, load_interval_gains
from fxc_env.training.recipes import rings
from fxc_env.training.recipes.rings import EVALUATION_SEED, evaluate, physical_map, task_config
from fxc_env.utils.threads import torch_threads

#: Training episodes are drawn from ``np.random.default_rng(TRAINING_SEED + seed)``; the evaluation's from seeds 0 ...
TRAINING_SEED = 2_000
#: The shipped file's training: episodes in the batch, at most this many L-BFGS steps (20 iterations each).
FULL = {"episodes": 64, "steps": 15}
QUICK = {"episodes": 8, "steps": 1}
#: Where a learned table stops being worth refining: the mean deadline error at float64 round-off.
FLOOR = 1e-13


def factor_table(config: Any, q: Any) -> Any:
    """The ``(K, 2, 2)`` table in normalized units (torch float64) of the factors ``q`` ``(ceil(K / 2), 2)``.

    Pairs as in the module; an odd K's last interval is the real factor ``G = a P``; normalized units are
    the inverse of :func:`fxc_env.training.recipes.rings.physical_map`.
    """
    import torch

    tau = torch.as_tensor(np.array(config.schedule.intervals, dtype=np.float64))
    K = len(tau)
    a, b = q[:, 0], q[:, 1]
    rotation = torch.stack([torch.stack([a, -b], -1), torch.stack([b, a], -1)], -2)  # (M, 2, 2)
    coast = torch.eye(2, dtype=torch.float64).repeat(K, 1, 1)
    coast[:, 0, 1] = tau
    first = rotation[: (K + 1) // 2] @ coast[0::2]
    second = coast[1::2] @ rotation[: K // 2].transpose(-1, -2)
    gains = torch.empty(K, 2, 2, dtype=torch.float64)
    gains[0::2], gains[1::2] = first, second
    if K % 2:
        gains[-1] = a[-1] * coast[-1]
    return gains / torch.as_tensor(rings.gain_scale(config))


def log_errors(config: Any, gains: Any, x0: np.ndarray, v0: np.ndarray, w_hat: np.ndarray) -> Any:
    """``log D(T_s)/D(0)`` ``(B,)`` of the table ``gains``, as :func:`fxc_env.training.recipes.rings.episode_log_errors`, in any range.

    Each episode's state is rescaled to unit size after every interval and the logarithms of the scales
    summed (D is homogeneous of degree one), so a table that grows the state by 1e400 scores a finite loss.
    """
    import torch

    g = physical_map(config, gains)
    tau = torch.as_tensor(np.array(config.schedule.intervals, dtype=np.float64))
    w = torch.as_tensor(w_hat)
    z = torch.stack([torch.as_tensor(x0), torch.as_tensor(v0)], dim=-1)  # (B, N, 2)
    weights = torch.tensor([1.0, config.settling_time], dtype=torch.float64)

    def spread(z: Any) -> Any:
        return (z.amax(-2) - z.amin(-2)) @ weights

    z = z / spread(z)[:, None, None]  # D(0) = 1
    log_sizes = torch.zeros(len(z), dtype=torch.float64)
    for k in range(len(tau)):
        coast = torch.stack([z[..., 0] + tau[k] * z[..., 1], z[..., 1]], dim=-1)
        z = coast - torch.einsum("nm,bmc,dc->bnd", w, z, g[k])
        z = z - z.mean(dim=-2, keepdim=True)  # D is translation invariant
        size = z.abs().amax(dim=(-2, -1)).clamp_min(1e-300).detach()  # a constant scale: value and gradient exact
        z = z / size[:, None, None]
        log_sizes = log_sizes + torch.log(size)
    return torch.log(spread(z) + 1e-300) + log_sizes


def minimise(
    parameter: Any,
    loss: Callable[[], Any],
    steps: int,
    restarts: int = 0,
    stop: Callable[[float], bool] | None = None,
    progress: Callable[[int, float], None] | None = None,
) -> tuple[list[float], int]:
    """L-BFGS on ``loss()`` over the tensor ``parameter``: the loop of every gain-schedule trainer here.

    At most ``steps`` steps of 20 L-BFGS iterations (strong-Wolfe); it ends on a non-finite loss, when
    ``stop(loss)`` holds, or when a step lowers nothing after ``restarts`` fresh curvature histories.
    ``progress(step, loss)`` follows every step. Returns the loss before and after each step, and the restarts.
    """
    import torch

    def fresh() -> Any:
        return torch.optim.LBFGS([parameter], lr=1.0, max_iter=20, history_size=20, line_search_fn="strong_wolfe")

    optimiser = fresh()

    def closure() -> Any:
        optimiser.zero_grad()
        value = loss()
        value.backward()
        return value

    curve, used = [float(loss().detach())], 0
    for _ in range(steps):
        optimiser.step(closure)
        curve.append(float(loss().detach()))
        if progress is not None:
            progress(len(curve) - 1, curve[-1])
        if not np.isfinite(curve[-1]) or (stop is not None and stop(curve[-1])):
            break
        if curve[-1] >= curve[-2]:
            if used == restarts:
                break
            used, optimiser = used + 1, fresh()
    return curve, used


def training_episodes(config: Any, episodes: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``x0, v0`` ``(episodes, N)`` of seeded episodes of the task and ``Ŵ`` of one drawn ring (the labels change no D)."""
    return rings.drawn_rings(
        ConsensusEngine(config, n_episodes=1), np.random.default_rng(TRAINING_SEED + seed), episodes
    )


def train(
    episodes: int = FULL["episodes"], steps: int = FULL["steps"], seed: int = 0, free: bool = False
) -> tuple[IntervalGainPolicy, dict]:
    """The ``rings_scratch`` policy and a record of how it was made (see the module).

    ``free=True`` is the control experiment: the same start, loss and optimiser over the free
    ``(K, 2, 2)`` table instead of the factors.
    """
    integer("episodes", episodes, 1)
    integer("steps", steps, 1)
    integer("seed", seed, 0)
    with torch_threads(1):  # one thread: the tensors are small, and a second one only waits on a shared machine
        return _train(episodes, steps, seed, free)


def _train(episodes: int, steps: int, seed: int, free: bool) -> tuple[IntervalGainPolicy, dict]:
    import torch

    config = task_config()
    began = time.perf_counter()
    x0, v0, w_hat = training_episodes(config, episodes, seed)
    start = np.random.default_rng(seed).normal(size=((config.n_intervals + 1) // 2, 2))
    q = torch.tensor(start, dtype=torch.float64, requires_grad=True)
    if free:
        q = factor_table(config, q).detach().requires_grad_(True)

    def table() -> Any:
        return q if free else factor_table(config, q)

    def loss() -> Any:
        return log_errors(config, table(), x0, v0, w_hat).mean()

    curve, _ = minimise(q, loss, steps, stop=lambda value: np.exp(value) < FLOOR)
    if not np.isfinite(curve[-1]):
        raise RuntimeError(f"rings_scratch: the loss became {curve[-1]} (seed {seed}); try another --seed")
    record = {
        "method": "L-BFGS on the mean log D(T_s)/D(0) through the exact interval map, factor parameterisation",
        "teacher": None,
        "init": "random normal factors",
        "parameterisation": "free (K, 2, 2) table" if free else "factors",
        "episodes": episodes,
        "lbfgs_steps": len(curve) - 1,
        "loss_curve": [round(v, 4) for v in curve],
        "training_mean_deadline_error": float(np.exp(curve[-1])),
        "wall_s": round(time.perf_counter() - began, 2),
    }
    with torch.no_grad():
        gains = table().numpy().copy()
    header = rings.ring_header(
        "rings_scratch",
        config,
        config.family.draw(config.n_agents, np.random.default_rng(0)),
        task_ranges=True,
        factors=None if free else q.detach().numpy().tolist(),
        training=record,
    )
    return IntervalGainPolicy(gains, header), record


def main(argv: Sequence[str] | None = None) -> int:
    parser = FlagParser(prog="python -m fxc_env.training.recipes.rings_scratch", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="where to save the policy (.npz)")
    parser.add_argument("--quick", action="store_true", help="train for seconds (8 episodes, one L-BFGS step)")
    parser.add_argument("--episodes", type=int, default=None, help="training episodes (default 64, --quick 8)")
    parser.add_argument("--steps", type=int, default=None, help="L-BFGS steps of 20 iterations (default 15)")
    parser.add_argument("--seed", type=int, default=0, help="training seed: the random start and the episodes")
    parser.add_argument("--free", action="store_true", help="control: optimise the free table from the same start")
    parser.add_argument("--evaluate", default=None, help="only measure the policy saved at this path")
    parser.add_argument("--seeds", type=int, default=20, help="held-out evaluation episodes (seeds 0 ..)")
    args = parser.parse_args(argv)
    integer("--seed", args.seed, 0)
    integer("--seeds", args.seeds, 1)
    if args.evaluate is not None:
        policy = load_interval_gains(args.evaluate)
    else:
        preset = QUICK if args.quick else FULL
        episodes = preset["episodes"] if args.episodes is None else args.episodes
        steps = preset["steps"] if args.steps is None else args.steps
        try:
            policy, _ = train(episodes, steps, args.seed, args.free)
        except ArgumentError as exc:
            parser.error(str(exc))
        rings.record_run(policy, "rings_scratch", argv, args.seed, args.out, hidden=("loss_curve",))
    result = evaluate(policy, 20, range(EVALUATION_SEED, EVALUATION_SEED + args.seeds))
    print(rings.comparison_line("rings", result, "held-out seeds"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
