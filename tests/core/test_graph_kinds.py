"""The graph kinds are one table (fxc_env.core.graph_kinds.GRAPH_KINDS): the names, the families and their keys, the
flags and the training-domain check read it, and each entry's parts agree with each other."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from fxc_env.config import flags
from fxc_env.core import families, graphs
from fxc_env.core.graph_kinds import FAMILY_KEYS, FAMILY_KINDS, GRAPH_KINDS, TOPOLOGY_NAMES, union_kind
from fxc_env.core.validation import ArgumentError
from fxc_env.policies import domain, records

STRUCTURED = [name for name, kind in GRAPH_KINDS.items() if kind.edges is not None]


def test_the_names_families_and_keys_are_read_from_the_table():
    assert TOPOLOGY_NAMES == tuple(GRAPH_KINDS) == ("paper_fig1", "ring", "path", "star", "complete", "random")
    assert graphs.TOPOLOGY_NAMES is TOPOLOGY_NAMES and families.FAMILY_KINDS is FAMILY_KINDS is records.FAMILY_KINDS
    assert FAMILY_KINDS == ("ring", "path", "star", "complete", "random") and families.FAMILY_KEYS is FAMILY_KEYS
    assert FAMILY_KEYS["random"] == ("mean_in_degree", "period") and FAMILY_KEYS["complete"] == ("period",)
    parser = argparse.ArgumentParser()
    flags.add_env_arguments(parser)
    choices = next(a.choices for a in parser._actions if "--family" in a.option_strings)
    assert tuple(choices) == FAMILY_KINDS


@pytest.mark.parametrize("name", STRUCTURED)
@pytest.mark.parametrize("n_agents", [2, 3, 7, 12])
def test_each_structured_kind_is_recognised_in_any_labelling_and_bounds_its_in_degree(name, n_agents):
    topology = graphs.named_topology(name, n_agents)
    np.testing.assert_array_equal(graphs.structured_edges(name, n_agents), GRAPH_KINDS[name].edges(np.arange(n_agents)))
    family = families.TopologyFamily(name)
    draw = family.draw(n_agents, np.random.default_rng(1))
    if n_agents > 3:  # on fewer agents some kinds are one graph (a ring of 3 or less is complete, a star of 2 a path)
        assert domain.union_kind(topology) == domain.union_kind(draw) == name
    assert max(int(d.max()) for d in draw.in_degree) == family.max_in_degree(n_agents)


def test_a_kind_without_mean_in_degree_refuses_the_flag_naming_the_kinds_that_take_it():
    parser = argparse.ArgumentParser()
    flags.add_env_arguments(parser)
    args = parser.parse_args(["--family", "ring", "--mean-in-degree", "2"])
    with pytest.raises(ArgumentError, match=r"^--mean-in-degree: shapes --family random only, got --family ring"):
        flags.env_kwargs_from(args)


def test_a_domain_record_of_a_kind_takes_the_keys_the_table_gives_it():
    with pytest.raises(ArgumentError, match=r"graphs\[0\]: a 'ring' entry holds \['family', 'period'\]"):
        records._check_graph("graphs[0]", {"family": "ring", "period": [1, 1], "mean_in_degree": [2.0, 2.0]})
    records._check_graph("graphs[0]", {"family": "random", "period": [1, 1], "mean_in_degree": [2.0, 2.0]})
    assert union_kind(np.array([1]), np.array([1]), 0) == "another graph"
