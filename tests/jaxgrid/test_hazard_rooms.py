"""HazardRooms-v0: layouts, constraint draws, harmless lava, and solvability by the oracle."""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgrid import language as L
from jaxgrid import monitor as M
from jaxgrid.constants import CLOSED, DOOR, FLOOR, FORWARD, GOAL, KEY, LAVA, WALL
from jaxgrid.hazard import FLOOR_COLOURS, HazardRooms
from jaxgrid.oracle import rollout_oracle
from jaxgrid.scenarios import DOOR_COLOURS

ENV = HazardRooms(width=13, height=13, max_steps=150)
TYPES = L.CONSTRAINT_TYPES


@pytest.fixture(scope="module")
def resets():
    states, ts = jax.jit(jax.vmap(ENV.reset))(jax.random.split(jax.random.key(3), 1000))
    return jax.tree.map(np.asarray, states.replace(key=None)), jax.tree.map(np.asarray, ts)


def _room(pos):
    return int(pos[0] > 6) + 2 * int(pos[1] > 6)


def test_layouts_follow_the_contract(resets):
    states, _ = resets
    spec = states.extras.monitor.spec
    # An "after" clause's ground trigger lies on the doorsteps out of the agent's room.
    doorstep = (spec.gate[:, 0] == M.AFTER) & ~spec.trigger_pickup[:, 0]
    doorstep &= (spec.trigger_kind[:, 0] == LAVA) | (spec.trigger_kind[:, 0] == FLOOR)
    assert doorstep.sum() >= 20
    for e in range(len(states.grid)):
        g = states.grid[e]
        kind = g[..., 0]
        assert (kind[6, :] != 0).all() and (kind[:, 6] != 0).all()
        doors = np.argwhere(kind == DOOR)
        assert len(doors) == 4
        colours = g[doors[:, 0], doors[:, 1], 1]
        assert len(set(colours)) == 4 and set(colours) <= set(DOOR_COLOURS.tolist())
        assert (g[doors[:, 0], doors[:, 1], 2] == CLOSED).all()
        assert ((kind == WALL) | (kind == DOOR))[6, :].all()
        agent_room = _room(states.agent_pos[e])
        trigger = (spec.trigger_kind[e, 0], spec.trigger_colour[e, 0])
        steps = 0
        for x, y in doors:  # beside a door: empty, or the trigger on the agent's doorsteps
            for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                cell = (x + dx, y + dy)
                if kind[cell] == WALL:
                    continue
                if doorstep[e] and _room(cell) == agent_room:
                    assert kind[cell] == trigger[0]
                    assert trigger[0] == LAVA or g[cell][1] == trigger[1]
                    steps += 1
                else:
                    assert kind[cell] == 1
        assert steps == (2 if doorstep[e] else 0)
        goal = np.argwhere(kind == GOAL)
        key = np.argwhere(kind == KEY)
        assert len(goal) == 1 and len(key) == 1
        assert _room(goal[0]) == 3 - agent_room and _room(key[0]) == agent_room
        floors = set(g[kind == FLOOR][:, 1].tolist())
        assert floors <= set(FLOOR_COLOURS)
        zone = states.extras.monitor.zone[e].any(0)
        ax, ay = states.agent_pos[e]
        assert not zone[ax, ay] and not zone[goal[0][0], goal[0][1]]
    # Most strips are of the hazard a budget or sequence names; avoid clauses get the mix.
    kind, colour = spec.target_kind[:, 0], spec.target_colour[:, 0]
    ground = (kind == LAVA) | (kind == FLOOR)
    cells = np.array([
        ((g[..., 0] == k) & ((k == LAVA) | (g[..., 1] == c))).sum()
        for g, k, c in zip(states.grid, kind, colour, strict=True)
    ])  # fmt: skip
    boosted = ground & ((spec.budget[:, 0] > 0) | (spec.gate[:, 0] != M.ALWAYS))
    plain = ground & (spec.gate[:, 0] == M.ALWAYS) & (spec.budget[:, 0] == 0)
    assert cells[boosted].mean() > 2 * cells[plain].mean() > 0


def test_constraint_types_are_uniform_and_tokens_say_the_monitored_constraint(resets):
    states, ts = resets
    c = states.extras.constraint
    share = np.bincount(c.type_id, minlength=len(TYPES)) / len(c.type_id)
    assert np.all(np.abs(share - 1 / len(TYPES)) < 0.05), share
    for e in range(0, len(c.type_id), 3):
        sentence = L.detokenize(ts.observation["constraint"][e])
        parsed = L.parse(sentence)
        assert TYPES[c.type_id[e]] == parsed.type, sentence
        want = M.encode(parsed)
        got = jax.tree.map(lambda a, e=e: a[e], states.extras.monitor.spec)
        for name in want.__dataclass_fields__:
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=sentence)


def test_the_split_keeps_heldout_phrases_out_of_training():
    train = HazardRooms(width=13, height=13, max_steps=150).constraint_table()
    held = HazardRooms(width=13, height=13, max_steps=150, split="heldout").constraint_table()
    rows = lambda t: {tuple(r) for r in t["tokens"]}  # noqa: E731
    assert rows(train).isdisjoint(rows(held))
    assert set(held["type_id"]) == set(range(len(L.CLAUSE_TYPES)))


def test_lava_costs_but_does_not_kill():
    env = HazardRooms(width=13, height=13, max_steps=150, sentences=("avoid lava",))
    state, _ = jax.jit(env.reset)(jax.random.key(0))  # jitted: eager resets are slower
    front = state.agent_pos + jnp.array([[1, 0], [0, 1], [-1, 0], [0, -1]])[state.agent_dir]
    grid = state.grid.at[front[0], front[1]].set(jnp.array([LAVA, 0, 0], jnp.uint8))
    state = state.replace(grid=grid)
    state = state.replace(
        extras=state.extras.replace(monitor=M.start(state.extras.monitor.spec, grid))
    )
    new, ts = jax.jit(env.step)(state, jnp.int32(FORWARD))
    np.testing.assert_array_equal(new.agent_pos, front)
    assert not ts.terminated and bool(ts.info["violation"]) and float(ts.info["cost"]) == 1.0


def test_fixed_sentences_are_the_only_constraints():
    sentences = (
        "avoid lava",
        "never stand next to the red door and use the blue door at most once",
    )
    env = HazardRooms(width=13, height=13, max_steps=150, sentences=sentences)
    _, ts = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 64))
    seen = {L.detokenize(t) for t in np.asarray(ts.observation["constraint"])}
    assert seen == set(sentences)


def test_step_compiles_once_and_is_deterministic():
    step = jax.jit(chex.assert_max_traces(ENV.step, n=1))
    a, _ = ENV.reset(jax.random.key(7))
    b, _ = ENV.reset(jax.random.key(7))
    np.testing.assert_array_equal(a.grid, b.grid)
    for action in (2, 1, 2, 5):
        a, ta = step(a, jnp.int32(action))
        b, tb = step(b, jnp.int32(action))
        np.testing.assert_array_equal(a.agent_pos, b.agent_pos)


@pytest.mark.parametrize("n", [500, pytest.param(50_000, marks=pytest.mark.slow)])
def test_the_oracle_solves_every_episode_without_a_violation(n):
    r = jax.tree.map(np.asarray, rollout_oracle(ENV, jax.random.key(11), n, avoid_lava=False))
    counts = np.bincount(r["constraint_type"], minlength=len(TYPES))
    assert counts.min() >= n / len(TYPES) * 0.7
    assert r["success"].all(), np.flatnonzero(~r["success"])[:10]
    assert (r["violations"] == 0).all()


@pytest.mark.slow  # 17 s; python -m benchmarks.hazard_checks measures it over 10,000 episodes
def test_ignoring_the_constraint_violates_it_often():
    r = rollout_oracle(ENV, jax.random.key(11), 1000, obey_constraint=False, avoid_lava=False)
    r = jax.tree.map(np.asarray, r)
    assert r["success"].all()
    violated = r["violations"] > 0
    rates = [violated[r["constraint_type"] == k].mean() for k in range(len(TYPES))]
    assert min(rates) > 0.1 and violated.mean() >= 0.3, dict(zip(TYPES, rates, strict=True))


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="width must be at least 9"):
        HazardRooms(width=8, height=11, max_steps=10)
    with pytest.raises(ValueError, match="budgets"):
        HazardRooms(width=13, height=13, max_steps=10, budgets=(0, 1))
    with pytest.raises(ValueError, match="split"):
        HazardRooms(width=13, height=13, max_steps=10, split="test")
    with pytest.raises(ValueError, match="'teleport'"):
        HazardRooms(width=13, height=13, max_steps=10, sentences=("teleport to lava",))
