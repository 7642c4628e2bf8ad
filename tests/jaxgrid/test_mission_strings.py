"""Mission strings as token ids and text (``jaxgrid.mission``, ``Environment.mission``).

* Every MiniGrid id: MiniGrid resets converted with ``from_minigrid`` state MiniGrid's mission
  exactly, as text and as token ids decoded, native families (missions read from
  ``state.extras``) and fixed levels alike.
* Native resets of the levels whose mission varies draw each mission string as often as
  MiniGrid's generator does (two-sample chi-square at ``ALPHA``), and the mission agrees with
  the layout (LockedRoom: the locked door's colour and the key room's door colour).
* ``WithMission`` puts the ids in every observation, fresh episodes' own after auto-reset.
* Bad input: unknown words, too many words, malformed slots, out-of-range ids, a batch
  passed to ``mission_text``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import minigrid_reference as R
from helpers.layout_stats import compare_distributions, id_param, jax_reset_states
from helpers.xla import CHEAP

import jaxgrid
from jaxgrid import mission as M
from jaxgrid.ascii import from_ascii
from jaxgrid.compat import from_minigrid
from jaxgrid.constants import COLOR_NAMES, DOOR, KEY, LOCKED
from jaxgrid.wrappers import BatchedAutoReset, WithMission

MINIGRID_IDS = [i for i in jaxgrid.registered_ids() if i.startswith("MiniGrid-")]
VARIABLE = [
    "MiniGrid-Fetch-5x5-N2-v0",
    "MiniGrid-GoToDoor-5x5-v0",
    "MiniGrid-GoToObject-6x6-N2-v0",
    "MiniGrid-PutNear-6x6-N2-v0",
    "MiniGrid-KeyCorridorS3R1-v0",
    "MiniGrid-UnlockPickup-v0",
    "MiniGrid-LockedRoom-v0",
]
DEFAULT = {"MiniGrid-Fetch-5x5-N2-v0", "MiniGrid-LockedRoom-v0"}


def test_every_minigrid_mission_converts_exactly():
    for env_id in MINIGRID_IDS:
        mg = R.make_reference(env_id)
        for seed in range(2):
            mg.reset(seed=seed)
            env, state, _ = from_minigrid(mg)
            assert env.mission_text(state) == mg.mission, env_id
            ids = np.asarray(env.mission(state))
            assert ids.shape == (M.MAX_WORDS,) and ids.dtype == np.int32
            assert M.decode(ids) == mg.mission, env_id
            np.testing.assert_array_equal(ids, M.encode(mg.mission))


def missions(env, n, seed=0) -> np.ndarray:
    states = jax_reset_states(env, n, seed)
    ids = jax.jit(jax.vmap(env.mission), compiler_options=CHEAP)(states)
    return np.array([M.decode(row) for row in np.asarray(ids)])


@pytest.mark.parametrize("env_id", [id_param(i, DEFAULT) for i in VARIABLE])
def test_native_missions_are_drawn_as_minigrid_draws_them(env_id):
    n = 1000 if env_id in DEFAULT else 2000
    mg = R.make_reference(env_id)
    ref = []
    mg.reset(seed=0)
    for i in range(n):
        if i:
            mg.reset()
        ref.append(mg.mission)
    ours = missions(jaxgrid.make(env_id), 2 * n)
    compare_distributions(f"{env_id} mission", ours, np.array(ref))


def test_locked_room_mission_names_its_layout():
    env = jaxgrid.make("MiniGrid-LockedRoom-v0")
    states = jax_reset_states(env, 200, seed=3)
    texts = missions(env, 200, seed=3)
    tops, sizes, doors = env.rooms()
    for grid, text in zip(states.grid, texts, strict=True):
        colour = lambda cell, grid=grid: COLOR_NAMES[grid[tuple(cell)][1]]
        (locked,) = [c for c in doors if tuple(grid[tuple(c)])[::2] == (DOOR, LOCKED)]
        (key,) = np.argwhere(grid[..., 0] == KEY)
        inside = (key >= tops + 1) & (key < tops + sizes - 1)
        (room,) = np.nonzero(inside.all(axis=1))[0]
        expected = (
            f"get the {colour(locked)} key from the {colour(doors[room])} room, "
            f"unlock the {colour(locked)} door and go to the goal"
        )
        assert text == expected


def test_with_mission_observes_each_episodes_own_mission():
    env = jaxgrid.make("MiniGrid-Fetch-5x5-N2-v0", max_steps=4)
    batched = BatchedAutoReset(WithMission(env))
    states, ts = jax.jit(batched.reset)(jax.random.split(jax.random.PRNGKey(0), 16))
    first = np.asarray(ts.observation["mission"])
    assert len({M.decode(m) for m in first}) > 1  # phrasings, colours and types vary
    step = jax.jit(batched.step)
    ended = np.zeros(16, bool)
    for t in range(6):
        states, ts = step(states, jnp.zeros(16, jnp.int32))  # turn left: only truncation ends
        now = np.asarray(ts.observation["mission"])
        np.testing.assert_array_equal(now, np.asarray(jax.vmap(env.mission)(states)))
        ended |= np.asarray(ts.truncated)
        if t < 3:
            np.testing.assert_array_equal(now, first)
    assert ended.all()
    assert (now != first).any(axis=1).any()  # fresh episodes, fresh missions
    _, ts = WithMission(env).reset(jax.random.PRNGKey(0))
    assert set(ts.observation) == {"image", "direction", "mission"}


def test_fixed_levels_keep_their_own_mission():
    level = from_ascii("##########\n##>>..G.##\n##########")
    state, _ = level.reset(jax.random.PRNGKey(0))
    assert level.mission_text(state) == "get to the green goal square"
    custom = level.replace(mission_string="get to the shiny goal, quickly")
    ids = np.asarray(custom.mission(state))
    assert custom.mission_text(state) == "get to the shiny goal, quickly"
    assert M.decode(ids) == "get to the <unk> goal, <unk>"


def test_bad_missions_are_refused_by_name():
    with pytest.raises(ValueError, match="'shiny'"):
        M.encode("get to the shiny goal")
    with pytest.raises(ValueError, match="more than 24"):
        M.encode(" ".join(["the"] * 25))
    with pytest.raises(ValueError, match=r"slot \{size\}"):
        M.fill("go to the {size} door", size=1)
    with pytest.raises(ValueError, match="'kind'"):
        M.fill("go to the {colour} {kind}", colour=1)
    with pytest.raises(ValueError, match="malformed"):
        M.fill("go to the {colour door", colour=1)
    with pytest.raises(ValueError, match="shape"):
        M.decode(np.zeros((2, M.MAX_WORDS), np.int32))
    with pytest.raises(ValueError, match=r"0\.\."):
        M.decode(np.array([M.VOCAB_SIZE]))
    env = jaxgrid.make("MiniGrid-Empty-5x5-v0")
    states, _ = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 2))
    with pytest.raises(ValueError, match="one state"):
        env.mission_text(states)


def test_the_vocabulary_only_grows():
    # ids saved with a model keep their meaning: the first words are fixed
    assert M.WORDS[:3] == ("<pad>", "<unk>", ",")
    assert M.WORDS[3:9] == ("red", "green", "blue", "purple", "yellow", "grey")
    assert len(set(M.WORDS)) == len(M.WORDS)
    assert M.decode(M.fill("pick up the {colour} {kind}", colour=2, kind=6)) == (
        "pick up the blue ball"
    )
