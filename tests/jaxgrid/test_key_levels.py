"""Unlock, UnlockPickup, BlockedUnlockPickup and KeyCorridor against MiniGrid 3.2.0.

* Layouts: many vmapped jaxgrid resets and MiniGrid resets (one seeded RNG stream) are reduced
  to the generator's random choices (door cell and colour, key, box, ball and target cells,
  agent cell and direction, a few joints) and to per-cell occupancy by object type and to
  colour/state counts per type. Each marginal must have the same support (a category drawn
  k times on one side only fails when seeing it never on the other side has Poisson
  probability below ``ALPHA`` divided by the number of categories) and pass a two-sample
  chi-square homogeneity test at ``ALPHA`` (``helpers.layout_stats``), after merging the
  categories expected below 5 samples into one.
  Marginals of objects present once per layout are i.i.d. across layouts; those pooling the
  closed doors of KeyCorridor (a variable number per layout) are approximately so. All seeds
  are fixed, so the outcome is deterministic.
  The same holds for room sizes and corridor shapes that have no registered id (``-m slow``).
* Steps: MiniGrid episodes converted with ``from_minigrid`` (which returns the native level)
  are stepped by both with the level's own rules, every field compared after every step up
  to MiniGrid's episode end. Half of the episodes follow a scripted solution (so every
  success rule fires), the other half biased random actions (truncation, drops, toggles
  elsewhere); further episodes continue from MiniGrid states after success, where MiniGrid
  pays again on the next matching action.
* Every jaxgrid reset is solved by the scripted solution, stepped with jaxgrid's own ``step``,
  and succeeds exactly on the solution's last action.
"""

from __future__ import annotations

import collections

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import minigrid_reference as R
from helpers.layout_stats import (
    cell_id,
    compare_distributions,
    jax_reset_states,
    minigrid_resets,
    single_cell,
)
from helpers.xla import compile_seconds
from minigrid.core.mission import MissionSpace
from minigrid.core.roomgrid import RoomGrid
from minigrid.envs import BlockedUnlockPickupEnv, KeyCorridorEnv, UnlockEnv, UnlockPickupEnv

import jaxgrid
from jaxgrid.compat import from_minigrid
from jaxgrid.constants import (
    BALL,
    BOX,
    CLOSED,
    DIR_TO_VEC,
    DONE,
    DOOR,
    DROP,
    EMPTY,
    FORWARD,
    KEY,
    LEFT,
    LOCKED,
    OPEN,
    PICKUP,
    RIGHT,
    TOGGLE,
    WALL,
)
from jaxgrid.levels import BlockedUnlockPickup, KeyCorridor, Unlock, UnlockPickup
from jaxgrid.levels.fixed import FixedLevel
from jaxgrid.levels.keys import IDS

N_MINIGRID = 3000
N_MINIGRID_DEFAULT = 2000  # the default run's layout tests (the others run with -m slow)
UNLOCKS = ["MiniGrid-Unlock-v0", "MiniGrid-UnlockPickup-v0", "MiniGrid-BlockedUnlockPickup-v0"]
CORRIDORS = [i for i in IDS if "KeyCorridor" in i]
DEFAULT_LAYOUTS = {"MiniGrid-BlockedUnlockPickup-v0", "MiniGrid-KeyCorridorS3R3-v0"}
DEFAULT_STEPS = {"MiniGrid-Unlock-v0", "MiniGrid-KeyCorridorS3R2-v0"}
MAX_T = 300  # steps per episode: past Unlock's 288 and KeyCorridorS3's 270 (truncation)


def _param(env_id, default):
    return pytest.param(env_id, id=env_id, marks=() if env_id in default else pytest.mark.slow)


# ------------------------------------------------------------------------------ layouts


def target_of(mg):
    """``(kind, colour, x, y)`` of the object a MiniGrid layout's task is about."""
    target = mg.door if isinstance(mg, UnlockEnv) else mg.obj
    return (*target.encode()[:2], *target.cur_pos)


def lattice(width, height, room_size):
    xs, ys = np.meshgrid(np.arange(width), np.arange(height), indexing="ij")
    return (xs % (room_size - 1) == 0) | (ys % (room_size - 1) == 0)


def layout_choices(env, grids, pos, dirs, targets):
    """Check structure; return the random choices (name -> one category per layout)."""
    n, w, h, _ = grids.shape
    rows = np.arange(n)
    kinds = grids[..., 0]
    s = env.room_size
    walls = lattice(w, h, s)
    is_corridor = isinstance(env, KeyCorridor)
    if is_corridor:  # remove_wall(1, j, 3): the corridor's inner walls are gone
        for j in range(1, env.num_rows):
            walls[s : 2 * s - 2, j * (s - 1)] = False
    assert ((kinds == WALL) | (kinds == DOOR) == walls[None]).all(), "walls or doors off-lattice"
    assert (kinds[:, ~walls] != DOOR).all()
    assert (kinds[rows, pos[:, 0], pos[:, 1]] == EMPTY).all(), "agent on an object"
    front = pos + DIR_TO_VEC[dirs]
    # placed last but connect_all: the agent never starts facing an object other than a door
    assert np.isin(kinds[rows, front[:, 0], front[:, 1]], (EMPTY, WALL, DOOR)).all()
    locked = single_cell(grids, (kinds == DOOR) & (grids[..., 2] == LOCKED))
    key = single_cell(grids, kinds == KEY)
    door_colour = grids[rows, locked[:, 0], locked[:, 1], 1]
    assert (grids[rows, key[:, 0], key[:, 1], 1] == door_colour).all(), "key opens the door"
    agent = cell_id(pos, h)
    out = {
        "agent_cell": agent,
        "agent_dir": dirs,
        "agent_pose": agent * 4 + dirs,
        "locked_door_cell": cell_id(locked, h),
        "locked_door_colour": door_colour,
        "key_cell": cell_id(key, h),
        "key_and_agent": cell_id(key, h) * w * h + agent,
        "door_and_agent": cell_id(locked, h) * w * h + agent,
    }
    objects = (kinds != WALL) & (kinds != EMPTY)
    b, xs, ys = np.nonzero(objects)
    for kind, label in ((DOOR, "door"), (KEY, "key"), (BALL, "ball"), (BOX, "box")):
        sel = kinds[b, xs, ys] == kind
        if sel.any():
            out[f"{label}_cells"] = xs[sel] * h + ys[sel]  # per-cell occupancy of this type
            out[f"{label}_colour_state"] = (
                grids[b[sel], xs[sel], ys[sel], 1] * 3 + grids[b[sel], xs[sel], ys[sel], 2]
            )
    target = targets[:, 2:]
    carried = (target == -1).all(axis=1)
    assert not carried.any()
    cell = grids[rows, target[:, 0], target[:, 1]]
    assert (cell[:, 0] == targets[:, 0]).all() and (cell[:, 1] == targets[:, 1]).all()
    out["target_cell"] = cell_id(target, h)
    out["target_colour"] = targets[:, 1]
    if isinstance(env, Unlock):
        assert (targets[:, 0] == DOOR).all() and (
            cell_id(target, h) == out["locked_door_cell"]
        ).all()
        assert (objects.sum(axis=(1, 2)) == 2).all(), "door + key only"
    elif isinstance(env, UnlockPickup):
        assert (targets[:, 0] == BOX).all() and (target[:, 0] > s - 1).all()
        blocked = isinstance(env, BlockedUnlockPickup)
        assert (objects.sum(axis=(1, 2)) == 3 + blocked).all()
        if blocked:  # the ball sits in front of the door, on the agent's side
            ball = single_cell(grids, kinds == BALL)
            assert (ball == locked - [1, 0]).all()
        out["target_and_key"] = out["target_cell"] * w * h + out["key_cell"]
    else:
        assert (targets[:, 0] == BALL).all()
        assert (locked[:, 0] == 2 * (s - 1)).all() and (target[:, 0] > 2 * (s - 1)).all()
        assert (target[:, 0] < 3 * (s - 1)).all(), "the ball is in the third column"
        assert (key[:, 0] < s - 1).all()
        closed = (kinds == DOOR) & (grids[..., 2] == CLOSED)
        assert (kinds == DOOR).sum() == closed.sum() + n, "no open doors"
        out["closed_doors"] = closed.sum(axis=(1, 2))
        out["locked_row_and_key_row"] = locked[:, 1] // (s - 1) * 16 + key[:, 1] // (s - 1)
        some = slice(0, 300)  # a Python flood fill per layout: a subset suffices
        assert reachable_rooms(grids[some], pos[some], s).all(), (
            "connect_all left a room unreachable"
        )
    return out


def reachable_rooms(grids, pos, room_size):
    """Per layout: every room is reachable from the agent through doors (any state) and gaps."""
    ok = []
    for g, p in zip(grids, pos, strict=True):
        free = g[..., 0] != WALL
        seen = np.zeros_like(free)
        todo = [tuple(p)]
        seen[tuple(p)] = True
        while todo:
            x, y = todo.pop()
            for dx, dy in DIR_TO_VEC:
                q = (x + dx, y + dy)
                if free[q] and not seen[q]:
                    seen[q] = True
                    todo.append(q)
        w, h = free.shape
        centres = [
            (i * (room_size - 1) + 1, j * (room_size - 1) + 1)
            for i in range((w - 1) // (room_size - 1))
            for j in range((h - 1) // (room_size - 1))
        ]
        ok.append(all(seen[c] or g[c][0] != EMPTY for c in centres))
    return np.array(ok)


LAYOUT_P = collections.defaultdict(dict)  # id -> marginal -> p (read by the slow report)


@pytest.mark.parametrize("env_id", [_param(i, DEFAULT_LAYOUTS) for i in UNLOCKS + CORRIDORS])
def test_layout_distribution(env_id):
    env = jaxgrid.make(env_id)
    n_mg = N_MINIGRID if env_id not in DEFAULT_LAYOUTS else N_MINIGRID_DEFAULT
    st = jax_reset_states(env, 2 * n_mg)
    m = st.extras
    targets = np.concatenate([m.kind[:, None], m.colour[:, None], m.pos], axis=1)
    ours = layout_choices(env, st.grid, st.agent_pos, st.agent_dir, targets)
    ref = layout_choices(env, *minigrid_resets(R.make_reference(env_id), n_mg, extra=target_of))
    assert set(ours) == set(ref)
    for name in ours:
        LAYOUT_P[env_id][name] = compare_distributions(f"{env_id} {name}", ours[name], ref[name])
    worst = min(LAYOUT_P[env_id], key=LAYOUT_P[env_id].get)
    print(f"{env_id}: {len(ours)} marginals, worst {worst} p={LAYOUT_P[env_id][worst]:.3g}")


def _sized(mg_cls, room_size, factor):
    """MiniGrid's generator of ``mg_cls`` (which fixes room_size 6) with another room size."""

    class Sized(mg_cls):
        def __init__(self):
            RoomGrid.__init__(
                self,
                mission_space=MissionSpace(mission_func=lambda: ""),
                num_rows=1,
                num_cols=2,
                room_size=room_size,
                max_steps=factor * room_size**2,
            )

    return Sized()


@pytest.mark.slow
@pytest.mark.parametrize(
    "cls, mg_cls, room_size",
    [
        (Unlock, UnlockEnv, 4),
        (UnlockPickup, UnlockPickupEnv, 5),
        (BlockedUnlockPickup, BlockedUnlockPickupEnv, 4),
        (BlockedUnlockPickup, BlockedUnlockPickupEnv, 7),
        (KeyCorridor, KeyCorridorEnv, 4),
    ],
)
def test_custom_size_layout_distribution(cls, mg_cls, room_size):
    """Room sizes and corridor shapes without a registered id follow MiniGrid's generator."""
    if cls is KeyCorridor:
        mg = KeyCorridorEnv(room_size=room_size, num_rows=2, num_cols=4)
        env = cls(width=13, height=7, max_steps=480, room_size=room_size, num_rows=2, num_cols=4)
    else:
        mg = _sized(mg_cls, room_size, 8)
        width, height = 2 * room_size - 1, room_size
        env = cls(width=width, height=height, max_steps=100, room_size=room_size)
    st = jax_reset_states(env, 2 * N_MINIGRID)
    m = st.extras
    targets = np.concatenate([m.kind[:, None], m.colour[:, None], m.pos], axis=1)
    ours = layout_choices(env, st.grid, st.agent_pos, st.agent_dir, targets)
    ref = layout_choices(env, *minigrid_resets(mg, N_MINIGRID, extra=target_of))
    p = {
        name: compare_distributions(f"{cls.__name__} {room_size}", ours[name], ref[name])
        for name in ours
    }
    worst = min(p, key=p.get)
    print(
        f"{cls.__name__} room_size={room_size}: {len(p)} marginals, worst {worst} p={p[worst]:.3g}"
    )


def test_layout_test_detects_the_next_to_agent_rule():
    """Dropping ``reject_next_to`` (the box may then land next to the provisional agent cell
    (8, 3)) is caught by the support check."""
    ref = layout_choices(
        jaxgrid.make("MiniGrid-UnlockPickup-v0"),
        *minigrid_resets(R.make_reference("MiniGrid-UnlockPickup-v0"), 500, extra=target_of),
    )
    assert not {8 * 6 + 3, 7 * 6 + 3, 9 * 6 + 3, 8 * 6 + 2, 8 * 6 + 4} & set(ref["box_cells"])
    rng = np.random.default_rng(0)
    uniform = rng.integers(6, 10, 1000) * 6 + rng.integers(1, 5, 1000)  # any interior cell
    with pytest.raises(AssertionError, match="only jaxgrid draws"):
        compare_distributions("box", uniform, ref["box_cells"])


# ------------------------------------------------------------------ scripted solutions


class Planner:
    """Scripted solutions on numpy states (MiniGrid's rules for the actions it emits).

    Paths are breadth-first over (cell, direction); a closed door on the way is toggled open,
    a locked one too when the carried key matches. Objects in the way are never moved, except
    BlockedUnlockPickup's ball, which is carried off to a cell that keeps the rest reachable.
    """

    def __init__(self, grid, pos, direction, carrying=(EMPTY, 0, 0)):
        self.grid = np.array(grid)
        self.pos = (int(pos[0]), int(pos[1]))
        self.dir = int(direction)
        self.carrying = tuple(int(c) for c in carrying)
        self.actions = []

    def front(self, pos=None, d=None):
        pos, d = self.pos if pos is None else pos, self.dir if d is None else d
        return pos[0] + DIR_TO_VEC[d][0], pos[1] + DIR_TO_VEC[d][1]

    def _enterable(self, cell):
        kind, colour, state = self.grid[cell]
        if kind == EMPTY or (kind == DOOR and state != LOCKED):
            return True
        return kind == DOOR and self.carrying[:2] == (KEY, colour)

    def act(self, action):
        fwd = self.front()
        cell = self.grid[fwd]
        if action == LEFT:
            self.dir = (self.dir - 1) % 4
        elif action == RIGHT:
            self.dir = (self.dir + 1) % 4
        elif action == FORWARD and (cell[0] == EMPTY or (cell[0] == DOOR and cell[2] == OPEN)):
            self.pos = fwd
        elif action == PICKUP and self.carrying[0] == EMPTY and cell[0] in (KEY, BALL, BOX):
            self.carrying = tuple(int(c) for c in cell)
            self.grid[fwd] = (EMPTY, 0, 0)
        elif action == DROP and self.carrying[0] != EMPTY and cell[0] == EMPTY:
            self.grid[fwd] = self.carrying
            self.carrying = (EMPTY, 0, 0)
        elif action == TOGGLE and cell[0] == DOOR:
            if cell[2] != LOCKED or self.carrying[:2] == (KEY, cell[1]):
                self.grid[fwd][2] = CLOSED if cell[2] == OPEN else OPEN
        self.actions.append(action)

    def route(self, goal):
        """Shortest action list to a pose satisfying ``goal(pos, dir)``, or None."""
        start = (self.pos, self.dir)
        prev = {start: None}
        queue = collections.deque([start])
        while queue:
            pose = queue.popleft()
            if goal(*pose):
                path = []
                while prev[pose] is not None:
                    pose, acts = prev[pose]
                    path = acts + path
                return path
            pos, d = pose
            fwd = self.front(pos, d)
            steps = [((pos, (d - 1) % 4), [LEFT]), ((pos, (d + 1) % 4), [RIGHT])]
            if self._enterable(fwd):
                opened = self.grid[fwd][0] == DOOR and self.grid[fwd][2] != OPEN
                steps.append(((fwd, d), [TOGGLE, FORWARD] if opened else [FORWARD]))
            for nxt, acts in steps:
                if nxt not in prev:
                    prev[nxt] = (pose, acts)
                    queue.append(nxt)
        return None

    def face(self, cell):
        path = self.route(lambda p, d: self.front(p, d) == tuple(cell))
        if path is None:
            return False
        for a in path:
            self.act(a)
        return True

    def find(self, kind, state=None):
        mask = self.grid[..., 0] == kind
        if state is not None:
            mask &= self.grid[..., 2] == state
        return tuple(int(c) for c in np.argwhere(mask)[0])

    def drop_somewhere(self, keep_reachable, avoid=()):
        """Carry the held object to the nearest cell where dropping it keeps every cell of
        ``keep_reachable`` faceable, and drop it there."""
        path = self.route(
            lambda p, d: (
                self.grid[self.front(p, d)][0] == EMPTY
                and self.front(p, d) not in avoid
                and self._drop_ok(p, d, keep_reachable)
            )
        )
        if path is None:
            return False
        for a in path + [DROP]:
            self.act(a)
        return True

    def _drop_ok(self, pos, d, keep_reachable):
        probe = Planner(self.grid, pos, d)
        probe.grid[probe.front()] = (BALL, 0, 0)
        return all(
            probe.route(lambda p, dd, c=c: probe.front(p, dd) == c) is not None
            for c in keep_reachable
        )

    def solve(self, env) -> bool:
        """Append a solution of ``env``'s level to ``self.actions``; False if none was found."""
        door = self.find(DOOR, LOCKED)
        if isinstance(env, BlockedUnlockPickup):
            ball = (door[0] - 1, door[1])
            if not self.face(ball):
                return False
            self.act(PICKUP)
            if not self.drop_somewhere([self.find(KEY), ball], avoid={ball}):
                return False
        if not self.face(self.find(KEY)):
            return False
        self.act(PICKUP)
        if not self.face(door):
            return False
        self.act(TOGGLE)
        if isinstance(env, Unlock):
            return True
        target = BOX if isinstance(env, UnlockPickup) else BALL
        goal = self.find(target)
        if not self.drop_somewhere([goal]):
            return False
        if not self.face(goal):
            return False
        self.act(PICKUP)
        return True


# -------------------------------------------------------------------------- solvability


@pytest.mark.parametrize("env_id", [_param(i, {"MiniGrid-BlockedUnlockPickup-v0"}) for i in IDS])
def test_every_reset_is_solved_by_the_scripted_solution(env_id):
    env = jaxgrid.make(env_id)
    n = 64 if env_id == "MiniGrid-BlockedUnlockPickup-v0" else 256  # the default run's: 64
    states = jax_reset_states(env, n, seed=3)
    plans = []
    for b in range(n):
        planner = Planner(states.grid[b], states.agent_pos[b], states.agent_dir[b])
        assert planner.solve(env), f"{env_id} reset {b}: no scripted solution"
        plans.append(planner.actions)
    length = max(map(len, plans))
    actions = np.stack([R.pad_actions(p, length, [DONE] * length) for p in plans])
    _, outs = R.jax_rollout(env, jax.tree.map(jnp.asarray, states), jnp.asarray(actions))
    done_at = np.array([len(p) - 1 for p in plans])
    rows = np.arange(n)
    assert outs["terminated"][rows, done_at].all(), "the last scripted action succeeds"
    assert (np.asarray(outs["reward"])[rows, done_at] > 0).all()
    early = np.arange(length)[None] < done_at[:, None]
    assert not np.asarray(outs["terminated"])[early].any(), "success before the last action"


# ------------------------------------------------------------------------- differential


def _actions_for(mg, env, seed, num_steps, scripted):
    """Biased random actions; for even seeds if ``scripted``, a scripted solution first."""
    random = R.draw_actions(seed, 1, num_steps)[0]
    if seed % 2 or not scripted:
        return random
    planner = Planner(mg.grid.encode(), mg.agent_pos, mg.agent_dir)
    assert planner.solve(env)
    return R.pad_actions(planner.actions, num_steps, random)


def differential(env_id, seeds, num_steps=MAX_T, encode_every_step=False, after_success=False):
    """Convert MiniGrid resets, step both with the level's own rules, compare every field.

    ``after_success`` first plays the scripted solution in MiniGrid alone and converts the
    state it ends in, so the episodes continue past MiniGrid's termination.
    Returns the recorded MiniGrid episodes.
    """
    mg = R.make_reference(env_id)
    states, episodes, env = [], [], None
    for seed in seeds:
        mg.reset(seed=seed)
        if after_success:
            planner = Planner(mg.grid.encode(), mg.agent_pos, mg.agent_dir)
            assert planner.solve(jaxgrid.make(env_id))
            for a in planner.actions:
                mg.step(int(a))
        converted, state, _ = from_minigrid(mg)
        assert type(converted) is type(jaxgrid.make(env_id))
        assert env is None or converted == env, "one id, one configuration"
        env = converted
        actions = _actions_for(mg, env, seed, num_steps, scripted=not after_success)
        states.append(state)
        episodes.append(
            R.record_episode(mg, actions, seed=seed, encode_every_step=encode_every_step)
        )
    actions = np.stack([ep.actions for ep in episodes])
    obs0, outs = R.jax_rollout(env, R.stack(states), jnp.asarray(actions))
    R.compare(f"{env_id} own step", episodes, obs0, outs)
    return episodes


def successes(episodes):
    return sum(
        int(ep.steps["terminated"][ep.length - 1] and ep.steps["reward"][ep.length - 1] > 0)
        for ep in episodes
    )


@pytest.mark.parametrize("env_id", [_param(i, DEFAULT_STEPS) for i in IDS])
def test_converted_episodes_step_like_minigrid(env_id):
    episodes = differential(env_id, range(6))
    assert successes(episodes) >= 3  # the scripted halves


@pytest.mark.slow
@pytest.mark.parametrize("env_id", list(IDS))
def test_converted_episodes_step_like_minigrid_many_seeds(env_id):
    episodes = differential(env_id, range(100, 164), encode_every_step=True)
    stats = R.coverage(episodes)
    assert successes(episodes) >= 32  # every scripted episode, maybe a random one
    assert stats["unlocks"] >= 32 and stats["pickups"] >= 32 and stats["drops"] > 0
    truncated = sum(int(ep.steps["truncated"][ep.length - 1]) for ep in episodes)
    print(
        f"{env_id}: {len(episodes)} episodes, {stats['steps']} steps compared, "
        f"{successes(episodes)} successes, {truncated} truncated, 0 mismatches, {stats}"
    )


@pytest.mark.parametrize(
    "env_id",
    [_param(i, {"MiniGrid-UnlockPickup-v0"}) for i in (UNLOCKS + ["MiniGrid-KeyCorridorS3R1-v0"])],
)
def test_stepping_on_after_success_like_minigrid(env_id):
    """MiniGrid keeps stepping a terminated episode: Unlock pays again on any toggle while the
    door stays open, the pickup levels on any pickup while the target is held."""
    episodes = differential(env_id, range(0, 24, 2), num_steps=40, after_success=True)
    assert successes(episodes) >= 4


@pytest.mark.slow
def test_random_actions_rarely_succeed_but_success_is_exact():
    """Biased random play reaches Unlock's success now and then: compared with MiniGrid too."""
    episodes = differential("MiniGrid-Unlock-v0", range(1, 41, 2), num_steps=MAX_T)
    assert successes(episodes) >= 1


# --------------------------------------------------------------------------- registry


def _config(env):
    return {
        f: getattr(env, f)
        for f in ("width", "height", "max_steps", "view_size", "see_through_walls")
    }


@pytest.mark.parametrize("env_id", list(IDS))
def test_make_matches_minigrids_defaults(env_id):
    env = jaxgrid.make(env_id)
    mg = R.make_reference(env_id)
    mg.reset(seed=0)
    assert _config(env) == {
        "width": mg.width,
        "height": mg.height,
        "max_steps": mg.max_steps,
        "view_size": mg.agent_view_size,
        "see_through_walls": mg.see_through_walls,
    }
    assert env.room_size == mg.room_size
    assert env == from_minigrid(mg)[0]
    assert env_id in jaxgrid.registered_ids()


def test_from_minigrid_keeps_other_levels_and_base_step():
    mg = R.make_reference("MiniGrid-Unlock-v0")
    mg.reset(seed=0)
    assert isinstance(from_minigrid(mg, base_step=True)[0], FixedLevel)
    wrapped = gym.make("MiniGrid-Unlock-v0")
    wrapped.reset(seed=0)
    assert isinstance(from_minigrid(wrapped)[0], Unlock)

    class MyUnlock(UnlockEnv):
        pass

    mine = MyUnlock()
    mine.reset(seed=0)
    with pytest.raises(ValueError, match="MyUnlock overrides MiniGridEnv.step"):
        from_minigrid(mine)
    keyed = KeyCorridorEnv(obj_type="key")
    keyed.reset(seed=0)
    with pytest.raises(ValueError, match="obj_type='key'"):
        from_minigrid(keyed)
    assert isinstance(from_minigrid(keyed, base_step=True)[0], FixedLevel)
    for env_id in ("MiniGrid-DoorKey-5x5-v0", "BabyAI-GoToRedBall-v0"):
        other = R.make_reference(env_id)
        other.reset(seed=0)
        if env_id.startswith("MiniGrid-DoorKey"):
            assert isinstance(from_minigrid(other)[0], FixedLevel)
        else:
            with pytest.raises(ValueError, match="GoToRedBall overrides"):
                from_minigrid(other)


def test_custom_sizes_convert_and_generate():
    """A KeyCorridorEnv of a size with no registered id converts to the same configuration."""
    mg = KeyCorridorEnv(room_size=4, num_rows=2)
    mg.reset(seed=5)
    env, state, _ = from_minigrid(mg)
    assert (env.room_size, env.num_rows, env.width, env.height) == (4, 2, 10, 7)
    assert env.max_steps == 30 * 16
    assert int((state.grid[..., 0] == BALL).sum()) == 1 and int(state.extras.kind) == BALL
    assert jax.eval_shape(env.reset, jax.random.PRNGKey(0))[0].grid.shape == (10, 7, 3)


@pytest.mark.parametrize(
    "cls, kwargs, setting",
    [
        (Unlock, dict(width=11, height=6, room_size=3), "room_size"),
        (UnlockPickup, dict(width=11, height=6, room_size=6.0), "room_size"),
        (BlockedUnlockPickup, dict(width=12, height=6), "width"),
        (Unlock, dict(width=11, height=7), "height"),
        (Unlock, dict(width=9, height=5), "width"),  # below room_size 6's width: min_size
        (KeyCorridor, dict(width=7, height=7, room_size=3, num_rows=0), "num_rows"),
        (KeyCorridor, dict(width=5, height=7, room_size=3, num_cols=2), "num_cols"),
        (KeyCorridor, dict(width=7, height=7, room_size=2), "room_size"),
        (KeyCorridor, dict(width=7, height=8, room_size=3), "height"),
    ],
)
def test_bad_sizes_raise_naming_the_setting(cls, kwargs, setting):
    with pytest.raises(ValueError, match=rf"{cls.__name__}\.{setting}"):
        cls(max_steps=100, **kwargs)


def test_make_override_of_room_size_names_the_width():
    with pytest.raises(ValueError, match=r"KeyCorridor\.width must be 10"):
        jaxgrid.make("MiniGrid-KeyCorridorS3R3-v0", room_size=4)
    env = jaxgrid.make("MiniGrid-KeyCorridorS3R3-v0", room_size=4, width=10, height=10)
    assert jax.eval_shape(env.reset, jax.random.PRNGKey(0))[0].grid.shape == (10, 10, 3)


# ------------------------------------------------------------------------- compile cost


@pytest.mark.slow
@pytest.mark.parametrize("env_id", list(IDS))
def test_compile_seconds(env_id):
    """Compile time of ``jit(vmap(reset))`` and ``jit(vmap(step))`` (the suite's XLA flags)."""
    reset, run, step = compile_seconds(jaxgrid.make(env_id), 64)
    assert reset + run + step < 20
