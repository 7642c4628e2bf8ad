"""Constraints on any level: ``jaxgrid.make(id, constraint=..., constraints=..., weights=...,
lava=...)``, what the constrained level observes and reports, the draw of its sentences, the
lava rule, and every bad input refused by name before anything compiles.

The monitor's exactness on every family is ``test_level_monitor.py``; the MiniGrid step
rules under a constraint are there too and in ``test_differential.py``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.xla import CHEAP, batch_reset

import jaxgrid
from jaxgrid import language as L
from jaxgrid.constants import LAVA
from jaxgrid.constrained import (
    ConstrainedEnvironment,
    ConstrainedLevel,
    LevelExtras,
    constrain,
    language_table,
    sentence_tokens,
)
from jaxgrid.contents import Contents
from jaxgrid.sentences import LEVELS

LAVA_ID = "MiniGrid-LavaCrossingS9N1-v0"
BUDGET = "do not step on lava more than twice"


@functools.cache
def _resets(env, n: int, seed: int = 0):
    return jax.jit(jax.vmap(env.reset), compiler_options=CHEAP)(
        jax.random.split(jax.random.key(seed), n)
    )


def test_a_constraint_makes_any_level_a_constrained_env_with_the_declared_keys():
    env = jaxgrid.make(LAVA_ID, constraint=BUDGET, lava="cost")
    assert isinstance(env, ConstrainedLevel) and isinstance(env, ConstrainedEnvironment)
    assert language_table(env) is LEVELS and env.every_sentence_in_table
    np.testing.assert_array_equal(sentence_tokens(env)[0], LEVELS.tokenize(BUDGET))
    state, ts = env.reset(jax.random.key(0))
    state2, ts2 = env.step(state, jnp.int32(2))
    for t in (ts, ts2):
        assert sorted(t.observation) == sorted(env.OBSERVATION_KEYS)
        assert sorted(t.info) == sorted(env.INFO_KEYS)
        assert L.detokenize(t.observation["constraint"]) == BUDGET
        assert int(t.info["constraint_type"]) == L.CONSTRAINT_TYPES.index("budget")
        assert int(t.info["template_id"]) == -1
    assert isinstance(state2.extras, LevelExtras) and state2.extras.level == ()
    assert env.num_actions == 7 and env.max_steps == jaxgrid.make(LAVA_ID).max_steps
    assert env.mission_text(state) == jaxgrid.make(LAVA_ID).mission_text(state)


def test_without_a_constraint_the_level_is_unchanged():
    for env_id in (LAVA_ID, "MiniGrid-DoorKey-5x5-v0", "HazardRooms-v0"):
        plain = jaxgrid.make(env_id)
        assert jaxgrid.make(env_id, lava="lethal") == plain
        assert not isinstance(plain, ConstrainedLevel)


def test_a_constrained_reset_is_the_levels_reset_with_a_constraint():
    env = jaxgrid.make("MiniGrid-KeyCorridorS3R1-v0", constraint="do not use the red door")
    level = jaxgrid.make("MiniGrid-KeyCorridorS3R1-v0")
    states, ts = _resets(env, 16)
    plain, plain_ts = _resets(level, 16)
    inner = ConstrainedLevel.level_state(states)
    assert jax.tree.all(jax.tree.map(lambda a, b: bool(jnp.all(a == b)), inner, plain))
    for k in plain_ts.observation:
        np.testing.assert_array_equal(ts.observation[k], plain_ts.observation[k])


def test_a_random_colour_the_episode_lacks_leaves_its_constraint_vacuous():
    # KeyCorridorS3R1 draws its doors' colours: some episodes have no red door, and there the
    # forbidden zone is empty; in the others it is the red door's cells.
    env = jaxgrid.make("MiniGrid-KeyCorridorS3R1-v0", constraint="do not use the red door")
    states, _ = _resets(env, 64)
    grid = np.asarray(states.grid)
    red_doors = ((grid[..., 0] == 4) & (grid[..., 1] == 0)).sum(axis=(1, 2))
    zone = np.asarray(states.extras.monitor.zone)[:, 0].sum(axis=(1, 2))
    np.testing.assert_array_equal(zone, red_doors)
    assert (red_doors == 0).any() and (red_doors > 0).any()


def test_constraints_are_drawn_by_their_weights():
    sentences = ("avoid lava", "never stand next to lava", BUDGET)
    env = jaxgrid.make(LAVA_ID, constraints=sentences, weights=(6, 3, 1))
    states, _ = _resets(env, 2000)
    drawn = [L.detokenize(t) for t in np.asarray(states.extras.constraint.tokens)]
    share = np.array([drawn.count(s) for s in sentences]) / len(drawn)
    np.testing.assert_allclose(share, [0.6, 0.3, 0.1], atol=0.04)
    types = np.asarray(states.extras.constraint.type_id)
    assert set(types.tolist()) == {L.CONSTRAINT_TYPES.index(t) for t in
                                   ("avoid", "proximity", "budget")}  # fmt: skip


def test_a_table_draws_its_rows_the_level_holds_each_type_equally_often():
    env = jaxgrid.make("MiniGrid-DoorKey-5x5-v0", constraints=LEVELS)
    contents = env.contents()
    rows = [LEVELS.find(s) for s in env.draw.sentences]
    assert all(contents.allows(L.parse(r.sentence)) for r in rows)
    assert len(rows) == sum(contents.allows(L.parse(r.sentence)) for r in LEVELS.rows)
    states, _ = _resets(env, 2000)
    c = states.extras.constraint
    for tokens, template, ctype in zip(
        np.asarray(c.tokens[:50]), np.asarray(c.template_id), np.asarray(c.type_id),
        strict=False,
    ):  # fmt: skip
        row = LEVELS.find(L.detokenize(tokens))
        assert (row.template_id, row.type_id) == (template, ctype)
    types = {r.type_id for r in rows}
    assert types == {0, 1, 2, 3}  # DoorKey's door and key: every clause type
    share = np.bincount(np.asarray(c.type_id), minlength=4) / 2000
    np.testing.assert_allclose(share, 0.25, atol=0.04)


def test_lava_that_costs_ends_no_episode_and_is_judged():
    # LavaGapS5: lava at column 2 of rows 1-3 but the gap; the agent at (1, 1) facing right.
    for lava, ends in (("cost", False), ("lethal", True)):
        env = jaxgrid.make("MiniGrid-LavaGapS5-v0", constraint="avoid lava", lava=lava)
        states, _ = _resets(env, 32)
        first = int(np.argmax(np.asarray(states.grid)[:, 2, 1, 0] == LAVA))  # lava ahead
        state = jax.tree.map(lambda x, i=first: x[i], states)
        state, ts = env.step(state, jnp.int32(2))  # into the lava
        assert bool(ts.terminated) == ends and float(ts.discount) == (0.0 if ends else 1.0)
        assert bool(ts.info["violation"]) and float(ts.info["cost"]) == 1.0
        assert float(ts.reward) == 0.0
        if lava == "cost":  # walked on like floor, and out again without a new event
            state, ts = env.step(state, jnp.int32(2))
            assert not bool(ts.terminated) and not bool(ts.info["violation"])


def test_hazard_rooms_takes_sentences_and_weights_through_make():
    env = jaxgrid.make("HazardRooms-v0", constraints=("avoid lava", BUDGET), weights=(1, 3))
    assert env.sentences == ("avoid lava", BUDGET) and env.weights == (0.25, 0.75)
    assert jaxgrid.make("HazardRooms-v0", constraint="avoid lava", lava="cost").sentences == (
        "avoid lava",
    )


# --- bad input ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "env_id, kwargs, match",
    [
        (LAVA_ID, dict(constraint="after you pick up the ball avoid lava"), "the word 'ball'"),
        ("MiniGrid-DoorKey-8x8-v0", dict(constraint="avoid the blue floor"), "the word 'floor'"),
        ("MiniGrid-DoorKey-8x8-v0", dict(constraint="avoid the red door"), "the word 'red'"),
        ("MiniGrid-Empty-8x8-v0", dict(constraint="avoid lava"), "the word 'lava'"),
        ("MiniGrid-Empty-8x8-v0", dict(constraints=LEVELS), "holds nothing a sentence"),
        (LAVA_ID, dict(constraint="avoid the lava door"), "unexpected word 'door'"),
        (LAVA_ID, dict(constraint="avoid lava", lava="soft"), "lava must be one of"),
        (LAVA_ID, dict(lava="soft"), "lava must be one of"),
        (LAVA_ID, dict(lava="cost"), "needs a constraint"),
        (LAVA_ID, dict(weights=(1,)), "needs a constraint"),
        (LAVA_ID, dict(constraints=("avoid lava", BUDGET), weights=(1,)), "1 entries for 2"),
        (LAVA_ID, dict(constraints=("avoid lava", BUDGET), weights=(1, -1)), ">= 0"),
        (LAVA_ID, dict(constraints=("avoid lava", BUDGET), weights=(1, float("nan"))), ">= 0"),
        (LAVA_ID, dict(constraints=("avoid lava", BUDGET), weights=(0, 0)), "all be 0"),
        (LAVA_ID, dict(constraints=("avoid lava", BUDGET), weights=(True, 1)), ">= 0"),
        (LAVA_ID, dict(constraints=LEVELS, weights=(1,)), "weights= goes with"),
        (LAVA_ID, dict(constraint="avoid lava", constraints=("avoid lava",)), "one of"),
        (LAVA_ID, dict(constraints="avoid lava"), "a sequence of sentences"),
        (LAVA_ID, dict(constraints=()), "at least one"),
        ("ThreeRoomsKey-v0", dict(constraint="never stand next to lava"), "the word 'lava'"),
        ("TwoRooms-v0", dict(constraint="use the green door at most twice"), "the word 'green'"),
        ("TwoRooms-v0", dict(constraint="avoid the red door", lava="soft"), "lava must be one of"),
        ("TwoRooms-v0", dict(constraints=("avoid lava",)), "the word 'lava'"),
        ("ThreeRoomsKey-v0", dict(sentences=("avoid lava",)), "not a sentence of ThreeRoomsKey"),
        ("HazardRooms-v0", dict(constraint="avoid lava", lava="lethal"), "always costs"),
        ("HazardRooms-v0", dict(constraint="avoid the green door"), "the word 'green'"),
        ("HazardRooms-v0", dict(constraints=LEVELS), "its own table"),
    ],
)
def test_bad_input_raises_by_name_before_any_compile(env_id, kwargs, match, compiles):
    with pytest.raises(ValueError, match=match):
        jaxgrid.make(env_id, **kwargs)
    assert not compiles


def test_a_constrained_level_keeps_its_configuration_with_its_level():
    env = jaxgrid.make(LAVA_ID, max_steps=50, constraint="avoid lava")
    assert env.max_steps == env.level.max_steps == 50
    with pytest.raises(ValueError, match="set it on the level"):
        env.replace(max_steps=10)
    with pytest.raises(ValueError, match="unconstrained level"):
        env.replace(level=env)
    again = constrain(env, constraint=BUDGET, lava="cost")  # another sentence, same level
    assert again.level == env.level and again.draw.sentences == (BUDGET,)
    # a map's contents are its cells': nothing to name in one, lava in the other
    bare = jaxgrid.from_ascii("##########\n##>>..G.##\n##########")
    with pytest.raises(ValueError, match="nothing a constraint can name"):
        constrain(bare, constraint="avoid lava")
    lava_map = jaxgrid.from_ascii("##########\n##>>V...##\n##....G.##\n##########")
    assert lava_map.contents() == Contents(lava=True)
    assert isinstance(constrain(lava_map, constraint="avoid lava"), ConstrainedLevel)


# --- adapters -------------------------------------------------------------------------------
def test_gymnasium_passes_a_constraint_through_single_and_vector():
    gym = pytest.importorskip("gymnasium")
    from gymnasium.utils.env_checker import check_env

    import jaxgrid.gym  # noqa: F401  (registers the ids)

    kwargs = dict(constraint="avoid lava", lava="cost")
    env = gym.make("jaxgrid/MiniGrid-LavaGapS5-v0", **kwargs)
    check_env(env.unwrapped, skip_render_check=True)
    entered = 0
    for seed in range(6):  # LavaGapS5: lava ahead of the agent's start unless the gap is
        obs, info = env.reset(seed=seed)
        assert L.detokenize(obs["constraint"]) == "avoid lava" and info["cost"] == 0.0
        obs, _, terminated, _, info = env.step(2)
        entered += info["cost"] == 1.0
        assert not terminated and info["violation"] == (info["cost"] == 1.0)
    assert entered > 0  # entered lava, which costs and does not end the episode
    venv = gym.make_vec(f"jaxgrid/{LAVA_ID}", num_envs=4,
                        vectorization_mode="vector_entry_point", **kwargs)  # fmt: skip
    obs, info = venv.reset(seed=0)
    assert obs["constraint"].shape == (4, LEVELS.max_len) and info["cost"].shape == (4,)
    obs, _, _, _, info = venv.step(np.full(4, 2))
    assert info["cost"].dtype == np.float32 and info["violation"].dtype == np.bool_


def test_gymnax_runs_a_constrained_level():
    jgx = pytest.importorskip("jaxgrid.gymnax")
    env, params = jgx.make("MiniGrid-LavaGapS5-v0", constraint="avoid lava", lava="cost")
    plain, _ = jgx.make("MiniGrid-LavaGapS5-v0")
    width = env.observation_space(params).shape[0] - plain.observation_space(params).shape[0]
    assert width == LEVELS.max_len * LEVELS.vocab_size  # the constraint's one-hot tokens
    keys = jax.random.split(jax.random.key(0), 8)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, None, None)))
    total = 0.0
    for _ in range(2):  # forward: into the lava ahead unless the gap is there
        _, state, _, terminated, _, info = step(keys, state, jnp.int32(2), params)
        total += float(info["cost"].sum())
        assert not bool(terminated.any())
    assert obs.shape == (8, env.observation_space(params).shape[0]) and total > 0
    dict_env, _ = jgx.make(LAVA_ID, observation="dict", constraint="avoid lava")
    assert set(dict_env.observation_space(params).spaces) == {"image", "direction", "constraint"}


def test_a_paper_scenario_draws_the_sentences_of_its_table_it_is_given():
    """Every episode of TwoRooms-Lava given two of its table's sentences says one of them (that
    row's tokens, template and monitor clauses), in the scenario's own layouts."""
    from jaxgrid.sentences import PAPER

    said = ("do not use the red door", "Do not use the blue door and stay away from lava.")
    env = jaxgrid.make("TwoRoomsLava-v0", constraints=said)
    whole = jaxgrid.make("TwoRoomsLava-v0", split="all").constraint_table()
    rows = [int(np.flatnonzero((whole["tokens"] == PAPER.tokenize(s)).all(1))[0]) for s in said]
    keys = jax.random.split(jax.random.PRNGKey(0), 256)
    states, steps = batch_reset(env, keys)
    c = states.extras.constraint
    drawn = np.asarray(c.template_id)
    assert set(drawn.tolist()) == {int(whole["template_id"][r]) for r in rows}  # both, no other
    for r in rows:
        mine = drawn == whole["template_id"][r]
        assert (np.asarray(steps.observation["constraint"])[mine] == whole["tokens"][r]).all()
        assert (np.asarray(c.door_colour)[mine] == whole["door_colour"][r]).all()
        for got, want in zip(jax.tree.leaves(states.extras.monitor.spec),
                             jax.tree.leaves(whole["spec"]), strict=True):  # fmt: skip
            assert (np.asarray(got)[mine] == np.asarray(want)[r]).all()
    # the same scenario, its layouts unchanged: the grids of a default reset with the same keys
    default, _ = batch_reset(jaxgrid.make("TwoRoomsLava-v0"), keys)
    assert (np.asarray(default.grid) == np.asarray(states.grid)).all()


def test_a_paper_scenario_given_other_sentences_constrains_its_layouts_as_a_level():
    """A budget, a sequence or a distance (or weights=, lava=) on a paper scenario: its own
    layouts (grid, agent, direction seed for seed) constrained as a MiniGrid level is, with
    the levels' tokens and the draw's weights; its table's sentences alone keep the paper's."""
    from jaxgrid.constrained import ConstrainedLevel
    from jaxgrid.scenarios import ScenarioLayouts

    keys = jax.random.split(jax.random.PRNGKey(1), 256)
    cases = [
        ("TwoRooms-v0", dict(constraint="use the red door at most twice")),
        ("TwoRoomsLava-v0", dict(constraints=("never stand next to lava", "avoid the red door"),
                                 weights=(1, 3), lava="cost")),
        ("ThreeRoomsKey-v0", dict(constraint="after you pick up the key, do not use the red door")),
    ]  # fmt: skip
    for env_id, kwargs in cases:
        env = jaxgrid.make(env_id, **kwargs)
        assert isinstance(env, ConstrainedLevel) and isinstance(env.level, ScenarioLayouts)
        assert env.language_table is LEVELS and env.lava == kwargs.get("lava", "lethal")
        states, steps = jax.vmap(env.reset)(keys)
        paper, _ = jax.vmap(jaxgrid.make(env_id).reset)(keys)
        for field in ("grid", "agent_pos", "agent_dir"):
            same = np.asarray(getattr(states, field)) == np.asarray(getattr(paper, field))
            assert same.all(), (env_id, field)
        tokens = np.asarray(steps.observation["constraint"])
        said = [int(np.flatnonzero((env.constraint_table()["tokens"] == t).all(1))[0])
                for t in tokens]  # fmt: skip
        share = np.bincount(said, minlength=len(env.draw.sentences)) / len(keys)
        np.testing.assert_allclose(share, env.draw.weights, atol=0.08)
    # a sentence of the table with lava= (or weights=) leaves the paper's draw; alone, it keeps it
    level = jaxgrid.make("TwoRooms-v0", constraint="do not use the red door", lava="cost")
    assert isinstance(level, ConstrainedLevel) and level.lava == "cost"
    assert not isinstance(jaxgrid.make("TwoRooms-v0", constraint="avoid the red door"),
                          ConstrainedLevel)  # fmt: skip
    # a sentence table: its rows that the layouts can hold (ThreeRooms-Key has a key, no lava)
    drawn = jaxgrid.make("ThreeRoomsKey-v0", constraints=LEVELS)
    assert isinstance(drawn, ConstrainedLevel) and isinstance(drawn.level, ScenarioLayouts)
    sentences = drawn.draw.sentences
    assert any("key" in s for s in sentences) and not any("lava" in s for s in sentences)
    lava = jaxgrid.make("TwoRoomsLava-v0", constraints=LEVELS).draw.sentences
    assert any("lava" in s for s in lava)


# The scenarios and two MiniGrid levels in the default run; every id with -m slow.
_EVERY_TYPE_DEFAULT = {"TwoRooms-v0", "TwoRoomsLava-v0", "ThreeRoomsKey-v0", "HazardRooms-v0",
                       "MiniGrid-DoorKey-5x5-v0", "MiniGrid-Empty-5x5-v0"}  # fmt: skip


@functools.cache
def _one_sentence_per_type() -> dict[int, list[str]]:
    by_type: dict[int, list[str]] = {}
    for row in LEVELS.rows:
        by_type.setdefault(row.type_id, []).append(row.sentence)
    return by_type


@pytest.mark.parametrize("env_id", [
    pytest.param(i, marks=() if i in _EVERY_TYPE_DEFAULT else pytest.mark.slow)
    for i in jaxgrid.registered_ids()
])  # fmt: skip
def test_every_id_takes_a_sentence_of_every_type_its_contents_allow(env_id):
    """Each registered id, given a sentence of each clause type (and a conjunction) that names
    only what it can hold, builds and traces with it: the paper scenarios and HazardRooms
    included. An id that holds nothing nameable allows none."""
    contents = jaxgrid.make(env_id).contents()
    said = []
    for rows in _one_sentence_per_type().values():
        said += [s for s in rows if contents.allows(L.parse(s))][:1]
    if not said:
        assert not contents.constrainable, env_id
        return
    pair = f"{said[0]} and {said[-1]}"
    if L.parse(said[0]).type != L.parse(said[-1]).type and len(pair) <= L.MAX_CHARS:
        said.append(pair)
    for sentence in said:
        env = jaxgrid.make(env_id, constraint=sentence)
        obs = jax.eval_shape(env.reset, jax.random.PRNGKey(0))[1].observation
        assert obs["constraint"].shape == (env.language_table.max_len,), sentence
