"""MultiRoom, LockedRoom and RedBlueDoors, generated natively, against MiniGrid 3.2.0.

* Layouts: many vmapped jaxgrid resets and MiniGrid resets (one seeded RNG stream) are read
  back into the generator's random choices by one function for both sides, which also checks
  their structure. MultiRoom's chain of rooms is walked from the agent's room through its doors
  (this reading is checked against MiniGrid's own ``env.rooms``): the number of rooms, the
  first room's corner and size, each next room's size, exit wall, door offsets and door colour
  step, the sequence of exit walls, the chain's bounding box, agent and goal cells (and the
  first room's corner in 4 x 4 blocks, where the chain's acceptance shows most). LockedRoom:
  locked room, goal and key cells, key room, each room's door colour, agent pose.
  RedBlueDoors: the doors' rows and the agent's pose. Each marginal must have the same support
  and pass a two-sample chi-square homogeneity test at ``ALPHA`` (``helpers.layout_stats``);
  cells occupied by walls and doors pass a 2x2 test per cell at ``ALPHA / cells``. Seeds are
  fixed, so outcomes are deterministic. A MultiRoom generator that drops MiniGrid's eight
  tries per room (each room uniform among the places that fit) is caught at the default run's
  sample size.
* Steps: natively generated MultiRoom and LockedRoom states, copied into MiniGrid, step like
  MiniGrid (every field, every step) under actions of the BFS oracle with random ones mixed
  in; the oracle alone solves every such reset. RedBlueDoors episodes converted with
  ``from_minigrid`` (to the native level) step like MiniGrid's own ``step`` under scripted
  door orders (red then blue, blue first, red opened and closed again) and random actions;
  and, one step at a time, from states after MiniGrid's termination, where its rule keeps
  firing. A script solves every native RedBlueDoors reset.
* Registry defaults, conversions and refused settings.

The default run covers one MultiRoom id, LockedRoom and one RedBlueDoors id; ``-m slow`` runs
every id with more samples, settings without a registered id, and measures compile times.
"""

from __future__ import annotations

import collections
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.ndimage
from helpers import minigrid_reference as R
from helpers.layout_stats import (
    cell_id,
    compare_all,
    compare_distributions,
    id_param,
    jax_reset_states,
    jax_resets,
    minigrid_resets,
    single_cell,
)
from helpers.xla import CHEAP, compile_seconds
from minigrid.core.world_object import Door
from minigrid.envs import LockedRoomEnv, MultiRoomEnv, RedBlueDoorEnv

import jaxgrid
from jaxgrid.compat import from_minigrid
from jaxgrid.constants import (
    BLUE,
    CLOSED,
    DIR_TO_VEC,
    DOOR,
    EMPTY,
    FORWARD,
    GOAL,
    KEY,
    LEFT,
    LOCKED,
    OPEN,
    RED,
    RIGHT,
    TOGGLE,
    WALL,
)
from jaxgrid.grid import coords
from jaxgrid.levels import FixedLevel, LockedRoom, MultiRoom, RedBlueDoors
from jaxgrid.levels import rooms as rooms_module
from jaxgrid.levels.rooms import IDS
from jaxgrid.oracle import oracle_action

N_MINIGRID = 2000  # MiniGrid resets per layout test; jaxgrid draws twice as many (MultiRoom: as
N_SLOW = 6000  # many, its resets being the costly ones)
MULTIROOMS = [i for i in IDS if "MultiRoom" in i]
REDBLUE = [i for i in IDS if "RedBlue" in i]
DEFAULT_LAYOUTS = {
    "MiniGrid-MultiRoom-N6-v0",
    "MiniGrid-LockedRoom-v0",
    "MiniGrid-RedBlueDoors-8x8-v0",
}


# ------------------------------------------------------------------- MultiRoom layouts


def room_chain(grid, agent):
    """MultiRoom's rooms in MiniGrid's order, read from a grid: the agent's room, then through
    each room's one unvisited door into the next.

    Returns ``(rooms, exits, doors)``: ``(x, y, width, height)`` of each room, walls included;
    the wall each door leaves its room by (0 right, 1 bottom, 2 left, 3 top); the door cells.
    Asserts that every inside is a rectangle, every door is on the chain and every room but
    the last has exactly one door onward.
    """
    kind = grid[..., 0]
    labels, _ = scipy.ndimage.label((kind != WALL) & (kind != DOOR))

    def room_of(cell):
        inside = labels == labels[cell]
        xs, ys = np.nonzero(inside)
        room = (xs.min() - 1, ys.min() - 1, xs.max() - xs.min() + 3, ys.max() - ys.min() + 3)
        assert inside.sum() == (room[2] - 2) * (room[3] - 2), "an inside is not a rectangle"
        return tuple(int(v) for v in room)

    door_cells = [tuple(int(c) for c in d) for d in np.argwhere(kind == DOOR)]
    rooms, exits, doors = [room_of(tuple(agent))], [], []
    while True:
        x0, y0, w, h = rooms[-1]
        x1, y1 = x0 + w - 1, y0 + h - 1
        onward = [
            (x, y)
            for x, y in door_cells
            if (x, y) not in doors
            and ((x in (x0, x1) and y0 < y < y1) or (y in (y0, y1) and x0 < x < x1))
        ]
        if not onward:
            break
        assert len(onward) == 1, f"room {rooms[-1]} has doors {onward} onward"
        (x, y) = onward[0]
        wall = 0 if x == x1 else 1 if y == y1 else 2 if x == x0 else 3
        doors.append((x, y))
        exits.append(wall)
        dx, dy = DIR_TO_VEC[wall]
        rooms.append(room_of((x + dx, y + dy)))
    assert len(doors) == len(door_cells), "a door off the chain"
    return rooms, exits, doors


def multiroom_choices(grids, pos, dirs):
    """Check MultiRoom layouts; return their random choices (name -> one value per layout,
    ``cells:`` names -> bool ``(n, W, H)`` masks)."""
    n, width, height, _ = grids.shape
    xs, ys = coords(width, height)
    out = collections.defaultdict(list)
    walls_seen, doors_seen = [], []
    for grid, p, d in zip(grids, pos, dirs, strict=True):
        kind = grid[..., 0]
        rooms, exits, doors = room_chain(grid, p)
        walls = np.zeros((width, height), bool)
        for x0, y0, w, h in rooms:
            rect = (xs >= x0) & (xs < x0 + w) & (ys >= y0) & (ys < y0 + h)
            walls |= rect & ~((xs > x0) & (xs < x0 + w - 1) & (ys > y0) & (ys < y0 + h - 1))
        is_door = kind == DOOR
        assert (is_door <= walls).all() and ((kind == WALL) == (walls & ~is_door)).all()
        assert (grid[is_door][:, 2] == CLOSED).all(), "a door is not closed"
        assert np.isin(kind, [EMPTY, WALL, DOOR, GOAL]).all()
        (gx, gy), (ax, ay) = single_cell(grid[None], kind[None] == GOAL)[0], p
        (fx, fy, fw, fh), (lx, ly, lw, lh) = rooms[0], rooms[-1]
        assert fx < ax < fx + fw - 1 and fy < ay < fy + fh - 1, "the agent is not in room 0"
        assert lx < gx < lx + lw - 1 and ly < gy < ly + lh - 1, "the goal is not in the last"
        assert kind[ax, ay] == EMPTY
        out["rooms"].append(len(rooms))
        out["first_x"].append(fx)
        out["first_y"].append(fy)
        out["first_size"].append(fw * 16 + fh)
        out["first_x_by_4"].append(fx // 4)  # coarse: where the chain's acceptance shows most
        out["first_corner_by_4"].append(fx // 4 * 8 + fy // 4)
        out["exit_walls"].append(sum(w * 4**k for k, w in enumerate(exits)))
        colours = [int(grid[c][1]) for c in doors]
        for k, ((x, y), wall) in enumerate(zip(doors, exits, strict=True)):
            px, py = rooms[k][:2]
            cx, cy, cw, ch = rooms[k + 1]
            vertical = wall in (0, 2)  # the door is in a left or right wall
            out[f"room{k + 1}_size"].append(cw * 16 + ch)
            out[f"room{k + 1}_exit_wall"].append(wall)
            out[f"room{k + 1}_door_on_exit_wall"].append(y - py if vertical else x - px)
            out[f"room{k + 1}_door_on_entry_wall"].append(y - cy if vertical else x - cx)
            step = colours[k] if k == 0 else (colours[k] - colours[k - 1]) % 6
            assert k == 0 or step != 0, "two doors in a row share a colour"
            out[f"room{k + 1}_door_colour_step"].append(step)
        if len(colours) > 1:
            out["door_colours_1_2"].append(colours[0] * 6 + colours[1])
        wx, wy = np.nonzero(walls)
        out["min_x"].append(wx.min())
        out["min_y"].append(wy.min())
        out["max_x"].append(wx.max())
        out["max_y"].append(wy.max())
        out["agent_in_room"].append((ax - fx) * 16 + ay - fy)
        out["agent_dir"].append(int(d))
        out["goal_in_room"].append((gx - lx) * 16 + gy - ly)
        out["goal_cell"].append(gx * height + gy)
        walls_seen.append(walls)
        doors_seen.append(is_door)
    out = {name: np.array(v) for name, v in out.items()}
    out["cells:walls"], out["cells:doors"] = np.array(walls_seen), np.array(doors_seen)
    return out


def test_room_chain_reads_minigrids_rooms():
    """The chain read from a grid is MiniGrid's ``env.rooms`` (corners, sizes, entry doors)."""
    mg = R.make_reference("MiniGrid-MultiRoom-N6-v0")
    mg.reset(seed=0)
    for _ in range(100):
        mg.reset()
        rooms, _, doors = room_chain(mg.grid.encode(), mg.agent_pos)
        assert rooms == [(*r.top, *r.size) for r in mg.rooms]
        assert doors == [tuple(r.entryDoorPos) for r in mg.rooms[1:]]


@functools.cache
def minigrid_multiroom_choices(env_id, n):
    return multiroom_choices(*minigrid_resets(R.make_reference(env_id), n))


@pytest.mark.parametrize("env_id", [id_param(i, DEFAULT_LAYOUTS) for i in MULTIROOMS])
def test_multiroom_layout_distribution(env_id):
    env = jaxgrid.make(env_id)
    n = N_MINIGRID if env_id in DEFAULT_LAYOUTS else N_SLOW
    ours = multiroom_choices(*jax_resets(env, n))
    compare_all(env_id, ours, minigrid_multiroom_choices(env_id, n))
    assert (ours["rooms"] == env.max_num_rooms).all()


@pytest.mark.slow
def test_layout_test_detects_rooms_placed_without_minigrids_eight_tries(monkeypatch):
    """With unlimited tries per room (each room uniform among the places that fit, the
    natural shortcut), chains that start near the grid's sides fail less often, which shifts
    the first room's corner (``first_x_by_4``: p below 1e-6 on four other seeds)."""
    monkeypatch.setattr(rooms_module, "TRIES", 64)
    env = jaxgrid.make("MiniGrid-MultiRoom-N6-v0", max_steps=121)  # not the cached reset
    ours = multiroom_choices(*jax_resets(env, N_MINIGRID))
    ref = minigrid_multiroom_choices("MiniGrid-MultiRoom-N6-v0", N_MINIGRID)
    name = "first_x_by_4"
    with pytest.raises(AssertionError, match=f"{name}: chi-square"):
        compare_distributions(f"64 tries {name}", ours[name], ref[name])


# ------------------------------------------------------------------ LockedRoom layouts


def locked_room_choices(env, grids, pos, dirs):
    """Check LockedRoom layouts; return their random choices."""
    n = len(grids)
    rows = np.arange(n)
    kinds = grids[..., 0]
    tops, sizes, doors = env.rooms()
    layout = env.layout()[..., 0] == WALL
    door_mask = np.zeros_like(layout)
    door_mask[doors[:, 0], doors[:, 1]] = True
    assert ((kinds == WALL) == (layout & ~door_mask)[None]).all(), "walls off the layout"
    assert (kinds[:, door_mask] == DOOR).all() and ((kinds == DOOR).sum(axis=(1, 2)) == 6).all()
    colours = grids[:, doors[:, 0], doors[:, 1], 1].astype(int)  # (n, 6), rooms in order
    states = grids[:, doors[:, 0], doors[:, 1], 2]
    assert (np.sort(colours, axis=1) == np.arange(6)).all(), "door colours not a permutation"
    assert ((states == LOCKED).sum(axis=1) == 1).all() and np.isin(states, [LOCKED, CLOSED]).all()
    locked = np.argmax(states == LOCKED, axis=1)
    goal = single_cell(grids, kinds == GOAL, "goal")
    key = single_cell(grids, kinds == KEY, "key")
    assert (grids[rows, key[:, 0], key[:, 1], 1] == colours[rows, locked]).all(), "wrong key"

    def room_of(cells):  # the room whose rand_pos rectangle holds each cell (asserts one)
        lo, hi = tops + 1, tops + sizes - 2
        inside = ((cells[:, None] >= lo[None]) & (cells[:, None] <= hi[None])).all(axis=2)
        assert (inside.sum(axis=1) == 1).all(), "a cell outside every room"
        return np.argmax(inside, axis=1)

    assert (room_of(goal) == locked).all(), "the goal is not in the locked room"
    key_room = room_of(key)
    assert (key_room != locked).all(), "the key is in the locked room"
    left, right = env.width // 2 - 2, env.width // 2 + 2
    assert ((pos[:, 0] > left) & (pos[:, 0] < right)).all(), "the agent is not in the hallway"
    assert (kinds[rows, pos[:, 0], pos[:, 1]] == EMPTY).all()
    h = env.height
    out = {
        "locked_room": locked,
        "key_room": key_room,
        "locked_and_key_room": locked * 6 + key_room,
        "goal_cell": cell_id(goal, h),
        "key_cell": cell_id(key, h),
        "locked_door_colour": colours[rows, locked],
        "door_colours_0_1": colours[:, 0] * 6 + colours[:, 1],
        "agent_cell": cell_id(pos, h),
        "agent_dir": dirs,
    }
    for i in range(6):
        out[f"room{i}_door_colour"] = colours[:, i]
    return out


def check_locked_room_layouts(label, env, mg, n_minigrid, seed=0):
    ours = locked_room_choices(env, *jax_resets(env, 2 * n_minigrid, seed=seed))
    ref = locked_room_choices(env, *minigrid_resets(mg, n_minigrid, seed=seed))
    compare_all(label, ours, ref)


def test_locked_room_layout_distribution():
    env_id = "MiniGrid-LockedRoom-v0"
    check_locked_room_layouts(env_id, jaxgrid.make(env_id), R.make_reference(env_id), N_MINIGRID)


def test_locked_room_rooms_are_minigrids():
    env = jaxgrid.make("MiniGrid-LockedRoom-v0")
    mg = R.make_reference("MiniGrid-LockedRoom-v0")
    mg.reset(seed=0)
    tops, sizes, doors = env.rooms()
    assert tops.tolist() == [list(r.top) for r in mg.rooms]
    assert sizes.tolist() == [list(r.size) for r in mg.rooms]
    assert doors.tolist() == [list(r.doorPos) for r in mg.rooms]


# ---------------------------------------------------------------- RedBlueDoors layouts


def red_blue_choices(env, grids, pos, dirs):
    """Check RedBlueDoors layouts; return their random choices."""
    rows = np.arange(len(grids))
    kinds = grids[..., 0]
    size = env.height
    left = (env.width - size) // 2
    red = single_cell(grids, (kinds == DOOR) & (grids[..., 1] == RED), "red door")
    blue = single_cell(grids, (kinds == DOOR) & (grids[..., 1] == BLUE), "blue door")
    assert (red[:, 0] == left).all() and (blue[:, 0] == left + size - 1).all()
    assert ((kinds == DOOR).sum(axis=(1, 2)) == 2).all()
    assert (grids[kinds == DOOR][:, 2] == CLOSED).all()
    xs, ys = coords(env.width, size)
    outer = (xs == 0) | (xs == env.width - 1) | (ys == 0) | (ys == size - 1)
    walls = outer | (xs == left) | (xs == left + size - 1)
    assert ((kinds == WALL) | (kinds == DOOR) == walls[None]).all(), "walls off the layout"
    assert ((pos[:, 0] > left) & (pos[:, 0] < left + size - 1)).all(), "agent outside the room"
    assert (kinds[rows, pos[:, 0], pos[:, 1]] == EMPTY).all()
    agent = cell_id(pos, size)
    return {
        "agent_cell": agent,
        "agent_dir": dirs,
        "red_row": red[:, 1],
        "blue_row": blue[:, 1],
        "red_and_blue_rows": red[:, 1] * size + blue[:, 1],
        "agent_and_red_row": agent * size + red[:, 1],
    }


@pytest.mark.parametrize("env_id", [id_param(i, DEFAULT_LAYOUTS) for i in REDBLUE])
def test_red_blue_doors_layout_distribution(env_id):
    env = jaxgrid.make(env_id)
    n = N_MINIGRID if env_id in DEFAULT_LAYOUTS else N_SLOW
    ours = red_blue_choices(env, *jax_resets(env, 2 * n))
    ref = red_blue_choices(env, *minigrid_resets(R.make_reference(env_id), n))
    compare_all(env_id, ours, ref)


# -------------------------------------------------------- settings without a registered id


def _multiroom_variant(width, height, low, high, size):
    mg = MultiRoomEnv(low, high, maxRoomSize=size, width=width, height=height)
    env = MultiRoom(
        width=width,
        height=height,
        max_steps=mg.max_steps,
        min_num_rooms=low,
        max_num_rooms=high,
        max_room_size=size,
    )
    return env, mg


@pytest.mark.slow
@pytest.mark.parametrize(
    "label",
    ["MultiRoom 20x15 N2-4 S6", "MultiRoom 11x9 N1-3 S5", "LockedRoom 13", "LockedRoom 17"],
)
def test_other_settings_match_minigrids_generator(label):
    """Sizes and room counts without an id (a range of room counts; non-square MultiRooms,
    whose first room's row MiniGrid draws from the width; other LockedRoom sizes)."""
    if label.startswith("MultiRoom"):
        shape, rooms, size = label.split()[1:]
        width, height = map(int, shape.split("x"))
        low, high = map(int, rooms[1:].split("-"))
        env, mg = _multiroom_variant(width, height, low, high, int(size[1:]))
        ours = multiroom_choices(*jax_resets(env, N_SLOW))
        compare_all(label, ours, multiroom_choices(*minigrid_resets(mg, N_SLOW)))
        assert set(np.unique(ours["rooms"])) == set(range(low, high + 1))
    else:
        size = int(label.split()[1])
        env = LockedRoom(width=size, height=size, max_steps=10 * size)
        check_locked_room_layouts(label, env, LockedRoomEnv(size=size), N_SLOW)


@pytest.mark.slow
def test_red_blue_doors_of_odd_size_match_minigrids_generator():
    env = RedBlueDoors(width=10, height=5, max_steps=500)
    ours = red_blue_choices(env, *jax_resets(env, 2 * N_SLOW))
    ref = red_blue_choices(env, *minigrid_resets(RedBlueDoorEnv(size=5), N_SLOW))
    compare_all("RedBlueDoors 5", ours, ref)


@pytest.mark.slow
def test_multiroom_too_small_for_its_rooms_keeps_the_longest_chain():
    """Six rooms do not fit in 9 x 9 (MiniGrid would retry forever): after the cap, resets
    hold the longest chain found, a well-formed level with fewer rooms."""
    env = MultiRoom(width=9, height=9, max_steps=120)
    ours = multiroom_choices(*jax_resets(env, 64))
    assert 2 <= ours["rooms"].min() and ours["rooms"].max() < 6


# ------------------------------------------------------------------------------ steps

NOISE = 0.25  # odd episodes: the share of random actions mixed into the oracle's


@functools.partial(jax.jit, static_argnums=(0, 2), compiler_options=CHEAP)
def oracle_episodes(env, states, num_steps, key):
    """Oracle actions from each state, with random ones mixed into the odd episodes; returns
    ``(actions (B, T), success (B,))`` as jaxgrid steps them."""

    def episode(state, noisy, key):
        def body(carry, key):
            state, done, success = carry
            k1, k2 = jax.random.split(key)
            random = jax.random.randint(k1, (), 0, 7)
            action = jnp.where(
                noisy & (jax.random.uniform(k2) < NOISE), random, oracle_action(state)
            )
            state, ts = env.step(state, action)
            success = success | (~done & (ts.reward > 0))
            return (state, done | ts.terminated | ts.truncated, success), action

        false = jnp.zeros((), bool)
        (_, _, success), actions = jax.lax.scan(
            body, (state, false, false), jax.random.split(key, num_steps)
        )
        return actions, success

    batch = states.step_count.shape[0]
    noisy = jnp.arange(batch) % 2 == 1
    return jax.vmap(episode)(states, noisy, jax.random.split(key, batch))


def native_oracle_run(env_id, num, key_seed, **kw):
    """Reset natively, copy each state into MiniGrid, step both with the oracle's actions
    (random ones mixed into odd episodes); compare every field at every step."""
    env = jaxgrid.make(env_id)
    mg = R.make_reference(env_id)
    states = jax_reset_states(env, num, seed=key_seed)
    actions, success = jax.device_get(
        oracle_episodes(env, jax.tree.map(jnp.asarray, states), env.max_steps,
                        jax.random.PRNGKey(key_seed))
    )  # fmt: skip
    assert success[::2].all(), f"{env_id}: the oracle failed {(~success[::2]).sum()} resets"
    episodes = []
    for b in range(num):
        mg.reset(seed=b)  # anything; then overwrite with our state
        R.set_minigrid_state(mg, jax.tree.map(lambda x, b=b: x[b], states))
        episodes.append(R.record_episode(mg, actions[b], seed=b, **kw))
    cfg = R.config_env(env)  # these levels step with MiniGridEnv.step's rules
    obs0, outs = R.jax_rollout(cfg, jax.tree.map(jnp.asarray, states), jnp.asarray(actions))
    R.compare(f"native {env_id} key {key_seed}", episodes, obs0, outs)
    return episodes


STEP_DEFAULT = {"MiniGrid-MultiRoom-N4-S5-v1", "MiniGrid-LockedRoom-v0"}


@pytest.mark.parametrize(
    "env_id", [id_param(i, STEP_DEFAULT) for i in MULTIROOMS + ["MiniGrid-LockedRoom-v0"]]
)
def test_native_levels_step_like_minigrid(env_id):
    episodes = native_oracle_run(env_id, 8, key_seed=0)
    stats = R.coverage(episodes)
    assert stats["goal"] >= 4 and stats["grid_changes"] >= 8, stats
    if "LockedRoom" in env_id:
        assert stats["unlocks"] >= 4 and stats["pickups"] >= 4, stats


@pytest.mark.slow
@pytest.mark.parametrize("env_id", MULTIROOMS + ["MiniGrid-LockedRoom-v0"])
def test_native_levels_step_like_minigrid_many_seeds(env_id):
    episodes = native_oracle_run(env_id, 64, key_seed=3, encode_every_step=True)
    stats = R.coverage(episodes)
    print(f"{env_id}: {stats}")
    assert stats["goal"] >= 32, stats  # every oracle-only episode, some noisy ones


class Planner:
    """Shortest action lists that face a cell: breadth-first over cell and direction, walking
    on empty cells and open doors of a MiniGrid env's grid."""

    def __init__(self, mg):
        self.mg = mg
        self.actions = []

    def path(self, cell):
        """The actions that face ``cell`` from the agent's pose, or None if none do."""
        grid = self.mg.grid.encode()
        walkable = (grid[..., 0] == EMPTY) | ((grid[..., 0] == DOOR) & (grid[..., 2] == OPEN))
        start = (tuple(int(c) for c in self.mg.agent_pos), int(self.mg.agent_dir))
        prev, queue = {start: None}, collections.deque([start])
        while queue:
            pose = queue.popleft()
            (x, y), d = pose
            front = (x + DIR_TO_VEC[d][0], y + DIR_TO_VEC[d][1])
            if front == tuple(cell):
                path = []
                while prev[pose] is not None:
                    pose, action = prev[pose]
                    path.insert(0, action)
                return path
            moves = [(((x, y), (d - 1) % 4), LEFT), (((x, y), (d + 1) % 4), RIGHT)]
            if walkable[front]:
                moves.append(((front, d), FORWARD))
            for nxt, action in moves:
                if nxt not in prev:
                    prev[nxt] = (pose, action)
                    queue.append(nxt)
        return None

    def toggle(self, cell):
        """Face ``cell`` and toggle it, stepping the env."""
        for action in self.path(cell) + [TOGGLE]:
            self.mg.step(int(action))
            self.actions.append(int(action))


def cell_holding(mg, name):
    """``(x, y)`` of the cell holding the object ``mg.<name>`` itself."""
    for index, obj in enumerate(mg.grid.grid):
        if obj is getattr(mg, name):
            return index % mg.width, index // mg.width
    raise AssertionError(f"{name} is not in the grid")


# door orders: red then blue (success), blue first (failure), red opened and closed again
# before blue (failure), red only (then random actions)
SCRIPTS = (
    ("red_door", "blue_door"),
    ("blue_door",),
    ("red_door", "red_door", "blue_door"),
    ("red_door",),
)
MAX_T = 200


def scripted(env_id, seed, script):
    """A MiniGrid env reset with ``seed``, and the actions that toggle the doors of ``script``
    in order (found on a copy), then random ones up to ``MAX_T``."""
    mg = R.make_reference(env_id)
    mg.reset(seed=seed)
    copy = R.make_reference(env_id)
    copy.reset(seed=seed)
    planner = Planner(copy)
    for door in script:
        planner.toggle(cell_holding(copy, door))
    actions = planner.actions + list(R.draw_actions(seed, 1, MAX_T)[0])
    return mg, np.array(actions[:MAX_T], np.int32), len(planner.actions)


def red_blue_differential(env_id, seeds):
    """Convert MiniGrid resets, step both under the scripts' actions, compare every field."""
    states, episodes, env = [], [], None
    for seed in seeds:
        mg, actions, _ = scripted(env_id, seed, SCRIPTS[seed % len(SCRIPTS)])
        converted, state, _ = from_minigrid(mg)
        assert type(converted) is RedBlueDoors and (env is None or converted == env)
        env = converted
        assert tuple(state.extras.red.tolist()) == cell_holding(mg, "red_door")
        assert tuple(state.extras.blue.tolist()) == cell_holding(mg, "blue_door")
        states.append(state)
        episodes.append(R.record_episode(mg, actions, seed=seed))
    actions = jnp.asarray(np.stack([ep.actions for ep in episodes]))
    obs0, outs = R.jax_rollout(env, R.stack(states), actions)
    R.compare(f"{env_id} own step", episodes, obs0, outs)
    return episodes


@pytest.mark.parametrize("env_id", [id_param(i, {"MiniGrid-RedBlueDoors-6x6-v0"}) for i in REDBLUE])
def test_red_blue_doors_step_like_minigrid(env_id):
    episodes = red_blue_differential(env_id, range(12))
    wins, losses = R.outcomes(episodes)
    assert wins >= 3 and losses >= 6, (wins, losses)  # the scripts' outcomes, at least


@pytest.mark.slow
@pytest.mark.parametrize("env_id", REDBLUE)
def test_red_blue_doors_step_like_minigrid_many_seeds(env_id):
    episodes = red_blue_differential(env_id, range(100, 164))
    wins, losses = R.outcomes(episodes)
    print(f"{env_id}: {R.coverage(episodes)}, {wins} successes, {losses} failures")
    assert wins >= 16 and losses >= 32


def test_red_blue_doors_rule_keeps_firing_after_termination_like_minigrid():
    """MiniGrid steps on after termination: with both doors open every step pays again, with
    only the blue one open every step ends with 0, and toggling a door changes which (or
    stops the rule). From MiniGrid states after a success or a failure, the doors are toggled
    in turn with random actions between; every state is converted and stepped once by both."""
    env_id = "MiniGrid-RedBlueDoors-6x6-v0"
    states, episodes, env = [], [], None
    rng = np.random.default_rng(0)
    for seed in range(6):
        mg, actions, played = scripted(env_id, seed, SCRIPTS[seed % 2])
        for action in actions[:played]:
            mg.step(int(action))
        planner, plan = Planner(mg), []
        targets = ["blue_door", "red_door", "blue_door", "red_door", "blue_door"]
        for _ in range(30):
            if not plan and targets and rng.random() < 0.5:
                plan = (planner.path(cell_holding(mg, targets.pop(0))) or []) + [TOGGLE]
            action = plan.pop(0) if plan else int(rng.choice(7, p=R.ACTION_PROBS))
            converted, state, _ = from_minigrid(mg)
            env = env or converted
            states.append(state)
            episodes.append(R.record_episode(mg, np.array([action], np.int32), seed=seed))
    actions = jnp.asarray(np.stack([ep.actions for ep in episodes]))
    obs0, outs = R.jax_rollout(env, R.stack(states), actions)
    R.compare(f"{env_id} after termination", episodes, obs0, outs)
    reward = np.array([ep.steps["reward"][0] for ep in episodes])
    done = np.array([ep.steps["terminated"][0] for ep in episodes])
    print(f"{(done & (reward > 0)).sum()} paid, {(done & (reward == 0)).sum()} ended with 0, "
          f"{(~done).sum()} went on")  # fmt: skip
    assert (done & (reward > 0)).sum() >= 10 and (done & (reward == 0)).sum() >= 10
    assert (~done).sum() >= 5, "no state where the rule stops firing"


def test_every_red_blue_reset_is_solved_by_its_script():
    env = jaxgrid.make("MiniGrid-RedBlueDoors-8x8-v0")
    states = jax_reset_states(env, 16, seed=4)
    plans = []
    for b in range(16):
        mg = R.reference_for(env, jax.tree.map(lambda x, b=b: x[b], states))
        grid = mg.grid.encode()
        planner = Planner(mg)
        for colour in (RED, BLUE):
            door = (grid[..., 0] == DOOR) & (grid[..., 1] == colour)
            planner.toggle(single_cell(grid[None], door[None])[0])
        plans.append(planner.actions)
    length = max(map(len, plans))
    actions = np.stack([np.pad(p, (0, length - len(p)), constant_values=LEFT) for p in plans])
    _, outs = R.jax_rollout(env, jax.tree.map(jnp.asarray, states), jnp.asarray(actions))
    last = np.array([len(p) - 1 for p in plans])
    rows = np.arange(16)
    assert np.asarray(outs["terminated"])[rows, last].all()
    assert (np.asarray(outs["reward"])[rows, last] > 0).all()
    early = np.arange(length)[None] < last[:, None]
    assert not np.asarray(outs["terminated"])[early].any(), "ended before the blue door"


# --------------------------------------------------------------------------- registry


@pytest.mark.parametrize("env_id", list(IDS))
def test_make_matches_minigrids_defaults(env_id):
    env = jaxgrid.make(env_id)
    mg = R.make_reference(env_id)
    mg.reset(seed=0)
    ours = (env.width, env.height, env.max_steps, env.view_size, env.see_through_walls)
    assert ours == (mg.width, mg.height, mg.max_steps, mg.agent_view_size, mg.see_through_walls)
    if isinstance(env, MultiRoom):
        settings = (env.min_num_rooms, env.max_num_rooms, env.max_room_size)
        assert settings == (mg.minNumRooms, mg.maxNumRooms, mg.maxRoomSize)
    converted = from_minigrid(mg)[0]
    if isinstance(env, RedBlueDoors):
        assert converted == env  # the native level, this id's configuration
    else:
        assert isinstance(converted, FixedLevel) and R.config_env(converted) == R.config_env(env)
    assert env_id in jaxgrid.registered_ids()


def test_from_minigrid_red_blue_doors_conversions():
    mg = R.make_reference("MiniGrid-RedBlueDoors-6x6-v0")
    mg.reset(seed=3)
    assert isinstance(from_minigrid(mg, base_step=True)[0], FixedLevel)

    class MyDoors(RedBlueDoorEnv):
        pass

    mine = MyDoors(size=6)
    mine.reset(seed=0)
    with pytest.raises(ValueError, match="MyDoors overrides MiniGridEnv.step"):
        from_minigrid(mine)
    mg.grid.grid = [Door("red") if o is mg.red_door else o for o in mg.grid.grid]
    with pytest.raises(ValueError, match=r"RedBlueDoorEnv\.red_door is not in its grid"):
        from_minigrid(mg)


@pytest.mark.parametrize(
    "make, setting",
    [
        (lambda: MultiRoom(width=25, height=25, max_steps=9, min_num_rooms=0), "min_num_rooms"),
        (
            lambda: MultiRoom(width=25, height=25, max_steps=9, min_num_rooms=3, max_num_rooms=2),
            "max_num_rooms",
        ),
        (lambda: MultiRoom(width=25, height=25, max_steps=9, max_room_size=3), "max_room_size"),
        (lambda: MultiRoom(width=3, height=25, max_steps=9), "width"),
        (lambda: MultiRoom(width=25, height=4, max_steps=9), "height"),
        (lambda: LockedRoom(width=18, height=19, max_steps=9), "width"),
        (lambda: LockedRoom(width=19, height=18, max_steps=9), "height"),
        (lambda: LockedRoom(width=7, height=19, max_steps=9), "width"),
        (lambda: LockedRoom(width=19, height=11, max_steps=9), "height"),
        (lambda: RedBlueDoors(width=9, height=8, max_steps=9), "width"),
        (lambda: RedBlueDoors(width=16, height=2, max_steps=9), "height"),
    ],
)
def test_impossible_settings_raise_naming_the_setting(make, setting):
    with pytest.raises(ValueError, match=rf"^(MultiRoom|LockedRoom|RedBlueDoors)\.{setting} "):
        make()


# ------------------------------------------------------------------------ compile cost


@pytest.mark.slow
@pytest.mark.parametrize("env_id", list(IDS))
def test_compile_seconds(env_id):
    """Compile time of ``jit(vmap(reset))`` and ``jit(vmap(step))`` (the suite's XLA flags),
    and the time of one batch of 4096 resets."""
    reset, _, step = compile_seconds(jaxgrid.make(env_id), 4096)
    assert reset + step < 30
