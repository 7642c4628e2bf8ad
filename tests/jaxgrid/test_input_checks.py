"""Inputs that used to be read wrong are refused by name: numbers in sentences, setting types,
and fixed HazardRooms sentences that layouts can rarely satisfy."""

from __future__ import annotations

import dataclasses
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrid
from jaxgrid import hazard as HZ
from jaxgrid import language as L
from jaxgrid import monitor as M
from jaxgrid import parsing

LAVA = L.Target("lava")
BUDGET = r"a budget counts 1 to 10 times"
DISTANCE = r"a distance is 1 to 3 cells"

# ------------------------------------------------------------------- numbers in sentences

BAD_NUMBERS = [
    ("do not step on lava more than -1 times", "-1", "is negative", BUDGET),
    ("stay -2 cells away from lava", "-2", "is negative", DISTANCE),
    ("stay - 2 cells away from lava", "-2", "is negative", DISTANCE),
    ("stay minus two cells away from lava", "minus two", "is negative", DISTANCE),
    ("touch lava no more than negative three times", "negative three", "is negative", BUDGET),
    ("do not step on lava more than 1.5 times", "1.5", "is not a whole number", BUDGET),
    ("keep 2.5 cells away from water", "2.5", "is not a whole number", DISTANCE),
    ("do not step on lava more than +2 times", "+2", "is not written as the grammar", BUDGET),
    ("use the red door at most 007 times", "007", "is not written as the grammar", BUDGET),
    ("do not step on lava more than 10000 times", "10000", "is out of range", BUDGET),
    ("do not step on lava more than 1,000 times", "1,000", "is out of range", BUDGET),
    ("do not step on lava more than 0 times", "0", "is out of range", BUDGET),
    ("do not step on lava more than zero times", "zero", "is out of range", BUDGET),
    ("touch the blue floor no more than eleven times", "eleven", "is out of range", BUDGET),
    ("stay 5 cells away from lava", "5", "is out of range", DISTANCE),
    ("keep four cells away from water", "four", "is out of range", DISTANCE),
    ("avoid lava and stay 10 cells away from grass", "10", "is out of range", DISTANCE),
]


@pytest.mark.parametrize("sentence, numeral, why, allowed", BAD_NUMBERS)
def test_a_number_a_clause_cannot_take_is_refused_with_its_sign_and_range(
    sentence, numeral, why, allowed
):
    message = rf"number {re.escape(repr(numeral))} at position \d+ in .* {why}.*: {allowed}"
    with pytest.raises(ValueError, match=message):
        L.parse(sentence)
    with pytest.raises(ValueError, match=message):
        L.tokenize(sentence)


@pytest.mark.parametrize(
    "sentence, clause",
    [
        ("do not step on lava more than 3 times", L.Clause("budget", LAVA, count=3)),
        ("do not step on lava more than three times", L.Clause("budget", LAVA, count=3)),
        ("do not step on lava more than 10 times", L.Clause("budget", LAVA, count=10)),
        ("do not step on lava more than ten times", L.Clause("budget", LAVA, count=10)),
        ("step on lava at most 1 time", L.Clause("budget", LAVA, count=1)),
        ("stay 3 cells away from lava.", L.Clause("proximity", LAVA, distance=3)),
        ("stay one cell away from lava", L.Clause("proximity", LAVA, distance=1)),
        # A hyphen between a number and a word is a separator, not a sign.
        ("do not step on lava more than 3-times", L.Clause("budget", LAVA, count=3)),
    ],
)
def test_numbers_in_range_still_parse_as_words_and_digits(sentence, clause):
    assert L.parse(sentence).clauses == (clause,)


def test_numerals_stay_whole_words_with_their_sign():
    assert L.normalize("stay -2 cells, - 3 or +1.5 and 1,000") == [
        "stay", "-2", "cells", "-3", "or", "+1.5", "and", "1,000",
    ]  # fmt: skip
    assert L.normalize("do-not-use the red door, 3-times 1st") == [
        "do", "not", "use", "the", "red", "door", "3", "times", "1st",
    ]  # fmt: skip
    assert parsing.numeral_value("-1") == -1 and parsing.numeral_value("1.5") == 1.5
    assert parsing.numeral_value("twenty") == 20 and parsing.numeral_value("lava") is None


def test_a_signed_number_where_no_number_goes_is_named_by_position():
    with pytest.raises(ValueError, match=r"unexpected word '-1' at position 7"):
        L.parse("do not use the red door -1")


def test_the_monitor_refuses_a_distance_or_budget_it_cannot_represent():
    # The widest zone the language allows is drawn in full; one cell more would be cut short.
    grid = np.zeros((9, 9, 3), np.uint8)
    grid[..., 0] = 1
    grid[4, 4, 0] = 9  # lava
    zone, _ = M.zone_masks(jnp.asarray(grid), M.encode(L.Clause("proximity", LAVA, distance=3)))
    xs, ys = np.meshgrid(np.arange(9), np.arange(9), indexing="ij")
    np.testing.assert_array_equal(np.asarray(zone[0]), np.abs(xs - 4) + np.abs(ys - 4) <= 2)
    with pytest.raises(ValueError, match=r"distance must be an int in 0\.\.3, got 4"):
        M.encode(L.Clause("proximity", LAVA, distance=L.MAX_DISTANCE + 1))
    with pytest.raises(ValueError, match=r"count must be an int in 0\.\.10, got -1"):
        M.encode(L.Clause("budget", LAVA, count=-1))


# ------------------------------------------------------------------- setting types


def _typed_settings(env, declared: str) -> list[str]:
    return [f.name for f in dataclasses.fields(env) if f.type == declared]


def test_every_bool_setting_of_every_id_refuses_a_non_bool():
    checked = 0
    for env_id in jaxgrid.registered_ids():
        env = jaxgrid.make(env_id)
        for field in _typed_settings(env, "bool"):
            for value in ("False", 1, None):
                message = (
                    rf"{type(env).__name__}\.{field} must be a bool \(True or False\), "
                    rf"got {re.escape(repr(value))}"
                )
                with pytest.raises(ValueError, match=message):
                    jaxgrid.make(env_id, **{field: value})
            checked += 1
    assert checked >= len(jaxgrid.registered_ids())  # see_through_walls at least, everywhere


def test_every_int_setting_of_every_id_refuses_a_bool_a_float_or_a_string():
    for env_id in jaxgrid.registered_ids():
        env = jaxgrid.make(env_id)
        for field in _typed_settings(env, "int"):
            for value in (True, 5.5, 5.0, "5"):
                # The level's own check may come first; either way it names field and value.
                message = rf"\.{field} must be .*got {re.escape(repr(value))}"
                with pytest.raises(ValueError, match=message):
                    jaxgrid.make(env_id, **{field: value})


def test_the_reported_cases_are_refused_and_good_values_accepted():
    with pytest.raises(ValueError, match=r"TwoRooms\.has_lava must be a bool .*got 'False'"):
        jaxgrid.make("TwoRooms-v0", has_lava="False")
    with pytest.raises(ValueError, match=r"TwoRooms\.max_steps must be an int, got True"):
        jaxgrid.make("TwoRooms-v0", max_steps=True)
    with pytest.raises(ValueError, match=r"TwoRooms\.view_size must be an int, got 5\.5"):
        jaxgrid.make("TwoRooms-v0", view_size=5.5)
    with pytest.raises(ValueError, match=r"absent_colour_prob must be a number.*got True"):
        jaxgrid.make("TwoRooms-v0", absent_colour_prob=True)
    with pytest.raises(ValueError, match=r"absent_colour_prob must be a number.*got '0\.5'"):
        jaxgrid.make("TwoRooms-v0", absent_colour_prob="0.5")
    with pytest.raises(ValueError, match=r"HazardRooms\.budgets must be .* ints 1\.\.10"):
        jaxgrid.make("HazardRooms-v0", budgets=(True, 2))
    assert jaxgrid.make("TwoRooms-v0", has_lava=False).has_lava is False
    probs = jaxgrid.make("TwoRooms-v0", absent_colour_prob=jnp.array([0.1, 0.5]))
    assert probs.absent_colour_prob.shape == (2,)  # a leaf may be an array, to vmap over


# ------------------------------------------------------------------- satisfiable sentences

RARE = "stay three cells away from lava and stay three cells away from water"


def test_a_rarely_satisfiable_sentence_is_refused_at_make_naming_it_and_its_share():
    share = HZ.satisfiable_share(jaxgrid.make("HazardRooms-v0"), RARE)
    assert share < HZ.MIN_SATISFIABLE_SHARE
    message = f"{RARE!r} can rarely be met: only {share:.1%} of 256 sampled 13x13 layouts"
    with pytest.raises(ValueError, match=re.escape(message)):
        jaxgrid.make("HazardRooms-v0", sentences=(RARE,))
    with pytest.raises(ValueError, match=re.escape(repr(RARE))):
        jaxgrid.make("HazardRooms-v0", sentences=("avoid lava", RARE))


def test_satisfiable_shares_rank_constraints_and_the_hardest_default_rows_are_accepted():
    env = jaxgrid.make("HazardRooms-v0")
    easy = HZ.satisfiable_share(env, "avoid lava")
    hard = HZ.satisfiable_share(env, "stay three cells away from lava")
    assert easy > 0.9 and HZ.MIN_SATISFIABLE_SHARE < hard < easy
    assert HZ.satisfiable_share(env.replace(max_steps=7), "avoid lava") == easy  # cached, same
    # The default tables' hardest rows (about 15% of layouts) stay usable as fixed sentences.
    hardest = ("stay three cells away from lava", "keep three cells away from the blue floor")
    assert jaxgrid.make("HazardRooms-v0", sentences=hardest).sentences == hardest


def test_an_unsatisfiable_layout_is_flagged_in_info(monkeypatch):
    monkeypatch.setattr(HZ, "MIN_SATISFIABLE_SHARE", 0.0)  # let the rare sentence through
    env = jaxgrid.make("HazardRooms-v0", sentences=(RARE,))
    states, ts = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 64))
    flag = np.asarray(ts.info["satisfiable"])
    assert flag.dtype == bool and 0 < flag.sum() < len(flag)
    # The flag is exactly whether the kept layout has a route outside every zone.
    zones = jnp.any(states.extras.monitor.zone, axis=1)
    route = jax.vmap(HZ.solvable)(states.grid, states.agent_pos, zones)
    np.testing.assert_array_equal(flag, np.asarray(route))
    state = jax.tree.map(lambda a: a[0], states)
    _, step = jax.jit(env.step)(state, jnp.int32(2))
    assert bool(step.info["satisfiable"]) == bool(flag[0])  # the same all episode long
