"""A learned gain schedule: one 2 x 2 gain per sampling interval on the agent's aggregated relative row.

:class:`IntervalGainPolicy` is the network of the shipped ``rings`` policy (docs: training.md, "Training
learned policies"). Agent i reads its in-neighbour rows through the observation layout
(:class:`fxc_env.config.layout.ObservationLayout`; masked rows are ignored), forms the aggregated
relative row

    r_i = (1 / (d_i + 1)) sum_{j in N_i} (z_j - z_i),    z = (x, v)    (normalized units: 1, T_{k+1}),

and plans ``(alpha_x, alpha_v) = G_k r_i`` with ``k`` read off the clock and ``G_k`` a learned
``(K, 2, 2)`` float64 table in normalized units (``alpha_x = a_x / s_i``, ``alpha_v = T_{k+1} a_v /
s_i``); the paper's controller (eq. 11) is ``G_k = [[1, 1], [0, 1]]``. A table is tied to the
graph's spectrum, schedule, ``K`` and ``N``: outside its training domain it is refused by name
unless ``allow_out_of_domain=True``.

**File format** (``.npz``, read with ``allow_pickle=False``: nothing in it runs): ``gains``
``(K, 2, 2)`` float64 and ``header``, a JSON string: ``format`` (:data:`FORMAT`), ``name``,
``env`` (:func:`fxc_env.policies.policy_files.training_settings` of the training environment:
schedule, modes, ``dim``, ``obs_slots`` (for the record: the table reads any), ``n_agents``, ``n_intervals``, ``settling_time``,
``u_max``), ``topology`` (the graph family, e.g. ``{"family": "ring", "relabel": true}``),
``eigenvalues`` (the spectrum of ``(D + I)^{-1} L`` it was trained on, ``[[re, im], ...]``, 0 included),
``domain`` (:func:`fxc_env.policies.domain.training_domain` of the training environment; derived
from ``env`` and ``topology`` for a file without it) and ``training`` (how it was made: command,
method, wall time, figures).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.core.validation import ArgumentError
from fxc_env.policies.protocol import Policy

#: The ``format`` entry of a gain-schedule file's header.
FORMAT = "fxc_env.interval_gains/1"
#: The ``format`` of a two-regime schedule (:mod:`fxc_env.policies.regime_gains`), read here too.
REGIME_FORMAT = "fxc_env.regime_gains/1"
#: Readers of the other gain-schedule formats by ``format``: ``reader(path, gains, switching_gains, header)``.
#: A module that defines a format registers it here on import (:mod:`fxc_env.policies` imports them all).
FORMAT_READERS: dict[str, Callable[..., Any]] = {}
#: Settings of the environment a gain schedule must meet exactly (what its inputs and outputs mean),
#: with the keyword that sets each; where it was trained (N, K, T_s, schedule, graphs) is its domain.
MATCHED_SETTINGS = {
    "action_mode": "action_mode",
    "obs_mode": "obs_mode",
    "dim": "dim",
    "limit_feature": "u_max",
    "agent_model": "agent_model",
}


class IntervalGainPolicy(Policy):
    """The plan ``G_k r_i`` of a learned ``(K, 2, 2)`` gain table, every agent alike, deterministic.

    Args:
        gains: ``(K, 2, 2)`` gains in normalized units (see the module), float64.
        header: the file's header (see the module); ``env`` must hold the training settings.
        source: where it was read from, for messages.

    Attributes:
        gains, header, source; ``obs_size`` and ``action_size`` of the training environment;
        ``training_settings`` (the header's ``env``), as the other learned policies.
    """

    #: The settings :meth:`check` matches exactly (:data:`MATCHED_SETTINGS`).
    matched_settings = MATCHED_SETTINGS

    def __init__(self, gains: np.ndarray, header: Mapping[str, Any], source: str | Path | None = None) -> None:
        from fxc_env.config.layout import ObservationLayout
        from fxc_env.policies.records import checked_domain, file_number

        label = source or "the gain schedule"
        gains = np.asarray(gains, dtype=np.float64)
        settings = header.get("env")
        if not isinstance(settings, Mapping):
            raise ArgumentError(f"policy: {label}: env: expected the training settings (a mapping), got {settings!r}")
        settings = dict(settings)
        for key in ("n_intervals", "obs_slots", "dim"):
            file_number(label, f"env.{key}", settings.get(key), integral=True, minimum=1)
        if gains.ndim != 3 or gains.shape[1:] != (2, 2):
            raise ArgumentError(f"gains: expected a (K, 2, 2) table, got shape {gains.shape}")
        if settings["n_intervals"] != len(gains):
            raise ArgumentError(
                f"gains: the table has {len(gains)} intervals; the header's env records "
                f"n_intervals={settings.get('n_intervals')!r}"
            )
        if not np.all(np.isfinite(gains)):
            raise ArgumentError("gains: the table holds non-finite entries")
        checked_domain(header.get("domain"), label)
        self.gains = gains
        self.header = dict(header)
        self.source = source
        self.training_settings: dict[str, Any] = settings
        self.layout = ObservationLayout(int(settings["obs_slots"]), int(settings["dim"]))
        self.obs_size = self.layout.size
        self.action_size = 2 * int(settings["dim"])

    @property
    def n_intervals(self) -> int:
        return len(self.gains)

    @property
    def training_domain(self) -> dict[str, Any]:
        """Where the table was learned (:mod:`fxc_env.policies.domain`): the header's ``domain``, or for a
        file without one its ``env`` settings and ``topology`` family on ideal agents with periodic switching."""
        if self.header.get("domain") is not None:  # checked on load (records.checked_domain)
            return dict(self.header["domain"])
        from fxc_env.policies.domain import domain_from_settings

        domain = dict(domain_from_settings(self.training_settings) or {})
        family = dict(self.header.get("topology", {}))
        if "family" in family:
            period = family.get("period", 1)
            period = [int(period), int(period)] if isinstance(period, int | float) else [int(p) for p in period]
            domain["graphs"] = [{"family": family["family"], "period": period}]
        domain.update(switching=["periodic"], obs_noise=[0.0, 0.0], link_dropout=[0.0, 0.0])
        domain.pop("partial", None)
        return domain

    def read_slots(self, slots: int, dim: int | None = None) -> None:
        """Read observations with ``slots`` neighbour slots (any ``obs_slots``: ``r_i`` sums the real rows only).

        The aggregated row, and so the plan, is the same whatever the padding: masked rows enter
        the sum as exact zeros, and adding a zero rounds nothing. ``dim`` (only where ``dim`` is not a
        matched setting) reads another dimension, every axis planned alike.
        """
        from fxc_env.config.layout import ObservationLayout

        if dim is not None and "dim" in self.matched_settings and dim != self.layout.dim:
            raise ArgumentError(f"dim: this gain schedule reads dim={self.layout.dim} only, got {dim}")
        dim = self.layout.dim if dim is None else int(dim)
        self.layout = ObservationLayout(int(slots), dim, self.layout.limit_feature)
        self.obs_size = self.layout.size
        self.action_size = 2 * dim

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Plans ``(..., 2 dim)`` (``alpha_x`` then ``alpha_v``) for flat observations ``(..., obs_size)``."""
        _, _, _, k, r = self._read(obs)
        plan = self.gains[k] @ r  # (..., 2, dim)
        return np.concatenate([plan[..., 0, :], plan[..., 1, :]], axis=-1)

    def _read(self, obs: np.ndarray) -> tuple[np.ndarray, ...]:
        """``(rows, mask, clock, k, r)`` of flat observations: their parts, the interval ``k`` ``(...)`` and the
        aggregated relative row ``r`` ``(..., 2, dim)`` (masked rows left out)."""
        if obs.shape[-1] != self.obs_size:
            raise ArgumentError(f"observations: expected shape (..., {self.obs_size}), got {obs.shape}")
        rows, mask, clock = self.layout.split(obs)  # rows (..., slots, 2, dim)
        real = mask[..., None, None] > 0.5
        r = np.sum(np.where(real, rows, 0.0), axis=-3) / (np.sum(mask > 0.5, axis=-1)[..., None, None] + 1.0)
        k = np.clip(np.rint(clock[..., 2] * self.n_intervals).astype(np.int64), 0, self.n_intervals - 1)
        return rows, mask, clock, k, r

    def save(self, path: str | Path) -> Path:
        """Write the table and its header to ``path`` (``.npz``, no pickled objects)."""
        path = Path(path)
        header = {**self.header, "format": FORMAT}
        np.savez_compressed(path, gains=self.gains, header=np.array(json.dumps(header, sort_keys=True)))
        return path

    def check(self, env: Any, allow_out_of_domain: bool = False) -> None:
        """Refuse an environment this table was not trained for, naming the setting and both values.

        Checks every setting of :attr:`matched_settings` (what the table's inputs and outputs
        mean), then its training domain (:func:`fxc_env.policies.domain.check_domain`: N, K, T_s,
        schedule, ideal agents without ``obs_noise`` or ``link_dropout``, no switching, and the
        graph: a family must be the trained one, a fixed graph a directed ring in any labelling,
        whose ``(D + I)^{-1} L`` has the trained spectrum: the gains cancel those modes and no
        others). ``allow_out_of_domain`` runs it outside its domain with a warning naming every
        difference.
        """
        from fxc_env.config import config_of
        from fxc_env.policies.domain import check_domain
        from fxc_env.policies.policy_files import training_settings

        config = config_of(env, "IntervalGainPolicy")
        domain = self.training_domain
        here = training_settings(config)
        name = self.header.get("name", "this gain schedule")
        for key, keyword in self.matched_settings.items():
            trained, got = self.training_settings.get(key), here.get(key)
            if trained != got:
                raise ArgumentError(
                    f"{keyword}: the {name} policy was trained with {key}={trained!r}; this environment has "
                    f"{key}={got!r} (its gain table fits only the setting it was learned on)"
                )
        check_domain(domain, config, self.source or f"the {name} policy", allow_out_of_domain, stacklevel=4)

    def fit_to(self, config: Any, *, check: bool = True, allow_out_of_domain: bool = False) -> IntervalGainPolicy:
        """This table once it fits ``config``: :meth:`check` (unless ``check=False``), then it reads ``config``'s
        observations (:meth:`read_slots`), whose sizes must be its own (refused naming ``policy`` and both sizes)."""
        if check:
            self.check(config, allow_out_of_domain)
        self.read_slots(config.layout.slots, None if "dim" in self.matched_settings else config.dim)
        if (config.layout.size, config.action_size) != (self.obs_size, self.action_size):
            raise ArgumentError(
                f"policy: the table takes observations of size {self.obs_size}; this environment has "
                f"{config.layout.size}"
            )
        return self


def spectrum_matrix(topology: Any, g: int = 0) -> np.ndarray:
    """``Ŵ = (D + I)^{-1} L`` of graph ``g`` of a topology (its only one: a fixed topology), dense ``(N, N)``."""
    laplacian = topology.laplacian(g)
    laplacian = laplacian.toarray() if hasattr(laplacian, "toarray") else np.asarray(laplacian)
    return laplacian / (np.asarray(topology.in_degree[g], dtype=np.float64)[:, None] + 1.0)


def spectrum(topology: Any) -> np.ndarray:
    """The eigenvalues of ``(D + I)^{-1} L`` of a fixed topology, ``(N,)`` complex (dense; consensus mode 0 included)."""
    return np.linalg.eigvals(spectrum_matrix(topology))


def read_interval_gains(path: str | Path) -> IntervalGainPolicy:
    """The policy saved at ``path`` (``.npz``), read with ``allow_pickle=False``."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"policy: no gain-schedule file at {path}")
    try:
        with np.load(path, allow_pickle=False) as arrays:
            gains = np.array(arrays["gains"], dtype=np.float64)
            header = json.loads(str(arrays["header"]))
            switching = arrays["switching_gains"] if "switching_gains" in arrays.files else None
            switching = None if switching is None else np.array(switching, dtype=np.float64)
    except (KeyError, ValueError, OSError) as exc:
        raise ArgumentError(f"policy: {path} is not a gain-schedule file ({type(exc).__name__}: {exc})") from exc
    reader = FORMAT_READERS.get(header.get("format")) if isinstance(header, dict) else None
    if reader is not None:
        return reader(path, gains, switching, header)
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise ArgumentError(f"policy: {path} is not a {FORMAT!r} file")
    return IntervalGainPolicy(gains, header, source=path)


def load_interval_gains(
    path: str | Path, env: Any = None, *, check: bool = True, allow_out_of_domain: bool = False
) -> IntervalGainPolicy:
    """Read the policy at ``path``; with ``env``, refuse it (:meth:`IntervalGainPolicy.check`) unless it fits.

    ``allow_out_of_domain`` runs it outside its training domain with a warning naming every
    difference. ``check=False`` skips the settings and domain checks, silently (the observation
    size must still fit): for measuring, in training code, how a table transfers to settings it
    was not trained for.
    """
    policy = read_interval_gains(path)
    if env is not None:
        from fxc_env.config import config_of

        policy.fit_to(config_of(env, "policy"), check=check, allow_out_of_domain=allow_out_of_domain)
    return policy
