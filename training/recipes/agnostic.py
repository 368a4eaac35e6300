"""Train the shipped ``agnostic`` policy: gain schedules for every graph, learned without being told the graph.

The network is :class:`fxc_env.policies.regime_gains.RegimeGainPolicy`: agent i plans ``G_k r_i`` from its
own aggregated relative row, its mask and ``k / K``, from the **fixed-graph** ``(K, 2, 2)`` table, or the
**switching** one once its probe (coasting the first :data:`PROBES` intervals) has seen its in-neighbour set
change. Both tables are parameterised by factors (:func:`fxc_env.training.recipes.rings_scratch.factor_table`).

It is trained over the graphs of :data:`CASES` (rings except :data:`HELD_OUT_RINGS`, random digraphs, paths,
stars, periodic switching) by L-BFGS (:func:`fxc_env.training.recipes.rings_scratch.minimise`) on :func:`loss_terms`
through the exact closed-form interval map (:func:`log_errors`, :func:`probe_keeps_fixed`); no teacher, no
spectrum read. Training episodes are drawn from seed ``3000 + seed``, evaluation seeds from 0. The command, the
controls (``--init paper|chebyshev``), ``--quick``, ``--evaluate`` and the results: (docs: results.md,
"agnostic policy").
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from fxc_env.config import EnvConfig, make_config
from fxc_env.config.argument_types import FlagParser
from fxc_env.core.families import TopologyFamily
from fxc_env.core.validation import ArgumentError, integer
from fxc_env.engine.consensus_engine import ConsensusEngine
from fxc_env.policies.domain import training_domain
from fxc_env.policies.interval_gains import load_interval_gains
from fxc_env.policies.policy_files import training_settings
from fxc_env.policies.protocol import seeded_metrics
from fxc_env.policies.reference import ReferencePolicy
from fxc_env.policies.regime_gains import RegimeGainPolicy
from fxc_env.training.recipes import rings
from fxc_env.training.recipes.rings import TASK, comparison, physical_map, record_run, run_episodes, task_config
from fxc_env.training.recipes.rings_scratch import factor_table, minimise
from fxc_env.utils.threads import torch_threads

#: Training episodes are drawn from ``np.random.default_rng(TRAINING_SEED + seed)``; evaluation's from seeds 0 ...
TRAINING_SEED = 3_000
#: Directed ring sizes in 12..40 never trained on: the goal is measured there.
HELD_OUT_RINGS = (15, 19, 22, 24, 27, 30, 33, 36, 39)
TRAINED_RINGS = tuple(n for n in range(12, 41) if n not in HELD_OUT_RINGS)
RANDOM = {"mean_in_degree": (1.5, 3.0)}
#: The training distribution: (family keywords, N, episodes).
CASES: tuple[tuple[dict[str, Any], int, int], ...] = (
    *(({"kind": "ring"}, n, 2) for n in TRAINED_RINGS),
    *(({"kind": "random", **RANDOM}, n, 6) for n in (12, 20, 40)),
    *(({"kind": "path"}, n, 1) for n in (12, 20, 40)),
    *(({"kind": "star"}, n, 1) for n in (12, 20, 40)),
    ({"kind": "ring", "period": (2, 4)}, 20, 6),
    ({"kind": "random", "period": (2, 4), **RANDOM}, 20, 6),
)
QUICK_CASES = (
    ({"kind": "ring"}, 12, 2),
    ({"kind": "random", **RANDOM}, 12, 2),
    ({"kind": "ring", "period": (2, 4)}, 12, 2),
)
#: Bounds of the penalty, in decades relative to the reference's error on the same episode (floored at FLOOR).
RING_MARGIN = 1.3
OTHER_MARGIN = 0.5
FLOOR = 1e-15
#: Rings below this error leave the mean log error's pull to the larger rings.
RING_TARGET = 1e-8
PENALTY = 10.0
FULL = {"steps": 20}
QUICK = {"steps": 1}
#: Starts: ``q_m ~ N(0, 1)``, or the paper's controller (``q_m = 1``) plus NOISE times that draw.
INITS = ("random", "paper", "chebyshev")
NOISE = 0.3
#: The ``chebyshev`` start: pairs of the design (the rest the paper's) and the gap angle it is small beyond.
DESIGN_PAIRS = 60
DESIGN_GAP = 2 * np.pi / 44
#: Fresh L-BFGS histories allowed when a step finds nothing.
RESTARTS = 2
#: Intervals of the probe (fxc_env.policies.regime_gains): every agent coasts and checks that its rows coast too.
#: At least the longest switching period trained on (4), and even (the factors come in pairs of intervals).
PROBES = 4
#: Neighbour slots of the training environments (every draw's in-degree fits; the table reads any number).
SLOTS = 4
#: Threads the training uses (the tensors are small: a second thread only waits on a shared machine).
THREADS = 1


def case_config(family: dict[str, Any], n_agents: int) -> EnvConfig:
    """The task's environment (``rings``' K = 200, paper schedule, T_s = 20 s) on a graph family."""
    kwargs = dict(family)
    family = TopologyFamily(kwargs.pop("kind"), **kwargs)
    return make_config(None, **{**TASK, "n_agents": n_agents, "topology": family, "obs_slots": SLOTS})


def probe_keeps_fixed(topology: Any) -> np.ndarray:
    """``(N,)``: whether each agent's probe sees no change and it plays the fixed table (see the module).

    The probe (:mod:`fxc_env.policies.regime_gains`) sees no change exactly when the agent's row of ``Ŵ`` is the
    same on the graphs of intervals ``0 .. PROBES``.
    """
    rows = np.stack([rings.spectrum_matrix(topology, c % topology.period) for c in range(PROBES + 1)])
    return np.all(rows[1:] == rows[:1], axis=(0, 2))


#: Every period 1..4 divides it: an episode's graphs, repeated to this length, are indexed by ``k % CYCLE``.
CYCLE = 12


def draw_cases(cases: Sequence[tuple[dict[str, Any], int, int]], seed: int) -> dict[str, Any]:
    """Seeded episodes of every case in one batch padded to the largest N.

    ``x0, v0`` ``(B, N_max)``, ``mask`` ``(B, N_max)`` (1 on real agents), ``case`` ``(B,)`` (its entry of ``cases``), ``w`` ``(B, CYCLE, N_max,
    N_max)`` (interval k's ``Ŵ`` at ``k % CYCLE``, zero on padding), ``ring`` ``(B,)`` (a fixed directed
    ring), ``fixed`` ``(B, N_max)`` (1 where the agent's probe sees no change: it plays the fixed table)
    and ``labels``.
    """
    rng = np.random.default_rng(TRAINING_SEED + seed)
    n_max = max(n for _, n, _ in cases)
    x0, v0, mask, w, ring, fixed, labels, case = [], [], [], [], [], [], [], []
    for family, n, episodes in cases:
        engine = ConsensusEngine(case_config(family, n), n_episodes=1)
        for _ in range(episodes):
            d = engine.draw_episode(rng)
            pad = (0, n_max - n)
            x0.append(np.pad(d.x0[:, 0], pad))
            v0.append(np.pad(d.v0[:, 0], pad))
            mask.append(np.pad(np.ones(n), pad))
            graphs = [rings.spectrum_matrix(d.topology, c % d.topology.period) for c in range(CYCLE)]
            w.append(np.stack([np.pad(graph, [pad, pad]) for graph in graphs]))
            ring.append(family == {"kind": "ring"})
            fixed.append(np.pad(probe_keeps_fixed(d.topology), pad))
        labels.append([f"{family} N={n}", episodes])
        case.extend([len(labels) - 1] * episodes)
    return {
        "x0": np.stack(x0),
        "v0": np.stack(v0),
        "mask": np.stack(mask),
        "w": np.stack(w),
        "ring": np.array(ring),
        "fixed": np.stack(fixed).astype(np.float64),
        "labels": labels,
        "case": np.array(case),
    }


def log_errors(config: EnvConfig, tables: tuple[Any, Any], batch: dict[str, Any]) -> Any:
    """``log D(T_s)/D(0)`` ``(B,)`` of the two tables through the exact interval map, interval k on its own graph.

    :func:`fxc_env.training.recipes.rings_scratch.log_errors` with ``Ŵ`` per episode and interval, agent i playing
    ``tables[0]`` (fixed) or ``tables[1]`` (switching) as ``batch["fixed"]`` says, padded agents masked out.
    """
    import torch

    g_fixed, g_switching = (physical_map(config, table) for table in tables)
    tau = torch.as_tensor(np.array(config.schedule.intervals, dtype=np.float64))
    w = torch.as_tensor(batch["w"])
    mask = torch.as_tensor(batch["mask"])[..., None]  # (B, N, 1)
    fixed = torch.as_tensor(batch["fixed"])[..., None]
    count = mask.sum(dim=-2, keepdim=True)
    z = torch.stack([torch.as_tensor(batch["x0"]), torch.as_tensor(batch["v0"])], dim=-1)
    weights = torch.tensor([1.0, config.settling_time], dtype=torch.float64)
    real = mask > 0.5

    def spread(z: Any) -> Any:
        high = torch.where(real, z, torch.full_like(z, -np.inf)).amax(-2)
        low = torch.where(real, z, torch.full_like(z, np.inf)).amin(-2)
        return (high - low) @ weights

    z = z / spread(z)[:, None, None]
    log_sizes = torch.zeros(len(z), dtype=torch.float64)
    for k in range(len(tau)):
        coast = torch.stack([z[..., 0] + tau[k] * z[..., 1], z[..., 1]], dim=-1)
        wz = torch.einsum("bnm,bmc->bnc", w[:, k % CYCLE], z)
        z = coast - fixed * (wz @ g_fixed[k].T) - (1.0 - fixed) * (wz @ g_switching[k].T)
        z = (z - (z * mask).sum(dim=-2, keepdim=True) / count) * mask
        size = z.abs().amax(dim=(-2, -1)).clamp_min(1e-300).detach()
        z = z / size[:, None, None]
        log_sizes = log_sizes + torch.log(size)
    return torch.log(spread(z) + 1e-300) + log_sizes


def loss_terms(config: EnvConfig, tables: tuple[Any, Any], batch: dict[str, Any]) -> tuple[Any, Any, Any]:
    """The rings' mean log error, the penalty (see the module) and each episode's excess over its bound (decades)."""
    import torch

    floor = np.log10(FLOOR)
    log10 = torch.clamp_min(log_errors(config, tables, batch) / np.log(10.0), floor)
    ring = torch.as_tensor(batch["ring"])
    bound = torch.as_tensor(np.maximum(batch["reference_log10"], floor))
    bound = torch.where(ring, bound - RING_MARGIN, bound + OTHER_MARGIN)
    excess = log10 - bound
    rings = torch.clamp_min(log10[ring], np.log10(RING_TARGET))  # a ring below the target pulls no more
    # every case weighs alike in the penalty, however many episodes it has
    case = torch.as_tensor(batch["case"])
    per_case = torch.zeros(int(case.max()) + 1, dtype=torch.float64).index_add(0, case, torch.relu(excess) ** 2)
    penalty = (per_case / torch.bincount(case).to(torch.float64)).mean()
    return rings.mean() * np.log(10.0), penalty, excess


def chebyshev_factors(pairs: int, design: int = DESIGN_PAIRS, gap: float = DESIGN_GAP) -> np.ndarray:
    """Factors ``(pairs, 2)`` of a Chebyshev design on the directed-ring circle, Leja-ordered (the ``chebyshev`` start).

    On the directed rings' circle ``mu = (1 - e^{i theta}) / 2``, ``design`` pairs ``q = 1 + i t`` multiply a
    mode by a polynomial in ``v = cos^2(theta / 2)``; the roots ``v`` of the Chebyshev polynomial on
    ``[0, cos^2(gap / 2)]`` give ``t = sqrt(v / (1 - v))``. The other pairs are the paper's (``q = 1``).
    """
    j = np.arange(1, design + 1)
    top = np.cos(gap / 2) ** 2
    v = top * (1 + np.cos((2 * j - 1) * np.pi / (2 * design))) / 2
    q = np.concatenate([1 + 1j * np.sqrt(v / (1 - v)), np.ones(pairs - design)])
    roots, ordered = list(1 / q), []
    ordered.append(roots.pop(int(np.argmax(np.abs(roots)))))
    while roots:
        score = [sum(np.log(abs(r - o) * abs(r - np.conj(o)) + 1e-300) for o in ordered) for r in roots]
        ordered.append(roots.pop(int(np.argmax(score))))
    q = 1 / np.array(ordered)
    return np.stack([q.real, q.imag], axis=-1)


def train(
    steps: int = FULL["steps"], seed: int = 0, quick: bool = False, init: str = "random", progress: bool = False
) -> tuple[RegimeGainPolicy, dict]:
    """The ``agnostic`` policy and a record of how it was made (see the module)."""
    integer("steps", steps, 1)
    integer("seed", seed, 0)
    if init not in INITS:
        raise ArgumentError(f"init: expected one of {', '.join(INITS)}, got {init!r}")
    with torch_threads(THREADS):
        return _train(steps, seed, QUICK_CASES if quick else CASES, init, progress)


def _start(M: int, seed: int, init: str) -> Any:
    """The factors ``(2, M, 2)`` to start from: the fixed table's (``init``), the switching table's the paper's."""
    import torch

    start = np.random.default_rng(seed).normal(size=(M, 2))
    if init == "paper":  # the paper's controller (every q = 1), perturbed off the saddle in Im q
        start = np.array([1.0, 0.0]) + NOISE * start
    elif init == "chebyshev":
        start = chebyshev_factors(M) + 1e-3 * start
    paper = np.tile([1.0, 0.0], (M, 1))
    return torch.tensor(np.stack([start, paper]), dtype=torch.float64, requires_grad=True)


def _train(
    steps: int, seed: int, spec: Sequence[tuple[dict[str, Any], int, int]], init: str, progress: bool
) -> tuple[RegimeGainPolicy, dict]:
    import torch

    config = case_config({"kind": "ring"}, 20)
    began = time.perf_counter()
    cases = draw_cases(spec, seed)
    M = (config.n_intervals + 1) // 2
    paper = factor_table(config, torch.tensor([[1.0, 0.0]] * M, dtype=torch.float64))
    with torch.no_grad():
        # the reference's error on each training episode (every interval its own): the penalty's yardstick
        cases["reference_log10"] = (log_errors(config, (paper, paper), cases) / np.log(10.0)).numpy()
    q = _start(M, seed, init)
    keep = torch.ones(M, 1, dtype=torch.float64)
    keep[: PROBES // 2] = 0.0  # the probe's intervals coast in both tables

    def tables() -> tuple[Any, Any]:
        return factor_table(config, q[0] * keep), factor_table(config, q[1] * keep)

    def loss() -> Any:
        mean_log, penalty, _ = loss_terms(config, tables(), cases)
        return mean_log + PENALTY * penalty

    def show(step: int, value: float) -> None:
        if progress:
            print(f"step {step}: loss {value:.4f} ({time.perf_counter() - began:.0f} s)", flush=True)

    curve, restarts = minimise(q, loss, steps, restarts=RESTARTS, progress=show)
    if not np.isfinite(curve[-1]):
        raise RuntimeError(f"agnostic: the loss became {curve[-1]} (seed {seed}); try another --seed")
    with torch.no_grad():
        fixed, switching = tables()
        mean_log, penalty, excess = loss_terms(config, (fixed, switching), cases)
    record = {
        "method": "L-BFGS through the exact interval map over a distribution of graphs, factor parameterisation, "
        "two tables chosen per agent by its own probe",
        "teacher": None,
        "init": {"random": "random normal factors", "paper": f"paper's factors + {NOISE} x normal"}.get(
            init, "Chebyshev design (chebyshev_factors) + 1e-3 x normal"
        )
        + " (fixed table); the paper's factors (switching table)",
        "lbfgs_restarts": restarts,
        "parameterisation": "factors",
        "probes": PROBES,
        "cases": cases["labels"],
        "held_out_rings": list(HELD_OUT_RINGS),
        "lbfgs_steps": len(curve) - 1,
        "loss_curve": [round(v, 4) for v in curve],
        "training_ring_mean_log10_error": float(mean_log) / np.log(10.0),
        "training_penalty": float(penalty),
        "training_worst_excess_decades": round(float(excess.max()), 3),
        "wall_s": round(time.perf_counter() - began, 2),
    }
    header = _header(config, spec, q.detach().numpy(), record)
    return RegimeGainPolicy(fixed.numpy().copy(), switching.numpy().copy(), header), record


def _header(config: EnvConfig, spec: Sequence[Any], factors: np.ndarray, record: dict) -> dict[str, Any]:
    """The file's header: training settings, domain (every case's environment), probe, factors, record."""
    return {
        "name": "agnostic",
        "env": training_settings(config),
        "topology": {"family": "any", "relabel": True},
        "position_range": list(TASK["position_range"]),
        "velocity_range": list(TASK["velocity_range"]),
        "domain": training_domain(*(case_config(family, n) for family, n, _ in spec)),
        "probes": PROBES,
        "factors": {"fixed": factors[0].tolist(), "switching": factors[1].tolist()},
        "training": record,
    }


def evaluate_rings(policy: RegimeGainPolicy, sizes: Sequence[int], seeds: Sequence[int]) -> list[dict[str, float]]:
    """Median ``D(T_s)/D(0)`` of ``policy`` and of the reference on the same seeded directed rings of each size.

    The policy keeps a memory per agent, so it acts on every episode's agents at once.
    """
    rows = []
    for n in sizes:
        config = task_config(n)  # one neighbour slot: the table reads any number
        policy.read_slots(config.layout.slots)
        policy.reset()
        ours = np.asarray(seeded_metrics(config, policy, seeds)["relative_deadline_error"])
        reference = run_episodes(config, ReferencePolicy, seeds)["deadline_error"]
        rows.append(comparison(n, ours, reference))
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    parser = FlagParser(prog="python -m fxc_env.training.recipes.agnostic", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="where to save the policy (.npz)")
    parser.add_argument("--quick", action="store_true", help="train for seconds (three small cases, one L-BFGS step)")
    parser.add_argument("--steps", type=int, default=None, help="L-BFGS steps of 20 iterations (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="training seed: the random start and the episodes")
    parser.add_argument(
        "--init", default="random", choices=INITS, help="start: random factors or the paper's, perturbed"
    )
    parser.add_argument("--evaluate", default=None, help="only measure the policy saved at this path")
    parser.add_argument("--seeds", type=int, default=20, help="held-out evaluation episodes (seeds 0 ..)")
    parser.add_argument("--sizes", default=None, help="ring sizes to evaluate (comma-separated; default the held-out)")
    args = parser.parse_args(argv)
    try:
        integer("--seed", args.seed, 0)
        integer("--seeds", args.seeds, 1)
        sizes = HELD_OUT_RINGS if args.sizes is None else tuple(int(s) for s in args.sizes.split(","))
    except (ArgumentError, ValueError) as exc:
        parser.error(str(exc))
    if args.evaluate is not None:
        policy = load_interval_gains(args.evaluate)
    else:
        preset = QUICK if args.quick else FULL
        steps = preset["steps"] if args.steps is None else args.steps
        try:
            policy, _ = train(steps, args.seed, args.quick, args.init, progress=True)
        except ArgumentError as exc:
            parser.error(str(exc))
        record_run(policy, "agnostic", argv, args.seed, args.out, hidden=("loss_curve", "cases"))
    if args.quick:
        sizes, args.seeds = sizes[:1], min(args.seeds, 2)
    for row in evaluate_rings(policy, sizes, range(args.seeds)):
        print(
            f"ring N = {row['n_agents']}, {row['seeds']} held-out seeds: median D(T_s)/D(0) {row['median']:.3g} "
            f"(max {row['max']:.3g}), reference {row['reference_median']:.3g}, {row['ratio']:.3g}x below"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
