"""Hyperparameter sweeps in one program: ``agents.runner.run(..., sweep={name: values})``.

Each agent of a sweep must train as a run of its own with that value in the config would
(the swept value is traced instead of constant, so equal up to float rounding), the records
must say which agent is which, and a resume must name the same sweep.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers.agents_cases import TINY, count_compiles, leaves

from agents.config import SWEEPABLE
from agents.runner import run

SHAPED = dataclasses.replace(TINY, reward_mode="shaped", env_id="TwoRooms-v0")
SWEEP = {"penalty": (0.5, 2.0), "ent_coef": (0.0, 0.05)}
SEEDS = (0, 1)


@pytest.fixture(scope="module")
def swept():
    with count_compiles() as compiled:
        result = run(SHAPED, seeds=SEEDS, progress=False, sweep=SWEEP, final_episodes=4)
    return result, compiled


def test_agents_are_every_combination_times_every_seed(swept):
    r, _ = swept
    n = 2 * 2 * len(SEEDS)
    assert r["seeds"] == [0, 1] * 4
    np.testing.assert_array_equal(r["sweep"]["penalty"], [0.5] * 4 + [2.0] * 4)
    np.testing.assert_array_equal(r["sweep"]["ent_coef"], [0.0, 0.0, 0.05, 0.05] * 2)
    assert r["eval"]["success_rate"].shape == (n, SHAPED.num_chunks)
    assert r["final"]["success_rate"].shape == (n,)
    assert len(r["records"]) == n * SHAPED.num_chunks
    first = r["records"][:n]
    assert [(x["seed"], x["penalty"], x["ent_coef"]) for x in first] == [
        (s, p, e) for p in (0.5, 2.0) for e in (0.0, 0.05) for s in SEEDS
    ]


@pytest.mark.slow
def test_each_agent_trains_like_its_own_run(swept):
    """Seed 1 with penalty 2.0 and entropy 0.05 is agent 7: the same as a run of that config."""
    r, _ = swept
    own = run(dataclasses.replace(SHAPED, penalty=2.0, ent_coef=0.05), seeds=(1,), progress=False)
    for mine, theirs in zip(leaves(r["params"]), leaves(own["params"]), strict=True):
        np.testing.assert_allclose(np.asarray(mine)[7], np.asarray(theirs)[0], atol=1e-5)
    np.testing.assert_allclose(r["eval"]["mean_reward"][7], own["eval"]["mean_reward"][0],
                               atol=1e-5)  # fmt: skip
    # ... and the values really differ between agents of the same seed.
    kernel = np.asarray(leaves(r["params"])[0])
    assert not np.allclose(kernel[1], kernel[7])


def test_sweep_is_one_program_and_a_rerun_compiles_nothing(swept):
    _, compiled = swept
    assert compiled  # the sweep's programs
    with count_compiles() as again:
        run(SHAPED, seeds=SEEDS, progress=False, sweep=SWEEP)
    assert again == []


def test_resume_needs_the_same_sweep(tmp_path, swept):
    # The fixture's program (same sweep, same agents): nothing compiles again.
    run(SHAPED, seeds=SEEDS, progress=False, sweep=SWEEP, out_dir=tmp_path, max_chunks=1)
    other = {**SWEEP, "penalty": (0.5, 1.0)}
    with pytest.raises(ValueError, match="it was run with sweep"):
        run(SHAPED, seeds=SEEDS, progress=False, sweep=other, out_dir=tmp_path)
    done = run(SHAPED, seeds=SEEDS, progress=False, sweep=SWEEP, out_dir=tmp_path)
    assert done["complete"] and done["records"] == swept[0]["records"]


@pytest.mark.parametrize(
    ("sweep", "message"),
    [
        ({"gamma": (0.9, 0.99)}, "cannot sweep 'gamma'"),
        ({"penalty": (0.5, 0.5)}, "distinct"),
        ({"penalty": ()}, "distinct"),
        ({"checker_threshold": (0.5, 1.0)}, "checker_threshold must be in"),
        ({"lr": (1e-3, -1.0)}, "lr must be > 0"),
    ],
)
def test_bad_sweeps_fail_before_compiling(sweep, message):
    with count_compiles() as compiled, pytest.raises(ValueError, match=message):
        run(SHAPED, seeds=(0,), progress=False, sweep=sweep)
    assert compiled == []


def test_sweepable_names_are_config_fields():
    fields = {f.name for f in dataclasses.fields(SHAPED)}
    assert set(SWEEPABLE) <= fields
