"""What a row of the arguments table (:data:`fxc_env.config.arguments.ENV_ARGUMENTS`) holds, how it
checks a single value (:mod:`fxc_env.core.validation`'s helpers) and how a card gets its table."""

from __future__ import annotations

import argparse
import inspect
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, TypedDict

import numpy as np

from fxc_env.core import validation


class _Marker:
    """A named sentinel (readable in reprs and in the card)."""

    def __init__(self, name: str) -> None:
        self._name = name

    def __repr__(self) -> str:
        return self._name


#: :attr:`Argument.fallback` of an argument that has none.
NO_FALLBACK: Any = _Marker("NO_FALLBACK")
#: :attr:`Argument.default` of an argument the caller must give (``n_envs``).
REQUIRED: Any = inspect.Parameter.empty

#: The checks :meth:`Argument.check` knows, each a helper of :mod:`fxc_env.core.validation`.
CHECK_KINDS = ("choice", "integer", "real", "probability", "seed", "boolean")
#: What argparse turns a flag's text into; ``"numbers"``: a number or comma-separated numbers.
FLAG_KINDS = ("str", "int", "float", "numbers")


@dataclass(frozen=True)
class Flag:
    """How an argument is written on the ``fxc simulate`` / ``fxc evaluate`` command line.

    The flag is ``--`` and the argument's name with dashes (``--n-agents``); left out, it
    keeps the scenario's value.
    """

    #: One of :data:`FLAG_KINDS`: argparse's ``type`` (``str``, ``int``, ``float``), or
    #: ``"numbers"`` for ``1.5`` or ``1.5,3`` (a range or a set, parsed by the flags module).
    kind: str = "str"
    #: The values argparse accepts (None: any); defaults to the argument's choices.
    choices: tuple[str, ...] | None = None
    #: The flag's help when it differs from the argument's one-line help.
    help: str | None = None


@dataclass(frozen=True)
class Argument:
    """One argument of the environment: everything the signatures, checks, flags and cards say of it."""

    #: The keyword, as every signature spells it.
    name: str
    #: Its type as the signatures write it (a string: the package postpones annotations).
    annotation: str
    #: The signature's default (:data:`REQUIRED` when there is none). ``None`` usually means
    #: "not given": the scenario's value, else :attr:`fallback`, applies.
    default: Any
    #: One line: the flag's ``--help`` text.
    help: str
    #: The card's "meaning" column (reST inline markup; a literal ``|`` is written ``\\|``).
    card: str
    #: How :meth:`check` validates a single value (one of :data:`CHECK_KINDS`), or ``""``
    #: when a helper of its own checks it (structured values, ranges known only with the graph).
    kind: str = ""
    #: The allowed values of a ``"choice"`` argument.
    choices: tuple[str, ...] | None = None
    #: Bounds of an ``"integer"`` or ``"real"`` argument (inclusive; None: unbounded).
    minimum: float | None = None
    maximum: float | None = None
    #: A ``"real"`` argument must be > 0.
    positive: bool = False
    #: The value ``make_config`` uses when neither the call nor the scenario gives one
    #: (the card's ``[value]``); :data:`NO_FALLBACK` when there is none.
    fallback: Any = NO_FALLBACK
    #: Whether a named scenario may set it (:data:`fxc_env.SCENARIOS`).
    from_scenario: bool = False
    #: The card's "type" column when the annotation (or the choices) would not say it well.
    card_type: str | None = None
    #: The card's "default" column when it is not the default or the fallback.
    card_default: str | None = None
    #: Its command-line flag, or None when the command line has none.
    flag: Flag | None = None

    def check(self, value: Any) -> Any:
        """``value`` checked by the :mod:`fxc_env.core.validation` helper of :attr:`kind` (its message on error).

        ``None`` passes when it is the default (it means "not given").
        """
        if value is None and self.default is None:
            return None
        if self.kind == "choice":
            return validation.choice(self.name, value, self.choices or ())
        if self.kind == "integer":
            return validation.integer(self.name, value, _optional_int(self.minimum), _optional_int(self.maximum))
        if self.kind == "real":
            return validation.real(self.name, value, self.minimum, self.maximum, positive=self.positive)
        if self.kind == "probability":
            return validation.probability(self.name, value)
        if self.kind == "seed":
            return validation.optional_seed(self.name, value)
        if self.kind == "boolean":
            if not isinstance(value, bool | np.bool_):
                raise validation.ArgumentTypeError(f"{self.name}: expected True or False, got {value!r}")
            return bool(value)
        raise TypeError(f"{self.name}: checked by a helper of its own, not by Argument.check")

    @property
    def flag_name(self) -> str:
        """``--name-with-dashes``."""
        return "--" + self.name.replace("_", "-")

    @property
    def card_row(self) -> str:
        """The argument's row of a card's Arguments table."""
        return f"| ``{self.name}`` | {self._card_type()} | {self._card_default()} | {self.card} |"

    def _card_type(self) -> str:
        if self.card_type is not None:
            return self.card_type
        if self.kind == "choice" and self.choices:
            options = " \\| ".join(f'"{option}"' for option in self.choices)
            return f"``None \\| {options}``" if self.default is None else f"``{options}``"
        return "``" + self.annotation.replace("|", "\\|") + "``"

    def _card_default(self) -> str:
        if self.card_default is not None:
            return self.card_default
        if self.fallback is not NO_FALLBACK:
            return f"[{_default_text(self.fallback)}]"
        return "required" if self.default is REQUIRED else _default_text(self.default)


def _optional_int(value: float | None) -> int | None:
    return None if value is None else int(value)


def _default_text(value: Any) -> str:
    return f'``"{value}"``' if isinstance(value, str) else repr(value)


def arguments_table(arguments: Iterable[Argument]) -> str:
    """A card's Arguments table: the header, then one :attr:`Argument.card_row` per argument."""
    rows = [argument.card_row for argument in arguments]
    return "\n".join(["| parameter | type | default | meaning |", "|-----------|------|---------|---------|", *rows])


#: The line a card's docstring holds where :func:`with_arguments_table` puts the table.
TABLE_MARKER = "{arguments table}"


def with_arguments_table(doc: str | None, arguments: Sequence[Argument]) -> str:
    """``doc`` with its :data:`TABLE_MARKER` line replaced by the table of ``arguments``, at that line's indent."""
    lines = (doc or "").split("\n")
    marked = [i for i, line in enumerate(lines) if line.strip() == TABLE_MARKER]
    if len(marked) != 1:
        raise ValueError(
            f"with_arguments_table: expected one {TABLE_MARKER!r} line in the docstring, got {len(marked)}"
        )
    line = lines[marked[0]]
    indent = line[: len(line) - len(line.lstrip())]
    table = [indent + row for row in arguments_table(arguments).split("\n")]
    return "\n".join([*lines[: marked[0]], *table, *lines[marked[0] + 1 :]])


class StoreOnce(argparse._StoreAction):
    """argparse's ``store`` that refuses a flag given twice (``--task A --task B`` would keep B in silence).

    Every flag it stores is recorded in ``namespace.given_flags`` (its ``dest``), so a command can tell a
    flag given from its default. The refusal is one line, ``fxc <command>: error: --flag: ...``, exit status 2.
    """

    def __call__(self, parser: Any, namespace: Any, values: Any, option_string: str | None = None) -> None:
        given = set(getattr(namespace, "given_flags", ()))
        if self.dest in given:
            flag = option_string or self.dest
            parser.exit(2, f"{parser.prog}: error: {flag}: given twice ({getattr(namespace, self.dest)!r}, then "
                           f"{values!r}); give it once\n")  # fmt: skip
        setattr(namespace, self.dest, values)
        namespace.given_flags = given | {self.dest}


#: A Sphinx cross-reference (``:data:`fxc_env.SCENARIOS```, ``:meth:`title <target>```) or a literal in double backticks.
_MARKUP = re.compile(r":[a-z]+:`(~?)([^`<]*?)\s*(?:<[^`>]*>)?`|``([^`]*)``")


def plain_text(text: str) -> str:
    """``text`` with its docstring markup read as a terminal shows it: a role's title (or target) and a literal's text.

    ``:data:`fxc_env.SCENARIOS``` reads ``fxc_env.SCENARIOS``, ``:func:`~fxc_env.engine.draws.draw_batch```
    reads ``draw_batch``, ``:meth:`Observer.measure <fxc_env...>``` reads ``Observer.measure``, and
    ````rings20-v2```` reads ``rings20-v2``.
    """

    def shown(match: re.Match[str]) -> str:
        tilde, target, literal = match.groups()
        if literal is not None:
            return literal
        return target.rsplit(".", 1)[-1] if tilde else target

    return _MARKUP.sub(shown, text)


class PlainHelpFormatter(argparse.HelpFormatter):
    """``--help`` in plain text: descriptions and flag help are built from docstrings, whose markup it drops."""

    def _format_text(self, text: str) -> str:
        return super()._format_text(plain_text(text))

    def _expand_help(self, action: argparse.Action) -> str:
        return plain_text(super()._expand_help(action))


class FlagParser(argparse.ArgumentParser):
    """The ``fxc`` parser: a flag is stored by :class:`StoreOnce`, so a repeated one is refused.

    Its help is plain text (:class:`PlainHelpFormatter`), its sub-commands' too (they are FlagParsers).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", PlainHelpFormatter)
        super().__init__(*args, **kwargs)
        self.register("action", None, StoreOnce)
        self.register("action", "store", StoreOnce)


class EnvKwargs(TypedDict, total=False):
    """The environment's keyword arguments after ``scenario`` (the annotations of :data:`~fxc_env.config.arguments.ENV_ARGUMENTS`), as front ends take them.

    ``**kwargs: Unpack[EnvKwargs]`` lets type checkers and IDEs see each one; :func:`~fxc_env.config.arguments.env_signature`
    writes them out with their defaults for ``help()`` and ``inspect``.
    """

    n_agents: int | None
    topology: Any
    settling_time: float | None
    n_intervals: int | None
    schedule: Any
    dim: int | None
    action_mode: str
    obs_mode: str
    obs_format: str
    obs_dtype: str
    global_state: str
    action_bound: float | None
    reward_floor: float
    initial_state: Any
    position_range: float | tuple[float, float] | None
    velocity_range: float | tuple[float, float] | None
    topology_seed: int | None
    mean_in_degree: float | None
    topology_period: int | None
    obs_slots: int | None
    u_max: float | Sequence[float] | None
    obs_noise: float
    obs_resolution: float | None
    link_dropout: float
    switching: str
    agent_model: Any
    formation_offsets: Any
