"""GoToDoor, GoToObject, Fetch and PutNear, generated natively, against MiniGrid 3.2.0.

* Layouts: many vmapped jaxgrid resets and MiniGrid resets (one seeded RNG stream) are
  checked for structure and reduced to the generator's random choices, read back from the
  grid and the task (``state.extras``; MiniGrid's ``target_pos``, ``target_color``, ...).
  GoToDoor: the room's width and height, each door's offset along its wall and colour, the
  set of colours, agent pose, the target door's wall and colour. The object levels: the
  objects' cells and (type, colour) pairs, pooled and per type, how many distinct pairs a
  layout holds, agent pose, the agent's distance to the nearest object, the target's cell,
  pair and distance from the agent (Fetch: the target's pair and how many copies of it lie
  in the room; PutNear: the object to move and the target, their distance, the objects'
  pairwise distance). Each marginal must have the same support and pass a two-sample
  chi-square homogeneity test at ``ALPHA`` (``helpers.layout_stats``). Seeds are fixed, so
  outcomes are deterministic. Generators that drop MiniGrid's duplicate-pair redraw
  (GoToObject) or its ``near_obj`` rejection (PutNear), or take PutNear's two objects in
  placement order, are caught.
* Steps: MiniGrid episodes converted with ``from_minigrid`` (to the native level) and
  natively generated states copied into MiniGrid (task attributes included) are stepped by
  both with the level's own rules, every field compared at every step, past MiniGrid's
  termination (MiniGrid steps on, and so does its rule). Episodes start with scripted
  actions (success; ``done`` next to another door or object; a toggle; Fetch's wrong pickup;
  PutNear's drop far from the target, drop on an occupied cell, pickup of the target), then
  biased random actions. Scripted successes end the episode exactly on their last action.
* Registry defaults and conversions; refused settings.

The default run covers one id per family; ``-m slow`` runs every id with more samples and
seeds, sizes without a registered id, and measures compile times.
"""

from __future__ import annotations

import collections
import functools
from dataclasses import fields

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import minigrid_reference as R
from helpers.layout_stats import (
    cell_id,
    compare_all,
    compare_distributions,
    id_param,
    jax_reset_states,
    minigrid_resets,
)
from helpers.xla import compile_seconds
from minigrid.envs import FetchEnv, GoToDoorEnv, GoToObjectEnv, PutNearEnv

import jaxgrid
from jaxgrid.compat import from_minigrid
from jaxgrid.constants import (
    BALL,
    BOX,
    CLOSED,
    COLOR_NAMES,
    COLOR_TO_IDX,
    DIR_TO_VEC,
    DONE,
    DOOR,
    DROP,
    EMPTY,
    FORWARD,
    KEY,
    LEFT,
    OBJECT_NAMES,
    OBJECT_TO_IDX,
    PICKUP,
    RIGHT,
    TOGGLE,
    WALL,
)
from jaxgrid.grid import coords
from jaxgrid.levels import Fetch, FixedLevel, GoToDoor, GoToObject, PutNear
from jaxgrid.levels.keys import mission
from jaxgrid.levels.missions import IDS, PutNearMission
from jaxgrid.sentences import LEVELS

N_MINIGRID = 2000  # MiniGrid resets per layout test; jaxgrid draws twice as many
N_SLOW = 6000
NUM_STEPS = 120  # per episode: past GoToDoor-5x5's 100 and PutNear-6x6's 30 (truncation)
DEFAULT = {
    "MiniGrid-GoToDoor-6x6-v0",
    "MiniGrid-GoToObject-6x6-N2-v0",
    "MiniGrid-Fetch-8x8-N3-v0",
    "MiniGrid-PutNear-6x6-N2-v0",
}
STEP_DEFAULT = {
    "MiniGrid-GoToDoor-5x5-v0",
    "MiniGrid-GoToObject-6x6-N2-v0",
    "MiniGrid-Fetch-5x5-N2-v0",
    "MiniGrid-PutNear-6x6-N2-v0",
}


# ------------------------------------------------------------------------- tasks


def _mission(kind, colour, pos):
    return np.array([kind, colour, *pos], np.int64)


def minigrid_task(mg):
    """What MiniGrid's ``step`` reads, as int rows ``(kind, colour, x, y)``: one row (GoToDoor,
    GoToObject, Fetch, whose position is unknown: -1) or two (PutNear: move, target)."""
    if isinstance(mg, GoToDoorEnv):
        return _mission(DOOR, COLOR_TO_IDX[mg.target_color], mg.target_pos)[None]
    if isinstance(mg, GoToObjectEnv):
        kind = OBJECT_TO_IDX[mg.targetType]
        return _mission(kind, COLOR_TO_IDX[mg.target_color], mg.target_pos)[None]
    if isinstance(mg, FetchEnv):
        return _mission(OBJECT_TO_IDX[mg.targetType], COLOR_TO_IDX[mg.targetColor], (-1, -1))[None]
    move = _mission(OBJECT_TO_IDX[mg.move_type], COLOR_TO_IDX[mg.moveColor], mg.move_pos)
    target = _mission(OBJECT_TO_IDX[mg.target_type], COLOR_TO_IDX[mg.target_color], mg.target_pos)
    return np.stack([move, target])


def native_task(extras):
    """:func:`minigrid_task`'s rows from (batched) ``state.extras``."""
    parts = [extras.move, extras.target] if hasattr(extras, "move") else [extras]
    rows = [
        np.concatenate(
            [np.asarray(m.kind)[..., None], np.asarray(m.colour)[..., None], np.asarray(m.pos)],
            axis=-1,
        )
        for m in parts
    ]
    return np.stack(rows, axis=-2).astype(np.int64)


def set_task(mg, task):
    """Give the MiniGrid env ``mg`` the task rows of :func:`minigrid_task`."""
    kind, colour, x, y = (int(v) for v in task[0])
    pos = (x, y)
    if isinstance(mg, GoToDoorEnv):
        mg.target_pos, mg.target_color = pos, COLOR_NAMES[colour]
    elif isinstance(mg, GoToObjectEnv):
        mg.target_pos, mg.target_color = pos, COLOR_NAMES[colour]
        mg.targetType = OBJECT_NAMES[kind]
    elif isinstance(mg, FetchEnv):
        mg.targetType, mg.targetColor = OBJECT_NAMES[kind], COLOR_NAMES[colour]
    else:
        mg.move_type, mg.moveColor, mg.move_pos = OBJECT_NAMES[kind], COLOR_NAMES[colour], pos
        kind, colour, x, y = (int(v) for v in task[1])
        mg.target_type, mg.target_color = OBJECT_NAMES[kind], COLOR_NAMES[colour]
        mg.target_pos = (x, y)


# ------------------------------------------------------------------------------ layouts


def _chebyshev(a, b):
    return np.abs(np.asarray(a) - np.asarray(b)).max(axis=-1)


def door_choices(env, grids, pos, dirs, tasks):
    """Check GoToDoor layouts; return their random choices."""
    n, w, h, _ = grids.shape
    rows = np.arange(n)
    kinds = grids[..., 0]
    xs, ys = coords(w, h)
    solid = (kinds == WALL) | (kinds == DOOR)
    rw = np.array([xs[s].max() + 1 for s in solid])
    rh = np.array([ys[s].max() + 1 for s in solid])
    out = collections.defaultdict(list)
    for g, k, p, a, b in zip(grids, kinds, pos, rw, rh, strict=True):
        inside = (xs < a) & (ys < b)
        border = inside & ((xs == 0) | (ys == 0) | (xs == a - 1) | (ys == b - 1))
        assert ((k == WALL) | (k == DOOR) == border).all(), "walls off the room's border"
        assert (k[~border] == EMPTY).all(), "an object off the walls"
        doors = np.argwhere(k == DOOR)
        assert len(doors) == 4 and (g[k == DOOR][:, 2] == CLOSED).all()
        on = {  # the door of each wall: top, bottom, left, right
            "top": [d for d in doors if d[1] == 0],
            "bottom": [d for d in doors if d[1] == b - 1],
            "left": [d for d in doors if d[0] == 0],
            "right": [d for d in doors if d[0] == a - 1],
        }
        assert all(len(v) == 1 for v in on.values()), f"doors {doors.tolist()}"
        colours = []
        for wall, ((x, y),) in on.items():
            along = x if wall in ("top", "bottom") else y
            assert 2 <= along <= (a if wall in ("top", "bottom") else b) - 3
            out[f"{wall}_door_offset"].append(along)
            out[f"{wall}_door_colour"].append(g[x, y, 1])
            colours.append(int(g[x, y, 1]))
        assert len(set(colours)) == 4, "two doors share a colour"
        out["colour_set"].append(sum(1 << c for c in colours))
        out["top_bottom_colours"].append(colours[0] * 6 + colours[1])
        assert 0 < p[0] < a - 1 and 0 < p[1] < b - 1, "the agent is outside the room"
    (kind, colour, tx, ty) = tasks[:, 0].T
    assert (kind == DOOR).all()
    assert (kinds[rows, tx, ty] == DOOR).all() and (grids[rows, tx, ty, 1] == colour).all()
    wall = np.where(ty == 0, 0, np.where(ty == rh - 1, 1, np.where(tx == 0, 2, 3)))
    out = {name: np.array(v) for name, v in out.items()}
    out.update(
        room_width=rw,
        room_height=rh,
        room_size=rw * 16 + rh,
        agent_cell=cell_id(pos, h),
        agent_dir=dirs,
        target_wall=wall,
        target_colour=colour,
        target_wall_and_room=wall * 256 + rw * 16 + rh,
        agent_to_target=np.abs(pos - tasks[:, 0, 2:]).sum(axis=1),
    )
    return out


def object_choices(env, grids, pos, dirs, tasks):
    """Check GoToObject, Fetch and PutNear layouts; return their random choices."""
    n, w, h, _ = grids.shape
    rows = np.arange(n)
    kinds = grids[..., 0]
    xs, ys = coords(w, h)
    border = (xs == 0) | (ys == 0) | (xs == w - 1) | (ys == h - 1)
    assert ((kinds == WALL) == border[None]).all(), "walls off the border"
    types = (KEY, BALL) if isinstance(env, Fetch) else (KEY, BALL, BOX)
    objects = ~border[None] & (kinds != EMPTY)
    assert np.isin(kinds[objects], types).all() and (grids[objects][:, 2] == 0).all()
    assert (objects.sum(axis=(1, 2)) == env.num_objs).all(), "not num_objs objects"
    assert (kinds[rows, pos[:, 0], pos[:, 1]] == EMPTY).all(), "the agent is on an object"
    out = collections.defaultdict(list)
    b, ox, oy = np.nonzero(objects)
    pair = (kinds[b, ox, oy].astype(int) - KEY) * 6 + grids[b, ox, oy, 1]
    out["object_cells"] = ox * h + oy  # pooled over the objects of every layout
    out["object_pairs"] = pair
    for kind in types:
        sel = kinds[b, ox, oy] == kind
        out[f"{OBJECT_NAMES[kind]}_cells"] = ox[sel] * h + oy[sel]
    cells = np.stack([ox, oy], axis=1).reshape(n, env.num_objs, 2)
    pairs = pair.reshape(n, env.num_objs)
    distinct = np.array([len(set(p)) for p in pairs])
    if not isinstance(env, Fetch):
        assert (distinct == env.num_objs).all(), "two objects share a (type, colour) pair"
    gaps = [
        _chebyshev(c[i], c[j]) for c in cells for i in range(len(c)) for j in range(i + 1, len(c))
    ]
    if isinstance(env, PutNear):
        assert min(gaps) >= 2, "two objects next to each other"
    agent_gap = np.abs(cells - pos[:, None]).sum(axis=2).min(axis=1)
    out = {name: np.asarray(v) for name, v in out.items()}
    out.update(
        distinct_pairs=distinct,
        object_gaps=np.array(gaps),
        agent_cell=cell_id(pos, h),
        agent_dir=dirs,
        agent_to_nearest_object=agent_gap,
    )
    task = tasks[:, 0]
    task_pair = (task[:, 0] - KEY) * 6 + task[:, 1]
    copies = (pairs == task_pair[:, None]).sum(axis=1)
    assert (copies >= 1).all(), "the mission names an object that is not in the room"
    out["target_pair"] = task_pair
    out["target_copies"] = copies
    if isinstance(env, Fetch):
        return out
    for i, name in enumerate(("target",) if tasks.shape[1] == 1 else ("move", "target")):
        kind, colour, x, y = tasks[:, i].T
        assert (kinds[rows, x, y] == kind).all() and (grids[rows, x, y, 1] == colour).all()
        out[f"{name}_cell"] = x * h + y
        # along 0, 1 or 2 walls: PutNear's earlier objects lie there more often than later ones
        out[f"{name}_walls"] = (x == 1) + (x == w - 2) + (y == 1) + (y == h - 2)
        out[f"{name}_pair"] = (kind - KEY) * 6 + colour
        out[f"agent_to_{name}"] = np.abs(pos - tasks[:, i, 2:]).sum(axis=1)
    if isinstance(env, PutNear):
        out["move_to_target"] = _chebyshev(tasks[:, 0, 2:], tasks[:, 1, 2:])
        out["move_and_target_types"] = tasks[:, 0, 0] * 8 + tasks[:, 1, 0]
    return out


def choices(env, grids, pos, dirs, tasks):
    pick = door_choices if isinstance(env, GoToDoor) else object_choices
    return pick(env, grids, pos, dirs, tasks)


@functools.cache
def minigrid_choices(env_id, n):
    env = jaxgrid.make(env_id)
    return choices(env, *minigrid_resets(R.make_reference(env_id), n, extra=minigrid_task))


def jax_choices(env, n):
    st = jax_reset_states(env, n)
    return choices(env, st.grid, st.agent_pos, st.agent_dir, native_task(st.extras))


@pytest.mark.parametrize("env_id", [id_param(i, DEFAULT) for i in IDS])
def test_layout_distribution(env_id):
    env = jaxgrid.make(env_id)
    n = N_MINIGRID if env_id in DEFAULT else N_SLOW
    compare_all(env_id, jax_choices(env, 2 * n), minigrid_choices(env_id, n))


def test_layout_test_detects_duplicate_pairs_kept(monkeypatch):
    """GoToObject without the redraw of a (type, colour) pair already placed: two objects
    share a pair in about one layout in 18, which MiniGrid never draws."""
    monkeypatch.setattr(GoToObject, "DISTINCT", False)
    env = jaxgrid.make("MiniGrid-GoToObject-6x6-N2-v0", max_steps=179)  # not the cached reset
    with pytest.raises(AssertionError, match="two objects share a"):
        jax_choices(env, N_MINIGRID)


def test_layout_test_detects_objects_placed_next_to_each_other(monkeypatch):
    """PutNear without ``near_obj``: objects next to each other, which MiniGrid never draws."""
    monkeypatch.setattr(PutNear, "APART", False)
    env = jaxgrid.make("MiniGrid-PutNear-8x8-N3-v0", max_steps=39)  # not the cached reset
    with pytest.raises(AssertionError, match="two objects next to each other"):
        jax_choices(env, N_MINIGRID)


class PutNearFirstTwo(PutNear):
    """PutNear whose object to move and target are the first two objects placed."""

    def generate(self, key):
        grid, kinds, colours, cells, agent, direction, _ = self._layout(key, 2)
        about = lambda i: mission(kinds[i], colours[i], cells[i])
        extras = PutNearMission(move=about(0), target=about(1))
        return self.init_state(grid, agent, direction, key, extras)


def test_layout_test_detects_the_objects_drawn_in_placement_order():
    """With ``near_obj`` the objects placed later lie along the walls more often (an earlier
    object blocks inner cells more often than cells by the walls): drawing the object to move
    and the target as the first two placed, rather than uniformly, shifts ``target_walls``."""
    env_id = "MiniGrid-PutNear-6x6-N2-v0"
    base = jaxgrid.make(env_id)
    env = PutNearFirstTwo(**{f.name: getattr(base, f.name) for f in fields(base)})
    ours = jax_choices(env, 2 * N_MINIGRID)
    ref = minigrid_choices(env_id, N_MINIGRID)
    with pytest.raises(AssertionError, match="target_walls: chi-square"):
        compare_distributions("target_walls", ours["target_walls"], ref["target_walls"])


@pytest.mark.slow
@pytest.mark.parametrize(
    "cls, mg_cls, size, n",
    [
        (GoToDoor, GoToDoorEnv, 11, None),
        (GoToObject, GoToObjectEnv, 5, 4),
        (Fetch, FetchEnv, 4, 3),
        (PutNear, PutNearEnv, 7, 4),
    ],
)
def test_other_sizes_match_minigrids_generator(cls, mg_cls, size, n):
    """Sizes and object counts without a registered id (PutNear's 7 x 7 with 4 objects is
    the tightest: every draw still finds a cell)."""
    kw = {} if n is None else dict(num_objs=n)
    mg = mg_cls(size=size, **({} if n is None else dict(numObjs=n)))
    env = cls(width=size, height=size, max_steps=mg.max_steps, see_through_walls=True, **kw)
    ref = choices(env, *minigrid_resets(mg, N_SLOW, extra=minigrid_task))
    compare_all(f"{cls.__name__} {size} N{n}", jax_choices(env, 2 * N_SLOW), ref)


# ------------------------------------------------------------------------------ scripts


class Planner:
    """Scripted actions on a numpy state: breadth-first over (cell, direction) through empty
    cells (doors are never entered), with MiniGrid's rules for the actions it emits."""

    def __init__(self, grid, pos, direction):
        self.grid = np.array(grid)
        self.pos = (int(pos[0]), int(pos[1]))
        self.dir = int(direction)
        self.carrying = EMPTY
        self.actions = []

    def front(self, pos=None, d=None):
        pos, d = self.pos if pos is None else pos, self.dir if d is None else d
        return pos[0] + DIR_TO_VEC[d][0], pos[1] + DIR_TO_VEC[d][1]

    def act(self, action):
        fwd = self.front()
        if action == LEFT:
            self.dir = (self.dir - 1) % 4
        elif action == RIGHT:
            self.dir = (self.dir + 1) % 4
        elif action == FORWARD and self.grid[fwd][0] == EMPTY:
            self.pos = fwd
        elif action == PICKUP and self.carrying == EMPTY and self.grid[fwd][0] in (KEY, BALL, BOX):
            self.carrying, self.grid[fwd] = self.grid[fwd].copy(), (EMPTY, 0, 0)
        elif action == DROP and self.carrying is not EMPTY and self.grid[fwd][0] == EMPTY:
            self.grid[fwd], self.carrying = self.carrying, EMPTY
        self.actions.append(int(action))

    def go(self, goal) -> bool:
        """Walk the shortest way to a pose satisfying ``goal(pos, dir)``; False if none."""
        start = (self.pos, self.dir)
        prev, queue = {start: None}, collections.deque([start])
        while queue:
            pose = queue.popleft()
            if goal(*pose):
                path = []
                while prev[pose] is not None:
                    pose, action = prev[pose]
                    path.insert(0, action)
                for a in path:
                    self.act(a)
                return True
            (x, y), d = pose
            fwd = self.front((x, y), d)
            moves = [(((x, y), (d - 1) % 4), LEFT), (((x, y), (d + 1) % 4), RIGHT)]
            if self.grid[fwd][0] == EMPTY:
                moves.append(((fwd, d), FORWARD))
            for nxt, action in moves:
                if nxt not in prev:
                    prev[nxt] = (pose, action)
                    queue.append(nxt)
        return False

    def face(self, cell) -> bool:
        return self.go(lambda p, d: self.front(p, d) == tuple(cell))

    def next_to(self, cell) -> bool:
        return self.go(lambda p, d: abs(p[0] - cell[0]) + abs(p[1] - cell[1]) == 1)

    def cells(self, kinds):
        return [tuple(c) for c in np.argwhere(np.isin(self.grid[..., 0], kinds))]


SCRIPTS = 4  # variants, by episode index


def script(env, grid, pos, direction, task, variant):
    """Scripted actions from a state (``task``: :func:`minigrid_task`'s rows).

    Returns ``(actions, succeeds)``: whether the last action ends the episode with the
    success reward (when the script reached it; a script that finds no way returns ``[]``).
    """
    p = Planner(grid, pos, direction)
    kind, colour, tx, ty = (int(v) for v in task[0])
    target = (tx, ty)
    if isinstance(env, (GoToDoor, GoToObject)):
        others = [c for c in p.cells([DOOR, KEY, BALL, BOX]) if c != target]
        elsewhere = [c for c in others if abs(c[0] - tx) + abs(c[1] - ty) > 2]
        if variant == 1 and elsewhere:  # done next to another door or object: reward 0
            ok = p.go(
                lambda q, d: (
                    any(abs(q[0] - c[0]) + abs(q[1] - c[1]) == 1 for c in elsewhere)
                    and abs(q[0] - tx) + abs(q[1] - ty) != 1
                )
            )
            return (p.actions + [DONE], False) if ok else ([], False)
        if variant == 2:  # toggle the target (a door opens, a box vanishes): reward 0
            return (p.actions + [TOGGLE], False) if p.face(target) else ([], False)
        if variant == 3 and isinstance(env, GoToObject):  # carry the target off, come back
            if not p.face(target):
                return [], False
            p.act(PICKUP)
            p.go(lambda q, d: abs(q[0] - tx) + abs(q[1] - ty) >= 3)
        return (p.actions + [DONE], True) if p.next_to(target) else ([], False)
    if isinstance(env, Fetch):
        same = [c for c in p.cells([KEY, BALL]) if tuple(p.grid[c][:2]) == (kind, colour)]
        wrong = [c for c in p.cells([KEY, BALL]) if c not in same]
        cells, succeeds = (wrong, False) if variant % 2 and wrong else (same, True)
        ok = p.go(lambda q, d: p.front(q, d) in cells)
        return (p.actions + [PICKUP], succeeds) if ok else ([], False)
    # PutNear: pick up the object to move, drop it near (or far from) the target
    target = tuple(int(v) for v in task[1][2:])
    if variant == 2:  # pick up the target: the wrong object
        return (p.actions + [PICKUP], False) if p.face(target) else ([], False)
    if not p.face((tx, ty)):
        return [], False
    p.act(PICKUP)
    if variant == 3:  # drop while facing the target: nothing is put down, reward 0
        return (p.actions + [DROP], False) if p.face(target) else ([], False)
    near = variant == 0

    def drop_here(q, d):
        fwd = p.front(q, d)
        return p.grid[fwd][0] == EMPTY and (_chebyshev(fwd, target) <= 1) == near

    return (p.actions + [DROP], near) if p.go(drop_here) else ([], False)


def play(mg, actions, seed, num_steps=NUM_STEPS):
    """Step MiniGrid ``mg`` with ``actions``, then biased random ones, ``num_steps`` in all,
    past termination. A forward onto a door becomes ``done``: an agent on a door of the
    grid's border facing out makes MiniGrid raise."""
    rng = np.random.default_rng(seed)
    obs = mg.gen_obs()
    grid0 = mg.grid.encode()
    steps = collections.defaultdict(list)
    played = []
    for t in range(num_steps):
        action = actions[t] if t < len(actions) else int(rng.choice(7, p=R.ACTION_PROBS))
        front = mg.grid.get(*mg.front_pos)
        if action == FORWARD and front is not None and front.type == "door":
            action = DONE
        o, reward, terminated, truncated, _ = mg.step(action)
        played.append(action)
        for name, value in (
            ("image", o["image"]),
            ("direction", o["direction"]),
            ("reward", reward),
            ("terminated", terminated),
            ("truncated", truncated),
            ("grid", mg.grid.encode()),
            ("agent_pos", np.asarray(mg.agent_pos)),
            ("carrying", mg.carrying.encode() if mg.carrying else (EMPTY, 0, 0)),
        ):
            steps[name].append(value)
    steps = {name: np.array(v) for name, v in steps.items()}
    return R.Episode(
        seed, np.array(played, np.int32), num_steps, obs["image"], int(obs["direction"]), grid0,
        steps,
    )  # fmt: skip


def outcomes(episodes):
    """``(successes, failures)``: steps that terminated with a positive / zero reward."""
    term = np.array([ep.steps["terminated"] for ep in episodes])
    reward = np.array([ep.steps["reward"] for ep in episodes])
    return int((term & (reward > 0)).sum()), int((term & (reward == 0)).sum())


def check_scripts(episodes, plans):
    """Each scripted episode ends exactly on its script's last action, as the script says."""
    for ep, (actions, succeeds) in zip(episodes, plans, strict=True):
        if not actions:
            continue
        last = len(actions) - 1
        assert not ep.steps["terminated"][:last].any(), f"seed {ep.seed}: ended early"
        assert ep.steps["terminated"][last], f"seed {ep.seed}: the script did not end it"
        assert (ep.steps["reward"][last] > 0) == succeeds, f"seed {ep.seed}: wrong outcome"


# ------------------------------------------------------------------------------ steps


def converted_run(env_id, seeds, constrained=False):
    """Convert MiniGrid resets, play scripts then random actions in both, compare; with
    ``constrained``, jaxgrid steps the level with a constraint on (a row of the levels' table
    for each episode) and must still step like MiniGrid."""
    mg = R.make_reference(env_id)
    states, episodes, plans, env = [], [], [], None
    for i, seed in enumerate(seeds):
        mg.reset(seed=seed)
        converted, state, _ = from_minigrid(mg)
        assert type(converted) is type(jaxgrid.make(env_id)) and converted == jaxgrid.make(env_id)
        env = converted
        task = minigrid_task(mg)
        ours = native_task(state.extras)
        if isinstance(mg, FetchEnv):  # the first cell holding such an object
            assert tuple(state.grid[tuple(ours[0, 2:])][:2].tolist()) == tuple(task[0, :2])
            ours[0, 2:] = -1
        np.testing.assert_array_equal(ours, task)
        plan = script(env, mg.grid.encode(), mg.agent_pos, mg.agent_dir, task, i % SCRIPTS)
        plans.append(plan)
        states.append(state)
        episodes.append(play(mg, plan[0], seed))
    actions = jnp.asarray(np.stack([ep.actions for ep in episodes]))
    states = R.stack(states)
    if constrained:
        env, states = R.with_constraints(jaxgrid.make(env_id, constraints=LEVELS), states, 0)
    obs0, outs = R.jax_rollout(env, states, actions)
    R.compare(f"{env_id} converted", episodes, obs0, outs)
    check_scripts(episodes, plans)
    return episodes


def native_run(env_id, num, key_seed):
    """Native resets copied into MiniGrid (task attributes included); scripts, then random
    actions, in both; compare."""
    env = jaxgrid.make(env_id)
    mg = R.make_reference(env_id)
    states = jax_reset_states(env, num, seed=key_seed)
    tasks = native_task(states.extras)
    episodes, plans = [], []
    for b in range(num):
        state = jax.tree.map(lambda x, b=b: x[b], states)
        mg.reset(seed=b)  # anything; then overwrite with our state and task
        R.set_minigrid_state(mg, state)
        set_task(mg, tasks[b])
        plan = script(env, state.grid, state.agent_pos, state.agent_dir, tasks[b], b % SCRIPTS)
        assert plan[0], f"{env_id} reset {b}: no scripted solution"
        plans.append(plan)
        episodes.append(play(mg, plan[0], b))
    actions = jnp.asarray(np.stack([ep.actions for ep in episodes]))
    obs0, outs = R.jax_rollout(env, jax.tree.map(jnp.asarray, states), actions)
    R.compare(f"native {env_id} key {key_seed}", episodes, obs0, outs)
    check_scripts(episodes, plans)
    return episodes


@pytest.mark.parametrize("env_id", [id_param(i, STEP_DEFAULT) for i in IDS])
def test_converted_episodes_step_like_minigrid(env_id):
    episodes = converted_run(env_id, range(8))
    wins, losses = outcomes(episodes)
    assert wins >= 2 and losses >= 4, (wins, losses)


@pytest.mark.parametrize(
    "env_id", [id_param(i, STEP_DEFAULT) for i in IDS if jaxgrid.make(i).contents().constrainable]
)
def test_converted_episodes_step_like_minigrid_with_a_constraint(env_id):
    episodes = converted_run(env_id, range(8), constrained=True)
    wins, losses = outcomes(episodes)
    assert wins >= 2 and losses >= 4, (wins, losses)


@pytest.mark.parametrize("env_id", [id_param(i, STEP_DEFAULT) for i in IDS])
def test_native_resets_step_like_minigrid(env_id):
    episodes = native_run(env_id, 8, key_seed=1)
    wins, losses = outcomes(episodes)
    assert wins >= 2 and losses >= 4, (wins, losses)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", list(IDS))
def test_many_episodes_step_like_minigrid(env_id):
    episodes = converted_run(env_id, range(100, 164)) + native_run(env_id, 64, key_seed=5)
    wins, losses = outcomes(episodes)
    print(f"{env_id}: {R.coverage(episodes)}, {wins} successful steps, {losses} failing ones")
    assert wins >= 32 and losses >= 64


def _retask(mg, variant):
    """Point the mission (Fetch's target, PutNear's object to move) at the first object of the
    grid: its own type and colour (variant 0), its type in another colour (1), or its colour
    on another type (2). Returns the object's cell."""
    obj = next(o for o in mg.grid.grid if o is not None and o.type in ("key", "ball", "box"))
    types = ("key", "ball") if isinstance(mg, FetchEnv) else ("key", "ball", "box")
    kind = obj.type if variant != 2 else next(t for t in types if t != obj.type)
    colour = obj.color if variant != 1 else next(c for c in COLOR_NAMES if c != obj.color)
    if isinstance(mg, FetchEnv):
        mg.targetType, mg.targetColor = kind, colour
    else:
        mg.move_type, mg.moveColor = kind, colour
    return tuple(int(c) for c in obj.cur_pos)


@pytest.mark.parametrize("env_id", ["MiniGrid-Fetch-5x5-N2-v0", "MiniGrid-PutNear-6x6-N2-v0"])
def test_pickups_are_judged_by_type_and_colour_together(env_id):
    """Picking up an object of the mission's type but another colour, or of its colour but
    another type, fails (Fetch: reward 0; PutNear: the episode ends); of both, it succeeds
    (Fetch) or goes on (PutNear), in MiniGrid and here alike."""
    mg = R.make_reference(env_id)
    states, episodes, env = [], [], None
    for seed in range(9):
        mg.reset(seed=seed)
        variant = seed % 3
        cell = _retask(mg, variant)
        env, state, _ = from_minigrid(mg)
        planner = Planner(mg.grid.encode(), mg.agent_pos, mg.agent_dir)
        assert planner.face(cell)
        planner.act(PICKUP)
        states.append(state)
        episode = play(mg, planner.actions, seed)
        last = len(planner.actions) - 1
        assert episode.steps["terminated"][last] == (
            variant != 0 or env_id.startswith("MiniGrid-F")
        )
        assert (episode.steps["reward"][last] > 0) == (variant == 0 and isinstance(env, Fetch))
        episodes.append(episode)
    actions = jnp.asarray(np.stack([ep.actions for ep in episodes]))
    obs0, outs = R.jax_rollout(env, R.stack(states), actions)
    R.compare(f"{env_id} retasked", episodes, obs0, outs)


def test_out_of_range_actions_act_as_done():
    env = jaxgrid.make("MiniGrid-GoToDoor-5x5-v0")
    states = jax.tree.map(jnp.asarray, jax_reset_states(env, 8, seed=2))
    _, outs = R.jax_rollout(env, states, jnp.full((8, NUM_STEPS), DONE))  # the steps' shapes
    for action in (7, -1):
        _, other = R.jax_rollout(env, states, jnp.full((8, NUM_STEPS), action))
        for name in ("reward", "terminated"):
            np.testing.assert_array_equal(other[name], outs[name])
    assert np.asarray(outs["terminated"]).all()


# --------------------------------------------------------------------------- registry


@pytest.mark.parametrize("env_id", list(IDS))
def test_make_matches_minigrids_defaults(env_id):
    env = jaxgrid.make(env_id)
    mg = R.make_reference(env_id)
    mg.reset(seed=0)
    ours = (env.width, env.height, env.max_steps, env.view_size, env.see_through_walls)
    assert ours == (mg.width, mg.height, mg.max_steps, mg.agent_view_size, mg.see_through_walls)
    if not isinstance(env, GoToDoor):
        assert env.num_objs == mg.numObjs
    assert from_minigrid(mg)[0] == env
    assert isinstance(from_minigrid(mg, base_step=True)[0], FixedLevel)
    assert env_id in jaxgrid.registered_ids()


def test_from_minigrid_refuses_subclasses_and_sizes_it_cannot_generate():
    class MyFetch(FetchEnv):
        pass

    mine = MyFetch(size=5, numObjs=2)
    mine.reset(seed=0)
    with pytest.raises(ValueError, match="MyFetch overrides MiniGridEnv.step"):
        from_minigrid(mine)
    small = PutNearEnv(size=5, numObjs=2)  # 3 x 3 inside: MiniGrid may loop forever
    small.reset(seed=1)
    with pytest.raises(ValueError, match=r"PutNear\.width must be at least 6"):
        from_minigrid(small)
    assert isinstance(from_minigrid(small, base_step=True)[0], FixedLevel)


def test_fetch_converted_while_carrying_the_target():
    """A Fetch episode converted after its successful pickup: the task's cell is another
    copy's or (-1, -1), and every step pays again while the target is held."""
    env_id = "MiniGrid-Fetch-5x5-N2-v0"
    mg = R.make_reference(env_id)
    states, episodes = [], []
    for seed in range(8):
        mg.reset(seed=seed)
        task = minigrid_task(mg)
        plan, _ = script(jaxgrid.make(env_id), mg.grid.encode(), mg.agent_pos, mg.agent_dir,
                         task, 0)  # fmt: skip
        for action in plan:
            mg.step(action)
        env, state, _ = from_minigrid(mg)
        x, y = native_task(state.extras)[0, 2:]
        assert (x, y) == (-1, -1) or tuple(state.grid[x, y, :2].tolist()) == tuple(task[0, :2])
        states.append(state)
        episodes.append(play(mg, [LEFT, RIGHT], seed))
    actions = jnp.asarray(np.stack([ep.actions for ep in episodes]))
    obs0, outs = R.jax_rollout(env, R.stack(states), actions)
    R.compare("Fetch after success", episodes, obs0, outs)
    first = slice(0, 2)  # turns: the target still held
    assert np.asarray(outs["terminated"])[:, first].all()
    assert (np.asarray(outs["reward"])[:, first] > 0).all()


@pytest.mark.parametrize(
    "make, setting",
    [
        (lambda: GoToDoor(width=4, height=8, max_steps=9), "width"),
        (lambda: GoToDoor(width=8, height=4, max_steps=9), "height"),
        (lambda: GoToObject(width=3, height=8, max_steps=9), "width"),
        (lambda: GoToObject(width=8, height=8, max_steps=9, num_objs=19), "num_objs"),
        (lambda: GoToObject(width=8, height=8, max_steps=9, num_objs=0), "num_objs"),
        (lambda: Fetch(width=8, height=8, max_steps=9, num_objs=2.0), "num_objs"),
        (lambda: Fetch(width=8, height=4, max_steps=9, num_objs=4), "height"),
        (lambda: PutNear(width=8, height=8, max_steps=9, num_objs=1), "num_objs"),
        (lambda: PutNear(width=5, height=8, max_steps=9), "width"),
        (lambda: PutNear(width=8, height=8, max_steps=9, num_objs=5), "width"),
    ],
)
def test_impossible_settings_raise_naming_the_setting(make, setting):
    with pytest.raises(ValueError, match=rf"^(GoToDoor|GoToObject|Fetch|PutNear)\.{setting} "):
        make()


def test_min_sizes():
    assert GoToObject(width=4, height=4, max_steps=9, num_objs=3).min_size()[:2] == (4, 4)
    assert Fetch(width=5, height=5, max_steps=9, num_objs=8).min_size()[:2] == (5, 5)
    # 4 objects apart fit in a 4 x 4 interior whatever the order; 5 need a 7 x 7 interior
    assert PutNear(width=6, height=6, max_steps=9, num_objs=4).min_size()[:2] == (6, 6)
    assert PutNear(width=9, height=9, max_steps=9, num_objs=5).min_size()[:2] == (9, 9)


# ------------------------------------------------------------------------ compile cost


@pytest.mark.slow
@pytest.mark.parametrize("env_id", list(IDS))
def test_compile_seconds(env_id):
    """Compile time of ``jit(vmap(reset))`` and ``jit(vmap(step))`` (the suite's XLA flags)."""
    reset, run, step = compile_seconds(jaxgrid.make(env_id), 4096)
    assert reset + run + step < 20
