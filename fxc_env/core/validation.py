"""Argument checks, written once: every front end (config, engine, envs, VecEnv, ``simulate``, CLI) calls these.

Each check returns the value in canonical form (``int``, ``float``, float64 array) or raises
:class:`ArgumentError` (a ``ValueError``) or :class:`ArgumentTypeError` (also a
``TypeError``) whose message starts with the argument's name and says what was expected.
The ``fxc`` command line prints exactly these as one-line usage errors (exit 2); any other
exception is a bug and shows its traceback.

Float64 ranges. :data:`STATE_LIMIT` (1e100), :data:`MIN_INTERVAL` (1e-30 s) and
:data:`MAX_SETTLING_TIME` (1e30 s) keep every quantity of one step finite in float64 for any
state they admit; what an action can still do is caught by the step itself, which refuses a
non-finite result and leaves the state as it was (docs: bad-input.md, "Float64 ranges").
"""

from __future__ import annotations

import math
import operator
import sys
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

#: Largest accepted magnitude of a position, velocity, noise level or input limit (m, m/s, m/s^2).
STATE_LIMIT = 1e100
#: Shortest accepted sampling interval (s).
MIN_INTERVAL = 1e-30
#: Largest state magnitude with ``obs_dtype="float32"`` and ``obs_mode="raw"`` (m, m/s): float32's
#: largest number is 3.4e38, and a raw observation holds differences of two states (relative
#: positions), so 1e37 leaves a factor 17 for those and for growth within an episode.
FLOAT32_STATE_LIMIT = 1e37
#: float32's largest number (3.4e38): a raw float32 observation entry beyond it is ``inf``.
FLOAT32_MAX = float(np.finfo(np.float32).max)
#: Standard deviations of measurement noise kept below :data:`FLOAT32_MAX` by :func:`float32_row_limit`.
NOISE_MARGIN = 17
#: Longest accepted deadline ``T_s`` (s).
MAX_SETTLING_TIME = 1e30
#: Most sampling intervals K (the engine keeps per-instant arrays of K + 1 rows).
MAX_INTERVALS = 10**6
#: Fewest agents of an environment: consensus is agreement between agents, and one agent's
#: disagreement is zero before any step (every reward 0, no graph for a gain design).
MIN_AGENTS = 2
#: Most agents in one episode (node indices of a topology lie in ``[0, MAX_AGENTS)``).
MAX_AGENTS = 10**8
#: Most graphs in one switching period.
MAX_PERIOD = 10**4
#: Largest accepted space dimension.
MAX_DIM = 1024
#: Seeds numpy's generators accept: integers in ``[0, 2**128)``.
MAX_SEED = 2**128


class ArgumentError(ValueError):
    """A bad argument. The message names it and says what was expected."""


class ArgumentTypeError(ArgumentError, TypeError):
    """An argument of the wrong type (also a ``TypeError``)."""


#: Top-level packages whose frames a deprecation warning passes over to reach the user's line: this one
#: (``fxc_env.baselines`` and ``fxc_env.training`` live outside its folder), and TorchRL's and tensordict's
#: machinery that constructs a ``ConsensusTorchEnv`` (their metaclasses call ``__init__``).
_PASS_OVER = frozenset({"fxc_env", "torchrl", "tensordict"})


def deprecated(message: str) -> None:
    """A :class:`DeprecationWarning` pointed at the first caller outside the package (the user's line)."""
    warn_user(message, DeprecationWarning)


def warn_user(message: str, category: type[Warning]) -> None:
    """A warning of ``category`` pointed at the first caller outside the package (the user's line)."""
    frame, level = sys._getframe(1), 2
    while frame.f_back is not None and str(frame.f_globals.get("__name__", "")).split(".")[0] in _PASS_OVER:
        frame, level = frame.f_back, level + 1
    warnings.warn(message, category, stacklevel=level)


def _is_integer(value: Any) -> bool:
    return not isinstance(value, bool | np.bool_) and isinstance(value, int | np.integer)


def integer(name: str, value: Any, minimum: int | None = None, maximum: int | None = None) -> int:
    """``value`` as an ``int`` in ``[minimum, maximum]`` (bools and floats refused)."""
    if not _is_integer(value):
        raise ArgumentTypeError(f"{name}: expected an integer{_range_text(minimum, maximum)}, got {value!r}")
    number = operator.index(value)
    if (minimum is not None and number < minimum) or (maximum is not None and number > maximum):
        raise ArgumentError(f"{name}: expected an integer{_range_text(minimum, maximum)}, got {value!r}")
    return number


def real(
    name: str, value: Any, minimum: float | None = None, maximum: float | None = None, *, positive: bool = False
) -> float:
    """``value`` as a finite ``float`` in ``[minimum, maximum]`` (``> 0`` with ``positive``)."""
    expected = "a positive finite number" if positive else "a finite number"
    expected += _range_text(minimum, maximum)
    if isinstance(value, bool | np.bool_ | str | bytes):
        raise ArgumentTypeError(f"{name}: expected {expected}, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):
        raise ArgumentTypeError(f"{name}: expected {expected}, got {value!r}") from None
    if (
        not math.isfinite(number)
        or (positive and number <= 0)
        or (minimum is not None and number < minimum)
        or (maximum is not None and number > maximum)
    ):
        raise ArgumentError(f"{name}: expected {expected}, got {value!r}")
    return number


def in_range(
    name: str,
    value: Any,
    low: float,
    high: float,
    *,
    low_open: bool = False,
    high_open: bool = False,
    below: str = "",
    above: str = "",
) -> float:
    """``value`` as a finite ``float`` in the range ``low <= value <= high`` (an end excluded with ``low_open`` or
    ``high_open``): the one check of a law's parameter against the range where the law's promise holds.

    Outside, :class:`ArgumentError` (:class:`ArgumentTypeError` for a non-number) names ``name`` and the range
    (``amplitude: expected 1e-12 <= amplitude <= 1; ...``) and, after a semicolon, ``below`` or ``above``: what
    breaks on that side, so a user learns why the range ends there.
    """
    low_text, high_text = (_number_text(end).replace("e+", "e") for end in (low, high))  # 1e12, not 1e+12
    expected = f"{low_text} {'<' if low_open else '<='} {name} {'<' if high_open else '<='} {high_text}"
    if isinstance(value, bool | np.bool_ | str | bytes):
        raise ArgumentTypeError(f"{name}: expected a number, {expected}; got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):
        raise ArgumentTypeError(f"{name}: expected a number, {expected}; got {short_repr(value)}") from None
    too_low = number < low or (low_open and number == low)
    too_high = number > high or (high_open and number == high)
    if too_low or too_high or not math.isfinite(number):
        reason = below if too_low else above if too_high else ""
        raise ArgumentError(f"{name}: expected {expected}; " + (f"{reason}; " if reason else "") + f"got {value!r}")
    return number


def probability(name: str, value: Any) -> float:
    """``value`` as a probability in ``[0, 1)``."""
    number = real(name, value)
    if not 0 <= number < 1:
        raise ArgumentError(f"{name}: expected a probability in [0, 1), got {value!r}")
    return number


def boolean(name: str, value: Any) -> bool:
    """``value`` if it is True or False (not 0, 1 or a string)."""
    if not isinstance(value, bool):
        raise ArgumentError(f"{name}: expected True or False, got {value!r}")
    return value


def choice(name: str, value: Any, options: Sequence[str]) -> str:
    """``value`` if it is one of ``options``."""
    if not isinstance(value, str) or value not in options:
        raise ArgumentError(f"{name}: expected one of {tuple(options)}, got {value!r}")
    return value


#: The keys ``reset(options=...)`` reads: a fixed initial state for the episode (docs: environment.md, "The environment").
RESET_OPTION_KEYS = ("x0", "v0")
#: PettingZoo's API tests (``api_test``, ``parallel_api_test``) call ``reset(options={"options": 1})``
#: only to see that reset takes options: that exact probe is accepted and reads nothing.
PETTINGZOO_OPTIONS_PROBE = {"options": 1}


def reset_options(name: str, value: Any) -> Mapping[str, Any]:
    """``reset``'s ``options``: None (read as ``{}``) or a mapping whose keys are among :data:`RESET_OPTION_KEYS`.

    An unknown key (``"X0"``, ``"v00"``) is refused naming the known ones, so an intended
    initial state is never silently dropped; only PettingZoo's API-test probe
    (:data:`PETTINGZOO_OPTIONS_PROBE`) reads as ``{}``. The values are checked by the engine
    (:func:`state_array`).
    """
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ArgumentTypeError(f"{name}: expected a dict or None, got {type(value).__name__}")
    if (
        len(value) == 1
        and type(value.get("options")) is int
        and value["options"] == PETTINGZOO_OPTIONS_PROBE["options"]
    ):
        return {}
    unknown = [key for key in value if key not in RESET_OPTION_KEYS]
    if unknown:
        known = ", ".join(repr(key) for key in RESET_OPTION_KEYS)
        raise ArgumentError(f"{name}: unknown key(s) {unknown!r}; expected only {known} (a fixed initial state)")
    return value


def optional_seed(name: str, value: Any) -> int | None:
    """``None`` or a seed numpy's generators accept: an integer in ``[0, 2**128)``."""
    return None if value is None else integer(name, value, 0, MAX_SEED - 1)


def state_array(name: str, value: Any, n_agents: int, dim: int, limit: float = STATE_LIMIT) -> np.ndarray:
    """``value`` as a float64 ``(N, dim)`` array (``(N,)`` accepted when ``dim = 1``), entries within ±``limit``
    (:data:`STATE_LIMIT`, or :data:`FLOAT32_STATE_LIMIT` for raw float32 observations)."""
    accepted = f"({n_agents}, {dim})" + (f" or ({n_agents},)" if dim == 1 else "")
    array = real_array(name, value, f"an array of shape {accepted}", booleans=False)
    if dim == 1 and array.shape == (n_agents,):
        array = array[:, None]
    if array.shape != (n_agents, dim):
        raise ArgumentError(f"{name}: expected shape {accepted}, got {array.shape}")
    _check_entries(name, array, limit)
    return array


def float32_row_limit(obs_noise: float) -> float:
    """Largest difference of two states (a raw observation row, m or m/s) a step may reach with
    ``obs_dtype="float32"`` and ``obs_mode="raw"``: :data:`FLOAT32_MAX` less :data:`NOISE_MARGIN`
    standard deviations of the noise (``obs_noise`` is at most :data:`FLOAT32_STATE_LIMIT`
    there, so the limit is at least 1.7e38; without noise, exactly where a row would observe as ``inf``)."""
    return FLOAT32_MAX - NOISE_MARGIN * obs_noise


def state_batch(name: str, value: Any, shape: tuple[int, ...], limit: float | None = STATE_LIMIT) -> np.ndarray:
    """``value`` as a float64 array of exactly ``shape`` (an engine's ``(B, N, dim)`` initial positions or
    velocities), real, entries finite and within ±``limit``; raise naming ``name`` otherwise.

    The one check of a batch of initial states, used by both engine back ends (numpy, and
    torch for a host array); a torch tensor's values are checked on the device with the
    message of :func:`state_entries_error`.
    """
    array = real_array(name, value, f"an array of shape {shape}", booleans=False)
    if array.shape != shape:
        raise ArgumentError(f"{name}: expected shape {shape}, got {array.shape}")
    _check_entries(name, array, limit)
    return array


def state_entries_error(name: str, limit: float = STATE_LIMIT) -> str:
    """The message of a state whose entries were found (in one read off a device) not finite or beyond ±``limit``."""
    return (
        f"{name}: expected finite entries within ±{limit:g} (metres, m/s; "
        + ("float64 headroom" if limit == STATE_LIMIT else 'float32 range, obs_dtype="float32", obs_mode="raw"')
        + "), got a NaN, an infinity or a larger entry"
    )


def action_array(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` with finite entries (booleans refused): :func:`state_batch` unbounded."""
    return state_batch(name, value, shape, None)


def interval_lengths(name: str, value: Any) -> np.ndarray:
    """``value`` as a 1-D float64 array of K >= 1 interval lengths, each at least :data:`MIN_INTERVAL` seconds."""
    if isinstance(value, str | bytes):
        raise ArgumentTypeError(f"{name}: expected 'paper', 'uniform' or an array of interval lengths, got {value!r}")
    lengths = real_array(name, value, "an array of interval lengths")
    if lengths.dtype.kind == "b" or np.asarray(value).dtype.kind == "b":
        raise ArgumentTypeError(f"{name}: expected an array of interval lengths in seconds, got booleans")
    if lengths.ndim != 1 or lengths.size < 1:
        raise ArgumentError(f"{name}: expected a 1-D array of K >= 1 interval lengths, got shape {lengths.shape}")
    if not np.all(np.isfinite(lengths)) or np.any(lengths < MIN_INTERVAL):
        raise ArgumentError(
            f"{name}: every interval length must be finite and at least {MIN_INTERVAL:g} s (float64 range), "
            f"got a smallest of {np.min(lengths)!r}"
        )
    return lengths


def real_array(name: str, value: Any, expected: str, *, booleans: bool = True) -> np.ndarray:
    """``value`` as a float64 array (not copied when it is one); a ragged or non-numeric value raises naming ``name``.

    ``expected`` completes the message: ``"{name}: expected {expected} of real numbers, got ..."``.
    ``booleans=False`` refuses an array of booleans too (states and actions: ``True`` is no position).
    """
    try:
        array = np.asarray(value)
    except (TypeError, ValueError, OverflowError):
        raise ArgumentTypeError(f"{name}: expected {expected} of real numbers, got {short_repr(value)}") from None
    if array.dtype.kind not in "biuf":
        raise ArgumentTypeError(f"{name}: expected {expected} of real numbers, got {short_repr(value)}")
    if not booleans and array.dtype.kind == "b":
        raise ArgumentTypeError(f"{name}: expected {expected} of real numbers, got booleans")
    return array.astype(np.float64, copy=False)


def finite_array(name: str, array: np.ndarray) -> np.ndarray:
    """``array`` once every entry is finite (no NaN or inf); else an :class:`ArgumentError` naming ``name``."""
    _check_entries(name, array, None)
    return array


def _check_entries(name: str, array: np.ndarray, limit: float | None) -> None:
    if limit is None or not array.size:
        if not np.all(np.isfinite(array)):
            raise ArgumentError(f"{name}: every entry must be finite (no NaN or inf)")
        return
    largest = np.abs(array).max()  # one pass: a NaN propagates, and fails the comparison as an inf does
    if not largest <= limit:
        if not math.isfinite(largest):
            raise ArgumentError(f"{name}: every entry must be finite (no NaN or inf)")
        raise ArgumentError(
            f"{name}: entries must lie within ±{limit:g} ("
            + ("float64 headroom" if limit == STATE_LIMIT else 'float32 range, obs_dtype="float32", obs_mode="raw"')
            + f"), got {largest:g}"
        )


def _range_text(minimum: float | None, maximum: float | None) -> str:
    low, high = _number_text(minimum), _number_text(maximum)
    if minimum is not None and maximum is not None:
        return f" in [{low}, {high}]"
    if minimum is not None:
        return f" >= {low}"
    return f" <= {high}" if maximum is not None else ""


def _number_text(value: float | None) -> str:
    """Integers exactly while they are short (``4294967295``), powers of two as such, else ``%g``."""
    if value is None:
        return ""
    if isinstance(value, int):
        if value < 10**12:
            return str(value)
        if value + 1 == 2 ** (value + 1).bit_length() // 2:
            return f"2**{(value + 1).bit_length() - 1} - 1"
        if value == 2 ** (value.bit_length() - 1):
            return f"2**{value.bit_length() - 1}"
    return f"{value:g}"


def short_repr(value: Any) -> str:
    """``repr(value)``, cut to 80 characters for a message."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."
