"""Named scenarios: bundles of environment keyword arguments.

``parallel_env(scenario="paper_fig1")`` is the paper's example (Section 5): six agents, its
initial state, ``T_s = 20`` s and the **assumed** Fig. 1 switching set (the figure is lost;
docs: scenarios/paper_fig1.md gives our reconstruction). Keyword arguments given next to ``scenario`` override it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

from fxc_env.core.families import make_family
from fxc_env.core.validation import ArgumentError

PAPER_X0 = (1.0, -1.0, 2.0, 4.0, -4.0, -2.0)
PAPER_V0 = (1.0, 2.0, 3.0, -3.0, -2.0, 0.0)

#: A regular hexagon of radius 3 m (positions in the plane): the offsets of ``formation_hexagon``.
HEXAGON = tuple((3.0 * math.cos(math.pi * i / 3), 3.0 * math.sin(math.pi * i / 3)) for i in range(6))
#: Twenty agents on a line 1 m apart, centred (positions in the plane): the offsets of ``formation_line``.
LINE = tuple((i - 9.5, 0.0) for i in range(20))

_PRESETS: dict[str, dict[str, Any]] = {
    # The paper's example with the assumed Fig. 1 (periodic switching, Theorem 2).
    "paper_fig1": {
        "n_agents": 6,
        "topology": "paper_fig1",
        "settling_time": 20.0,
        "initial_state": (PAPER_X0, PAPER_V0),
    },
    # The paper's initial state on a fixed directed 6-ring (Theorem 1).
    "ring_6": {
        "n_agents": 6,
        "topology": "ring",
        "settling_time": 20.0,
        "initial_state": (PAPER_X0, PAPER_V0),
    },
    # Twenty agents in the plane on seeded random switching digraphs (period 3).
    "random_20_planar": {
        "n_agents": 20,
        "topology": "random",
        "topology_period": 3,
        "mean_in_degree": 2.0,
        "dim": 2,
        "settling_time": 20.0,
    },
    # A new graph every episode (training a policy that generalises): rings, paths, stars and
    # random digraphs on 20 agents, fixed or switching with periods up to 4, initial
    # states across two decades of scale. 4 observation slots hold every draw.
    "generalist": {
        "n_agents": 20,
        "topology": make_family(
            {
                "mixture": [
                    ({"family": "ring", "period": (1, 4)}, 1.0),
                    ({"family": "path", "period": (1, 2)}, 0.5),
                    ({"family": "star", "period": (1, 2)}, 0.5),
                    ({"family": "random", "mean_in_degree": (1.5, 3.0), "period": (1, 4)}, 2.0),
                ],
                "name": "generalist",
            }
        ),
        "obs_slots": 4,
        "position_range": (0.5, 50.0),
        "velocity_range": (0.2, 20.0),
    },
    # Bounded inputs (training a policy that sees its limit): six agents on switching rings
    # (the class of the assumed Fig. 1) and random digraphs, u_max drawn from {10, 100, 1000},
    # on the uniform schedule (T_s / K each): under a limit the paper's last, shortest
    # intervals cannot be used, while K equal intervals keep every one usable.
    "saturated": {
        "schedule": "uniform",
        "n_agents": 6,
        "topology": make_family(
            {
                "mixture": [
                    ({"family": "ring", "period": (1, 3)}, 1.0),
                    ({"family": "random", "mean_in_degree": (1.0, 2.5), "period": (1, 3)}, 1.0),
                ],
                "name": "saturated",
            }
        ),
        "obs_slots": 4,
        "u_max": (10.0, 100.0, 1000.0),
    },
    # Formation flying (the paper's introduction): six agents in the plane take a regular
    # hexagon (radius 3 m) by T_s on the assumed Fig. 1's switching graphs: they agree on
    # x_i - h_i, so the formation keeps moving with the common velocity.
    "formation_hexagon": {
        "n_agents": 6,
        "topology": "paper_fig1",
        "settling_time": 20.0,
        "dim": 2,
        "formation_offsets": HEXAGON,
    },
    # Twenty agents in the plane line up 1 m apart on a seeded random digraph (mean in-degree 2).
    "formation_line": {
        "n_agents": 20,
        "topology": "random",
        "mean_in_degree": 2.0,
        "settling_time": 20.0,
        "dim": 2,
        "formation_offsets": LINE,
    },
}


#: The named presets, read-only: ``make_config`` copies one and lets explicit arguments override it.
SCENARIOS: Mapping[str, Mapping[str, Any]] = MappingProxyType(
    {name: MappingProxyType(preset) for name, preset in _PRESETS.items()}
)


def scenario_preset(name: str | None) -> dict[str, Any]:
    """A fresh dict of scenario ``name``'s keyword arguments (empty for ``None``)."""
    if name is None:
        return {}
    if not isinstance(name, str) or name not in SCENARIOS:
        raise ArgumentError(f"scenario: expected None or one of {tuple(SCENARIOS)}, got {name!r}")
    return dict(SCENARIOS[name])
