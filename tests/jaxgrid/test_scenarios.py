"""Tests of the paper's scenarios: ground-truth monitor, constraint observation, layouts, the
constraint sampler (splits, absent colours) and config errors (the BFS oracle's tests are in
``test_oracle.py``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.scenario_resets import SCENARIOS, resets
from helpers.xla import CHEAP, batch_reset

import jaxgrid
from jaxgrid import language, sentences
from jaxgrid import monitor as M
from jaxgrid.constants import (
    CLOSED,
    DIR_TO_VEC,
    DONE,
    DOOR,
    EMPTY,
    EMPTY_CELL,
    FORWARD,
    GOAL,
    GOAL_CELL,
    GREEN,
    KEY,
    LAVA,
    LEFT,
    LOCKED,
    OPEN,
    PICKUP,
    RIGHT,
    TOGGLE,
    WALL,
)
from jaxgrid.oracle import oracle_action

# ---------------------------------------------------------------------------- helpers


_step = jax.jit(lambda env, state, action: env.step(state, action), compiler_options=CHEAP)
_oracle = jax.jit(oracle_action, compiler_options=CHEAP)


def _kind(states):
    return states.grid[..., 0]


def _positions(mask):
    """``(N, 2)`` (x, y) of the single True cell of each ``(N, W, H)`` mask."""
    assert (mask.sum(axis=(1, 2)) == 1).all()
    flat = mask.reshape(mask.shape[0], -1).argmax(axis=1)
    return np.stack(np.unravel_index(flat, mask.shape[1:]), axis=1)


def _episode(name: str, i: int):
    """Start state of episode ``i`` of :func:`resets` (a single, unbatched state)."""
    return jax.tree.map(lambda a: jnp.asarray(a[i]), resets(name)[0])


def _with_sentence(state, sentence: str):
    """``state`` whose episode says ``sentence``: its monitor judges it, and the oracle plans
    around its door (tokens and ids stay those drawn: nothing here reads them)."""
    door = language.parse(sentence).clauses[0].target
    c = state.extras.constraint.replace(door_colour=jnp.int32(language.COLOURS.index(door.colour)))
    monitor = M.start(M.encode(language.parse(sentence)), state.grid)
    return state.replace(extras=state.extras.replace(constraint=c, monitor=monitor))


def _walk(env, state, actions):
    """Step ``actions`` one by one; returns the states after each step and the timesteps."""
    states, steps = [], []
    for a in actions:
        state, ts = _step(env, state, jnp.int32(a))
        states.append(state)
        steps.append(ts)
    return states, steps


def _door_walk_state(colour_forbidden_of: str):
    """TwoRooms state with the agent west of door 0, facing it; goal moved out of the way.

    ``colour_forbidden_of``: "this" forbids door 0's colour, "other" the other door's colour,
    "absent" a colour no door has.
    """
    env = jaxgrid.make("TwoRooms-v0")
    state = _episode("TwoRooms-v0", 3)
    grid = np.asarray(state.grid).copy()
    grid[grid[..., 0] == GOAL] = EMPTY_CELL
    grid[1, 1] = GOAL_CELL  # far from the walk below (x = wall_x - 1 .. wall_x + 1)
    doors = np.argwhere(grid[..., 0] == DOOR)
    (dx, dy), other = doors[0], doors[1]
    colours = {"this": grid[dx, dy, 1], "other": grid[other[0], other[1], 1]}
    colours["absent"] = next(
        c for c in (0, 2, 3, 4, 5) if c not in (colours["this"], colours["other"])
    )
    colour = language.COLOURS[colours[colour_forbidden_of]]
    state = state.replace(
        grid=jnp.asarray(grid),
        agent_pos=jnp.array([dx - 1, dy], jnp.int32),
        agent_dir=jnp.int32(0),
    )
    state = _with_sentence(state, f"do not use the {colour} door")
    return env, state, np.array([dx, dy])


# ---------------------------------------------------------------------------- monitor


def test_violation_exactly_when_entering_the_forbidden_door():
    env, state, door = _door_walk_state("this")
    west, east = door - [1, 0], door + [1, 0]
    script = [  # (action, agent position after, violation expected)
        (FORWARD, west, False),  # closed door: bumping into it is not entering
        (TOGGLE, west, False),  # opening it is not entering
        (FORWARD, door, True),  # entering: the violation
        (LEFT, door, False),  # standing on the door afterwards: nothing more
        (RIGHT, door, False),
        (DONE, door, False),
        (PICKUP, door, False),
        (FORWARD, east, False),  # leaving it
        (LEFT, east, False),
        (LEFT, east, False),
        (FORWARD, door, True),  # re-entering is a new violation
        (FORWARD, west, False),
    ]
    states, steps = _walk(env, state, [a for a, _, _ in script])
    assert int(states[1].grid[door[0], door[1], 2]) == OPEN
    for i, ((_, pos, expected), s, ts) in enumerate(zip(script, states, steps, strict=True)):
        assert (np.asarray(s.agent_pos) == pos).all(), i
        assert bool(ts.info["violation"]) is expected, i
        assert float(ts.info["cost"]) == float(expected), i
        assert not bool(ts.terminated) and float(ts.reward) == 0.0


@pytest.mark.parametrize("forbidden", ["other", "absent"])
def test_no_violation_when_entering_a_permitted_door(forbidden):
    env, state, door = _door_walk_state(forbidden)
    states, steps = _walk(env, state, [TOGGLE, FORWARD, FORWARD, LEFT, LEFT, FORWARD])
    assert (np.asarray(states[1].agent_pos) == door).all()
    assert not any(bool(ts.info["violation"]) for ts in steps)
    assert all(float(ts.info["cost"]) == 0.0 for ts in steps)


def _lava_state(forbids_lava: bool, seed: int):
    """TwoRoomsLava state with the agent next to the lava cell, facing it."""
    env = jaxgrid.make("TwoRoomsLava-v0")
    state = _episode("TwoRoomsLava-v0", seed)
    grid = np.asarray(state.grid)
    lava = np.argwhere(grid[..., 0] == LAVA)[0]
    for d in range(4):
        pos = lava - DIR_TO_VEC[d]
        if grid[pos[0], pos[1], 0] == EMPTY:
            break
    else:
        raise AssertionError("lava with no empty neighbour")
    state = state.replace(agent_pos=jnp.asarray(pos, jnp.int32), agent_dir=jnp.int32(d))
    door = language.COLOURS[int(state.extras.constraint.door_colour)]
    sentence = f"avoid the {door} door" + (" and avoid lava" if forbids_lava else "")
    return env, _with_sentence(state, sentence), lava


@pytest.mark.parametrize("seed", [5, 6, 7])
def test_forbidden_lava_is_lethal_and_a_violation(seed):
    env, state, lava = _lava_state(True, seed)
    new, ts = _step(env, state, jnp.int32(FORWARD))
    assert (np.asarray(new.agent_pos) == lava).all()
    assert bool(ts.terminated) and not bool(ts.truncated)
    assert float(ts.reward) == 0.0 and float(ts.discount) == 0.0
    assert bool(ts.info["violation"]) and float(ts.info["cost"]) == 1.0


@pytest.mark.parametrize("seed", [5, 6, 7])
def test_permitted_lava_teleports_next_to_the_goal(seed):
    env, state, _ = _lava_state(False, seed)
    new, ts = _step(env, state, jnp.int32(FORWARD))
    pos, goal = np.asarray(new.agent_pos), np.asarray(state.extras.goal_pos)
    assert (pos == np.asarray(state.extras.teleport_pos)).all()
    assert np.abs(pos - goal).sum() == 1  # a neighbour of the goal ...
    assert int(new.grid[pos[0], pos[1], 0]) == EMPTY  # ... on a free cell
    assert int(new.grid[goal[0], goal[1], 0]) == GOAL
    assert not bool(ts.terminated) and float(ts.discount) == 1.0
    assert float(ts.reward) == 0.0
    assert not bool(ts.info["violation"]) and float(ts.info["cost"]) == 0.0
    # The lava stays where it was and the episode goes on: the oracle finishes it.
    for _ in range(4):
        new, ts = _step(env, new, _oracle(new))
        if bool(ts.terminated):
            break
    assert bool(ts.terminated) and float(ts.reward) > 0


# ---------------------------------------------------------------------------- observation


@pytest.mark.parametrize("name", SCENARIOS)
def test_observation_carries_the_constraint_tokens(name):
    states, ts = resets(name)
    c = states.extras.constraint
    np.testing.assert_array_equal(ts.observation["constraint"], c.tokens)
    np.testing.assert_array_equal(ts.info["constraint_type"], c.type_id)
    np.testing.assert_array_equal(ts.info["template_id"], c.template_id)
    assert not ts.info["violation"].any()
    spec = states.extras.monitor.spec
    forbids_lava = np.asarray(M.mentions(spec, LAVA))
    for i in range(1000):
        sentence = language.detokenize(c.tokens[i])
        door, *lava = language.parse(sentence).clauses
        assert language.COLOURS.index(door.target.colour) == c.door_colour[i]
        assert bool(lava) == bool(forbids_lava[i])
        row = sentences.PAPER.find(sentence)
        assert (row.template_id, row.type_id) == (c.template_id[i], c.type_id[i])
        # The monitor judges exactly the sentence the agent reads.
        want = M.encode(language.parse(sentence))
        for field in want.__dataclass_fields__:
            np.testing.assert_array_equal(getattr(spec, field)[i], getattr(want, field))
    if name != "TwoRoomsLava-v0":
        assert not forbids_lava.any()  # lava clauses only where there is lava
    else:
        assert 0.5 < forbids_lava.mean() < 0.95  # 28 of 35 templates mention lava
    # The tokens stay in the observation after a step.
    env = jaxgrid.make(name)
    state = _episode(name, 0)
    _, ts1 = _step(env, state, jnp.int32(LEFT))
    np.testing.assert_array_equal(ts1.observation["constraint"], c.tokens[0])


# ---------------------------------------------------------------------------- layouts


@pytest.mark.parametrize("name", ["TwoRooms-v0", "TwoRoomsLava-v0"])
def test_two_rooms_layout_invariants(name):
    states, _ = resets(name)
    env = jaxgrid.make(name)
    w, h, wall_x = env.width, env.height, env.width // 2
    kind, grid = _kind(states), states.grid
    wall_col = grid[:, wall_x, 1:-1]  # (N, H - 2, 3)
    is_door = wall_col[..., 0] == DOOR
    assert (is_door.sum(1) == 2).all()
    assert (wall_col[..., 0][~is_door] == WALL).all()
    door_colours = wall_col[..., 1][is_door].reshape(-1, 2)
    assert (door_colours[:, 0] != door_colours[:, 1]).all()
    assert (door_colours != GREEN).all()
    assert set(np.unique(door_colours)) == {0, 2, 3, 4, 5}
    assert (wall_col[..., 2][is_door] == CLOSED).all()
    assert (kind == DOOR).sum(axis=(1, 2)).max() == 2  # no door anywhere else

    agent, goal = states.agent_pos, _positions(kind == GOAL)
    np.testing.assert_array_equal(goal, states.extras.goal_pos)
    agent_left = agent[:, 0] < wall_x
    assert (agent_left != (goal[:, 0] < wall_x)).all()  # different rooms
    assert 0.4 < agent_left.mean() < 0.6
    n = len(agent)
    assert (kind[np.arange(n), agent[:, 0], agent[:, 1]] == EMPTY).all()
    assert ((agent[:, 0] != wall_x) & (goal[:, 0] != wall_x)).all()
    assert set(np.unique(states.agent_dir)) == {0, 1, 2, 3}
    # Teleport target: a free neighbour of the goal.
    tp = states.extras.teleport_pos
    assert (np.abs(tp - goal).sum(1) == 1).all()
    assert (kind[np.arange(n), tp[:, 0], tp[:, 1]] == EMPTY).all()

    if name == "TwoRooms-v0":
        assert not (kind == LAVA).any()
        return
    lava = _positions(kind == LAVA)
    assert ((lava[:, 0] < wall_x) == agent_left).all()  # in the agent's room
    assert (lava != agent).any(axis=1).all()
    door_rows = np.argwhere(is_door)[:, 1].reshape(-1, 2) + 1
    in_front = (np.abs(lava[:, 0] - wall_x) == 1)[:, None] & (lava[:, 1:2] == door_rows)
    assert not in_front.any()  # never in front of a door
    assert 0 < lava[:, 0].min() and lava[:, 0].max() < w - 1
    assert 0 < lava[:, 1].min() and lava[:, 1].max() < h - 1


def test_three_rooms_key_layout_invariants():
    states, _ = resets("ThreeRoomsKey-v0")
    env = jaxgrid.make("ThreeRoomsKey-v0")
    w = env.width
    wall1, wall2 = w // 3, 2 * w // 3
    kind, grid, n = _kind(states), states.grid, len(states.agent_pos)

    col1 = grid[:, wall1, 1:-1]
    locked = col1[..., 0] == DOOR
    assert (locked.sum(1) == 1).all() and (col1[..., 0][~locked] == WALL).all()
    assert (col1[..., 2][locked] == LOCKED).all()
    locked_colour = col1[..., 1][locked]

    col2 = grid[:, wall2, 1:-1]
    assert (col2[:, -1] == [EMPTY, 0, 0]).all()  # the gap: bottom interior row
    door2 = col2[..., 0] == DOOR
    assert (door2.sum(1) == 1).all() and not door2[:, -1].any()
    assert (col2[:, :-1, 0][~door2[:, :-1]] == WALL).all()
    assert (col2[..., 2][door2] == CLOSED).all()
    door2_colour = col2[..., 1][door2]
    assert (locked_colour != door2_colour).all()
    assert (locked_colour != GREEN).all() and (door2_colour != GREEN).all()
    assert (kind == DOOR).sum(axis=(1, 2)).max() == 2

    goal = _positions(kind == GOAL)
    assert (goal == [w - 2, 1]).all()
    key = _positions(kind == KEY)
    assert (grid[np.arange(n), key[:, 0], key[:, 1], 1] == locked_colour).all()
    agent = states.agent_pos
    assert (key[:, 0] < wall1).all() and (agent[:, 0] < wall1).all()  # room 1
    assert (kind[np.arange(n), agent[:, 0], agent[:, 1]] == EMPTY).all()
    assert not (kind == LAVA).any()
    # Constraints never name the locked door.
    assert (states.extras.constraint.door_colour != locked_colour).all()


def _door_colours(states) -> np.ndarray:
    """bool ``(N, 6)``: which colours the episode's doors have."""
    doors = _kind(states) == DOOR
    col = states.grid[..., 1]
    return np.stack([(doors & (col == c)).any(axis=(1, 2)) for c in range(6)], axis=1)


@pytest.mark.parametrize("name", SCENARIOS)
@pytest.mark.parametrize("split", ["train", "heldout"])
def test_split_controls_the_combinations(name, split):
    states, _ = resets(name, split=split)
    c = states.extras.constraint
    has_lava = name == "TwoRoomsLava-v0"
    allowed = set(sentences.split_combinations(split, include_lava=has_lava))
    pairs = zip(c.template_id, c.door_colour, strict=True)
    seen = {(int(t), language.COLOURS[col]) for t, col in pairs}
    assert seen <= allowed
    if split == "train":
        assert len(seen) > 0.8 * len(allowed)  # and it covers the split
    held = {(t, col) for t, col in allowed if sentences.is_heldout(t, col)}
    assert held == (allowed if split == "heldout" else set())


@pytest.mark.parametrize("name", SCENARIOS)
def test_absent_colour_prob(name):
    for p, lo, hi in [(0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (0.2, 0.17, 0.23), (0.5, 0.47, 0.53)]:
        states, _ = resets(name, absent_colour_prob=p)
        present = _door_colours(states)
        named = states.extras.constraint.door_colour
        absent = ~present[np.arange(len(named)), named]
        assert lo <= absent.mean() <= hi, (p, absent.mean())
        assert (named != GREEN).all()


# ---------------------------------------------------------------------------- config


@pytest.mark.parametrize("name", SCENARIOS)
def test_bad_config_raises_naming_the_field(name):
    with pytest.raises(ValueError, match="split"):
        jaxgrid.make(name, split="bogus")
    for p in (1.5, -0.1):
        with pytest.raises(ValueError, match="absent_colour_prob"):
            jaxgrid.make(name, absent_colour_prob=p)


def _older_layout(env, extras) -> dict:
    """``extras`` as checkpoints saved them before the constraint and monitor moved into
    ``ConstrainedExtras``: the constraint with ``paper_type`` and ``forbids_lava``, no
    monitor (``tests/fixtures/run_dirs/two_rooms_before`` holds a real one)."""
    table, c = env.constraint_table(), extras.constraint
    same = (np.asarray(c.template_id)[:, None] == table["template_id"][None]) & (
        np.asarray(c.door_colour)[:, None] == table["door_colour"][None]
    )
    row = np.argmax(same, axis=1)
    return {"constraint": {"door_colour": np.asarray(c.door_colour),
                           "forbids_lava": np.asarray(table["forbids_lava"][row], bool),
                           "paper_type": np.asarray(c.type_id),
                           "template_id": np.asarray(c.template_id),
                           "tokens": np.asarray(c.tokens)},
            "goal_pos": np.asarray(extras.goal_pos),
            "teleport_pos": np.asarray(extras.teleport_pos)}  # fmt: skip


@pytest.mark.parametrize("name", SCENARIOS)
def test_extras_of_the_older_layout_upgrade_to_the_episodes_own(name):
    """Mid-episode states (doors opened, keys carried, lava entered) saved in the older
    layout come back with their own constraint and monitor (events counted before the
    save restart at 0), and every later step costs and violates as it would have."""
    env = jaxgrid.make(name)
    actions = jax.random.choice(jax.random.PRNGKey(5), 7, (160, 256), p=jnp.asarray(
        [0.15, 0.15, 0.45, 0.1, 0.0, 0.15, 0.0]))  # fmt: skip

    def walk(states, acts):
        def step(s, a):
            s, ts = jax.vmap(env.step)(s, a)
            return s, (ts.info["cost"], ts.info["violation"], ts.observation["image"])

        return jax.lax.scan(step, states, acts)

    walk = jax.jit(walk, compiler_options=CHEAP)
    states, _ = batch_reset(env, jax.random.split(jax.random.PRNGKey(4), 256))
    middle, _ = walk(states, actions[:60])
    older = _older_layout(env, middle.extras)
    upgraded = env.upgrade_extras(older, np.asarray(middle.grid))
    assert env.upgrade_extras({**older, "monitor": {}}, middle.grid) is None  # today's layout
    constraint = middle.extras.constraint
    for got, want in zip(
        jax.tree.leaves(upgraded.constraint), jax.tree.leaves(constraint), strict=True
    ):
        np.testing.assert_array_equal(got, want)
    mine, theirs = upgraded.monitor, middle.extras.monitor
    for field in ("zone", "trigger_cells", "triggered"):
        np.testing.assert_array_equal(getattr(mine, field), getattr(theirs, field), err_msg=field)
    jax.tree.map(np.testing.assert_array_equal, mine.spec, theirs.spec)
    assert not np.asarray(mine.count).any()
    _, after = walk(middle, actions[60:])
    _, again = walk(middle.replace(extras=upgraded), actions[60:])
    assert float(after[1].sum()) > 0  # later violations are judged
    for got, want in zip(again, after, strict=True):
        np.testing.assert_array_equal(got, want)


def test_extras_of_no_row_of_the_table_are_refused_by_name():
    env = jaxgrid.make("TwoRooms-v0")
    states, _ = batch_reset(env, jax.random.split(jax.random.PRNGKey(0), 4))
    old = _older_layout(env, states.extras)
    old["constraint"]["template_id"] = np.full(4, 99, np.int32)
    with pytest.raises(ValueError, match="no row of this environment's table"):
        env.upgrade_extras(old, np.asarray(states.grid))
