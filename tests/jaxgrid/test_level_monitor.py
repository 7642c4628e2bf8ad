"""The monitor on constrained MiniGrid levels, exactly, and the levels' own step rules kept.

Exactness: for every family of levels (one id each; a map of floors, lava, doors and objects
for the fixed levels; the paper scenarios' layouts), episodes with a constraint of every type
the level can say (drawn each type equally often from the levels' table, and conjunctions of
its rows), with ``lava="cost"`` and lethal lava, are played with biased random actions;
every step's ``cost`` and ``violation`` must equal those of ``helpers.monitor_reference``,
which judges the parsed sentence from the states alone with Python loops. ``-m slow`` checks
at least 10,000 steps per (family, constraint type, lava rule); the default run 1,000 on a
few families.

Step rules: a constrained level's step is its level's own step, to the bit: from the same
states and actions, the state (the level's part), reward, termination, truncation, discount,
observation and info equal the level's; with ``lava="cost"`` only the termination on entering
lava differs. A few levels with their own rules in the default run, every id with ``-m slow``.
"""

from __future__ import annotations

import functools
import random

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.monitor_reference import ACTION_PROBS, compare
from helpers.xla import CHEAP

import jaxgrid
from jaxgrid import language as L
from jaxgrid.constants import LAVA
from jaxgrid.constrained import ConstrainedLevel
from jaxgrid.contents import Contents
from jaxgrid.sentences import LEVELS

# A fixed level holding what no MiniGrid level has: floors, besides lava, doors and objects.
MAP = """
####################
##>>..FB..##V...G.##
##..FBFBKY_R..V...##
##..FG..AR##..FG..##
##DY######LP##FGFG##
##..BP....DR......##
####################
"""
FIXED = "fixed map"
# (family, id): one level per family whose grid holds something a constraint names.
FAMILIES = [
    ("classic DoorKey", "MiniGrid-DoorKey-5x5-v0"),
    ("classic LavaGap", "MiniGrid-LavaGapS5-v0"),
    ("navigation Crossing", "MiniGrid-LavaCrossingS9N1-v0"),
    ("navigation DistShift", "MiniGrid-DistShift1-v0"),
    ("keys", "MiniGrid-KeyCorridorS3R1-v0"),
    ("keys UnlockPickup", "MiniGrid-BlockedUnlockPickup-v0"),
    ("rooms MultiRoom", "MiniGrid-MultiRoom-N2-S4-v0"),
    ("rooms LockedRoom", "MiniGrid-LockedRoom-v0"),
    ("rooms RedBlueDoors", "MiniGrid-RedBlueDoors-6x6-v0"),
    ("missions GoToDoor", "MiniGrid-GoToDoor-5x5-v0"),
    ("playground", "MiniGrid-Playground-v0"),
    ("obstructed", "MiniGrid-ObstructedMaze-1Dlh-v0"),
    # the paper scenarios' layouts, constrained as a level by sentences outside their table
    ("scenarios TwoRoomsLava", "TwoRoomsLava-v0"),
    ("scenarios ThreeRoomsKey", "ThreeRoomsKey-v0"),
    ("fixed", FIXED),
]
DEFAULT_FAMILIES = {"classic LavaGap", "keys", "fixed"}
HORIZON = 96  # steps per episode at most: random walks meet most of a level by then
ENVS = 128  # episodes per round


def _level(env_id: str):
    return jaxgrid.from_ascii(MAP, max_steps=HORIZON) if env_id == FIXED else jaxgrid.make(env_id)


@functools.cache
def sentences_for(contents: Contents, seed: int = 0) -> tuple[tuple[str, ...], tuple]:
    """Sentences of every type ``contents`` can say and their weights (each type equally
    often): up to 12 rows of the levels' table per clause type (budgets of 1 to 3, which
    random walks exceed), and 12 conjunctions of two of those rows of different types."""
    rng = random.Random(seed)
    allowed = [r for r in LEVELS.rows if contents.allows(L.parse(r.sentence))]
    allowed = [r for r in allowed if L.parse(r.sentence).clauses[0].count <= 3]
    by_type = {}
    for r in allowed:
        by_type.setdefault(r.type_id, []).append(r.sentence)
    chosen = {t: rng.sample(rows, min(12, len(rows))) for t, rows in by_type.items()}
    pool = [(t, s) for t, rows in chosen.items() for s in rows]
    pairs = set()
    while len(by_type) > 1 and len(pairs) < 12:
        (ta, a), (tb, b) = rng.sample(pool, 2)
        if ta != tb and len(f"{a} and {b}") <= L.MAX_CHARS:
            pairs.add(f"{a} and {b}")
    chosen[L.CONSTRAINT_TYPES.index("conjunction")] = sorted(pairs)
    chosen = {t: rows for t, rows in chosen.items() if rows}
    sentences = tuple(s for rows in chosen.values() for s in rows)
    weights = tuple(1 / (len(chosen) * len(rows)) for rows in chosen.values() for _ in rows)
    return sentences, weights


def _constrained(env_id: str, lava: str):
    level = _level(env_id)
    sentences, weights = sentences_for(level.contents())
    return jaxgrid.constrained.constrain(
        level, constraints=sentences, weights=weights, lava=lava, name=env_id
    )


def _check_family(env_id: str, lava: str, steps_per_type: int):
    env = _constrained(env_id, lava)
    types = {L.parse(s).type_id for s in env.draw.sentences}
    counted = np.zeros(len(L.CONSTRAINT_TYPES), int)
    costs = violations = 0
    for seed in range(400):  # rounds of ENVS episodes, one compile
        c, out = compare(env, seed, ENVS, min(env.max_steps, HORIZON))
        counted += c
        costs += int((out["cost"][out["active"]] > 0).sum())
        violations += int(out["violation"][out["active"]].sum())
        if all(counted[t] >= steps_per_type for t in types):
            break
    assert all(counted[t] >= steps_per_type for t in types), counted
    assert set(np.flatnonzero(counted)) == types
    # The comparison saw what it judges: costly steps and violations.
    assert violations > 0 and costs >= violations, (costs, violations)
    return counted


def _family_params(slow_only: bool):
    out = []
    for family, env_id in FAMILIES:
        holds_lava = _level(env_id).contents().lava
        for lava in ("cost", "lethal"):
            default = family in DEFAULT_FAMILIES and not slow_only
            default = default and (holds_lava or lava == "lethal")
            marks = () if default else pytest.mark.slow
            out.append(pytest.param(env_id, lava, marks=marks, id=f"{family}-{lava}"))
    return out


@pytest.mark.parametrize("env_id, lava", _family_params(slow_only=False))
def test_the_monitor_matches_the_reference_on_every_family(env_id, lava, request):
    slow = request.node.get_closest_marker("slow") is not None
    _check_family(env_id, lava, 10_000 if slow else 1_000)


def test_every_family_can_say_every_type_its_contents_allow():
    for _, env_id in FAMILIES:
        contents = _level(env_id).contents()
        sentences, weights = sentences_for(contents)
        types = {L.parse(s).type == "sequential" for s in sentences}
        # a sequential clause needs a trigger other than its target: a key, a ball, a box, or
        # a second nameable thing; lava alone has none
        lava_only = contents == Contents(lava=True)
        assert (True in types) == (not lava_only), env_id
        assert abs(sum(weights) - 1) < 1e-9


# --- the level's own step rules -------------------------------------------------------------
CONSTRAINABLE = [
    i for i in jaxgrid.registered_ids()
    if i.startswith("MiniGrid-") and jaxgrid.make(i).contents().constrainable
]  # fmt: skip
DEFAULT_RULES = {
    "MiniGrid-LavaGapS5-v0",
    "MiniGrid-ObstructedMaze-1Dlh-v0",
    "MiniGrid-RedBlueDoors-6x6-v0",
    "MiniGrid-GoToDoor-5x5-v0",
}


@functools.partial(jax.jit, static_argnames=("lethal", "cost", "n", "t"), compiler_options=CHEAP)
def _same_steps(lethal, cost, key, n, t):
    """``t`` random steps of ``n`` envs of ``lethal``; per step and env: whether its step and
    ``cost``'s (the same level with lava that costs) equal the level's own step, and whether
    the step entered lava."""
    level = lethal.level
    k_reset, k_act = jax.random.split(key)
    states, _ = jax.vmap(lethal.reset)(jax.random.split(k_reset, n))

    def same(a, b):
        return jax.tree.map(lambda x, y: (x == y).reshape(n, -1).all(1), a, b)

    def body(states, k):
        actions = jax.random.choice(k, 6, (n,), p=jnp.asarray(ACTION_PROBS))
        inner = ConstrainedLevel.level_state(states)
        want, want_ts = jax.vmap(level.step)(inner, actions)
        got, got_ts = jax.vmap(lethal.step)(states, actions)
        got_c, got_c_ts = jax.vmap(cost.step)(states, actions)
        moved = jnp.any(want.agent_pos != inner.agent_pos, axis=-1)
        into_lava = moved & (want.grid[jnp.arange(n), want.agent_pos[:, 0],
                                       want.agent_pos[:, 1], 0] == LAVA)  # fmt: skip
        obs = {k: v for k, v in got_ts.observation.items() if k != "constraint"}
        obs_c = {k: v for k, v in got_c_ts.observation.items() if k != "constraint"}
        info = {k: got_ts.info[k] for k in want_ts.info}
        checks = [
            same(ConstrainedLevel.level_state(got), want),
            same(ConstrainedLevel.level_state(got_c), want),
            same((obs, obs_c), (want_ts.observation, want_ts.observation)),
            same(info, want_ts.info),
            same(
                (got_ts.reward, got_ts.terminated, got_ts.truncated, got_ts.discount),
                (want_ts.reward, want_ts.terminated, want_ts.truncated, want_ts.discount),
            ),
            same(
                (got_c_ts.reward, got_c_ts.terminated, got_c_ts.truncated),
                (want_ts.reward, want_ts.terminated & ~into_lava, want_ts.truncated),
            ),
        ]
        ok = jnp.stack([x for c in checks for x in jax.tree.leaves(c)]).all(0)
        return got, {"same": ok, "lava": into_lava}

    return jax.lax.scan(body, states, jax.random.split(k_act, t))[1]


@pytest.mark.parametrize(
    "env_id",
    [pytest.param(i, marks=() if i in DEFAULT_RULES else pytest.mark.slow)
     for i in CONSTRAINABLE],
)  # fmt: skip
def test_a_constrained_level_steps_by_its_levels_own_rules(env_id):
    lethal, cost = _constrained(env_id, "lethal"), _constrained(env_id, "cost")
    out = jax.tree.map(np.asarray, _same_steps(lethal, cost, jax.random.key(3), 64, 64))
    assert out["same"].all(), np.argwhere(~out["same"])[:5]
    if lethal.contents().lava:
        assert out["lava"].any()
