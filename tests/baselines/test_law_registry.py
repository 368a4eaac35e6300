"""The law registry is the one list of laws: a law is named in its own module and the registry, the exports of
``fxc_env.baselines`` and ``fxc_env`` and the optimality figure's styles are read from it."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import fxc_env
from fxc_env import baselines
from fxc_env.baselines import figures
from fxc_env.baselines.registry import LAWS, Law, register

ROOT = Path(__file__).resolve().parents[2]
LIBRARY = [p for folder in ("fxc_env", "baselines", "training") for p in (ROOT / folder).rglob("*.py")]
BASELINE_LAWS = [law for law in LAWS.values() if law.policy.__module__.startswith("fxc_env.baselines.")]


def _files_naming(name: str) -> set[Path]:
    word = re.compile(rf"\b{name}\b")
    return {p for p in LIBRARY if word.search(p.read_text(encoding="utf-8"))}


def test_each_law_class_is_named_in_at_most_one_library_file_besides_its_own():
    """Adding a law touches its module and the registry only (a module subclassing a law names its base: that
    is the law's own code, not a list to edit)."""
    assert len(BASELINE_LAWS) >= 11
    crowded = {}
    for law in BASELINE_LAWS:
        cls = law.policy
        own = {Path(inspect.getfile(cls)).resolve()}
        own |= {Path(inspect.getfile(sub)).resolve() for sub in cls.__subclasses__()}
        others = _files_naming(cls.__name__) - own
        if len(others) > 1:
            crowded[cls.__name__] = sorted(str(p.relative_to(ROOT)) for p in others)
    assert not crowded


def test_the_exports_are_the_registered_laws():
    names = {law.policy.__name__ for law in BASELINE_LAWS}
    assert set(baselines.LAW_CLASSES) == names
    assert names <= set(baselines.__all__) and names <= set(fxc_env.__all__)
    for law in BASELINE_LAWS:
        assert getattr(baselines, law.policy.__name__) is law.policy is getattr(fxc_env, law.policy.__name__)


def test_a_newly_registered_law_gets_its_own_marker_and_colour(monkeypatch):
    monkeypatch.setattr("fxc_env.baselines.registry.LAWS", dict(LAWS))
    from fxc_env.baselines import registry
    from fxc_env.baselines.harness.suite import Contender

    for i in range(12):  # more laws than the hand-picked pairs
        register(Law(f"extra_{i}", LAWS["linear"].policy, True, "uniform", "accel", "raw"))
    contenders = [Contender(name, name, *law.settings) for name, law in registry.LAWS.items()]
    styles = [figures.optimality_style(contenders, c.name) for c in contenders]
    assert len({marker for marker, _ in styles}) == len({colour for _, colour in styles}) == len(contenders)
