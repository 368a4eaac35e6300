"""Gain tables fitted for measurement noise on a directed ring: the measured error-energy frontier (issue 25, item 5).

Law, source, proven graph class and refusals: docs: optimality.md, "Noise-fitted gain tables (`noise_gains`)".
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from fxc_env.config import make_config
from fxc_env.config.argument_types import FlagParser
from fxc_env.core.validation import ArgumentError, integer, real
from fxc_env.policies.interval_gains import IntervalGainPolicy, spectrum
from fxc_env.policies.protocol import seeded_metrics
from fxc_env.training.recipes.rings import gain_scale, ring_header
from fxc_env.utils.threads import torch_threads

#: The task: directed ring of 20, K = 200 uniform intervals, T_s = 20 s, the optimality suite's noise case.
TASK = {"topology": "ring", "n_agents": 20, "n_intervals": 200, "settling_time": 20.0, "schedule": "uniform"}


def task_config(sigma: float, **changes: Any) -> Any:
    """The environment of the task at ``obs_noise = sigma`` (plans on normalized rows, as the suite runs ``minimum_time``)."""
    real("sigma", sigma, 0.0)
    return make_config(**{**TASK, **changes}, obs_noise=sigma, action_mode="plan", obs_mode="normalized")


def _modes(config: Any) -> tuple[np.ndarray, np.ndarray]:
    """The disagreement eigenvalues of ``Ŵ`` (one of each conjugate pair) and their multiplicities."""
    if config.topology is None or config.topology.name != "ring" or config.topology.period != 1:
        raise ArgumentError("topology: the closed form needs one fixed directed ring (a normal Ŵ)")
    mu = spectrum(config.topology)
    mu = mu[(np.abs(mu) > 1e-9) & (mu.imag >= -1e-12)]
    return mu, np.where(np.abs(mu.imag) > 1e-12, 2.0, 1.0)


def _variances(config: Any) -> np.ndarray:
    """``E[x_i^2], E[v_i^2]`` of the uniform draw ``U(-a, a)`` (a log-uniform half-width: its mean square)."""

    def mean_square(low: float, high: float) -> float:
        return low * low if low == high else (high * high - low * low) / (2.0 * np.log(high / low))

    return np.array([mean_square(*config.position_range), mean_square(*config.velocity_range)]) / 3.0


def ring_moments(config: Any, gains: Any, sigma: float | None = None) -> tuple[Any, Any, float, float]:
    """``(E[S_K], E[energy], S_0, E[E*])`` of the physical table ``gains`` ``(K, 2, 2)`` (torch, differentiable).

    ``S = sum_i |x_i - x̄|^2 + T_s^2 |v_i - v̄|^2``; expectations over the uniform initial draw and the
    noise (``sigma``, default ``config.obs_noise``). Energy in m²/s³, summed over agents.
    """
    import torch

    sigma = config.obs_noise if sigma is None else sigma
    mu_np, weight_np = _modes(config)
    tau, settling = np.asarray(config.schedule.intervals, dtype=np.float64), config.settling_time
    var = _variances(config)
    mu, weight = torch.tensor(mu_np), torch.tensor(weight_np)
    moment = torch.diag(torch.tensor(var, dtype=torch.complex128)).expand(len(mu_np), 2, 2)
    noise = sigma**2 / 4.0  # one in-neighbour: r carries half of each row's noise
    metric = torch.tensor([1.0, settling**2], dtype=torch.float64)
    energy = torch.zeros((), dtype=torch.float64)
    for k, t in enumerate(tau):
        coast = torch.tensor([[1.0, t], [0.0, 1.0]], dtype=torch.complex128)
        cost = torch.tensor([[12 / t**3, -6 / t**2], [-6 / t**2, 4 / t]], dtype=torch.float64)
        g = gains[k]
        second = (mu.abs() ** 2)[:, None, None] * moment + noise * torch.eye(2)
        energy = energy + (weight * torch.einsum("ab,mba->m", (g.T @ cost @ g).to(second.dtype), second).real).sum()
        step = coast - mu[:, None, None] * g.to(torch.complex128)
        moment = step @ moment @ step.conj().transpose(-1, -2) + noise * (g @ g.T)
    final = (weight * (moment.diagonal(dim1=-2, dim2=-1).real @ metric)).sum()
    gram_inv = np.array([[12 / settling**3, -6 / settling**2], [-6 / settling**2, 4 / settling]])
    predict = np.array([[1.0, settling], [0.0, 1.0]])
    e_star = float(weight_np.sum() * np.trace(gram_inv @ predict @ np.diag(var) @ predict.T))
    return final, energy, float(weight_np.sum() * (var @ metric.numpy())), e_star


def rank_one_floor(config: Any) -> float:
    """The least relative root-mean-square disagreement ``sqrt(E S_K / S_0)`` of any rank-one table (module)."""
    mu, weight = _modes(config)
    steps = np.ones(config.n_intervals)
    lowest = np.prod(np.abs(np.sin(np.angle(mu)))[:, None] ** steps, axis=1)  # min |det Φ_K(mu)|
    var = _variances(config)
    smallest = min(var[0], config.settling_time**2 * var[1])
    return float(
        np.sqrt(np.sum(weight * 2 * lowest * smallest) / (weight.sum() * (var[0] + config.settling_time**2 * var[1])))
    )


def start_table(config: Any, start: str) -> np.ndarray:
    """A physical ``(K, 2, 2)`` start: ``minimum_time``'s dead-beat table, ``accel`` (``u = 0.5 r_x + r_v``) or a saved table (.npy)."""
    if start.endswith(".npy"):
        gains = np.load(start, allow_pickle=False)
        if gains.shape != (config.n_intervals, 2, 2) or not np.all(np.isfinite(gains)):
            raise ArgumentError(f"start: {start} holds no finite ({config.n_intervals}, 2, 2) table")
        return gains
    if start == "deadbeat":
        from fxc_env.baselines.registry import LAWS

        return LAWS["minimum_time"].policy(config, allow_noise=config.obs_noise > 0).gains.copy()
    if start == "accel":
        tau = np.asarray(config.schedule.intervals, dtype=np.float64)
        shape = np.stack([tau**2 / 2, tau], axis=-1)[:, :, None]  # (K, 2, 1): offsets of a constant input
        return shape * np.array([0.5, 1.0])[None, None, :]
    raise ArgumentError(f"start: expected 'deadbeat', 'accel' or a table's .npy path, got {start!r}")


def fit(
    config: Any,
    cap: float,
    start: str = "deadbeat",
    steps: int = 20,
    weight: float = 3.0,
    out: str | None = None,
    progress: Callable[[str], Any] | None = None,
) -> tuple[np.ndarray, list]:
    """A table fitted for ``config.obs_noise`` under ``cap x E[E*]`` (module): ``(gains (K, 2, 2), history)``.

    Minimises ``log E[S_K]/S_0 + weight * softplus(10 log(E[energy] / (cap E[E*]))) / 10`` with L-BFGS
    (``steps`` rounds of 50 iterations); ``history`` lists ``(seconds, rms, energy ratio)`` per round.
    ``out``: a .npy path, rewritten with the table after every round (an interrupted fit keeps its progress);
    ``progress`` receives one line per round.
    """
    import torch

    real("cap", cap, positive=True)
    integer("steps", steps, 1)
    real("weight", weight, positive=True)
    tau = np.asarray(config.schedule.intervals, dtype=np.float64)
    # The variables are accelerations: G_k = diag(T_k^2 / 2, T_k) theta_k (theta in 1/s^2 and 1/s), scaled alike.
    shape = torch.tensor(np.stack([tau**2 / 2, tau], axis=-1)[:, :, None])
    theta = torch.tensor(start_table(config, start) / shape.numpy(), requires_grad=True)
    optimiser = torch.optim.LBFGS([theta], lr=1.0, max_iter=50, history_size=30, line_search_fn="strong_wolfe")

    def loss() -> tuple[Any, float, float]:
        final, energy, initial, e_star = ring_moments(config, shape * theta)
        ratio = energy / e_star
        penalty = torch.nn.functional.softplus(10 * torch.log(ratio / cap)) / 10
        return (
            torch.log(final / initial) + weight * penalty,
            float(final.detach() / initial) ** 0.5,
            float(ratio.detach()),
        )

    def closure() -> Any:
        optimiser.zero_grad()
        value = loss()[0]
        value.backward()
        return value

    began, history = time.perf_counter(), []
    with torch_threads(1):
        for _ in range(steps):
            optimiser.step(closure)
            with torch.no_grad():
                _, rms, ratio = loss()
            history.append((round(time.perf_counter() - began, 1), rms, ratio))
            if progress is not None:
                progress(f"{history[-1][0]:8.1f} s  predicted rms {rms:.3g}  energy {ratio:.3g} x E[E*]")
            if out is not None:
                np.save(out, (shape * theta).detach().numpy())
    return (shape * theta).detach().numpy(), history


def policy_of(config: Any, gains: np.ndarray, training: dict[str, Any] | None = None) -> IntervalGainPolicy:
    """The table as an :class:`~fxc_env.policies.interval_gains.IntervalGainPolicy` for ``config`` (saved with ``.save``).

    ``gains`` are physical ``(K, 2, 2)``; the policy holds them in normalized units (divided by
    ``[[1, T_k], [1/T_k, 1]]`` entrywise) and records ``config``'s domain, noise level included.
    """
    gains = np.asarray(gains, dtype=np.float64)
    if gains.shape != (config.n_intervals, 2, 2) or not np.all(np.isfinite(gains)):
        raise ArgumentError(f"gains: expected a finite ({config.n_intervals}, 2, 2) table, got shape {gains.shape}")
    return IntervalGainPolicy(
        gains / gain_scale(config), ring_header("noise_gains", config, config.topology, training=training or {})
    )


def measure(config: Any, policy: Any, seeds: Sequence[int] = tuple(range(20))) -> dict[str, float]:
    """Medians of ``D(T_s)/D(0)`` and energy / E* of ``policy`` on ``seeds``, as the optimality suite scores a law.

    The initial states come from ``np.random.default_rng(seed)`` and the noise from
    ``np.random.default_rng([*seeds, K])``, as in :func:`fxc_env.baselines.harness.jobs.run_job`.
    """
    if not callable(policy):
        raise ArgumentError(f"policy: expected a callable of observations, got {type(policy).__name__}")
    metrics = seeded_metrics(config, policy, seeds, np.random.default_rng([*seeds, config.n_intervals]))
    return {
        "error": float(np.median(metrics["relative_deadline_error"])),
        "energy_ratio": float(np.median(metrics["energy_ratio"])),
        "noise_floor": float(np.median(metrics["noise_floor"])) if config.obs_noise > 0 else 0.0,
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = FlagParser(prog="python -m fxc_env.training.recipes.noise_gains", description=__doc__.splitlines()[0])
    parser.add_argument("--sigma", type=float, default=1e-3, help="obs_noise (m, m/s)")
    parser.add_argument("--cap", type=float, default=1e3, help="energy budget, in units of E[E*]")
    parser.add_argument(
        "--start", default="deadbeat", help="'deadbeat' (minimum_time's table), 'accel' or a saved table (.npy)"
    )
    parser.add_argument("--steps", type=int, default=20, help="L-BFGS rounds of 50 iterations")
    parser.add_argument("--weight", type=float, default=3.0, help="weight of the energy penalty")
    parser.add_argument("--policy", default=None, help="save the table as an interval-gain policy (.npz)")
    parser.add_argument(
        "--table", default=None, help="measure this table instead of fitting: 'deadbeat', 'accel' or a saved .npy"
    )
    parser.add_argument("--out", default=None, help="save the fitted physical table here after every round (.npy)")
    args = parser.parse_args(argv)
    try:
        config = task_config(args.sigma)
        print(f"rank-one floor (any energy): relative rms >= {rank_one_floor(config):.3g}")
        if args.table is None:
            gains, _ = fit(config, args.cap, args.start, args.steps, args.weight, args.out, print)
        else:
            gains = start_table(config, args.table)
        if args.policy:
            print("wrote", policy_of(config, gains, {"command": " ".join(sys.argv)}).save(args.policy))
        for sigma in (args.sigma, 0.0):
            result = measure(task_config(sigma), policy_of(task_config(sigma), gains))
            print(
                f"measured, sigma = {sigma:g}, 20 seeds: median D(T_s)/D(0) {result['error']:.3g}, "
                f"energy {result['energy_ratio']:.3g} x E*, noise floor {result['noise_floor']:.3g}"
            )
    except ArgumentError as exc:
        parser.error(str(exc))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
