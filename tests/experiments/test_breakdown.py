"""Replaying a finished run split by constraint: the agents restored as trained, every
episode in one template group and one colour group, bad input named before any work."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from helpers.agents_cases import SEEDS, TINY

from agents.runner import load_agents, run
from experiments import breakdown


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    return out, run(TINY, seeds=SEEDS, out_dir=out, progress=False)


def test_agents_load_as_trained_without_changing_the_directory(finished):
    out, result = finished
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    agents = load_agents(out)
    assert agents["complete"] and agents["seeds"] == list(SEEDS)
    assert agents["config"] == dataclasses.replace(TINY, seed=agents["config"].seed)
    for a, b in zip(jax.tree.leaves(agents["params"]), jax.tree.leaves(result["params"]),
                    strict=True):  # fmt: skip
        np.testing.assert_array_equal(a, b)
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before


def test_every_episode_falls_in_one_template_and_one_colour_group(finished, tmp_path):
    out, _ = finished
    cfg = breakdown.BreakdownConfig(run=str(out), episodes=24, out=str(tmp_path / "b.json"))
    result = breakdown.run(cfg)
    assert [r["seed"] for r in result["agents"]] == list(SEEDS)
    for row in result["agents"]:
        for kind in ("template", "colour"):
            groups = {k: g for k, g in row["groups"].items() if k.startswith(kind)}
            assert sum(g["episodes"] for g in groups.values()) == 24
            overall = sum(g["episodes"] * g["violation_rate"] for g in groups.values()) / 24
            assert overall == pytest.approx(row["violation_rate"])
    assert (tmp_path / "b.json").exists()


def test_groups_name_the_colours_a_sentence_names():
    from jaxgrid import language

    tokens = language.tokenize_batch(["avoid the red door", "no blue door and no lava",
                                      "avoid the red door"])  # fmt: skip
    masks = breakdown.groups(tokens, np.array([3, 2, 3]))
    assert masks["colour red"].tolist() == [True, False, True]
    assert masks["colour blue"].tolist() == [False, True, False]
    assert masks["template 3: avoid the red door"].tolist() == [True, False, True]


@pytest.mark.parametrize(
    ("argv", "message"),
    [([], "no run.json"), (["--run", "/nonexistent"], "no run.json"),
     (["--episodes", "0"], "episodes must be")],
)
def test_bad_input_is_named(argv, message, finished, capsys):
    out, _ = finished
    argv = argv if "--run" in argv or not argv else ["--run", str(out), *argv]
    with pytest.raises(SystemExit) as e:
        breakdown.main(argv)
    assert e.value.code == 2
    assert message in capsys.readouterr().err
