"""House limit of the engine's hub: :class:`~fxc_env.engine.ConsensusEngine` wires its parts and stays small.

Its pieces live in the engine package's modules (draws, resets, observations, agents, ...); the
class itself holds at most :data:`ENGINE_CLASS_LINES` source lines, docstrings included.
"""

from __future__ import annotations

import ast
import inspect

import fxc_env.engine.consensus_engine as consensus_engine

#: Most source lines of the ConsensusEngine class statement (from ``class`` to its last line).
ENGINE_CLASS_LINES = 300


def test_consensus_engine_class_is_at_most_300_lines():
    tree = ast.parse(inspect.getsource(consensus_engine))
    (engine,) = (node for node in tree.body if isinstance(node, ast.ClassDef) and node.name == "ConsensusEngine")
    lines = engine.end_lineno - engine.lineno + 1
    assert lines <= ENGINE_CLASS_LINES, f"ConsensusEngine is {lines} lines (limit {ENGINE_CLASS_LINES})"
