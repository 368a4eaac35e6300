"""Lost links: every law that claims exactness refuses ``link_dropout`` by name unless opted in, says what a lost
link costs, and ``fxc benchmark --suite dropout`` reports the curve with the share of exact seeds."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from PIL import Image

from fxc_env.baselines.harness.dropout import DROPOUT_LEVELS, dropout_contenders
from fxc_env.baselines.harness.suite import load_policy
from fxc_env.baselines.registry import LAWS
from fxc_env.cli import main
from fxc_env.config import make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine

EXACT_LAWS = ("minimum_time", "leader_follower", "signalling", "graph_agnostic", "bounded_steer")
RING = dict(topology="ring", n_agents=6, n_intervals=60, schedule="uniform", action_mode="plan", obs_mode="raw")


def test_every_law_that_claims_exactness_has_a_lossy_opt_in_and_no_other_law_refuses_dropout():
    lossy = {law.name for law in LAWS.values() for o in law.opt_ins if o.setting == "link_dropout"}
    assert lossy == set(EXACT_LAWS)
    assert [c.name for c in dropout_contenders()] == ["reference", *(f"{n}/lossy" for n in EXACT_LAWS)]


@pytest.mark.parametrize("name", EXACT_LAWS)
def test_without_the_opt_in_a_law_refuses_dropout_by_name_saying_what_a_lost_link_costs(name):
    config = make_config(**RING, link_dropout=0.01)
    with pytest.raises(ArgumentError, match=r"^link_dropout: .*allow_dropout=True runs it anyway") as caught:
        load_policy(name, config)
    assert LAWS[name].policy.LOST_LINK in str(caught.value)
    with pytest.raises(ArgumentError, match=r"^allow_dropout: expected True or False, got 'yes'"):
        LAWS[name].policy(config, allow_dropout="yes")
    # The opt-in is the law itself where nothing is lost: refused without link_dropout, naming it.
    with pytest.raises(ArgumentError, match=r"^link_dropout: .*lossy is .* opted in under link_dropout"):
        load_policy(f"{name}/lossy", make_config(**RING))


def run(policy, config, seeds=(0, 1, 2)):
    engine = ConsensusEngine(config, n_episodes=len(seeds))
    engine.reset_from_draws(
        [engine.draw_episode(np.random.default_rng(s)) for s in seeds], rng=np.random.default_rng(7)
    )
    while not engine.done:
        engine.step(np.asarray(policy(engine.observations()), dtype=np.float64))
    return engine.batch_metrics()["relative_deadline_error"]


@pytest.mark.parametrize("name", EXACT_LAWS)
def test_the_opt_in_runs_claims_no_exactness_and_is_exact_where_no_link_is_lost(name):
    lossy = load_policy(f"{name}/lossy", make_config(**RING, link_dropout=0.3))
    assert lossy.guarantee().startswith("no exact guarantee under link_dropout = 0.3 (exact wherever none of the ")
    assert lossy.LOST_LINK in lossy.guarantee()
    run(lossy, make_config(**RING, link_dropout=0.3))  # runs to T_s
    # At p = 1e-12 no draw loses a link: the opted-in law lands as exactly as the law itself.
    rare = make_config(**RING, link_dropout=1e-12)
    assert np.all(run(load_policy(f"{name}/lossy", rare), rare) <= 1e-9)


def test_the_dropout_suite_reports_median_worst_and_the_share_of_exact_seeds(tmp_path, capsys):
    argv = ["benchmark", "--suite", "dropout", "--quick", "--seeds", "4", "--out", str(tmp_path), "--no-progress"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "### Lost links" in printed
    with Image.open(tmp_path / "error_vs_dropout.png") as image:
        assert image.format == "PNG" and image.size[0] > 400
    episodes = list(csv.DictReader((tmp_path / "episodes.csv").open()))
    for contender in dropout_contenders():
        row = next(line for line in printed.splitlines() if line.startswith(f"| ring N=20 | {contender.name} |"))
        cells = [c.strip() for c in row.strip("|").split("|")[2:]]
        assert len(cells) == len(DROPOUT_LEVELS)
        for p, cell in zip(DROPOUT_LEVELS, cells, strict=True):
            case = f"ring N=20, link_dropout={p:g}"
            errors = [
                float(e["relative_deadline_error"])
                for e in episodes
                if (e["policy"], e["case"]) == (contender.name, case)
            ]
            assert len(errors) == 4
            share = sum(e <= 1e-9 for e in errors) / len(errors)
            assert cell.endswith(f"· {share:.0%}"), (contender.name, p, cell)
