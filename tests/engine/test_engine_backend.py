"""The engine's array backend: numpy refuses a bad step at once, torch flags it on the device."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from fxc_env.core.validation import ArgumentError
from fxc_env.engine.agents import Interval
from fxc_env.engine.backend import NumpyBackend, make_backend


def interval(b, finite=True):
    energy = np.ones((b, 4))
    if not finite:
        energy[b - 1, 2] = np.inf
    return Interval(np.zeros((b, 4, 2, 1)), energy, energy, None, None, None, disagreement=np.ones(b))


def test_numpy_refuses_a_non_finite_interval_and_keeps_the_state():
    backend = NumpyBackend("float64", 2)
    current = np.ones((2, 4, 2, 1))
    with pytest.raises(ArgumentError, match="refused"):
        backend.commit_if_finite(
            current, interval(2, finite=False), lambda: backend.refusal(np.ones((2, 4, 2)), interval(2, False), 3, 0.5)
        )
    state, spare = backend.commit_if_finite(current, interval(2), lambda: None)
    assert spare is current and state is not current  # double buffering: the buffers swap


def test_numpy_checks_actions_in_full_naming_the_argument():
    backend = NumpyBackend("float64", 1)
    with pytest.raises(ArgumentError, match="actions"):
        backend.checked(np.ones((1, 3, 2)), (1, 4, 2))
    with pytest.raises(ArgumentError, match="my_actions"):
        backend.checked(np.full((1, 4, 2), np.nan), (1, 4, 2), "my_actions")


def test_torch_flags_bad_episodes_without_raising_until_asked():
    torch = pytest.importorskip("torch")
    backend = make_backend("cpu", "float64", 3)
    actions = torch.zeros((3, 4, 2))
    actions[1, 0, 0] = float("nan")
    backend.checked(actions, (3, 4, 2))  # no host read: the episode is flagged
    assert backend.invalid.tolist() == [False, True, False]
    with pytest.raises(ArgumentError, match=r"episodes \[1\]"):
        backend.raise_if_invalid()
    backend.clear_flags(torch.tensor([False, True, False]))
    backend.raise_if_invalid()


def test_a_bad_device_is_named():
    pytest.importorskip("torch")
    with pytest.raises(ArgumentError, match="device"):
        make_backend("not-a-device", "float64", 1)
    with pytest.raises(ArgumentError, match="dtype"):
        make_backend(None, "float16", 1)


def test_backends_pickle_without_their_namespace_module():
    backend = pickle.loads(pickle.dumps(NumpyBackend("float32", 2)))
    assert backend.zeros((2, 3)).dtype == np.float32 and backend.xp is not None
