"""Nothing silently wrong: impossible worlds, bad actions, bad keys and unsupported conversions
raise clear errors before any compile, and every legal world is well formed and solvable.

* Worlds: each level states its minimum size; smaller ones raise ``ValueError`` naming the
  setting and the minimum. Every registered id, reset at its minimum size and at random legal
  sizes (for RoomGrid levels: room sizes, and KeyCorridor's rows and columns of rooms), puts
  agent, goal, doors, keys, balls, boxes and lava on legal cells in the numbers its family
  places (bounded where the layout decides them). The oracle solves every episode of the levels
  won by reaching the goal without a violation; those with their own success rule (Unlock,
  UnlockPickup, BlockedUnlockPickup, KeyCorridor) are solvable by reachability: the key, then
  the locked door, then the target, which the locked door shuts away; so are GoToDoor,
  GoToObject, Fetch and PutNear (next to the target; its object faced, then a cell near the
  target).
* Actions and keys: concrete bad values raise ``TypeError``/``ValueError``; traced values are
  untouched (out-of-range actions still act as ``done``, ``jit`` compiles once, ``vmap`` works).
* gymnasium: actions are checked against the action space; ``render()`` without a mode warns.
* ``from_minigrid``: levels with their own ``step`` and non-MiniGrid envs are refused, except
  the families with a native level of their own rules, which convert to it.
"""

from __future__ import annotations

import functools
import warnings
import zlib

import chex
import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.ndimage

import jaxgrid
import jaxgrid.gym as jgym
from jaxgrid.compat import from_minigrid
from jaxgrid.constants import (
    BALL,
    BOX,
    COLOR_TO_IDX,
    DONE,
    DOOR,
    EMPTY,
    FLOOR,
    GOAL,
    KEY,
    LAVA,
    LOCKED,
    WALL,
)
from jaxgrid.levels import (
    BlockedUnlockPickup,
    DynamicObstacles,
    Fetch,
    FixedLevel,
    GoToDoor,
    GoToObject,
    KeyCorridor,
    Memory,
    MultiRoom,
    ObstructedMaze1D,
    ObstructedMazeFull,
    Playground,
    PutNear,
    RedBlueDoors,
    Unlock,
    UnlockPickup,
)
from jaxgrid.levels.keys import IDS as KEY_IDS
from jaxgrid.levels.keys import RoomLevel, roomgrid_size
from jaxgrid.levels.missions import IDS as MISSION_IDS
from jaxgrid.levels.missions import MissionLevel
from jaxgrid.levels.navigation import IDS as NAVIGATION_IDS
from jaxgrid.levels.obstructed import IDS as OBSTRUCTED_IDS
from jaxgrid.levels.rooms import IDS as ROOM_IDS
from jaxgrid.oracle import rollout_oracle

KEY0 = jax.random.PRNGKey(0)
IDS = jaxgrid.registered_ids()  # the built-in ids (collected before any test registers one)
EPISODES = 32  # per (id, size), in one jitted call


def _min_settings(env) -> list[dict]:
    """The smallest legal sizes: the stated minimum, or its two neighbours where the corner
    itself is refused (Empty's 3x3 has no room for both agent and goal).

    A RoomGrid level's size follows from its rooms: its smallest is its smallest
    ``room_size`` with the id's rows and columns of rooms.
    """
    if isinstance(env, RoomLevel):
        return [_room_settings(env, env.MIN_ROOM_SIZE, *env.rows_cols())]
    mw, mh, _ = env.min_size()
    sizes = [(mw, mh)] if _legal(env, mw, mh) else [(mw + 1, mh), (mw, mh + 1)]
    assert all(_legal(env, *s) for s in sizes), sizes
    return [dict(width=w, height=h) for w, h in sizes]


def _room_settings(env, room_size, rows, cols) -> dict:
    width, height = roomgrid_size(room_size, rows, cols)
    settings = dict(width=width, height=height, room_size=room_size)
    if isinstance(env, KeyCorridor):
        settings.update(num_rows=rows, num_cols=cols)
    return settings


def _legal(env, width, height, **settings) -> bool:
    try:
        env.replace(width=width, height=height, **settings)
    except ValueError:
        return False
    return True


def _random_settings(env_id, env, count) -> list[dict]:
    rng = np.random.default_rng(zlib.crc32(env_id.encode()))
    if isinstance(env, RoomLevel):  # room sizes (and KeyCorridor's rows and columns)
        low = env.MIN_ROOM_SIZE
        shapes = [env.rows_cols()]
        if isinstance(env, KeyCorridor):
            shapes = [(r, c) for r in range(1, 5) for c in (3, 4)]
        options = [_room_settings(env, s, r, c) for s in range(low, low + 7) for r, c in shapes]
        options = [o for o in options if _legal(env, **o)]
        picks = rng.choice(len(options), size=min(count, len(options)), replace=False)
        return [options[i] for i in sorted(picks)]
    mw, mh, _ = env.min_size()
    sizes = []
    while len(sizes) < count:
        size = (int(rng.integers(mw, mw + 10)), int(rng.integers(mh, mh + 8)))
        if _legal(env, *size) and size not in sizes:
            sizes.append(size)
    return [dict(width=w, height=h) for w, h in sizes]


def _expected(env) -> dict[str, int | range | None]:
    """Objects every layout of ``env`` holds: a count, a range where the layout decides (the
    doors ``connect_all`` adds), or None where :func:`_check_structure` counts them per
    layout (Crossing's lava: which rivers were drawn)."""
    name, w, h = type(env).__name__, env.width, env.height
    counts = dict(goal=1, door=0, key=0, ball=0, box=0, lava=0)
    if name == "DoorKey":
        counts.update(door=1, key=1)
    elif name == "LavaGap":
        counts.update(lava=h - 3)  # the interior column minus its one-cell gap
    elif name == "TwoRooms":
        counts.update(door=2, lava=int(env.has_lava))
    elif name == "ThreeRoomsKey":
        counts.update(door=2, key=1)
    elif name == "HazardRooms":  # its lava strips may overlap and are painted over
        counts.update(door=4, key=1, lava=None)
    elif name == "Crossing":
        counts.update(lava=None if env.obstacle == "lava" else 0)
    elif name == "DistShift":  # columns 3 .. width - 4 of row 1 and of row strip2_row
        counts.update(lava=max(w - 6, 0) * (1 if env.strip2_row == 1 else 2))
    elif isinstance(env, (ObstructedMaze1D, ObstructedMazeFull)):  # no goal: the blue ball
        full = isinstance(env, ObstructedMazeFull)
        quarters = env.num_quarters if full else 1
        locked = 2 * quarters if full else 1
        # v0: a side room's second blocking ball may cover the key added before it
        covered = full and env.blocked and not env.keys_after_doors
        keys = range(locked - quarters, locked + 1) if covered else locked
        counts.update(goal=0, door=locked + quarters * full, ball=1 + locked * env.blocked)
        counts.update(key=0 if env.key_in_box else keys, box=keys if env.key_in_box else 0)
    elif isinstance(env, RoomLevel):  # no goal: success is the level's own rule
        counts.update(goal=0, door=1, key=1)
        if isinstance(env, UnlockPickup):
            counts.update(box=1, ball=int(isinstance(env, BlockedUnlockPickup)))
        if isinstance(env, KeyCorridor):
            # The locked door, then connect_all's doors until every room is reachable: a
            # spanning tree at least (the corridor's open walls and the locked door join some
            # rooms already), at most every wall left (it may close a cycle).
            rows, cols = env.rows_cols()
            walls = rows * (cols - 1) + (rows - 1) * cols - (rows - 1)  # less the corridor's
            counts.update(ball=1, door=range(rows * (cols - 1), walls + 1))
    elif name == "MultiRoom":  # a door into each room after the first
        counts.update(door=range(env.max_num_rooms))
    elif name == "LockedRoom":  # a door into each of the six rooms, one locked
        counts.update(door=6, key=1)
    elif name == "RedBlueDoors":  # no goal: success is opening the blue door after the red
        counts.update(goal=0, door=2)
    elif name == "GoToDoor":  # no goal: success is done next to the target door
        counts.update(goal=0, door=4)
    elif isinstance(env, MissionLevel):  # num_objs objects: _check_structure counts them
        counts.update(goal=0, key=None, ball=None, box=0 if name == "Fetch" else None)
    elif name == "Memory":  # the start room's key or ball, and one of each at the far end
        counts.update(goal=0, key=range(1, 3), ball=range(1, 3))
    elif name == "Playground":  # a door in each inner wall; twelve objects, any types
        counts.update(goal=0, door=12, key=None, ball=None, box=None)
    elif name == "DynamicObstacles":
        counts.update(ball=env.n_obstacles)
    else:
        assert name in ("Empty", "FourRooms"), f"{name}: state what its layouts hold"
    return counts


@functools.partial(jax.jit, static_argnames="oracle")
def _resets_and_oracle(env, key, oracle):
    states, _ = jax.vmap(env.reset)(jax.random.split(key, EPISODES))
    if not oracle:
        return states, None
    # The same resets, then the oracle (through HazardRooms' lava, which only costs).
    avoid_lava = type(env).__name__ != "HazardRooms"
    return states, rollout_oracle(env, key, EPISODES, avoid_lava=avoid_lava)


def _check_world(env_id, **settings):
    env = jaxgrid.make(env_id, **settings)
    # The oracle's success is reaching the goal: it does not know the own-success levels
    # (open the door, pick up the box or ball), so those are checked for solvability by
    # reachability in _check_rooms, and solved by a scripted solution in test_key_levels.
    # Memory has no goal, Playground no task, and Dynamic-Obstacles' balls move into the
    # oracle's path: their reachability is checked in _check_structure.
    oracle = not isinstance(env, (RoomLevel, RedBlueDoors, MissionLevel, Memory, Playground))
    oracle &= not isinstance(env, DynamicObstacles)
    states, result = jax.device_get(_resets_and_oracle(env, KEY0, oracle))
    expected = _expected(env)
    width, height = env.width, env.height
    where = f"{env_id} at {width}x{height}" + "".join(
        f" {k}={v}" for k, v in settings.items() if k not in ("width", "height")
    )
    for i in range(EPISODES):
        grid, kind = states.grid[i], states.grid[i, ..., 0]
        assert kind.shape == (width, height), where
        ring = np.concatenate([kind[0], kind[-1], kind[:, 0], kind[:, -1]])
        outer = not isinstance(env, (MultiRoom, GoToDoor))  # GoToDoor: its room's, below
        assert (ring == WALL).all() or not outer, f"{where}: an object replaced the outer wall"
        x, y = states.agent_pos[i]
        assert 0 < x < width - 1 and 0 < y < height - 1, where
        assert kind[x, y] == EMPTY, f"{where}: the agent starts on object {kind[x, y]}"
        if hasattr(states.extras, "goal_pos"):
            assert kind[tuple(states.extras.goal_pos[i])] == GOAL, where
        for name, obj in (("goal", GOAL), ("door", DOOR), ("key", KEY), ("ball", BALL),
                          ("box", BOX), ("lava", LAVA)):  # fmt: skip
            want, got = expected[name], int((kind == obj).sum())
            if want is not None:
                ok = got in want if isinstance(want, range) else got == want
                assert ok, f"{where}: {got} {name} cells, expected {want}"
        locked = grid[kind == DOOR][grid[kind == DOOR][:, 2] == LOCKED]
        keys = np.argwhere(kind == KEY)
        if type(env).__name__ == "HazardRooms":  # its key opens nothing: it is a trigger
            keys = keys[:0]
        if isinstance(env, (MissionLevel, Memory, Playground)):  # keys as objects: no locks
            keys = keys[:0]
        extras = jax.tree.map(lambda a, i=i: a[i], states.extras)
        if isinstance(env, (ObstructedMaze1D, ObstructedMazeFull)):  # several locks, boxes
            _check_obstructed(env, grid, (x, y), extras, where)
            continue
        for kx, ky in keys:  # the key opens the locked door
            assert len(locked) == 1 and grid[kx, ky, 1] == locked[0, 1], where
        if isinstance(env, RoomLevel):
            _check_rooms(env, grid, (x, y), extras, where)
        elif isinstance(env, MissionLevel):
            _check_mission(env, grid, (x, y), extras, where)
        elif not isinstance(env, (MultiRoom, Playground)):  # theirs: their own test files
            _check_doors(env, kind, where)
        if isinstance(env, RedBlueDoors):  # both doors can be faced from the agent's cell
            reach = _reach(kind == EMPTY, (x, y))
            assert all(_faceable(reach, d) for d in np.argwhere(kind == DOOR)), where
        _check_structure(env, kind, where)
    if oracle:
        assert result["success"].all(), f"{where}: the oracle failed {(~result['success']).sum()}"
        assert (result["violations"] == 0).all(), f"{where}: the oracle had to violate"


def _check_doors(env, kind, where):
    """Each door sits in a vertical wall and leads across it (HazardRooms: one door in each
    half of its middle column and row)."""
    if type(env).__name__ == "HazardRooms":
        mx, my = env.width // 2, env.height // 2
        doors = {tuple(d) for d in np.argwhere(kind == DOOR).tolist()}
        halves = [{d for d in doors if d[0] == mx and (d[1] < my) == up} for up in (1, 0)]
        halves += [{d for d in doors if d[1] == my and (d[0] < mx) == lf} for lf in (1, 0)]
        assert [len(h) for h in halves] == [1, 1, 1, 1], f"{where}: doors {sorted(doors)}"
        return
    # Rows of a door's wall that may be open: ThreeRoomsKey's second wall has a bottom-row gap.
    gaps = {env.height - 2} if type(env).__name__ == "ThreeRoomsKey" else set()
    for dx, dy in np.argwhere(kind == DOOR):
        openings = np.flatnonzero(~np.isin(kind[dx, 1:-1], [WALL, DOOR])) + 1
        assert set(openings.tolist()) <= gaps, f"{where}: door ({dx}, {dy}) not in a wall"
        assert kind[dx - 1, dy] != WALL and kind[dx + 1, dy] != WALL, where


def _check_structure(env, kind, where):
    """Where the level's fixed walls and lava lie, family by family."""
    name, w, h = type(env).__name__, env.width, env.height
    xs, ys = np.meshgrid(np.arange(w), np.arange(h), indexing="ij")
    inner = (xs > 0) & (xs < w - 1) & (ys > 0) & (ys < h - 1)
    if name == "FourRooms":  # the middle column and row, one gap in each of their four halves
        walls = inner & (kind == WALL)
        assert (walls <= ((xs == w // 2) | (ys == h // 2))).all(), f"{where}: a stray wall"
        assert walls.sum() == (w - 2) + (h - 2) - 1 - 4, f"{where}: {walls.sum()} inner walls"
    elif name == "Crossing":
        # Rivers on even lines 2 .. size - 3, each missing one cell off the other rivers: a
        # column with h - 3 obstacles is a river, any other holds only the row rivers' cells.
        obstacle = inner & (kind == (LAVA if env.obstacle == "lava" else WALL))
        on_lines = ((xs % 2 == 0) & (xs >= 2) & (xs <= w - 3)) | (
            (ys % 2 == 0) & (ys >= 2) & (ys <= h - 3)
        )
        assert (obstacle <= on_lines).all(), f"{where}: an obstacle off the river lines"
        v = int((obstacle[2 : w - 2 : 2].sum(1) == h - 3).sum())
        hz = int((obstacle[:, 2 : h - 2 : 2].sum(0) == w - 3).sum())
        n = env.num_crossings
        assert v + hz == n, f"{where}: {v} + {hz} rivers, expected {n}"
        want = v * (h - 2) + hz * (w - 2) - v * hz - n
        assert obstacle.sum() == want, f"{where}: {obstacle.sum()} obstacles, expected {want}"
        assert (inner & (kind == WALL)).sum() == (0 if env.obstacle == "lava" else want), where
    elif name == "DistShift":
        lava_rows = (ys == 1) | (ys == env.strip2_row)
        assert ((kind == LAVA) <= (lava_rows & (xs >= 3) & (xs <= w - 4))).all(), where
        assert kind[w - 2, 1] == GOAL, where
    elif name == "GoToDoor":  # a room from (0, 0), 5 .. size wide, a door inside each wall
        solid = (kind == WALL) | (kind == DOOR)
        rw, rh = xs[solid].max() + 1, ys[solid].max() + 1
        edge = (xs == 0) | (ys == 0) | (xs == rw - 1) | (ys == rh - 1)
        assert rw >= 5 and rh >= 5 and (solid == ((xs < rw) & (ys < rh) & edge)).all(), where
        doors = np.argwhere(kind == DOOR)
        walls = [(x == 0) + 2 * (x == rw - 1) + 4 * (y == 0) + 8 * (y == rh - 1) for x, y in doors]
        assert sorted(walls) == [1, 2, 4, 8], f"{where}: doors {doors.tolist()}"
        for x, y in doors:  # two cells from the room's corners at least
            along, length = (x, rw) if y in (0, rh - 1) else (y, rh)
            assert 2 <= along <= length - 3, f"{where}: door ({x}, {y}) by a corner"
    elif isinstance(env, MissionLevel):  # num_objs objects (PutNear: apart) inside the walls
        objects = np.argwhere(np.isin(kind, [KEY, BALL, BOX]))
        assert len(objects) == env.num_objs, f"{where}: {len(objects)} objects"
        if isinstance(env, PutNear):
            gaps = np.abs(objects[:, None] - objects[None]).max(-1) + 2 * np.eye(len(objects))
            assert gaps.min() >= 2, f"{where}: two objects next to each other"
    elif name == "Memory":  # both end objects' neighbour cells reachable from the agent
        start = np.argwhere((kind == EMPTY) & (ys == h // 2) & (xs == 1))[0]
        reach = _reach((kind == EMPTY), start)
        ends = np.argwhere(np.isin(kind, [KEY, BALL]) & (xs > 1))
        assert len(ends) == 2, where
        for x, y in ends:
            assert reach[x, y + (1 if y < h // 2 else -1)], f"{where}: ({x}, {y}) cut off"
    elif name == "Playground":  # every empty cell connected through the doors
        open_ = ~np.isin(kind, [WALL])
        reach = _reach(open_, np.argwhere(kind == EMPTY)[0])
        assert (reach | ~open_).all(), f"{where}: a room cut off"
        assert np.isin(kind, [KEY, BALL, BOX]).sum() == 12, where
    elif name == "DynamicObstacles":  # the goal reachable from the start, balls aside
        reach = _reach(kind != WALL, np.argwhere(kind == GOAL)[0])
        assert reach[inner].all(), where


def _reach(passable, start) -> np.ndarray:
    """bool ``(W, H)``: the cells reachable from ``start`` through ``passable`` cells."""
    labels, _ = scipy.ndimage.label(passable)  # 4-connected components
    return labels == labels[tuple(start)]


def _faceable(reach, cell) -> bool:
    """Whether the agent can stand next to ``cell`` (facing it) within ``reach``."""
    x, y = cell
    return bool(reach[x - 1, y] | reach[x + 1, y] | reach[x, y - 1] | reach[x, y + 1])


def _check_mission(env, grid, agent, mission, where):
    """GoToDoor, GoToObject, Fetch, PutNear: the task's objects lie where ``state.extras`` says,
    and a solution exists by reachability (walking on empty cells): stand next to the target
    (GoTo*); face an object of the target's type and colour (Fetch); face the object to move,
    then, carrying it, an empty cell within one cell of the target (PutNear). Not checked with
    three objects or more in GoToObject and Fetch: two of them may shut the agent into a
    corner, away from the target, in MiniGrid's layouts and here alike."""
    kind = grid[..., 0]
    parts = [mission.move, mission.target] if hasattr(mission, "move") else [mission]
    for m in parts:
        cell = tuple(m.pos)
        assert (kind[cell], grid[cell][1]) == (m.kind, m.colour), f"{where}: task off its object"
    target = tuple(parts[-1].pos)
    # _faceable on a padded grid: GoToDoor's doors may lie on the grid's border
    faceable = lambda reach, c: _faceable(np.pad(reach, 1), (c[0] + 1, c[1] + 1))
    reach = _reach(kind == EMPTY, agent)
    if isinstance(env, (GoToObject, Fetch)) and env.num_objs >= 3:
        return
    if isinstance(env, (GoToDoor, GoToObject)):
        assert faceable(reach, target), f"{where}: no way next to the target"
    elif isinstance(env, Fetch):
        same = (kind == mission.kind) & (grid[..., 1] == mission.colour)
        assert any(faceable(reach, c) for c in np.argwhere(same)), f"{where}: out of reach"
    else:
        move = tuple(mission.move.pos)
        assert faceable(reach, move), f"{where}: the object to move is out of reach"
        xs, ys = np.meshgrid(*map(np.arange, kind.shape), indexing="ij")
        free = (kind == EMPTY) | ((xs == move[0]) & (ys == move[1]))  # once it is picked up
        carried = _reach(free, agent)
        near = free & (np.abs(xs - target[0]) <= 1) & (np.abs(ys - target[1]) <= 1)
        assert any(faceable(carried, c) for c in np.argwhere(near)), f"{where}: nowhere to drop"


def _check_rooms(env, grid, agent, mission, where):
    """RoomGrid levels: the rooms' walls, doors leading between rooms, the mission object, and
    a solution by reachability (MiniGrid's moves: walk on empty cells and open doors, open
    closed doors, a locked one with its key; face an object to pick it up)."""
    kind, state = grid[..., 0], grid[..., 2]
    s = env.room_size - 1
    rows, cols = env.rows_cols()
    xs, ys = np.meshgrid(np.arange(env.width), np.arange(env.height), indexing="ij")
    lattice = (xs % s == 0) | (ys % s == 0)
    removed = np.zeros_like(lattice)  # KeyCorridor: the corridor's walls between its rooms
    if isinstance(env, KeyCorridor):
        removed = (ys % s == 0) & (ys > 0) & (ys < env.height - 1) & (xs > s) & (xs < 2 * s)
    assert (np.isin(kind[lattice & ~removed], [WALL, DOOR])).all(), f"{where}: a wall is open"
    assert not (np.isin(kind, [WALL, DOOR]) & ~lattice).any(), f"{where}: a stray wall/door"
    assert not np.isin(kind[removed], [WALL, DOOR]).any(), f"{where}: the corridor is closed"
    for dx, dy in np.argwhere(kind == DOOR):  # between two rooms, not at a wall's corner
        across = [(dx - 1, dy), (dx + 1, dy)] if dx % s == 0 else [(dx, dy - 1), (dx, dy + 1)]
        assert (dx % s == 0) != (dy % s == 0), f"{where}: door ({dx}, {dy}) at a corner"
        assert all(kind[c] != WALL for c in across), f"{where}: door ({dx}, {dy}) leads nowhere"
    # place_agent(i, j): in room (i, j), walls included (KeyCorridor's removed ones are free)
    i, j = (1, rows // 2) if isinstance(env, KeyCorridor) else (0, 0)
    in_room = i * s <= agent[0] <= (i + 1) * s and j * s <= agent[1] <= (j + 1) * s
    assert in_room, f"{where}: the agent starts outside room ({i}, {j})"
    # connect_all: every room reachable from the agent's, doors counted as passable.
    assert _reach(kind != WALL, agent)[kind != WALL].all(), f"{where}: a room is cut off"
    # The mission object lies where state.extras says.
    target = tuple(mission.pos)
    assert (kind[target], grid[target][1]) == (mission.kind, mission.colour), where
    locked = [tuple(c) for c in np.argwhere((kind == DOOR) & (state == LOCKED))]
    assert len(locked) == 1, f"{where}: {len(locked)} locked doors"
    door = locked[0]
    # Objects picked up free their cells. This relaxes where BlockedUnlockPickup's ball is put
    # down (its cell is freed; the scripted solutions of test_key_levels drop it somewhere).
    unlocked = np.isin(kind, [EMPTY, FLOOR, GOAL]) | ((kind == DOOR) & (state != LOCKED))
    if isinstance(env, BlockedUnlockPickup):  # the ball in front of the door, moved first
        ball = (door[0] - 1, door[1])
        assert kind[ball] == BALL and _faceable(_reach(unlocked, agent), ball), where
        unlocked[ball] = True
    (key,) = [tuple(c) for c in np.argwhere(kind == KEY)]
    assert _faceable(_reach(unlocked, agent), key), f"{where}: the key is out of reach"
    unlocked[key] = True
    without_key = _reach(unlocked, agent)
    assert _faceable(without_key, door), f"{where}: the locked door is out of reach"
    if isinstance(env, Unlock):
        assert target == door, where
        return
    with_key = _reach(unlocked | (kind == DOOR), agent)
    assert not _faceable(without_key, target), f"{where}: the target is not locked away"
    assert _faceable(with_key, target), f"{where}: the target is out of reach"


def _check_obstructed(env, grid, agent, task, where):
    """ObstructedMaze: the rooms' walls, doors between rooms, the agent in its room, the red
    ball where ``state.extras`` says, a key for every lock (loose or in a box: the box's
    ``contents``; v0 layouts may have lost one under a blocking ball), a green ball in front of
    every locked door when blocked, and the ball reachable with doors and objects cleared."""
    kind, state = grid[..., 0], grid[..., 2]
    s = env.room_size - 1
    xs, ys = np.meshgrid(np.arange(env.width), np.arange(env.height), indexing="ij")
    lattice = (xs % s == 0) | (ys % s == 0)
    assert np.isin(kind[lattice], [WALL, DOOR]).all(), f"{where}: a wall is open"
    assert not np.isin(kind[~lattice], [WALL, DOOR]).any(), f"{where}: a stray wall/door"
    i, j = env.agent_room if isinstance(env, ObstructedMazeFull) else (0, 0)
    assert i * s < agent[0] < (i + 1) * s and j * s < agent[1] < (j + 1) * s, where
    target = tuple(task.pos)
    assert (kind[target], grid[target][1]) == (BALL, COLOR_TO_IDX["blue"]), where
    boxes = kind == BOX
    inside = task.contents[..., 0]
    assert (inside[boxes] == KEY).all() and (inside[~boxes] == EMPTY).all(), where
    keys = np.concatenate([grid[kind == KEY][:, 1], task.contents[boxes][:, 1]])
    locks = grid[(kind == DOOR) & (state == LOCKED)][:, 1]
    assert set(keys.tolist()) <= set(locks.tolist()), f"{where}: a key opens no door"
    may_lose = isinstance(env, ObstructedMazeFull) and env.blocked and not env.keys_after_doors
    assert may_lose or sorted(keys.tolist()) == sorted(locks.tolist()), f"{where}: keys {keys}"
    for dx, dy in np.argwhere((kind == DOOR) & (state == LOCKED)):
        across = [(dx - 1, dy), (dx + 1, dy)] if dx % s == 0 else [(dx, dy - 1), (dx, dy + 1)]
        balls = [c for c in across if kind[c] == BALL and grid[c][1] == COLOR_TO_IDX["green"]]
        assert len(balls) == int(env.blocked), f"{where}: door ({dx}, {dy}) blocked wrongly"
    # no connect_all: rooms beyond the quarters stay shut, but the ball is always in reach
    assert _faceable(_reach(kind != WALL, agent), target), f"{where}: the ball is shut away"


# FourRooms, the Crossings, DistShift and the key levels: one case per level class (and
# obstacle) in the default run, every id with -m slow. At its minimum size an id differs from
# the others of its class only in a setting such as num_crossings (KeyCorridorS4R3 .. S6R3
# are all S3R3 there).
ONE_PER_CLASS = {
    "MiniGrid-FourRooms-v0",
    "MiniGrid-LavaCrossingS9N1-v0",
    "MiniGrid-SimpleCrossingS9N1-v0",
    "MiniGrid-DistShift1-v0",
    "MiniGrid-Unlock-v0",
    "MiniGrid-UnlockPickup-v0",
    "MiniGrid-BlockedUnlockPickup-v0",
    "MiniGrid-KeyCorridorS3R2-v0",
    "MiniGrid-MultiRoom-N6-v0",
    "MiniGrid-LockedRoom-v0",
    "MiniGrid-RedBlueDoors-6x6-v0",
    "MiniGrid-GoToDoor-5x5-v0",
    "MiniGrid-GoToObject-6x6-N2-v0",
    "MiniGrid-Fetch-5x5-N2-v0",
    "MiniGrid-PutNear-6x6-N2-v0",
    "MiniGrid-ObstructedMaze-1Dlhb-v0",
    "MiniGrid-ObstructedMaze-Full-v0",
}
MIN_SIZE_IDS = [
    i if i not in {**NAVIGATION_IDS, **KEY_IDS, **ROOM_IDS, **MISSION_IDS, **OBSTRUCTED_IDS}
    or i in ONE_PER_CLASS
    else pytest.param(i, marks=pytest.mark.slow)
    for i in IDS
]  # fmt: skip


@pytest.mark.parametrize("env_id", MIN_SIZE_IDS)
def test_every_id_is_legal_and_solvable_at_its_minimum_size(env_id):
    env = jaxgrid.make(env_id)
    for settings in _min_settings(env):
        _check_world(env_id, **settings)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", IDS)
def test_every_id_is_legal_and_solvable_at_many_sizes(env_id):
    env = jaxgrid.make(env_id)
    for settings in _random_settings(env_id, env, 6):
        _check_world(env_id, **settings)


@pytest.mark.parametrize("env_id", IDS)
def test_below_the_minimum_size_raises_naming_the_setting_and_minimum(env_id):
    env = jaxgrid.make(env_id)
    mw, mh, _ = env.min_size()
    # A RoomGrid level's size is its rooms' (room_size, rows, columns): exactly that size.
    size = r"{} for room_size=" if isinstance(env, RoomLevel) else r"at least {} "
    with pytest.raises(ValueError, match=rf"\.width must be {size.format(mw)}"):
        jaxgrid.make(env_id, width=mw - 1)
    with pytest.raises(ValueError, match=rf"\.height must be {size.format(mh)}"):
        jaxgrid.make(env_id, height=mh - 1)
    if isinstance(env, RoomLevel):
        low = env.MIN_ROOM_SIZE
        with pytest.raises(ValueError, match=rf"\.room_size must be an int >= {low} "):
            jaxgrid.make(env_id, room_size=low - 1)


@pytest.mark.parametrize(
    "env_id, overrides, message",
    [
        ("MiniGrid-Empty-8x8-v0", dict(width=1, height=1), r"Empty\.width must be at least 3"),
        ("MiniGrid-Empty-8x8-v0", dict(width=3, height=3), r"cannot both be 3"),
        ("TwoRooms-v0", dict(width=2), r"TwoRooms\.width must be at least 5"),
        ("TwoRooms-v0", dict(height=3), r"TwoRooms\.height must be at least 4"),
        ("TwoRoomsLava-v0", dict(width=6), r"TwoRooms\.width must be at least 7"),
        ("MiniGrid-DoorKey-8x8-v0", dict(width=3), r"DoorKey\.width must be at least 5"),
        ("MiniGrid-LavaGapS5-v0", dict(width=4), r"LavaGap\.width must be at least 5"),
        ("ThreeRoomsKey-v0", dict(width=5), r"ThreeRoomsKey\.width must be at least 7"),
        ("TwoRooms-v0", dict(view_size=4), r"view_size must be an odd int"),
        ("MiniGrid-Unlock-v0", dict(width=12), r"Unlock\.width must be 11 for room_size=6"),
        ("MiniGrid-KeyCorridorS3R1-v0", dict(num_cols=4, width=9), r"num_rows must be at least 2"),
        (
            "MiniGrid-KeyCorridorS3R3-v0",
            dict(num_cols=4, width=9),
            r"KeyCorridor\.room_size must be at least 4 when num_cols is 4",
        ),
    ],
)
def test_impossible_worlds_raise_at_make(env_id, overrides, message):
    with pytest.raises(ValueError, match=message):
        jaxgrid.make(env_id, **overrides)


def test_fixed_level_agent_must_start_inside_on_a_standable_cell():
    level = jaxgrid.from_ascii(
        """
        ##########
        ##>>..##G.
        ##..KYLY..
        ##########
        """
    )
    assert level.agent_start == (1, 1)
    with pytest.raises(ValueError, match=r"agent_start \(0, 0\) is on a wall"):
        level.replace(agent_start=(0, 0))
    with pytest.raises(ValueError, match=r"agent_start \(2, 2\) is on a key"):
        level.replace(agent_start=(2, 2))
    with pytest.raises(ValueError, match=r"agent_start \(5, 1\) is outside the 5x4 grid"):
        level.replace(agent_start=(5, 1))
    with pytest.raises(ValueError, match=r"agent_dir must be 0\.\.3 or -1"):
        level.replace(agent_dir=4)
    assert isinstance(level.replace(agent_start=(4, 1)), FixedLevel)  # the goal: allowed


# --------------------------------------------------------------------------- actions and keys

ENVS = ["MiniGrid-Empty-5x5-v0", "TwoRooms-v0"]  # Environment.step and Scenario.step


@functools.cache
def _start(env_id):
    """``(env, first state)``; the reset is jitted (op-by-op it compiles every small op)."""
    env = jaxgrid.make(env_id)
    return env, jax.jit(env.reset)(KEY0)[0]


@pytest.mark.parametrize("env_id", ENVS)
@pytest.mark.parametrize(
    "action, error, message",
    [
        (2.7, TypeError, r"action must be an integer scalar .* got float 2\.7"),
        (2.0, TypeError, r"got float 2\.0"),
        ("2", TypeError, r"got str '2'"),
        (True, TypeError, r"got bool True"),
        ([2], TypeError, r"got list \[2\]"),
        (np.float32(1), TypeError, r"got dtype float32"),
        (jnp.array(1.5), TypeError, r"got dtype float32"),
        (np.array([2, 2]), ValueError, r"action .* got an array of shape \(2,\).*jax\.vmap"),
        (jnp.array([[2]]), ValueError, r"got an array of shape \(1, 1\)"),
    ],
)
def test_concrete_bad_actions_raise(env_id, action, error, message):
    env, state = _start(env_id)
    with pytest.raises(error, match=message):
        env.step(state, action)


@pytest.mark.parametrize("env_id", ENVS)
@pytest.mark.parametrize(
    "key, error, message",
    [
        (0, TypeError, r"reset's key must be one PRNG key.* got int 0"),
        (jnp.zeros(2), TypeError, r"got an array of dtype float32"),
        (np.zeros(2, np.int32), TypeError, r"got an array of dtype int32"),
        (jax.random.split(KEY0, 3), ValueError, r"got shape \(3, 2\).*jax\.vmap\(env\.reset\)"),
        (jax.random.split(jax.random.key(0), 3), ValueError, r"\(shape \(\)\), got shape \(3,\)"),
        (np.zeros(3, np.uint32), ValueError, r"\(shape \(2,\)\), got shape \(3,\)"),
    ],
)
def test_concrete_bad_keys_raise(env_id, key, error, message):
    env = jaxgrid.make(env_id)
    with pytest.raises(error, match=message):
        env.reset(key)


def test_every_integer_kind_is_an_action_and_out_of_range_acts_as_done():
    # Regression guard: the checks accept every integer scalar and keep the documented rule.
    env, state = _start("TwoRooms-v0")
    done, _ = env.step(state, DONE)
    for action in (2, np.int64(2), np.array(2, np.uint8), jnp.int32(2), jnp.array(2)):
        chex.assert_trees_all_equal(env.step(state, action), env.step(state, 2))
    for action in (7, -1, 2**20, jnp.int32(9)):
        chex.assert_trees_all_equal(env.step(state, action)[0], done)
    env = jaxgrid.make("MiniGrid-Empty-5x5-v0")  # a cheap reset to run op by op
    assert jax.random.key_data(env.reset(jax.random.key(3))[0].key).shape == (2,)
    chex.assert_trees_all_equal(env.reset(np.asarray(KEY0)), env.reset(KEY0))


def test_traced_actions_and_keys_are_untouched():
    # Regression guard: jit compiles once for every action, out-of-range acts as done under
    # jit, and vmap of reset and step works on batches.
    env, state = _start("TwoRooms-v0")
    done, _ = jax.jit(env.step)(state, DONE)
    step = jax.jit(chex.assert_max_traces(env.step, n=1))
    for action in (0, 2, 9, -3):
        out, _ = step(state, jnp.int32(action))
        if action in (9, -3):
            chex.assert_trees_all_equal(out, done)
    keys = jnp.stack([KEY0, KEY0, KEY0, KEY0])
    states, _ = jax.jit(jax.vmap(env.reset))(keys)
    chex.assert_trees_all_equal(jax.tree.map(lambda x: x[1], states), _start("TwoRooms-v0")[1])
    states, ts = jax.jit(jax.vmap(env.step))(states, jnp.array([0, 2, 9, 5]))
    assert ts.reward.shape == (4,)


# --------------------------------------------------------------------------------- gymnasium


@pytest.mark.parametrize("action", [7, -1, 2.5, 2.0, "2", np.float32(1), [2], np.array([2])])
def test_gym_step_rejects_actions_outside_the_space(action):
    env = gym.make("jaxgrid/MiniGrid-Empty-5x5-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action .* is not in Discrete\(7\)"):
        env.step(action)


def test_gym_step_accepts_the_space_members_and_jax_integers():
    env = gym.make("jaxgrid/MiniGrid-Empty-5x5-v0")
    env.reset(seed=0)
    for action in (1, np.int64(2), np.array(0), jnp.int32(2)):
        env.step(action)


@pytest.mark.parametrize(
    "actions", [[7, 0, 0], [-1, 0, 0], [2.5, 1, 1], [1, 1], np.zeros((1, 3), int), 2, "abc"]
)
def test_gym_vector_step_rejects_actions_outside_the_space(actions):
    envs = jgym.JaxGridVectorEnv("MiniGrid-Empty-5x5-v0", 3)
    envs.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions .* is not in MultiDiscrete\(\[7 7 7\]\)"):
        envs.step(actions)
    envs.step([0, 1, 2])
    envs.step(jnp.array([0, 1, 2]))


def test_gym_render_without_a_mode_warns_like_gymnasium():
    message = r"You are calling render method without specifying any render mode"
    env = gym.make("jaxgrid/MiniGrid-Empty-5x5-v0")
    env.reset(seed=0)
    with pytest.warns(UserWarning, match=message + r".*jaxgrid/MiniGrid-Empty-5x5-v0"):
        assert env.render() is None
    envs = jgym.JaxGridVectorEnv("MiniGrid-Empty-5x5-v0", 2)
    envs.reset(seed=0)
    with pytest.warns(UserWarning, match=message + r".*JaxGridVectorEnv\(\"MiniGrid-Empty"):
        assert envs.render() is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # with a mode: no warning
        env = gym.make("jaxgrid/MiniGrid-Empty-5x5-v0", render_mode="ansi")
        env.reset(seed=0)
        assert isinstance(env.render(), str)


# ----------------------------------------------------------------------------- from_minigrid

# MiniGrid levels whose class overrides MiniGridEnv.step (rules of their own), and has no
# native level (those convert to it: NATIVE_OWN_STEP).
OWN_STEP = ["BabyAI-GoToRedBall-v0"]
NATIVE_OWN_STEP = {
    "MiniGrid-Unlock-v0": Unlock,
    "MiniGrid-UnlockPickup-v0": UnlockPickup,
    "MiniGrid-BlockedUnlockPickup-v0": BlockedUnlockPickup,
    "MiniGrid-KeyCorridorS3R1-v0": KeyCorridor,
    "MiniGrid-RedBlueDoors-6x6-v0": RedBlueDoors,
    "MiniGrid-Fetch-5x5-N2-v0": Fetch,
    "MiniGrid-GoToDoor-5x5-v0": GoToDoor,
    "MiniGrid-GoToObject-6x6-N2-v0": GoToObject,
    "MiniGrid-PutNear-6x6-N2-v0": PutNear,
    "MiniGrid-MemoryS7-v0": Memory,
    "MiniGrid-Dynamic-Obstacles-5x5-v0": DynamicObstacles,
    "MiniGrid-ObstructedMaze-1Dl-v0": ObstructedMaze1D,
    "MiniGrid-ObstructedMaze-2Q-v0": ObstructedMazeFull,
    "MiniGrid-ObstructedMaze-Full-v1": ObstructedMazeFull,
}


def _minigrid(env_id):
    import minigrid  # noqa: F401  (registers the MiniGrid ids)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mg = gym.make(env_id)
    mg.reset(seed=0)
    return mg


@pytest.mark.parametrize("env_id", OWN_STEP)
def test_from_minigrid_refuses_levels_with_their_own_step(env_id):
    mg = _minigrid(env_id)
    name = type(mg.unwrapped).__name__
    with pytest.raises(ValueError, match=rf"{name} overrides MiniGridEnv\.step: its own step"):
        from_minigrid(mg)
    env, state, _ = from_minigrid(mg, base_step=True)  # explicitly: the layout, base rules
    assert env.grid.shape == (mg.unwrapped.width, mg.unwrapped.height, 3)


@pytest.mark.parametrize("env_id", list(NATIVE_OWN_STEP))
def test_from_minigrid_converts_own_step_levels_with_a_native_level_to_it(env_id):
    mg = _minigrid(env_id)
    env, state, _ = from_minigrid(mg)
    assert type(env) is NATIVE_OWN_STEP[env_id], type(env)  # its own rules, not FixedLevel's
    assert env == jaxgrid.make(env_id)  # the registered id's configuration
    np.testing.assert_array_equal(state.grid, mg.unwrapped.grid.encode())
    if any(getattr(o, "contains", None) for o in mg.unwrapped.grid.grid):  # ObstructedMaze's
        with pytest.raises(ValueError, match=r"Box holding a key at cell .* without base_step"):
            from_minigrid(mg, base_step=True)  # the base rules would drop them
        return
    env, _, _ = from_minigrid(mg, base_step=True)  # explicitly: the layout, base rules
    assert isinstance(env, FixedLevel)


def test_from_minigrid_converts_levels_with_the_base_step():
    # Regression guard: levels stepping with MiniGridEnv.step itself convert as before.
    for env_id in ("MiniGrid-DoorKey-5x5-v0", "MiniGrid-FourRooms-v0", "MiniGrid-LavaGapS5-v0"):
        env, _, _ = from_minigrid(_minigrid(env_id))
        assert isinstance(env, FixedLevel)


@pytest.mark.parametrize("env_id, name", [("CartPole-v1", "CartPoleEnv"), (None, "object")])
def test_from_minigrid_refuses_what_is_not_a_minigrid_env(env_id, name):
    env = object() if env_id is None else gym.make(env_id)
    with pytest.raises(ValueError, match=rf"got {name}, which is not a MiniGrid env"):
        from_minigrid(env)
