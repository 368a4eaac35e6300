"""Actors with memory or messages for the torch back end (``fxc train --backend torch --policy-arch``).

Three actor architectures share the policy file of :mod:`fxc_env.policies.torch_policy`: ``mlp``
(the default, memoryless), ``gru`` (:class:`RecurrentActor`, a GRU over the agent's own
observations and a gain head) and ``gnn`` (:class:`MessagePassingActor`, ``rounds`` rounds of
messages along the interval graph: a communication model beyond the paper's, opt-in). Docs:
training.md, "Actors with memory or messages".

Shapes: observations ``[..., obs_size]`` (float32), hidden states ``[..., gru_size]``, graphs as
:mod:`fxc_env.engine.graph_tensors` gives them (``edge_index`` ``[..., 2, E]``, ``edge_mask``
``[..., E]``, :func:`interval_graph`).
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import torch
from torch import nn

from fxc_env.core.validation import ArgumentError, choice
from fxc_env.engine.graph_tensors import graph_tensors
from fxc_env.policies.networks import ACTIVATIONS, mlp

#: ``--policy-arch`` choices.
ARCHS = ("mlp", "gru", "gnn")
#: What a ``gru`` actor's GRU reads (:class:`RecurrentActor`).
GRU_INPUTS = ("observation", "schedule")


class GainHead(nn.Module):
    """``mu = A(f) o + b(f)`` (``affine``) or ``mu = A(f) o``: ``A`` ``[action_size, inputs]`` from features ``f`` by an MLP."""

    def __init__(
        self,
        features: int,
        inputs: int,
        action_size: int,
        hidden: tuple[int, ...],
        activation: str,
        affine: bool = True,
    ) -> None:
        super().__init__()
        self.inputs, self.action_size, self.affine = inputs, action_size, affine
        self.net = mlp(features, action_size * (inputs + int(affine)), hidden, activation, 0.01)

    def forward(self, features: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        out = self.net(features).unflatten(-1, (self.action_size, self.inputs + int(self.affine)))
        mean = torch.einsum("...ao,...o->...a", out[..., : self.inputs], obs)
        return mean + out[..., self.inputs] if self.affine else mean


class RecurrentActor(nn.Module):
    """A GRU over the agent's observations and a gain head (see the module).

    Args:
        obs_size, action_size: the layout's sizes.
        hidden, activation: the gain head's hidden widths and activation.
        gru_size: the hidden state's width.
        clock_index: the observation entry holding ``k/K`` (0 at an episode's start).
        gru_input: ``observation`` (the GRU reads the whole observation; the head is affine in
            it) or ``schedule`` (the GRU reads everything but the relative rows: mask, clock,
            input-limit feature; the head is linear in the rows, ``mu_k = A(h_k) rows_k``, so the
            plan is zero at consensus and every agent with the same schedule history applies the
            same gain, as in the paper's eq. (11) and the minimum-time law).
        rows_end: where the rows end in the observation (``schedule`` only).
    """

    def __init__(
        self,
        obs_size: int,
        action_size: int,
        hidden: tuple[int, ...],
        activation: str,
        gru_size: int,
        clock_index: int,
        gru_input: str = "observation",
        rows_end: int = 0,
    ) -> None:
        super().__init__()
        choice("gru_input", gru_input, GRU_INPUTS)
        self.obs_size, self.gru_size, self.clock_index = obs_size, gru_size, clock_index
        self.gru_input, self.rows_end = gru_input, rows_end if gru_input == "schedule" else 0
        self.gru = nn.GRU(obs_size - self.rows_end, gru_size)
        affine = gru_input == "observation"
        self.head = GainHead(gru_size, obs_size if affine else rows_end, action_size, hidden, activation, affine)

    def _head(self, states: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        return self.head(states, obs if self.gru_input == "observation" else obs[..., : self.rows_end])

    def initial_state(self, shape: tuple[int, ...], device: Any = None) -> torch.Tensor:
        """Zeros ``[*shape, gru_size]`` (float32)."""
        return torch.zeros((*shape, self.gru_size), dtype=torch.float32, device=device)

    def _starts(self, obs: torch.Tensor) -> torch.Tensor:
        return obs[..., self.clock_index : self.clock_index + 1] == 0

    def step(self, obs: torch.Tensor, hidden: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Means ``[..., action_size]`` and the next hidden state for observations ``[..., obs_size]``.

        The hidden state ``[..., gru_size]`` is zeroed first where ``obs[..., clock_index] == 0``.
        """
        hidden = torch.where(self._starts(obs), torch.zeros_like(hidden), hidden)
        shape = obs.shape[:-1]
        read = obs[..., self.rows_end :].reshape(1, -1, self.obs_size - self.rows_end)
        _, new = self.gru(read, hidden.reshape(1, -1, self.gru_size))
        new = new.reshape(*shape, self.gru_size)
        return self._head(new, obs), new

    def sequence(self, obs: torch.Tensor, hidden: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Means ``[T, ..., action_size]`` over a sequence ``[T, ..., obs_size]`` from ``hidden`` ``[..., gru_size]``.

        The same as :meth:`step` T times (memories reset where the clock reads k = 0), with the GRU
        run over each stretch between resets in one call and the head applied to all T steps at once.
        """
        steps, shape = obs.shape[0], obs.shape[1:-1]
        flat = obs.reshape(steps, -1, self.obs_size)
        read = flat[..., self.rows_end :]
        memory = hidden.reshape(1, -1, self.gru_size)
        starts = self._starts(flat)  # [T, M, 1]
        cuts = [0, *(int(t) for t in torch.nonzero(starts.any(dim=1).reshape(-1)).reshape(-1) if t > 0), steps]
        outputs = []
        for begin, end in itertools.pairwise(cuts):
            if begin == end:
                continue
            memory = torch.where(starts[begin][None], torch.zeros_like(memory), memory)
            out, memory = self.gru(read[begin:end], memory)
            outputs.append(out)
        states = torch.cat(outputs).reshape(steps, *shape, self.gru_size)
        return self._head(states, obs), memory.reshape(*shape, self.gru_size)


class MessagePassingActor(nn.Module):
    """Embeddings, ``rounds`` rounds of messages along the interval graph, and a gain head (see the module).

    Args:
        obs_size, action_size: the layout's sizes.
        hidden, activation: the gain head's hidden widths and the activation everywhere.
        embed_size: the embedding's width.
        rounds: message rounds (each reaches one hop further upstream).
    """

    def __init__(
        self, obs_size: int, action_size: int, hidden: tuple[int, ...], activation: str, embed_size: int, rounds: int
    ) -> None:
        super().__init__()
        self.obs_size, self.embed_size, self.rounds = obs_size, embed_size, rounds
        self.embed = nn.Linear(obs_size, embed_size)
        self.own = nn.ModuleList(nn.Linear(embed_size, embed_size) for _ in range(rounds))
        self.message = nn.ModuleList(nn.Linear(embed_size, embed_size, bias=False) for _ in range(rounds))
        for layer in [self.embed, *self.own, *self.message]:
            nn.init.orthogonal_(layer.weight, math.sqrt(2.0))
            if layer.bias is not None:
                nn.init.zeros_(layer.bias)
        self.activation = ACTIVATIONS[activation]()
        self.head = GainHead(embed_size, obs_size, action_size, hidden, activation)

    def forward(self, obs: torch.Tensor, edge_index: torch.Tensor, edge_mask: torch.Tensor) -> torch.Tensor:
        """Means ``[..., N, action_size]`` of observations ``[..., N, obs_size]`` on the interval graph.

        ``edge_index`` ``[..., 2, E]`` (row 0 the source j, row 1 the target i, agents of the same
        episode) and ``edge_mask`` ``[..., E]`` (True for an edge), as
        :func:`fxc_env.engine.graph_tensors.graph_tensors` gives them; leading dimensions broadcast
        to ``obs``'s. Each round is a scatter-add over the edges (``index_add_``).
        """
        n, lead, width = obs.shape[-2], obs.shape[:-2], edge_index.shape[-1]
        edge_index = torch.broadcast_to(edge_index, (*lead, 2, width)).reshape(-1, 2, width)
        weight = torch.broadcast_to(edge_mask, (*lead, width)).reshape(-1).to(obs.dtype)
        graphs = edge_index.shape[0]
        # N + 1 node rows per graph: padding is the edge N -> N (graph_tensors), into a row dropped at the end.
        offset = (torch.arange(graphs, device=obs.device) * (n + 1))[:, None]
        source = (edge_index[:, 0] + offset).reshape(-1)
        target = (edge_index[:, 1] + offset).reshape(-1)
        nodes = graphs * (n + 1)
        degree = torch.zeros(nodes, dtype=obs.dtype, device=obs.device).index_add_(0, target, weight)
        scale = (1.0 / (degree + 1.0))[:, None]
        features = self.activation(self.embed(obs.reshape(graphs, n, self.obs_size)))
        features = torch.cat([features, features.new_zeros(graphs, 1, self.embed_size)], dim=1).reshape(nodes, -1)
        for own, message in zip(self.own, self.message, strict=True):
            sent = message(features)[source] * weight[:, None]
            received = torch.zeros_like(features).index_add_(0, target, sent)
            features = self.activation(own(features) + scale * received)
        features = features.reshape(graphs, n + 1, self.embed_size)[:, :n]
        return self.head(features.reshape(*lead, n, self.embed_size), obs)


def interval_graph(engine: Any, observations: Any = None, width: int | None = None) -> tuple[Any, Any]:
    """``(edge_index, edge_mask)`` of each episode's coming interval, ``[B, 2, E]`` and ``[B, E]``, torch.

    :func:`fxc_env.engine.graph_tensors.graph_tensors` (links lost to ``link_dropout`` left out);
    ``width`` pads ``E`` (:func:`~fxc_env.engine.graph_tensors.edge_capacity` keeps it fixed).
    """
    tensors = graph_tensors(engine, observations, width)
    return torch.as_tensor(tensors.edge_index), torch.as_tensor(tensors.edge_mask)


def build_actor(record: dict[str, Any], obs_size: int, action_size: int, out_gain: float = 1.0) -> nn.Module:
    """The actor a policy record's ``arch`` describes (``mlp``, ``gru``, ``gnn``); raise naming ``arch`` otherwise.

    ``out_gain``: the ``mlp``'s orthogonal gain of its output layer (a new actor's; a loaded one's weights replace it).
    """
    arch = str(record.get("arch", "mlp"))
    hidden = tuple(int(w) for w in record["hidden"])
    activation = str(record["activation"])
    if arch == "mlp":
        return mlp(obs_size, action_size, hidden, activation, out_gain)
    if arch == "gru":
        return RecurrentActor(
            obs_size,
            action_size,
            hidden,
            activation,
            int(record["gru_size"]),
            int(record["clock_index"]),
            str(record.get("gru_input", "observation")),
            int(record.get("rows_end", 0)),
        )
    if arch == "gnn":
        return MessagePassingActor(
            obs_size, action_size, hidden, activation, int(record["embed_size"]), int(record["rounds"])
        )
    raise ArgumentError(f"arch: expected one of {ARCHS}, got {arch!r}")
