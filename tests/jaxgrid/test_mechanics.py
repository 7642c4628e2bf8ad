"""Hand-built cases of MiniGrid's mechanics on ASCII maps (legend in ``jaxgrid/ascii.py``).

Every case states the expected outcome by hand *and* replays the same actions in MiniGrid
3.2.0 from the same state (``minigrid_reference.check_steps``), so a wrong expectation here
cannot hide a divergence from the reference. Action sequences are padded with ``done`` to a
fixed length so maps of one size share a single compiled rollout.
"""

from __future__ import annotations

import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import minigrid_reference as R
from helpers.xla import CHEAP
from minigrid.core.grid import Grid
from minigrid.core.world_object import Ball, Box, Key, Wall, WorldObj

import jaxgrid
from jaxgrid.ascii import parse_ascii
from jaxgrid.compat import from_minigrid
from jaxgrid.constants import (
    BALL,
    BLUE,
    BOX,
    CLOSED,
    DONE,
    DOOR,
    DROP,
    EMPTY,
    FLOOR,
    FORWARD,
    GOAL,
    GREEN,
    GREY,
    KEY,
    LAVA,
    LEFT,
    LOCKED,
    OPEN,
    PICKUP,
    PURPLE,
    RED,
    RIGHT,
    TOGGLE,
    WALL,
    YELLOW,
)
from jaxgrid.observation import see_behind, visibility_mask

KEY0 = jax.random.PRNGKey(0)
T = 8  # padded episode length
EMPTY3 = (EMPTY, 0, 0)


def strip(front: str, **kwargs) -> jaxgrid.levels.FixedLevel:
    """A 5x3 map: the agent at (1, 1) facing right at the cell ``front`` (two characters)."""
    return jaxgrid.from_ascii(
        f"""
        ##########
        ##>>{front}..##
        ##########
        """,
        **kwargs,
    )


def play(level, actions, num_steps: int = T):
    """Reset ``level``, step it with ``actions`` (padded with done) and check against MiniGrid.

    Returns ``(start state, reset observation, per-step outputs)`` (numpy, one episode).
    """
    state, _ = level.reset(KEY0)
    actions = list(actions) + [DONE] * (num_steps - len(actions))
    obs0, outs, _ = R.check_steps(level, state, actions, label=f"actions {actions}")
    return state, obs0, outs


# ------------------------------------------------------------------------------- doors


@pytest.mark.parametrize(
    "carrying, opens",
    [((KEY, RED, 0), True), ((KEY, BLUE, 0), False), ((BALL, RED, 0), False), (None, False)],
)
def test_locked_door_opens_only_with_a_key_of_its_colour(carrying, opens):
    _, _, outs = play(strip("LR", carrying=carrying), [TOGGLE, FORWARD, FORWARD, TOGGLE])
    door = tuple(outs["grid"][0, 2, 1])
    assert door == ((DOOR, RED, OPEN) if opens else (DOOR, RED, LOCKED))
    held = tuple(carrying) if carrying else EMPTY3
    assert (outs["carrying"] == held).all()  # the key is kept
    assert tuple(outs["agent_pos"][2]) == ((3, 1) if opens else (1, 1))
    if not opens:  # toggling again never unlocks it either
        assert tuple(outs["grid"][3, 2, 1]) == (DOOR, RED, LOCKED)


@pytest.mark.parametrize("carrying", [None, (KEY, GREEN, 0)])
def test_toggle_flips_unlocked_doors(carrying):
    _, _, outs = play(strip("DB", carrying=carrying), [TOGGLE, TOGGLE, TOGGLE, FORWARD])
    states = [int(outs["grid"][t, 2, 1, 2]) for t in range(3)]
    assert states == [OPEN, CLOSED, OPEN]
    assert tuple(outs["agent_pos"][3]) == (2, 1)  # now standing in the open door
    _, _, outs = play(strip("_B"), [TOGGLE, FORWARD])
    assert tuple(outs["grid"][0, 2, 1]) == (DOOR, BLUE, CLOSED)
    assert tuple(outs["agent_pos"][1]) == (1, 1)


# ----------------------------------------------------------------------------- forward

PASSABLE = ["..", "F.", "_R", "G.", "V."]
BLOCKING = ["##", "WR", "DR", "LR", "KR", "AB", "BG"]


@pytest.mark.parametrize("front", PASSABLE + BLOCKING)
def test_forward_only_into_empty_or_overlappable_cells(front):
    _, _, outs = play(strip(front), [FORWARD, FORWARD])
    moved = front in PASSABLE
    assert tuple(outs["agent_pos"][0]) == ((2, 1) if moved else (1, 1))
    assert bool(outs["terminated"][0]) == (front in ("G.", "V."))


def test_lava_terminates_with_reward_zero():
    state, _, outs = play(strip("V."), [FORWARD])
    assert bool(outs["terminated"][0]) and not bool(outs["truncated"][0])
    assert float(outs["reward"][0]) == 0.0
    assert tuple(outs["agent_pos"][0]) == (2, 1)  # the agent steps into the lava
    np.testing.assert_array_equal(outs["grid"][0], state.grid)


@pytest.mark.parametrize("max_steps", [10, 60])
def test_goal_reward_decays_with_the_step_count(max_steps):
    _, _, outs = play(strip("G.", max_steps=max_steps), [LEFT, RIGHT, LEFT, RIGHT, FORWARD])
    assert (outs["reward"][:4] == 0).all() and not outs["terminated"][:4].any()
    assert bool(outs["terminated"][4])
    assert abs(float(outs["reward"][4]) - (1 - 0.9 * 5 / max_steps)) < 1e-6


def test_truncation_at_max_steps():
    _, _, outs = play(strip("..", max_steps=3), [LEFT, LEFT, LEFT])
    assert outs["truncated"][:3].tolist() == [False, False, True]
    assert not outs["terminated"][:3].any()


@pytest.mark.parametrize("front, reward", [("G.", 0.1), ("V.", 0.0)])
def test_truncation_can_coincide_with_termination(front, reward):
    _, _, outs = play(strip(front, max_steps=1), [FORWARD])
    assert bool(outs["terminated"][0]) and bool(outs["truncated"][0])
    assert abs(float(outs["reward"][0]) - reward) < 1e-6


# ------------------------------------------------------------------ pickup, drop, toggle

PICKABLE = ["KR", "AB", "BG"]
NOT_PICKABLE = ["..", "##", "WR", "F.", "DR", "LR", "_R", "G.", "V."]


@pytest.mark.parametrize("front", PICKABLE + NOT_PICKABLE)
def test_pickup_only_keys_balls_and_boxes(front):
    state, _, outs = play(strip(front), [PICKUP])
    cell = tuple(np.asarray(state.grid)[2, 1])
    if front in PICKABLE:
        assert tuple(outs["carrying"][0]) == cell
        assert tuple(outs["grid"][0, 2, 1]) == EMPTY3
    else:
        assert tuple(outs["carrying"][0]) == EMPTY3
        np.testing.assert_array_equal(outs["grid"][0], state.grid)


def test_pickup_only_with_empty_hands():
    state, _, outs = play(strip("AB", carrying=(KEY, GREEN, 0)), [PICKUP])
    assert tuple(outs["carrying"][0]) == (KEY, GREEN, 0)
    np.testing.assert_array_equal(outs["grid"][0], state.grid)
    # ... and a picked-up object can be dropped again and picked up again.
    _, _, outs = play(strip("AB"), [PICKUP, DROP, PICKUP])
    assert [tuple(c) for c in outs["carrying"][:3]] == [(BALL, BLUE, 0), EMPTY3, (BALL, BLUE, 0)]


@pytest.mark.parametrize("front", ["..", "##", "F.", "_R", "DR", "G.", "V.", "KR", "BG"])
def test_drop_only_onto_an_empty_cell(front):
    carried = (BALL, PURPLE, 0)
    state, _, outs = play(strip(front, carrying=carried), [DROP])
    if front == "..":
        assert tuple(outs["grid"][0, 2, 1]) == carried
        assert tuple(outs["carrying"][0]) == EMPTY3
    else:
        np.testing.assert_array_equal(outs["grid"][0], state.grid)
        assert tuple(outs["carrying"][0]) == carried


@pytest.mark.parametrize("carrying", [None, (KEY, YELLOW, 0)])
def test_empty_box_vanishes_when_toggled(carrying):
    _, _, outs = play(strip("BG", carrying=carrying), [TOGGLE, FORWARD])
    assert tuple(outs["grid"][0, 2, 1]) == EMPTY3
    assert tuple(outs["carrying"][0]) == (tuple(carrying) if carrying else EMPTY3)
    assert tuple(outs["agent_pos"][1]) == (2, 1)


@pytest.mark.parametrize("front", ["..", "##", "F.", "G.", "V.", "KR", "AB"])
def test_toggle_does_nothing_to_other_objects(front):
    state, _, outs = play(strip(front, carrying=(KEY, RED, 0)), [TOGGLE])
    np.testing.assert_array_equal(outs["grid"][0], state.grid)


def test_turning():
    _, _, outs = play(strip(".."), [LEFT, LEFT, LEFT, LEFT, RIGHT, RIGHT, RIGHT, RIGHT])
    assert outs["direction"].tolist() == [3, 2, 1, 0, 1, 2, 3, 0]


_jit_step = jax.jit(
    lambda env, state, action: env.step(state, action), static_argnums=0, compiler_options=CHEAP
)


@pytest.mark.parametrize("action", [-1, 7, 100, 2**31 - 1, -(2**31)])
@pytest.mark.parametrize("front", ["..", "KR", "DR"])
def test_out_of_range_actions_act_as_done_under_jit(action, front):
    level = strip(front, carrying=(KEY, RED, 0) if front == "DR" else None)
    step = functools.partial(_jit_step, R.config_env(level))  # one compile for all cases
    state, _ = level.reset(KEY0)
    done_state, done_ts = step(state, jnp.int32(DONE))
    new_state, ts = step(state, jnp.int32(action))
    chex.assert_trees_all_equal(new_state, done_state)
    chex.assert_trees_all_equal(ts, done_ts)
    chex.assert_trees_all_equal(new_state.replace(step_count=state.step_count), state)
    assert int(new_state.step_count) == int(state.step_count) + 1


# --------------------------------------------------------------------------- observation

ROOM = """
    ##################
    ##..............##
    ##..............##
    ##..............##
    ##..............##
    ##..............##
    ##..............##
    ##......^^......##
    ##################
"""  # 9x9; agent at (4, 7) facing up: the 7x7 view cell [i, j] is world cell (i + 1, j + 1)
LOOK_AROUND = [LEFT, LEFT, RIGHT, RIGHT, RIGHT, RIGHT, LEFT, LEFT]


def room(*edits: tuple[int, int, str], **kwargs):
    """``ROOM`` with cell ``(x, y)`` replaced by the two-character symbol of each edit."""
    rows = [r for r in ROOM.strip("\n").split("\n")]
    rows = [r.strip() for r in rows]
    for x, y, sym in edits:
        rows[y] = rows[y][: 2 * x] + sym + rows[y][2 * x + 2 :]
    return jaxgrid.from_ascii("\n".join(rows), **kwargs)


def wall_row(y: int, door: str | None = None):
    return [(x, y, door if (door and x == 4) else "##") for x in range(1, 8)]


def view(level, actions=LOOK_AROUND):
    """Reset image (7x7) after checking the reset and every step against MiniGrid."""
    _, obs0, _ = play(level, actions)
    return obs0["image"]


def hidden(image) -> np.ndarray:
    return (image == 0).all(axis=-1)


def test_single_wall_ahead_hides_nothing():
    # MiniGrid's process_vis lights the row above diagonally, so light leaks around one wall.
    image = view(room((4, 6, "##")))
    assert not hidden(image).any()
    assert tuple(image[3, 5]) == (WALL, GREY, 0)


@pytest.mark.parametrize("door", [None, "DR", "LR"])
def test_wall_row_and_closed_doors_hide_what_lies_behind(door):
    image = view(room(*wall_row(5, door)))
    assert hidden(image)[:, :4].all()  # world rows 1..4
    assert not hidden(image)[:, 4:].any()
    if door:
        assert tuple(image[3, 4]) == (DOOR, RED, CLOSED if door == "DR" else LOCKED)


def test_open_door_in_a_wall_row_reveals_the_room_behind():
    # Visibility spreads sideways through a transparent row once one cell of it is visible.
    image = view(room(*wall_row(5, "_R")))
    assert not hidden(image).any()
    assert tuple(image[3, 4]) == (DOOR, RED, OPEN)


def test_corridor_walls_hide_everything_beyond_them():
    edits = [(x, y, "##") for x in (3, 5) for y in range(1, 8)]
    image = view(room(*edits))
    assert hidden(image)[[0, 1, 5, 6]].all()
    assert not hidden(image)[2:5].any()


def test_wall_beside_the_agent_hides_the_rest_of_its_row_only():
    image = view(room((3, 7, "##")))
    assert hidden(image)[:2, 6].all()  # world (1, 7), (2, 7)
    assert hidden(image).sum() == 2  # the row ahead is lit diagonally and spreads sideways


def test_see_through_walls_shows_everything():
    image = view(room(*wall_row(5, "DR"), see_through_walls=True))
    assert not hidden(image).any()
    assert tuple(image[3, 0]) == (EMPTY, 0, 0)


@pytest.mark.parametrize("see_through_walls", [False, True])
def test_out_of_grid_cells_read_as_grey_walls(see_through_walls):
    # No border walls: the agent at the edge looks out of the grid (a view-only check against
    # MiniGrid, whose step would index outside its grid here).
    level = jaxgrid.from_ascii(
        """
        ^^....
        ......
        ......
    """,
        view_size=5,
        see_through_walls=see_through_walls,
    )
    state, ts = level.reset(KEY0)
    image = np.asarray(ts.observation["image"])
    mg = R.reference_for(level, state)
    np.testing.assert_array_equal(image, mg.gen_obs()["image"])
    outside = np.zeros((5, 5), bool)
    outside[:, :4] = outside[:2, 4] = True  # ahead, and left of the agent
    seen = ~hidden(image)
    assert (image[outside & seen] == (WALL, GREY, 0)).all()
    assert seen[outside].sum() == (22 if see_through_walls else 5)  # occluded: 4 ahead, 1 left
    # ... and the edge blocks forward like a wall.
    new_state, _ = level.step(state, FORWARD)
    assert tuple(np.asarray(new_state.agent_pos)) == (0, 0)


@pytest.mark.parametrize("view_size", [3, 5, 7, 9, 11])
def test_view_sizes(view_size):
    level = room(
        (2, 2, "KR"),
        (6, 3, "AB"),
        (4, 4, "DY"),
        (1, 5, "V."),
        (7, 1, "G."),
        (5, 6, "BG"),
        view_size=view_size,
    )
    _, obs0, outs = play(
        level, [FORWARD, LEFT, FORWARD, RIGHT, RIGHT, FORWARD, FORWARD, LEFT], num_steps=T
    )
    assert obs0["image"].shape == (view_size, view_size, 3)
    assert outs["image"].shape[1:] == (view_size, view_size, 3)
    v = view_size
    assert tuple(obs0["image"][v // 2, v - 1]) == EMPTY3
    assert tuple(obs0["image"][v // 2, v - 2]) == EMPTY3  # (4, 6), in front of the agent
    if v >= 5:
        assert tuple(obs0["image"][v // 2, v - 4]) == (DOOR, YELLOW, CLOSED)  # (4, 4)


@pytest.mark.parametrize("view_size", [3, 5, 7])
def test_carried_object_shown_at_the_agents_view_cell(view_size):
    carried = (BALL, PURPLE, 0)
    _, obs0, outs = play(strip("..", carrying=carried, view_size=view_size), [DROP, PICKUP])
    v = view_size
    assert tuple(obs0["image"][v // 2, v - 1]) == carried
    assert tuple(outs["image"][0, v // 2, v - 1]) == EMPTY3  # dropped
    assert tuple(outs["image"][0, v // 2, v - 2]) == carried  # now in front
    assert tuple(outs["image"][1, v // 2, v - 1]) == carried  # picked up again


@pytest.mark.parametrize(
    "view_size",
    [3, 5, 7, 9, 11, 13, *(pytest.param(v, marks=pytest.mark.slow) for v in (15, 21, 31))],
)
def test_visibility_mask_matches_process_vis(view_size):
    """``visibility_mask`` against ``Grid.process_vis`` on random (all, for 3x3) patterns."""
    v = view_size
    rng = np.random.default_rng(v)
    if v == 3:
        bits = np.arange(2**9)[:, None] >> np.arange(9)[None, :] & 1
        patterns = bits.reshape(-1, 3, 3).astype(bool)
    else:
        n = 600 if v <= 13 else 100
        density = rng.uniform(0.3, 0.97, size=(n, 1, 1))
        patterns = rng.random((n, v, v)) < density
    mask = jax.jit(jax.vmap(visibility_mask), compiler_options=CHEAP)
    ours = np.asarray(mask(jnp.asarray(patterns)))
    for n, transparent in enumerate(patterns):
        grid = Grid(v, v)
        for i, j in np.argwhere(~transparent):
            grid.set(int(i), int(j), Wall())
        ref = grid.process_vis((v // 2, v - 1))
        if not np.array_equal(ours[n], ref):
            raise AssertionError(
                f"view {v} pattern {n}: transparent (rows = y)\n{transparent.T.astype(int)}\n"
                f"jaxgrid\n{ours[n].T.astype(int)}\nminigrid\n{ref.T.astype(int)}"
            )


def test_view_sizes_above_31_are_rejected_up_front():
    with pytest.raises(ValueError, match="view_size"):
        jaxgrid.make("MiniGrid-DoorKey-16x16-v0", view_size=33)
    jaxgrid.make("MiniGrid-DoorKey-16x16-v0", view_size=31)  # the largest supported


def test_see_behind_matches_minigrid_objects():
    cells = [
        (t, c, s) for t in range(1, 10) for c in range(6) for s in range(3) if t == DOOR or s == 0
    ]
    ours = np.asarray(see_behind(jnp.asarray(cells, jnp.uint8)))
    for cell, mine in zip(cells, ours, strict=True):
        obj = WorldObj.decode(*cell)
        assert mine == (obj is None or obj.see_behind()), cell


# --------------------------------------------------------------------------- ASCII maps


def test_ascii_legend():
    grid, pos, direction = parse_ascii("""
        ##WRF.FPG.V.DRLB_Y
        KPAGBE..vv    ####
    """)
    expected = {
        (0, 0): (WALL, GREY, 0),
        (1, 0): (WALL, RED, 0),
        (2, 0): (FLOOR, BLUE, 0),
        (3, 0): (FLOOR, PURPLE, 0),
        (4, 0): (GOAL, GREEN, 0),
        (5, 0): (LAVA, RED, 0),
        (6, 0): (DOOR, RED, CLOSED),
        (7, 0): (DOOR, BLUE, LOCKED),
        (8, 0): (DOOR, YELLOW, OPEN),
        (0, 1): (KEY, PURPLE, 0),
        (1, 1): (BALL, GREEN, 0),
        (2, 1): (BOX, GREY, 0),
        (3, 1): EMPTY3,
        (4, 1): EMPTY3,
        (5, 1): EMPTY3,
        (6, 1): EMPTY3,
        (7, 1): (WALL, GREY, 0),
        (8, 1): (WALL, GREY, 0),
    }
    assert grid.shape == (9, 2, 3)
    for (x, y), cell in expected.items():
        assert tuple(grid[x, y]) == cell, (x, y)
    assert pos == (4, 1) and direction == 1
    for sym, d in ((">>", 0), ("VV", 1), ("<<", 2), ("^^", 3)):
        assert parse_ascii(f"##{sym}##")[1:] == ((1, 0), d)


@pytest.mark.parametrize(
    "text, fragments",
    [
        ("##>>####\n##..QQ##", ["unknown symbol", "'QQ'", "line 2", "column 5"]),
        ("##>>##\n##KZ##", ["unknown colour", "'KZ'", "line 2", "column 3"]),
        ("##..##\n######", ["no agent"]),
        ("##>>##\n##..##\n<<....", ["2 agents", "line 3", "column 1"]),
        ("##>>####\n##....##\n##..##", ["line 3", "same width"]),
        ("##>>..##\n##..", ["line 2"]),
        ("##>>###\n##....#", ["line 1", "two characters"]),
        ("   \n  ", ["empty"]),
    ],
    ids=[
        "unknown-symbol",
        "unknown-colour",
        "no-agent",
        "two-agents",
        "ragged",
        "short-row",
        "odd-width",
        "empty",
    ],
)
def test_ascii_parser_errors_name_the_place(text, fragments):
    with pytest.raises(ValueError) as err:
        jaxgrid.from_ascii(text)
    for fragment in fragments:
        assert fragment in str(err.value), (fragment, str(err.value))


def test_ascii_map_must_be_a_string():
    with pytest.raises(TypeError):
        jaxgrid.from_ascii(["##>>##"])


# --------------------------------------------------------------------- from_minigrid errors


def _reset(env_id="MiniGrid-DoorKey-5x5-v0"):
    mg = R.make_reference(env_id)
    mg.reset(seed=0)
    return mg


def test_from_minigrid_rejects_a_box_with_contents():
    mg = _reset()
    mg.grid.set(3, 1, Box("red", contains=Key("blue")))
    with pytest.raises(ValueError, match=r"Box holding a key at cell \(3, 1\)"):
        from_minigrid(mg)
    mg = _reset()
    mg.carrying = Box("green", contains=Ball("red"))
    with pytest.raises(ValueError, match="Box holding a ball carried by the agent"):
        from_minigrid(mg)


def test_from_minigrid_rejects_unsupported_objects():
    class Teleporter(WorldObj):
        def __init__(self):
            super().__init__("agent", "purple")  # a type outside the supported set

    mg = _reset()
    mg.grid.set(3, 2, Teleporter())
    with pytest.raises(ValueError, match=r"unsupported MiniGrid object Teleporter.*\(3, 2\)"):
        from_minigrid(mg)


def test_from_minigrid_needs_a_reset_env():
    with pytest.raises(ValueError, match="reset"):
        from_minigrid(R.make_reference("MiniGrid-DoorKey-5x5-v0"))


def test_from_minigrid_keeps_the_step_count_and_wrapped_envs_work():
    import gymnasium as gym

    mg = gym.make("MiniGrid-DoorKey-5x5-v0")  # wrapped: from_minigrid reads .unwrapped
    mg.reset(seed=3)
    for a in (LEFT, LEFT, RIGHT):
        mg.step(a)
    env, state, ts = from_minigrid(mg)
    assert int(state.step_count) == 3
    np.testing.assert_array_equal(ts.observation["image"], mg.unwrapped.gen_obs()["image"])
    start, _ = env.reset(KEY0)  # reset goes back to step 0 of the converted layout
    assert int(start.step_count) == 0
    np.testing.assert_array_equal(start.grid, mg.unwrapped.grid.encode())
