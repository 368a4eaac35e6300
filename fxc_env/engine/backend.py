"""The engine's array backend: numpy arrays or torch tensors, chosen once at construction.

A backend owns what differs between the two: how arrays are made (dtype, device), how
random numbers are drawn, how actions are checked, and how a bad step is reported.

:class:`NumpyBackend` refuses a bad step at once (:meth:`~NumpyBackend.commit_if_finite`, state
unchanged); :class:`TorchBackend` never reads back to the host on the stepping path and sets a
per-episode flag, :attr:`TorchBackend.invalid`, read by :meth:`TorchBackend.raise_if_invalid`.
Everything else is written once against the array API (:mod:`fxc_env.core.arrays`, ``backend.xp``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from fxc_env.core import validation
from fxc_env.core.arrays import namespace
from fxc_env.core.validation import ArgumentError

#: The smallest positive float64: floors a division by a scale that may be 0.
TINY = np.finfo(np.float64).tiny
#: Array dtypes the engine computes in (float32: see the TorchRL environment's card for its floor).
DTYPES = ("float64", "float32")
#: The torch device types the engine runs on (``meta``: shapes only, for the no-host-read checks).
TORCH_DEVICE_TYPES = ("cpu", "cuda", "meta")
#: Largest seed a ``torch.Generator`` takes (``manual_seed`` reads an unsigned 64-bit integer).
MAX_TORCH_SEED = 2**64 - 1


def torch_seed(name: str, value: Any) -> int | None:
    """None or a seed of a ``torch.Generator``: an integer in ``[0, 2**64)`` (bools and floats refused)."""
    return None if value is None else validation.integer(name, value, 0, MAX_TORCH_SEED)


def to_host(array: Any) -> np.ndarray:
    """A numpy copy (or the array itself) of a numpy array or a torch tensor: a read off the device."""
    return array if isinstance(array, np.ndarray) else array.detach().cpu().numpy()


class NumpyBackend:
    """numpy arrays (``device=None``); a bad step is refused at once, nothing is flagged.

    Args:
        dtype: ``"float64"`` or ``"float32"``.
        n_episodes: the batch size B.
    """

    is_numpy = True
    device = None

    def __init__(self, dtype: str, n_episodes: int) -> None:
        self.n_episodes = n_episodes
        self.dtype = getattr(np, validation.choice("dtype", dtype, DTYPES))
        #: The dtype's smallest positive number (the floor of a division by a scale).
        self.tiny = float(np.finfo(dtype).tiny)
        self.xp = namespace(np.empty(0))
        #: No device flags on numpy (:meth:`commit_if_finite` raises instead).
        self.invalid = None
        #: Raw float32 observations only (:meth:`limit_rows`): the largest difference of two
        #: states a step may reach, and the disagreement below which no difference can reach it.
        self.row_limit: float | None = None
        self.quiet_disagreement = math.inf

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        del state["xp"]  # a module: found again on unpickling
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self.xp = self._namespace()

    def _namespace(self) -> Any:
        return namespace(np.empty(0))

    # ------------------------------------------------------------- arrays
    def array(self, values: Any, dtype: Any = None) -> Any:
        """``values`` (numpy or a number) as an array of this backend's dtype (or ``dtype``)."""
        return np.asarray(values, dtype=self.dtype if dtype is None else dtype)

    def zeros(self, shape: tuple[int, ...]) -> Any:
        return self.xp.zeros(shape, dtype=self.dtype, device=self.device)

    def full(self, shape: Any, value: float) -> Any:
        return self.xp.full(shape, value, dtype=self.dtype, device=self.device)

    def spare(self, shape: tuple[int, ...]) -> Any:
        """The second state buffer of double buffering (numpy), or None (torch makes a new tensor)."""
        return self.zeros(shape)

    # --------------------------------------------------------------- draws
    def generator(self, seed: int | None) -> Any:
        """A fresh generator of noise, dropout and switching: ``np.random.default_rng(seed)``.

        ``seed`` is None or an integer in ``[0, 2**128)`` (bools, floats and negative numbers are
        refused by name, as the PettingZoo env's ``reset(seed=...)`` refuses them).
        """
        return np.random.default_rng(validation.optional_seed("seed", seed))

    def uniform(self, rng: Any, shape: tuple[int, ...]) -> Any:
        """Uniform draws on ``[0, 1)``."""
        return rng.random(shape)

    def normal(self, rng: Any, shape: tuple[int, ...]) -> Any:
        """Standard normal draws."""
        return rng.standard_normal(shape)

    # ------------------------------------------------------------- actions
    def checked(self, actions: object, expected: tuple[int, ...], name: str = "actions") -> Any:
        """A ``(B, N, 2 dim)`` real, finite action array, checked in full; raise naming ``name`` otherwise."""
        return validation.action_array(name, actions, expected)

    def limit_rows(self, row_limit: float, component_weights: Any) -> None:
        """Refuse (numpy) or flag (torch) a step after which two states differ by more than ``row_limit``
        in a component (raw float32 observations: a larger row would be observed as ``inf``).

        ``component_weights`` are the disagreement's weights ``T_s^l`` of the state's components
        (``D = sum_l T_s^l e_l``, so every difference is at most ``D / min(weights)``): while the
        disagreement stays below ``row_limit * min(weights)`` no difference can reach the limit and
        the step's check is the one comparison folded into the finite check.
        """
        self.row_limit = float(row_limit)
        self.quiet_disagreement = self.row_limit * float(min(component_weights))

    def largest_difference(self, state: Any) -> Any:
        """Per episode ``(B,)``: the largest difference of two agents' states in one component and axis."""
        xp = self.xp
        return xp.max(xp.max(state, axis=1) - xp.min(state, axis=1), axis=(1, 2))

    def commit_if_finite(self, current: Any, following: Any, refusal: Callable[[], ArgumentError]) -> tuple[Any, Any]:
        """The ``(state, spare)`` pair after an interval played into the spare buffer ``following.state``.

        One scalar decides (a sum overflowing past 1.8e308 is refused too: such energies
        would overflow the episode's totals); a step that is not finite raises
        ``refusal()`` and the state is unchanged. With raw float32 observations
        (:meth:`limit_rows`) the same sum of disagreements, once above
        :attr:`quiet_disagreement`, has the states' differences compared with :attr:`row_limit`.
        """
        disagreement = following.disagreement.sum()
        if not math.isfinite(disagreement + following.energy.sum()):
            raise refusal()
        if disagreement > self.quiet_disagreement and self.largest_difference(following.state).max() > self.row_limit:
            raise refusal()
        return following.state, current

    def refusal(self, actions: np.ndarray, following: Any, k: int, interval: float) -> ArgumentError:
        """The error of a step whose result (``following``, an :class:`~fxc_env.engine.agents.Interval`)
        would not be finite in float64 at instant ``k`` (interval ``T`` seconds), naming what caused it."""
        energy, disagreement_next = following.energy, following.disagreement
        bad_episodes = np.flatnonzero(~np.isfinite(disagreement_next) | ~np.isfinite(energy).all(axis=-1))
        if not len(bad_episodes) and self.row_limit is not None:
            return self._row_refusal(actions, following, k, interval)
        b = int(bad_episodes[0])
        agents = np.flatnonzero(~np.isfinite(energy[b]) | ~np.isfinite(following.state[b]).all(axis=(-2, -1)))
        shown = [int(a) for a in agents[:10]]
        episode = f" in episode {b}" if self.n_episodes > 1 else ""
        largest = float(np.max(np.abs(actions[b])))
        return ArgumentError(
            f"actions: the interval k = {k} (T = {interval:g} s) would overflow float64{episode} "
            f"(agents {shown}: a non-finite state, energy or disagreement); the largest action entry is {largest:g}. "
            "The step was refused and the state is unchanged; smaller actions (or a smaller obs_noise / state "
            "scale) keep it finite"
        )

    # -------------------------------------------------------------- states
    def checked_state(
        self, name: str, value: Any, shape: tuple[int, ...], limit: float = validation.STATE_LIMIT
    ) -> Any:
        """A real ``shape`` state array, entries finite and within ``±limit``, checked in full
        (:func:`fxc_env.core.validation.state_batch`); raise naming ``name`` otherwise."""
        return validation.state_batch(name, value, shape, limit)

    def check_state_values(self, named: dict[str, Any], limit: float = validation.STATE_LIMIT) -> None:
        """Nothing left to read on numpy: :meth:`checked_state` checked the values in full."""

    def _row_refusal(self, actions: np.ndarray, following: Any, k: int, interval: float) -> ArgumentError:
        """The error of a finite step whose states would differ by more than :attr:`row_limit` (raw float32)."""
        largest = self.largest_difference(following.state)
        b = int(np.argmax(largest))
        episode = f" in episode {b}" if self.n_episodes > 1 else ""
        return ArgumentError(
            f"actions: the interval k = {k} (T = {interval:g} s) would take two agents' states {largest[b]:g} "
            f"apart{episode}, beyond ±{self.row_limit:g}, where raw float32 observations overflow to inf "
            f'(obs_dtype="float32", obs_mode="raw"); the largest action entry is {float(np.max(np.abs(actions[b]))):g}. '
            'The step was refused and the state is unchanged; smaller actions keep it in range, or use obs_dtype="float64"'
        )

    def flag(self, mask: Any) -> None:
        """Nothing to flag on numpy (a step past ``T_s`` or a bad value was refused at once)."""

    def clear_flags(self, episodes: Any = None) -> None:
        """Nothing to clear on numpy."""

    def raise_if_invalid(self) -> None:
        """Nothing to read on numpy: bad steps were refused when played."""


class TorchBackend(NumpyBackend):
    """torch tensors on ``device``; a bad step sets :attr:`invalid` on the device (no host read).

    Args:
        device: a torch device (``"cpu"``, ``"cuda"``, ``"cuda:1"``, ``"meta"``).
        dtype: ``"float64"`` or ``"float32"``.
        n_episodes: the batch size B.
    """

    is_numpy = False

    def __init__(self, device: Any, dtype: str, n_episodes: int) -> None:
        import torch  # the torch backend only: a numpy user never imports torch here

        try:
            chosen = torch.device(device)
        except (RuntimeError, TypeError) as error:
            raise ArgumentError(
                f"device: expected None (numpy) or a torch device such as 'cpu' or 'cuda', got {device!r}"
            ) from error
        if chosen.type not in TORCH_DEVICE_TYPES:
            raise ArgumentError(
                f"device: expected None (numpy) or a torch device of type {' / '.join(TORCH_DEVICE_TYPES)}, "
                f"got {device!r}"
            )
        if chosen.type == "cuda" and not torch.cuda.is_available():
            raise ArgumentError(
                f"device: {device!r} asks for CUDA, but torch.cuda.is_available() is False on this machine"
            )
        self.device = chosen
        self.n_episodes = n_episodes
        self.xp = self._namespace()
        self.dtype = getattr(self.xp, validation.choice("dtype", dtype, DTYPES))
        self.tiny = float(np.finfo(dtype).tiny)
        #: Per episode: a non-finite action or result, or a step past ``T_s``, was seen since
        #: its last reset. Read by :meth:`raise_if_invalid`.
        self.invalid = self.xp.zeros(n_episodes, dtype=self.xp.bool, device=chosen)
        self.row_limit: float | None = None  # see NumpyBackend.limit_rows
        self.quiet_disagreement = math.inf

    def _namespace(self) -> Any:
        import torch

        return namespace(torch.empty(0, device=self.device))

    def array(self, values: Any, dtype: Any = None) -> Any:
        return self.xp.asarray(np.array(values), dtype=self.dtype if dtype is None else dtype, device=self.device)

    def spare(self, shape: tuple[int, ...]) -> None:
        return None

    def generator(self, seed: int | None) -> Any:
        """A ``torch.Generator`` on the device (None on ``meta``, which draws shapes only); ``seed`` in ``[0, 2**64)``."""
        import torch

        seed = torch_seed("seed", seed)

        if self.device.type == "meta":
            return None
        generator = torch.Generator(device=self.device)
        if seed is None:
            generator.seed()
        else:
            generator.manual_seed(int(seed))
        return generator

    def uniform(self, rng: Any, shape: tuple[int, ...]) -> Any:
        import torch

        return torch.rand(shape, generator=rng, dtype=self.dtype, device=self.device)

    def normal(self, rng: Any, shape: tuple[int, ...]) -> Any:
        import torch

        return torch.randn(shape, generator=rng, dtype=self.dtype, device=self.device)

    def checked(self, actions: object, expected: tuple[int, ...], name: str = "actions") -> Any:
        """Shape and dtype checked at once (known on the host); a non-finite entry sets :attr:`invalid`.

        A numpy array (already on the host) is checked in full at once, like numpy's, and
        converted to a tensor on the device.
        """
        import torch

        xp = self.xp
        if isinstance(actions, np.ndarray):
            return self.array(validation.action_array(name, actions, expected))
        if not isinstance(actions, torch.Tensor):
            raise ArgumentError(f"{name}: expected a torch tensor of shape {expected}, got {type(actions).__name__}")
        if tuple(actions.shape) != expected:
            raise ArgumentError(f"{name}: expected shape {expected}, got {tuple(actions.shape)}")
        if not xp.isdtype(actions.dtype, ("real floating", "integral")):
            raise ArgumentError(f"{name}: expected real numbers, got dtype {actions.dtype}")
        actions = xp.astype(actions, self.dtype)
        self.flag(~xp.all(xp.isfinite(actions), axis=(1, 2)))
        return actions

    def commit_if_finite(self, current: Any, following: Any, refusal: Callable[[], ArgumentError]) -> tuple[Any, Any]:
        """Adopt the new state; episodes whose disagreement or energy is not finite are flagged."""
        xp = self.xp
        finite = xp.isfinite(following.disagreement) & xp.all(xp.isfinite(following.energy), axis=-1)
        self.flag(~finite)
        if self.row_limit is not None:  # raw float32 observations: rows beyond float32's range
            self.flag(self.largest_difference(following.state) > self.row_limit)
        return following.state, None

    def flag(self, mask: Any) -> None:
        """Mark the episodes of the ``(B,)`` boolean ``mask`` (None: none) as not to be trusted."""
        if mask is not None:
            self.invalid = self.invalid | mask

    def clear_flags(self, episodes: Any = None) -> None:
        """Clear the flags of the restarted ``episodes`` (a ``(B,)`` mask; None: all)."""
        zeros = self.xp.zeros_like(self.invalid)
        self.invalid = zeros if episodes is None else self.xp.where(episodes, zeros, self.invalid)

    def checked_state(
        self, name: str, value: Any, shape: tuple[int, ...], limit: float = validation.STATE_LIMIT
    ) -> Any:
        """A ``shape`` real state on the device, entries finite and within ``±limit``; raise naming ``name``.

        numpy input is checked in full, as on numpy (:func:`fxc_env.core.validation.state_batch`),
        and copied to the device; a tensor's shape and dtype are checked on the host, its values
        by :meth:`check_state_values`.
        """
        import torch

        if isinstance(value, np.ndarray | list | tuple):
            return self.array(validation.state_batch(name, value, shape, limit))
        if not isinstance(value, torch.Tensor):
            raise ArgumentError(f"{name}: expected a torch tensor of shape {shape}, got {type(value).__name__}")
        if tuple(value.shape) != shape:
            raise ArgumentError(f"{name}: expected shape {shape}, got {tuple(value.shape)}")
        if not self.xp.isdtype(value.dtype, ("real floating", "integral")):
            raise ArgumentError(f"{name}: expected real numbers, got dtype {value.dtype}")
        return self.xp.astype(value.to(self.device), self.dtype)

    def check_state_values(self, named: dict[str, Any], limit: float = validation.STATE_LIMIT) -> None:
        """Raise naming the first of ``named``'s tensors with a NaN, an infinity or an entry beyond ``±limit``.

        One read off the device for all of them (none on ``meta``): a NaN propagates through
        the largest magnitude, which then fails the comparison like an infinity does.
        """
        import torch

        if self.device.type == "meta":
            return
        within = torch.stack([value.abs().amax() for value in named.values()]) <= limit
        if not bool(within.all()):
            raise ArgumentError(validation.state_entries_error(list(named)[int(to_host(~within).argmax())], limit))

    def raise_if_invalid(self) -> None:
        """Raise :class:`ArgumentError` if any episode was flagged (one read off the device), clearing the flags."""
        bad = np.flatnonzero(to_host(self.invalid))
        if len(bad):
            # Reported once: the flags are cleared, so the next reset starts clean episodes
            # (a flag left set would make every later reset raise the same error).
            self.clear_flags()
            raise ArgumentError(
                f"actions: episodes {bad[:10].tolist()} received a non-finite action, overflowed float64 (or, with "
                'obs_dtype="float32" and obs_mode="raw", took states apart beyond float32\'s range) or were '
                "stepped past T_s since their last reset; reset them (their states are not to be trusted)"
            )


def make_backend(device: Any, dtype: str, n_episodes: int) -> NumpyBackend:
    """:class:`NumpyBackend` for ``device=None``, else :class:`TorchBackend` on ``device``."""
    return NumpyBackend(dtype, n_episodes) if device is None else TorchBackend(device, dtype, n_episodes)
