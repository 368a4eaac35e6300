"""The ``fxc-card`` directive: a scenario's or a named task's card, built from the library when the docs build.

A page writes ``{fxc-card} scenario:paper_fig1`` or ``{fxc-card} task:rings20-v1`` in a MyST
directive fence and gets two tables: the settings the name bundles (``fxc_env.SCENARIOS``,
``fxc_env.config.tasks.TASKS``) and what the environment they make reports (agents, graphs,
schedule, spaces, limits). Nothing is typed by hand, so a card cannot drift from the code.
"""

from __future__ import annotations

from typing import Any

from docutils import nodes
from docutils.parsers.rst import Directive
from docutils.statemachine import StringList


def _value(value: Any) -> str:
    """A setting as one short cell: families by name, long tuples cut."""
    name = getattr(value, "name", None)
    if name is not None and not isinstance(value, str | int | float):
        return f"family `{name}` (a new graph every episode)"
    text = repr(value)
    return text if len(text) <= 70 else text[:67] + "..."


def _environment_rows(kwargs: dict[str, Any]) -> list[tuple[str, str]]:
    import fxc_env

    config = fxc_env.make_config(**kwargs)
    env = fxc_env.parallel_env(**kwargs)
    agent = env.possible_agents[0]
    topology = config.topology
    graphs = f"`{topology.name}`, {len(topology.edges)} graph(s) per period"
    if config.family is not None:
        graphs = f"family `{getattr(config.family, 'name', config.family)}`, drawn per episode (e.g. `{topology.name}`)"
    rows = [
        ("agents N", str(topology.n_agents)),
        ("graphs", graphs),
        ("deadline T_s (s)", f"{float(config.schedule.times[-1]):g}"),
        ("sampling intervals K", str(len(config.schedule.intervals))),
        ("schedule", f"`{config.schedule.name}`"),
        ("dimension", str(config.dim)),
        ("agent model", f"`{config.agent_model}`"),
        ("observation space (per agent)", f"`{env.observation_space(agent)}`"),
        ("action space (per agent)", f"`{env.action_space(agent)}`"),
        ("observation / action mode", f"`{config.obs_mode}` / `{config.action_mode}`"),
        ("input limit u_max", "none" if config.u_max_choices is None else f"one of {config.u_max_choices} per episode"),
        ("formation offsets", "yes" if config.formation is not None else "no"),
    ]
    env.close()
    return rows


def _table(header: tuple[str, str], rows: list[tuple[str, str]]) -> list[str]:
    lines = [f"| {header[0]} | {header[1]} |", "|---|---|"]
    lines += ["| {} | {} |".format(key, value.replace("|", "\\|")) for key, value in rows]
    return [*lines, ""]


def card_markdown(spec: str) -> list[str]:
    """The Markdown of the card ``spec`` (``scenario:<name>`` or ``task:<id>``)."""
    kind, _, name = spec.partition(":")
    if kind == "scenario":
        from fxc_env import SCENARIOS

        settings = dict(SCENARIOS[name])
        kwargs = {"scenario": name}
        lines = [f"**Settings** (`fxc_env.SCENARIOS[{name!r}]`):", ""]
    elif kind == "task":
        from fxc_env.config.tasks import get_task

        task = get_task(name)
        settings, kwargs = task.kwargs(), task.kwargs()
        lines = [
            f"**{task.full_id}**: {task.description}. Evaluation seeds {task.eval_seeds[0]} … {task.eval_seeds[-1]}.",
            "",
            f"**Settings** (`fxc_env.config.tasks.TASKS[{task.id!r}].settings`):",
            "",
        ]
    else:
        raise ValueError(f"fxc-card: expected 'scenario:<name>' or 'task:<id>', got {spec!r}")
    lines += _table(("argument", "value"), [(f"`{k}`", f"`{_value(v)}`") for k, v in settings.items()])
    lines += ["**The environment it makes** (`fxc_env.parallel_env(...)`, read when these docs were built):", ""]
    return lines + _table(("field", "value"), _environment_rows(kwargs))


class FxcCard(Directive):
    """``{fxc-card} scenario:<name>`` / ``task:<id>``: the card as Markdown tables, parsed in place."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        text = "\n".join(card_markdown(self.arguments[0]))
        container = nodes.container()  # under MyST the state parses the nested text as Markdown
        self.state.nested_parse(StringList(text.splitlines()), self.content_offset, container)
        return container.children


def setup(app):
    app.add_directive("fxc-card", FxcCard)
    return {"version": "1", "parallel_read_safe": True}
