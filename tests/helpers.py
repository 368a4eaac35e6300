"""Independent ground truth for the tests: the paper's numbers and hand-built matrices.

Nothing here calls the package's own linear algebra; expected values are built from
the paper's definitions (Section 2 and the proof of Theorem 1) with plain numpy so the tests can catch the package being wrong.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from fxc_env.config.tasks import TASKS

# The paper's example (Section 5).
PAPER_X0 = np.array([1.0, -1.0, 2.0, 4.0, -4.0, -2.0])
PAPER_V0 = np.array([1.0, 2.0, 3.0, -3.0, -2.0, 0.0])
PAPER_SETTLING_TIME = 20.0
PAPER_XI = np.array([1 / 4, 1 / 8, 1 / 8, 1 / 4, 1 / 8, 1 / 8])
PAPER_X_STAR = -1.875
PAPER_V_STAR = -0.125
#: The assumed Fig. 1 (docs: scenarios/paper_fig1.md's reconstruction: the paper's image is lost): 1-based pairs (j, i), "i receives from j".
PAPER_GRAPHS_ONE_BASED = [[(1, 2), (4, 5)], [(2, 3), (5, 6)], [(3, 4), (6, 1)]]
PAPER_GRAPHS = [[(j - 1, i - 1) for j, i in graph] for graph in PAPER_GRAPHS_ONE_BASED]

ACTION_MODES = ("plan", "accel")
OBS_MODES = ("normalized", "raw")
MODES = list(itertools.product(ACTION_MODES, OBS_MODES))
#: ``MODES`` as parameters: the default mode (plan, normalized) in ``make check``, the other three marked slow.
MODES_DEFAULT_FAST = [
    pytest.param(*mode, id="-".join(mode), marks=() if mode == MODES[0] else pytest.mark.slow) for mode in MODES
]


def adjacency_by_hand(n: int, edges) -> np.ndarray:
    """Dense A with ``a_ij = 1`` iff i receives from j, i.e. edge ``(j, i)``."""
    a = np.zeros((n, n))
    for j, i in edges:
        a[int(i), int(j)] = 1.0
    return a


def averaging_matrix_by_hand(n: int, edges) -> np.ndarray:
    """``W = I - (D + I)^{-1} L`` with ``L = D - A`` (the paper, after (17a)), dense."""
    a = adjacency_by_hand(n, edges)
    d = np.diag(a.sum(axis=1))
    laplacian = d - a
    return np.eye(n) - np.linalg.inv(d + np.eye(n)) @ laplacian


def left_perron_vector(matrix: np.ndarray) -> np.ndarray:
    """Left eigenvector for the eigenvalue closest to 1, scaled to sum 1 (numpy ``eig``)."""
    values, vectors = np.linalg.eig(matrix.T)
    which = int(np.argmin(np.abs(values - 1.0)))
    xi = np.real(vectors[:, which])
    return xi / xi.sum()


def brute_spread(z: np.ndarray) -> float:
    """``max_ij ||z_i - z_j||_2`` over the rows of ``z`` (N, dim), by a double loop."""
    z = np.asarray(z, dtype=float)
    z = z.reshape(len(z), -1)
    best = 0.0
    for a in z:
        for b in z:
            best = max(best, float(np.sqrt(np.sum((a - b) ** 2))))
    return best


def reachable_from(n: int, edges, root: int) -> set[int]:
    """Nodes reachable from ``root`` along edges ``j -> i`` (plain graph search)."""
    out = {k: [] for k in range(n)}
    for j, i in edges:
        out[int(j)].append(int(i))
    seen, stack = {root}, [root]
    while stack:
        node = stack.pop()
        for nxt in out[node]:
            if nxt not in seen:
                seen.add(nxt)
                stack.append(nxt)
    return seen


def has_spanning_tree(n: int, edges) -> bool:
    """Some node reaches every node (a directed spanning tree exists)."""
    return any(len(reachable_from(n, edges, r)) == n for r in range(n))


def reference_actions(policy, observations: dict) -> dict:
    """One action per agent from the reference policy on each agent's own observation."""
    return {agent: policy(obs) for agent, obs in observations.items()}


def relative_error(a: np.ndarray, b: np.ndarray) -> float:
    """``max |a - b| / max |b|`` (the scale of the reference ``b``)."""
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / np.max(np.abs(b)))


def torch_mlp_policy_file(folder, env: dict, seed: int | None = None):
    """A ``policy.pt`` in ``folder`` for a small torch MLP (obs 15 = paper_fig1's 4 slots, plan actions, widths (8,)).

    ``env`` is the recorded training environment; ``seed`` seeds the weights (None: torch's current generator).
    """
    import torch

    from fxc_env.policies.torch_policy import POLICY_FORMAT, mlp

    if seed is not None:
        torch.manual_seed(seed)
    actor = mlp(15, 2, (8,), "tanh", 1.0)
    record = {
        "format": POLICY_FORMAT,
        "obs_size": 15,
        "action_size": 2,
        "action_bound": 2.0,
        "hidden": [8],
        "activation": "tanh",
        "actor": actor.state_dict(),
        "log_std": torch.zeros(2),
        "env": env,
        "timesteps": 0,
    }
    path = folder / "policy.pt"
    torch.save(record, path)
    return path


def recorded_observations(policy_class, config, seed: int = 0) -> np.ndarray:
    """The observation stream ``(K, N, obs_size)`` of one episode that ``policy_class(config)`` itself drives
    (for the scramble tests of the laws that read only their own rows)."""
    from fxc_env.engine import ConsensusEngine

    policy = policy_class(config)
    engine = ConsensusEngine(config, n_episodes=1)
    draw = engine.draw_episode(np.random.default_rng(seed))
    engine.reset(draw.x0[None], draw.v0[None])
    stream = []
    while not engine.done:
        obs = engine.observations()[0]
        stream.append(obs)
        engine.step(np.asarray(policy(obs[None]), dtype=np.float64))
    return np.stack(stream)


def stream_actions(policy, stream) -> np.ndarray:
    """``policy``'s actions on each instant of a recorded stream, in order (its memory carried along)."""
    return np.stack([policy(obs) for obs in stream])


#: Per shipped policy (``fxc_env.policies.learned.SHIPPED``), the keywords of an environment inside its training
#: domain (other than the training one): it loads there without a warning.
SHIPPED_INSIDE = {
    "generalist": {"scenario": None, "topology": {"family": "path"}, "n_agents": 20},
    "saturated": {"scenario": "paper_fig1", "schedule": "uniform", "u_max": 100.0},  # a ring of 6, period 3
    "paper_fig1": {"scenario": "paper_fig1"},
    "rings": {"scenario": None, "topology": "ring", "n_agents": 20},
    "rings_gru": {"scenario": None, "topology": "ring", "n_agents": 20, "switching": "random"},  # one graph: no switch
    "rings_scratch": {"scenario": None, "topology": "ring", "n_agents": 20},
    "agnostic": {"scenario": None, "topology": "ring", "n_agents": 24},  # a ring size it never met
    "ppo_rings20": {"scenario": None, **TASKS["rings20-v2"].settings},  # the task it was trained on
    "diff_rings20": {"scenario": None, **TASKS["rings20-v2"].settings},
}


#: The repository root and the library's folders with the import names they install as.
ROOT = Path(__file__).resolve().parents[1]
LIBRARY_FOLDERS = {"fxc_env": "fxc_env", "baselines": "fxc_env.baselines", "training": "fxc_env.training"}


def library_modules() -> dict[str, Path]:
    """Every module and package of the library by its import name, in folder order."""
    found = {}
    for folder, package in LIBRARY_FOLDERS.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = path.relative_to(ROOT / folder).with_suffix("").parts
            parts = parts[:-1] if parts[-1] == "__init__" else parts
            found[".".join((package, *parts))] = path
    return found
