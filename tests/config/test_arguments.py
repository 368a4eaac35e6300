"""The arguments' table (docs: environment.md, "The environment"): every signature, card, check and flag agrees with it."""

from __future__ import annotations

import argparse
import inspect
import pydoc

import numpy as np
import pytest

import fxc_env
from fxc_env import SCENARIOS, make_config
from fxc_env.config.arguments import (
    ARGUMENTS,
    ENV_ARGUMENTS,
    FRONT_END_ARGUMENTS,
    GRAPH_TENSORS,
    NO_FALLBACK,
    TABLE_MARKER,
    EnvKwargs,
    with_arguments_table,
)
from fxc_env.config.flags import FLAG_ARGUMENTS, MODEL_FLAGS, add_env_arguments, env_kwargs_from
from fxc_env.core import validation
from fxc_env.core.models import DEFAULT_DAMPING, DEFAULT_FREQUENCY, FLAT_PARAMETERS
from fxc_env.core.validation import ArgumentError
from fxc_env.envs.aec import ConsensusAECEnv
from fxc_env.envs.parallel import ConsensusParallelEnv
from fxc_env.envs.torch_env import TORCH_ARGUMENTS, ConsensusTorchEnv
from fxc_env.envs.vec_env import N_ENVS, ConsensusVecEnv

P = inspect.Parameter

#: Each front end: what it takes before the environment's arguments, and after them.
FRONT_ENDS = {
    "make_config": (make_config, (), ()),
    "ConsensusParallelEnv": (ConsensusParallelEnv, (), (*FRONT_END_ARGUMENTS, GRAPH_TENSORS)),
    "parallel_env": (fxc_env.parallel_env, (), (*FRONT_END_ARGUMENTS, GRAPH_TENSORS)),
    "ConsensusAECEnv": (ConsensusAECEnv, (), (*FRONT_END_ARGUMENTS, GRAPH_TENSORS)),
    "env": (fxc_env.env, (), (*FRONT_END_ARGUMENTS, GRAPH_TENSORS)),
    "raw_env": (fxc_env.raw_env, (), (*FRONT_END_ARGUMENTS, GRAPH_TENSORS)),
    "ConsensusVecEnv": (ConsensusVecEnv, (N_ENVS,), FRONT_END_ARGUMENTS),
    "ConsensusTorchEnv": (ConsensusTorchEnv, TORCH_ARGUMENTS, ()),
}

#: The environment flags of ``fxc simulate`` and ``fxc evaluate`` (scripts and the docs use them).
DOCUMENTED_FLAGS = {
    "--scenario",
    "--topology",
    "--family",
    "--n-agents",
    "--n-intervals",
    "--settling-time",
    "--schedule",
    "--dim",
    "--action-mode",
    "--obs-mode",
    "--topology-seed",
    "--mean-in-degree",
    "--topology-period",
    "--obs-slots",
    "--position-range",
    "--velocity-range",
    "--u-max",
    "--obs-noise",
    "--obs-resolution",
    "--link-dropout",
    "--switching",
    "--agent-model",
    "--order",
    "--damping",
    "--frequency",
}


# ------------------------------------------------------------------ signatures


@pytest.mark.parametrize("name", FRONT_ENDS)
def test_every_signature_lists_the_table_in_order_with_its_defaults_and_types(name):
    factory, before, after = FRONT_ENDS[name]
    parameters = inspect.signature(factory).parameters
    expected = [*before, *ENV_ARGUMENTS, *after]
    assert list(parameters) == [argument.name for argument in expected]
    for argument in expected:
        parameter = parameters[argument.name]
        assert parameter.default is argument.default or parameter.default == argument.default, argument.name
        assert parameter.annotation == argument.annotation, argument.name
    assert all(p.kind in (P.POSITIONAL_OR_KEYWORD, P.KEYWORD_ONLY) for p in parameters.values())
    # scenario is positional where it comes first; the others are keyword-only.
    positional = [n for n, p in parameters.items() if p.kind is P.POSITIONAL_OR_KEYWORD]
    assert positional == [argument.name for argument in expected[:1] if argument.name in ("scenario", "n_envs")]


def test_the_typed_keywords_of_the_front_ends_are_the_table():
    # Front ends take **kwargs: Unpack[EnvKwargs]: what type checkers and IDEs read must be the table's.
    annotations = {name: value.__forward_arg__ for name, value in EnvKwargs.__annotations__.items()}
    assert annotations == {argument.name: argument.annotation for argument in ENV_ARGUMENTS[1:]}
    assert EnvKwargs.__total__ is False


@pytest.mark.parametrize("name", list(FRONT_ENDS))
def test_an_unknown_keyword_is_refused_naming_it(name):
    factory = FRONT_ENDS[name][0]
    required = {"n_envs": 1} if name == "ConsensusVecEnv" else {}
    with pytest.raises(TypeError, match=r"^n_agent: not an argument of the environment; expected one of scenario, "):
        factory(**required, n_agent=4)


def test_the_torchrl_env_shows_its_arguments_in_help():
    text = pydoc.render_doc(ConsensusTorchEnv, renderer=pydoc.plaintext)
    signature = str(inspect.signature(ConsensusTorchEnv))
    for argument in (*TORCH_ARGUMENTS, *ENV_ARGUMENTS):
        assert f"{argument.name}:" in signature and f"``{argument.name}``" in text, argument.name


# ------------------------------------------------------------------ cards


@pytest.mark.parametrize("name", ["ConsensusParallelEnv", "ConsensusAECEnv", "ConsensusVecEnv", "ConsensusTorchEnv"])
def test_each_card_has_the_table_row_of_every_argument_it_takes(name):
    factory, before, after = FRONT_ENDS[name]
    card = inspect.getdoc(factory)
    for argument in (*before, *ENV_ARGUMENTS, *after):
        assert card.count(argument.card_row) == 1, argument.name
    assert card.count("| parameter | type | default | meaning |") == 1
    assert TABLE_MARKER not in card


def test_card_rows_show_choices_and_bracket_the_scenario_s_values():
    assert ARGUMENTS["action_mode"].card_row.startswith(
        '| ``action_mode`` | ``"plan" \\| "plan_balanced" \\| "accel" \\| "residual"`` | ``"plan"`` |'
    )
    assert ARGUMENTS["settling_time"].card_row.startswith("| ``settling_time`` | ``float \\| None`` | [20.0] |")
    assert ARGUMENTS["render_mode"].card_row.startswith('| ``render_mode`` | ``None \\| "human" \\| "rgb_array"`` |')


def test_a_card_without_the_marker_is_refused():
    with pytest.raises(ValueError, match="arguments table"):
        with_arguments_table("no table here", ENV_ARGUMENTS)


# ------------------------------------------------------------------ make_config reads the table


def test_make_config_falls_back_to_the_table_without_a_scenario():
    c = make_config()
    fallback = {argument.name: argument.fallback for argument in ENV_ARGUMENTS}
    assert c.topology.name == fallback["topology"] and c.n_agents == fallback["n_agents"]
    assert c.settling_time == fallback["settling_time"] and c.n_intervals == fallback["n_intervals"]
    assert c.schedule.name == fallback["schedule"] and c.dim == fallback["dim"]
    assert c.position_range == (fallback["position_range"],) * 2
    assert c.velocity_range == (fallback["velocity_range"],) * 2
    assert c.agent_model == fallback["agent_model"] and c.model is None
    assert make_config(topology={"family": "ring"}).n_agents == fallback["n_agents"]
    assert make_config(topology="random", n_agents=12).topology.period == fallback["topology_period"]
    drawn = make_config(topology="random", n_agents=12).topology.edges
    given = make_config(topology="random", n_agents=12, mean_in_degree=fallback["mean_in_degree"]).topology.edges
    assert all(np.array_equal(a, b) for a, b in zip(drawn, given, strict=True))


def test_make_config_keeps_the_signature_defaults():
    c = make_config()
    for name in ("action_mode", "obs_mode", "obs_format", "obs_dtype", "global_state", "switching"):
        assert getattr(c, name) == ARGUMENTS[name].default, name
    assert c.reward_floor == ARGUMENTS["reward_floor"].default
    assert (c.obs_noise, c.link_dropout) == (ARGUMENTS["obs_noise"].default, ARGUMENTS["link_dropout"].default)


def test_the_model_flags_state_the_models_defaults():
    assert make_config(agent_model="integrator_chain").n_states == 2 and "default 2)" in MODEL_FLAGS["order"][1]
    for name, parameter, default in (
        ("damped", "damping", DEFAULT_DAMPING),
        ("oscillator", "frequency", DEFAULT_FREQUENCY),
    ):
        assert f"default {default:g})" in MODEL_FLAGS[parameter][1]
        spelled = make_config(agent_model={"name": name, parameter: default}).model.A
        np.testing.assert_array_equal(make_config(agent_model=name).model.A, spelled)


@pytest.mark.parametrize("argument", [a for a in ENV_ARGUMENTS if a.kind == "choice"], ids=lambda a: a.name)
def test_make_config_accepts_exactly_the_table_s_choices(argument):
    for option in argument.choices:
        assert getattr(make_config(**{argument.name: option}), argument.name) == option
    with pytest.raises(ArgumentError) as refused:
        make_config(**{argument.name: "bogus"})
    assert str(refused.value) == f"{argument.name}: expected one of {argument.choices}, got 'bogus'"


def _outside(argument):
    """Values just outside the table's range of an integer or real argument."""
    if argument.kind == "probability":
        return [-0.1, 1.0]
    values = []
    if argument.minimum is not None:
        values.append(argument.minimum - 1)
    if argument.positive:
        values.append(0.0)
    if argument.maximum is not None:
        values.append(argument.maximum + 1 if argument.kind == "integer" else argument.maximum * 10)
    return values


BOUNDED = [a for a in ENV_ARGUMENTS if a.kind in ("integer", "real", "probability")]


@pytest.mark.parametrize("argument", BOUNDED, ids=lambda a: a.name)
def test_make_config_refuses_values_outside_the_table_s_range_with_the_helper_s_message(argument):
    context = {"topology": {"family": "ring"}} if argument.name == "n_agents" else {}
    assert _outside(argument)
    for value in _outside(argument):
        with pytest.raises(ArgumentError) as refused:
            make_config(**context, **{argument.name: value})
        with pytest.raises(ArgumentError) as helper:
            argument.check(value)
        assert str(refused.value) == str(helper.value) and str(refused.value).startswith(f"{argument.name}: ")


def test_the_range_ends_are_accepted():
    assert make_config(dim=validation.MAX_DIM, topology="complete", n_agents=2).dim == validation.MAX_DIM
    assert make_config(obs_noise=0.0, link_dropout=0.0).link_dropout == 0.0
    assert make_config(link_dropout=0.999).link_dropout == 0.999


def test_scenarios_set_only_what_a_scenario_may_set():
    for name, preset in SCENARIOS.items():
        for key in preset:
            assert ARGUMENTS[key].from_scenario, (name, key)
    assert {a.name for a in ENV_ARGUMENTS if a.fallback is not NO_FALLBACK} <= {
        a.name for a in ENV_ARGUMENTS if a.from_scenario
    }


def test_the_torchrl_env_refuses_arguments_beside_a_prebuilt_config():
    config = make_config("paper_fig1", n_intervals=5)
    assert ConsensusTorchEnv(config=config, batch_size=2).config is config
    with pytest.raises(
        ArgumentError, match=r"^config: give a prebuilt config or the environment's arguments.*n_agents"
    ):
        ConsensusTorchEnv(config=config, n_agents=8)
    with pytest.raises(TypeError, match=r"^config: expected an EnvConfig"):
        ConsensusTorchEnv(config={"n_agents": 8})


def test_every_front_end_builds_the_config_make_config_builds():
    kwargs = {"topology": "ring", "n_agents": 5, "dim": 2, "n_intervals": 7, "u_max": [1.0, 3.0], "obs_slots": 2}
    expected = make_config(**kwargs)
    for factory in (ConsensusParallelEnv, ConsensusAECEnv, lambda **kw: ConsensusVecEnv(2, **kw), ConsensusTorchEnv):
        config = factory(**kwargs).config
        for field in ("n_agents", "dim", "n_intervals", "u_max_choices", "obs_slots", "action_bound", "obs_dtype"):
            assert getattr(config, field) == getattr(expected, field), (factory, field)


# ------------------------------------------------------------------ flags


def _parser(scenario_default="paper_fig1"):
    parser = argparse.ArgumentParser()
    add_env_arguments(parser, scenario_default=scenario_default)
    return parser


def test_the_flags_are_the_documented_ones_generated_from_the_table():
    actions = {a.option_strings[0]: a for a in _parser()._actions if a.option_strings and a.dest != "help"}
    assert set(actions) == DOCUMENTED_FLAGS
    for argument in FLAG_ARGUMENTS:
        action = actions[argument.flag_name]
        assert action.dest == argument.name and argument.name in ARGUMENTS
        assert action.help == (argument.flag.help or argument.help) or argument.name == "scenario"
        expected_type = {"int": int, "float": float}.get(argument.flag.kind)
        assert action.type is expected_type, argument.name
        choices = argument.flag.choices or (argument.choices if argument.kind == "choice" else None)
        assert (tuple(action.choices) if action.choices else None) == choices, argument.name


def test_a_flag_left_out_keeps_the_scenario_s_value():
    assert env_kwargs_from(_parser().parse_args([])) == {"scenario": "paper_fig1"}
    assert env_kwargs_from(_parser(None).parse_args([])) == {"scenario": None}


def _sample(argument):
    """A flag value and what make_config receives for it."""
    kind, choices = argument.flag.kind, argument.flag.choices or argument.choices
    if choices:
        return choices[-1], choices[-1]
    return {
        "int": ("3", 3),
        "float": ("0.25", 0.25),
        "numbers": ("2", 2 if argument.name == "topology_period" else 2.0),
        "str": ("ring", "ring"),
    }[kind]


@pytest.mark.parametrize(
    "argument", [a for a in FLAG_ARGUMENTS if a.name not in ("scenario", *FLAT_PARAMETERS)], ids=lambda a: a.name
)
def test_each_flag_passes_its_value_to_its_argument(argument):
    text, value = _sample(argument)
    kwargs = env_kwargs_from(_parser().parse_args([argument.flag_name, text]))
    assert kwargs == {"scenario": "paper_fig1", argument.name: value}
    assert type(kwargs[argument.name]) is type(value)


@pytest.mark.parametrize(("flag", "value"), [("--order", "3"), ("--damping", "0.25"), ("--frequency", "2")])
def test_a_model_parameter_flag_joins_the_agent_model_spec(flag, value):
    name = {"--order": "integrator_chain", "--damping": "damped", "--frequency": "oscillator"}[flag]
    kwargs = env_kwargs_from(_parser().parse_args(["--agent-model", name, flag, value]))
    parameter = flag[2:]
    expected = int(value) if flag == "--order" else float(value)
    assert kwargs == {"scenario": "paper_fig1", "agent_model": {"name": name, parameter: expected}}
    with pytest.raises(ArgumentError, match=f"^{flag}: a parameter of --agent-model; give --agent-model too"):
        env_kwargs_from(_parser().parse_args([flag, value]))
