"""Behaviour cloning (DAgger) of the minimum-time law into a recurrent policy for directed rings.

The task is :mod:`fxc_env.training.recipes.rings`'s with ``action_bound = 20`` (the teacher's plans reach 14.2).
**Teacher:** the minimum-time law (:mod:`fxc_env.baselines.laws.minimum_time`), designed per episode from the drawn
ring. **Student:** the ``gru`` actor (:class:`fxc_env.policies.torch_memory.RecurrentActor`); with
``gru_input="schedule"`` (the default) the GRU reads ``[mask, t_k/T_s, T_{k+1}/T_s, k/K]`` and the plan is
linear in the measured row, ``mu_k = A(h_k) [(x_j - x_i)/s_i, T_{k+1} (v_j - v_i)/s_i]``; it is not told N or
the spectrum. Round 0 clones the teacher's plans (Adam on whole episodes), then :func:`polish` solves the gain
head's last layer by least squares; ``--rounds r`` adds DAgger rounds. Float32 networks, float64 episodes.
Commands and results: (docs: results.md, "Memory and message passing").
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from fxc_env.baselines.registry import LAWS
from fxc_env.config import EnvConfig, make_config
from fxc_env.config.argument_types import FlagParser
from fxc_env.core.validation import ArgumentError, integer
from fxc_env.policies.domain import training_domain
from fxc_env.policies.protocol import seeded_engine
from fxc_env.policies.reference import ReferencePolicy
from fxc_env.policies.torch_memory import RecurrentActor
from fxc_env.policies.torch_policy import POLICY_FORMAT, TorchPolicy, load_torch_policy
from fxc_env.training.recipes import rings

#: The task (keywords of :func:`fxc_env.make_config`, ``n_agents`` and ``topology`` aside).
TASK: dict[str, Any] = {**rings.TASK, "action_bound": 20.0}
#: Seeds of the demonstration episodes (disjoint from the evaluation seeds 0-19).
DEMONSTRATION_SEED = 10_000


def task_config(n_agents: int = 20) -> EnvConfig:
    """Directed rings of ``n_agents``, relabelled per episode (:data:`TASK`)."""
    return make_config(None, **{**TASK, "n_agents": n_agents, "topology": {"family": "ring"}})


def env_record(n_agents: int) -> dict[str, Any]:
    """The policy file's ``env``: keywords that rebuild the task (tuples as lists, for ``weights_only``)."""
    kwargs = {k: list(v) if isinstance(v, tuple) else v for k, v in TASK.items()}
    return {"scenario": None, **kwargs, "n_agents": n_agents, "topology": {"family": "ring"}}


# ------------------------------------------------------------------------------------ episodes
def play(config: EnvConfig, seeds: Sequence[int], student: Any = None, label: bool = True) -> dict[str, np.ndarray]:
    """Seeded episodes played by ``student`` (a callable on ``[B, N, obs]``, stateful), or the teacher if None.

    Returns ``deadline_error`` ``(B,)`` (inf for every episode when a diverging student overflows float64) and,
    with ``label``, the observations ``(K, B, N, obs_size)`` and the teacher's plans ``(K, B, N, 2)``.
    """
    engine, draws = seeded_engine(config, seeds)
    teachers = []
    if label or student is None:
        teachers = [
            LAWS["minimum_time"].policy(
                make_config(None, **{**TASK, "n_agents": config.n_agents, "topology": d.topology})
            )
            for d in draws
        ]
    observations, targets = [], []
    while not engine.done:
        obs = np.asarray(engine.observations())
        teacher = np.stack([policy(obs[b]) for b, policy in enumerate(teachers)]) if teachers else None
        act = teacher if student is None else np.asarray(student(obs), dtype=np.float64)
        if label:
            observations.append(obs.copy())
            targets.append(teacher)
        try:
            engine.step(act)
        except ArgumentError:  # a diverging student: the step would overflow float64 (the engine refuses it)
            return {"deadline_error": np.full(len(seeds), np.inf)}
    out = {"deadline_error": np.asarray(engine.batch_metrics()["relative_deadline_error"])}
    if label:
        out["observations"], out["targets"] = np.array(observations), np.array(targets)
    return out


class StudentPolicy:
    """A :class:`RecurrentActor` in training, acting on ``[B, N, obs]`` numpy observations (memory carried)."""

    def __init__(self, actor: RecurrentActor, bound: float) -> None:
        self.actor, self.bound, self.hidden = actor, bound, None

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        x = torch.as_tensor(obs, dtype=torch.float32)
        if self.hidden is None or self.hidden.shape[:-1] != x.shape[:-1]:
            self.hidden = self.actor.initial_state(tuple(x.shape[:-1]))
        with torch.no_grad():
            mean, self.hidden = self.actor.step(x, self.hidden)
        return mean.clamp(-self.bound, self.bound).double().numpy()


# ------------------------------------------------------------------------------------ training
def fit(
    actor: RecurrentActor,
    optimiser: torch.optim.Optimizer,
    observations: torch.Tensor,
    targets: torch.Tensor,
    steps: int,
    batch: int,
    generator: torch.Generator,
) -> list[float]:
    """``steps`` Adam steps on the MSE of whole sequences ``[K, M, obs]`` against plans ``[K, M, 2]``; the losses."""
    losses = []
    m = observations.shape[1]
    for _ in range(steps):
        index = torch.randint(m, (min(batch, m),), generator=generator)
        mean, _ = actor.sequence(observations[:, index], actor.initial_state((len(index),)))
        loss = torch.mean((mean - targets[:, index]) ** 2)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(actor.parameters(), 1.0)
        optimiser.step()
        losses.append(float(loss.detach()))
    return losses


def polish(actor: RecurrentActor, observations: torch.Tensor, targets: torch.Tensor, sequences: int = 256) -> float:
    """Least squares for the gain head's last layer given the features before it; the RMS residual after.

    The plan ``mu_a = sum_o rows_o (W_(a,o) . phi(h) + c_(a,o))`` is linear in ``(W, c)``: one float64
    least-squares problem per action component over ``sequences`` of the data.
    """
    if actor.gru_input != "schedule":
        raise ArgumentError("polish: only the schedule form's head is linear in its rows")
    net = actor.head.net
    last = net[-1]
    m = observations.shape[1]
    index = torch.linspace(0, m - 1, min(sequences, m)).round().long()
    with torch.no_grad():
        obs = observations[:, index]
        hidden_states = []
        memory = actor.initial_state((len(index),))
        for t in range(obs.shape[0]):
            _, memory = actor.step(obs[t], memory)
            hidden_states.append(memory)
        features = net[:-1](torch.stack(hidden_states)).double()  # [K, M', F]
        features = torch.cat([features, torch.ones_like(features[..., :1])], dim=-1)
        rows = obs[..., : actor.rows_end].double()  # [K, M', R]
        design = (rows[..., :, None] * features[..., None, :]).reshape(-1, rows.shape[-1] * features.shape[-1])
        wanted = targets[:, index].double().reshape(-1, targets.shape[-1])
        solution = torch.linalg.lstsq(design, wanted, rcond=1e-12, driver="gelsd").solution  # [R * (F + 1), A]
        residual = float(torch.sqrt(torch.mean((design @ solution - wanted) ** 2)))
        r, f = rows.shape[-1], features.shape[-1]
        coefficients = solution.T.reshape(-1, r, f)  # [A, R, F + 1]: output unit (a, o) of the last layer
        last.weight.copy_(coefficients[..., :-1].reshape(-1, f - 1).to(last.weight.dtype))
        last.bias.copy_(coefficients[..., -1].reshape(-1).to(last.bias.dtype))
    return residual


def train(
    sizes: Sequence[int] = (20,),
    rounds: int = 0,
    episodes: int = 8,
    steps: int = 600,
    batch: int = 32,
    lr: float = 3e-3,
    gru_size: int = 64,
    hidden: tuple[int, ...] = (64,),
    seed: int = 0,
    gru_input: str = "schedule",
    log: Any = print,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The student's policy record (:mod:`fxc_env.policies.torch_policy`'s format) and how it was made."""
    torch.manual_seed(seed)
    configs = [task_config(n) for n in sizes]
    layout = configs[0].layout
    clock_index = layout.clock_end - 1
    actor = RecurrentActor(
        layout.size, configs[0].action_size, hidden, "tanh", gru_size, clock_index, gru_input, layout.rows_end
    )
    optimiser = torch.optim.Adam(actor.parameters(), lr=lr)
    generator = torch.Generator().manual_seed(seed)
    bound = float(TASK["action_bound"])
    data_obs, data_targets = [], []  # every round's demonstrations, sequences along dim 1
    record: dict[str, Any] = {"sizes": list(sizes), "rounds": rounds, "episodes": episodes, "steps": steps}
    began = time.perf_counter()
    next_seed = DEMONSTRATION_SEED + 1000 * seed
    for r in range(rounds + 1):
        student = None if r == 0 else StudentPolicy(actor, bound)
        errors = []
        for config in configs:
            seeds = range(next_seed, next_seed + episodes)
            next_seed += episodes
            played = play(config, seeds, student)
            errors.append(float(np.median(played["deadline_error"])))
            k, b, n, size = played["observations"].shape
            data_obs.append(torch.as_tensor(played["observations"].reshape(k, b * n, size), dtype=torch.float32))
            data_targets.append(torch.as_tensor(played["targets"].reshape(k, b * n, -1), dtype=torch.float32))
        observations, targets = torch.cat(data_obs, dim=1), torch.cat(data_targets, dim=1)
        for group in optimiser.param_groups:
            group["lr"] = lr * (0.5**r)
        losses = fit(actor, optimiser, observations, targets, steps, batch, generator)
        polished = polish(actor, observations, targets) if gru_input == "schedule" else None
        who, last_mse = ("teacher" if r == 0 else "student"), float(np.mean(losses[-20:]))
        log(
            f"round {r}: {who} played {len(sizes) * episodes} episodes (median D(T_s)/D(0) per size "
            f"{', '.join(f'{e:.3g}' for e in errors)}); {observations.shape[1]} sequences; "
            f"MSE {losses[0]:.3g} -> {last_mse:.3g}"
            + ("" if polished is None else f", last layer by least squares: RMS {polished:.3g}")
            + f" ({time.perf_counter() - began:.0f} s)"
        )
        record[f"round_{r}"] = {"player": who, "median_deadline_error": errors, "last_mse": last_mse}
    record["wall_s"] = round(time.perf_counter() - began, 1)
    policy = _policy_record(actor, configs, sizes, hidden, gru_size, gru_input, bound)
    policy["imitation"] = json.dumps(record)
    return policy, record


def _policy_record(
    actor: Any,
    configs: list,
    sizes: Sequence[int],
    hidden: tuple[int, ...],
    gru_size: int,
    gru_input: str,
    bound: float,
) -> dict[str, Any]:
    """The trained ``actor``'s policy record, as ``fxc train --backend torch`` writes one for a ``gru``."""
    layout = configs[0].layout
    clock_index = layout.clock_end - 1
    return {
        "format": POLICY_FORMAT,
        "arch": "gru",
        "obs_size": layout.size,
        "action_size": configs[0].action_size,
        "action_bound": bound,
        "hidden": list(hidden),
        "activation": "tanh",
        "gru_size": gru_size,
        "clock_index": clock_index,
        "gru_input": gru_input,
        "rows_end": layout.rows_end,
        "actor": {k: v.detach().clone() for k, v in actor.state_dict().items()},
        "log_std": torch.full((configs[0].action_size,), -3.0),
        "env": env_record(int(sizes[0])),
        "domain": training_domain(*configs),
        "timesteps": 0,
    }


# ---------------------------------------------------------------------------------- evaluation
def evaluate(policy: TorchPolicy, n_agents: int = 20, seeds: Sequence[int] = range(20)) -> dict[str, float]:
    """Median ``D(T_s)/D(0)`` of ``policy`` and of the reference on the same seeded rings (as ``rings.evaluate``).

    The policy plays the whole batch ``[B, N, obs]`` at once, its memory carried across the steps of
    the episodes and reset at their start (the clock's ``k = 0``).
    """
    config = task_config(n_agents)
    policy.reset()
    ours = play(config, seeds, policy, label=False)["deadline_error"]
    reference = rings.run_episodes(rings.task_config(n_agents), ReferencePolicy, seeds)["deadline_error"]
    return rings.comparison(n_agents, ours, reference)


def _parser() -> argparse.ArgumentParser:
    parser = FlagParser(
        prog="python -m fxc_env.training.recipes.recurrent_imitation", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--out", default=None, help="run directory to write policy.pt into")
    parser.add_argument("--sizes", default="20", help="comma-separated ring sizes to train on")
    parser.add_argument("--rounds", type=int, default=0, help="DAgger rounds after the teacher's")
    parser.add_argument("--episodes", type=int, default=8, help="episodes per size and round")
    parser.add_argument("--steps", type=int, default=600, help="Adam steps per round")
    parser.add_argument("--batch", type=int, default=32, help="sequences per Adam step")
    parser.add_argument("--lr", type=float, default=3e-3, help="Adam's learning rate (halved each round)")
    parser.add_argument("--gru-size", type=int, default=64, help="width of the GRU's hidden state")
    parser.add_argument("--seed", type=int, default=0, help="seeds the weights, batches and demonstrations")
    parser.add_argument(
        "--gru-input",
        default="schedule",
        choices=("schedule", "observation"),
        help="what the GRU reads: the mask and clock (the head is then linear in the rows) or the whole observation",
    )
    parser.add_argument("--torch-threads", type=int, default=1, help="threads torch may use")
    parser.add_argument("--evaluate", default=None, help="only measure the policy saved at this path")
    parser.add_argument("--n-agents", default="20", help="comma-separated ring sizes to measure on")
    parser.add_argument("--seeds", type=int, default=20, help="evaluation episodes (seeds 0 ..)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    for flag in ("rounds", "episodes", "steps", "batch", "gru_size", "seeds", "torch_threads"):
        integer("--" + flag.replace("_", "-"), getattr(args, flag), 0 if flag == "rounds" else 1)
    torch.set_num_threads(args.torch_threads)
    try:
        sizes = tuple(int(n) for n in args.sizes.split(","))
        measure = tuple(int(n) for n in args.n_agents.split(","))
    except ValueError as exc:
        raise ArgumentError(f"--sizes/--n-agents: expected comma-separated integers ({exc})") from exc
    if args.evaluate is not None:
        policy = load_torch_policy(args.evaluate)
    else:
        settings = ("rounds", "episodes", "steps", "batch", "lr", "gru_size", "seed", "gru_input")
        record_policy, _ = train(sizes, **{name: getattr(args, name) for name in settings})
        info = json.loads(record_policy["imitation"])
        info["command"] = "python -m fxc_env.training.recipes.recurrent_imitation " + " ".join(sys.argv[1:])
        record_policy["imitation"] = json.dumps(info)
        if args.out:
            out = Path(args.out)
            out.mkdir(parents=True, exist_ok=True)
            torch.save(record_policy, out / "policy.pt")
            print("wrote", out / "policy.pt")
        policy = TorchPolicy(record_policy)
    for n in measure:
        print(rings.comparison_line("gru rings", evaluate(policy, n, range(args.seeds))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
