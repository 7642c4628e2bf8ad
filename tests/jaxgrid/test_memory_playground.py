"""Memory and Playground, generated natively, against MiniGrid 3.2.0.

* Layouts: vmapped jaxgrid resets and MiniGrid resets (one seeded RNG stream) are read back
  into the generators' random choices by one function per family for both sides, each
  marginal compared with a two-sample chi-square test at ``ALPHA`` (``helpers.layout_stats``).
  Memory: the hallway's end, the agent's column, the start room's object, the end objects'
  order, which end cell pays (``success_pos``) and which ends the episode with nothing
  (``failure_pos``); for every hallway end the walls are the same on both sides. Playground:
  each wall's door cell and colour, the walls, the objects' cells by type, (type, colour)
  pairs, counts per type and colour, the agent's pose.
* Steps: natively generated states copied into MiniGrid (with ``success_pos`` and
  ``failure_pos`` for Memory) and MiniGrid resets converted with ``from_minigrid`` are
  stepped by both, every field at every step, and on after MiniGrid's termination or
  truncation for all of the actions (MiniGrid keeps applying its rules; Memory's pays again
  while the agent stays on the cell). Memory runs start with scripted walks to the matching
  or the other object; some start near ``max_steps``, so that truncation and the reward's
  decay show.
* Every Memory layout is solvable (a shortest path to ``success_pos``), every Playground cell
  is reachable through its closed doors; the missions are MiniGrid's; the steps compile once
  and within 5 s; impossible settings are refused before any compile.
"""

from __future__ import annotations

import collections

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import minigrid_reference as R
from helpers.layout_stats import compare_all, id_param, jax_reset_states, minigrid_resets
from helpers.xla import CHEAP, compile_seconds

from jaxgrid.compat import from_minigrid
from jaxgrid.constants import (
    BALL,
    BOX,
    CLOSED,
    DOOR,
    EMPTY,
    EMPTY_CELL,
    FORWARD,
    GREEN,
    KEY,
    LEFT,
    RIGHT,
    WALL,
)
from jaxgrid.levels import memory, playground
from jaxgrid.levels.memory import Memory
from jaxgrid.levels.playground import Playground
from jaxgrid.oracle import distance_field

MEMORY_DEFAULT = {"MiniGrid-MemoryS13Random-v0"}
PLAYGROUND = "MiniGrid-Playground-v0"
STEPS = 200  # actions per replayed episode (slow run)
OBJECTS = (KEY, BALL, BOX)


# ------------------------------------------------------------------------------ replay


def record_through(mg, actions, seed):
    """Step MiniGrid with every action, on past its termination or truncation (MiniGrid
    steps on), encoding the grid after every step; an episode whose every step compares."""
    obs, grid0 = mg.gen_obs(), mg.grid.encode()
    steps = collections.defaultdict(list)
    for action in actions:
        o, reward, terminated, truncated, _ = mg.step(int(action))
        steps["image"].append(o["image"])
        steps["direction"].append(o["direction"])
        steps["reward"].append(float(reward))
        steps["terminated"].append(terminated)
        steps["truncated"].append(truncated)
        steps["grid"].append(mg.grid.encode())
        steps["agent_pos"].append(tuple(int(c) for c in mg.agent_pos))
        steps["carrying"].append(mg.carrying.encode() if mg.carrying else EMPTY_CELL)
    steps = {k: np.asarray(v) for k, v in steps.items()}
    actions = np.asarray(actions)
    return R.Episode(seed, actions, len(actions), obs["image"], int(obs["direction"]), grid0, steps)


def replay(label, rollout_env, starts, episodes):
    """Roll ``rollout_env`` from ``starts`` over the episodes' actions; compare every step."""
    actions = jnp.asarray(np.stack([ep.actions for ep in episodes]), jnp.int32)
    obs0, outs = R.jax_rollout(rollout_env, R.stack(starts), actions)
    R.compare(label, episodes, obs0, outs)
    return jax.tree.map(np.asarray, outs)


def outcome_counts(episodes) -> collections.Counter:
    """MiniGrid's paid terminations, unpaid ones, steps after termination, truncations."""
    counts = collections.Counter()
    for ep in episodes:
        s = ep.steps
        ended = np.cumsum(s["terminated"] | s["truncated"]) > 0
        counts["paid"] += int((s["terminated"] & (s["reward"] > 0)).sum())
        counts["unpaid"] += int((s["terminated"] & (s["reward"] == 0)).sum())
        counts["after end"] += int(ended[:-1].sum())  # steps taken once it had ended
        counts["truncated"] += int(s["truncated"].sum())
        counts["steps"] += len(ep.actions)
    return counts


def one_cell(pos, width, height):
    """bool ``(n, width, height)`` masks of one cell each."""
    mask = np.zeros((len(pos), width, height), bool)
    mask[np.arange(len(pos)), pos[:, 0], pos[:, 1]] = True
    return jnp.asarray(mask)


# ------------------------------------------------------------------------------ Memory


def memory_choices(grids, pos, dirs, success, failure):
    """Check Memory layouts; return their random choices and the walls per hallway end."""
    out = collections.defaultdict(list)
    walls = {}
    for grid, p, d, s, f in zip(grids, pos, dirs, success, failure, strict=True):
        kind = grid[..., 0]
        w, h = kind.shape
        mid = h // 2
        objects = np.argwhere(np.isin(kind, [KEY, BALL]))
        assert len(objects) == 3 and (grid[kind > WALL][:, 1] == GREEN).all()
        assert ((kind == EMPTY) | (kind == WALL) | np.isin(kind, [KEY, BALL])).all()
        (end_x,) = {x for x, _ in objects if x > 1}  # the objects at the hallway's end
        end = end_x - 1
        top, bottom, start = kind[end_x, mid - 2], kind[end_x, mid + 2], kind[1, mid - 1]
        assert {top, bottom} == {KEY, BALL} and start in (KEY, BALL)
        assert p[1] == mid and 1 <= p[0] <= end and d == 0 and kind[tuple(p)] == EMPTY
        up, down = (end_x, mid - 1), (end_x, mid + 1)
        assert kind[up] == kind[down] == EMPTY
        s, f = tuple(int(c) for c in s), tuple(int(c) for c in f)
        assert {s, f} == {up, down}, (s, f)
        assert s == (up if start == top else down), "success is not next to the matching one"
        seen = walls.setdefault(end, kind == WALL)
        assert (seen == (kind == WALL)).all(), f"walls differ for hallway end {end}"
        out["end"].append(end)
        out["agent_x"].append(p[0])
        out["start"].append(start)
        out["top"].append(top)
        out["success"].append(s[1] * w + s[0])
        out["failure"].append(f[1] * w + f[0])
        out["start_top"].append(start * 16 + top)  # the joint of the two object draws
    return {k: np.array(v) for k, v in out.items()}, walls


@pytest.mark.parametrize("env_id", [id_param(i, MEMORY_DEFAULT) for i in memory.IDS])
def test_memory_layouts_are_drawn_as_minigrid_draws_them(env_id):
    n = 400 if env_id in MEMORY_DEFAULT else 2000
    env = memory.IDS[env_id]()
    st = jax_reset_states(env, 2 * n)
    ours, our_walls = memory_choices(
        st.grid, st.agent_pos, st.agent_dir, st.extras.success, st.extras.failure
    )
    mg = R.make_reference(env_id)
    *ref, task = minigrid_resets(mg, n, extra=lambda m: (m.success_pos, m.failure_pos))
    ref, ref_walls = memory_choices(*ref, task[:, 0], task[:, 1])
    assert sorted(our_walls) == sorted(ref_walls)
    for end, mask in ref_walls.items():
        np.testing.assert_array_equal(our_walls[end], mask, err_msg=f"hallway end {end}")
    if not env.random_length:
        assert set(ours["end"]) == {env.width - 3}
    compare_all(env_id, ours, ref)


def test_memory_layouts_are_solvable():
    """A shortest path (through empty cells) leads from the start to ``success_pos``, and
    its length is what the scripted walk takes."""
    for env_id in ("MiniGrid-MemoryS17Random-v0", "MiniGrid-MemoryS7-v0"):
        env = memory.IDS[env_id]()
        st = jax_reset_states(env, 256, seed=4)
        target = one_cell(st.extras.success, env.width, env.height)
        dist = jax.jit(distance_field)(target, jnp.asarray(st.grid[..., 0] == EMPTY))
        dist = np.asarray(dist)[np.arange(256), st.agent_pos[:, 0], st.agent_pos[:, 1]]
        expected = st.extras.success[:, 0] - st.agent_pos[:, 0] + 1
        np.testing.assert_array_equal(dist, expected, err_msg=env_id)


def walk(mg, matching: bool) -> list[int]:
    """Actions from MiniGrid's start to the cell next to the matching (or other) object."""
    x, y = (int(c) for c in mg.agent_pos)
    target = mg.success_pos if matching else mg.failure_pos
    turn = LEFT if target[1] < y else RIGHT
    return [FORWARD] * (target[0] - x) + [turn, FORWARD]


def memory_run(env_id, seeds, native: bool, steps: int) -> collections.Counter:
    """Per seed: a native state copied into MiniGrid (``native``) or a MiniGrid reset
    converted; every third one advanced to 60 steps before ``max_steps``; a scripted walk
    to the matching or the other object (or none), then biased random actions."""
    env = memory.IDS[env_id]()
    native_states = jax_reset_states(env, len(seeds), seed=11)
    starts, episodes = [], []
    for b, seed in enumerate(seeds):
        mg = R.make_reference(env_id)
        mg.reset(seed=seed)
        late = env.max_steps - 60 if b % 3 == 1 else 0
        if native:
            state = jax.tree.map(lambda x, b=b: jnp.asarray(x[b]), native_states)
            state = state.replace(step_count=jnp.int32(late))
            R.set_minigrid_state(mg, state)
            mg.success_pos = tuple(int(c) for c in state.extras.success)
            mg.failure_pos = tuple(int(c) for c in state.extras.failure)
        else:
            mg.step_count = late
            converted, state, _ = from_minigrid(mg)
            assert converted == env
            assert tuple(np.asarray(state.extras.success)) == tuple(mg.success_pos)
            assert tuple(np.asarray(state.extras.failure)) == tuple(mg.failure_pos)
            assert int(state.step_count) == late
        script = walk(mg, matching=b % 3 != 2) if b % 4 else []
        random = R.draw_actions(seed, 1, steps)[0]
        actions = np.concatenate([script, random])[:steps].astype(np.int32)
        starts.append(state)
        episodes.append(record_through(mg, actions, seed))
    label = f"{env_id} {'native' if native else 'converted'}"
    replay(label, env, starts, episodes)
    return outcome_counts(episodes)


@pytest.mark.parametrize("native", [True, False], ids=["native", "converted"])
def test_memory_steps_like_minigrid_on_past_the_end(native):
    counts = memory_run("MiniGrid-MemoryS9-v0", range(12), native, 80)
    assert counts["paid"] >= 20 and counts["unpaid"] >= 10 and counts["truncated"] >= 20, counts
    assert counts["after end"] >= 300, counts


@pytest.mark.slow
@pytest.mark.parametrize("env_id", list(memory.IDS))
@pytest.mark.parametrize("native", [True, False], ids=["native", "converted"])
def test_memory_steps_like_minigrid_many_seeds(env_id, native):
    counts = memory_run(env_id, range(100, 132), native, STEPS)
    print(env_id, dict(counts))
    assert counts["steps"] == 32 * STEPS
    assert counts["paid"] >= 100 and counts["unpaid"] >= 50 and counts["truncated"] >= 200
    assert counts["after end"] >= 32 * STEPS // 2


def test_memory_reward_decays_with_the_step_count():
    """Paid exactly ``1 - 0.9 * step_count / max_steps`` (MiniGrid's ``_reward``) at success,
    0 at failure; the walk's length decides the step count."""
    env_id = "MiniGrid-MemoryS11-v0"
    env = memory.IDS[env_id]()
    mg = R.make_reference(env_id)
    mg.reset(seed=3)
    _, state, _ = from_minigrid(mg)
    step = jax.jit(env.step)
    for matching in (True, False):
        s = state
        for a in walk(mg, matching):
            s, ts = step(s, a)
        t = int(s.step_count)
        assert bool(ts.terminated) and not bool(ts.truncated)
        expected = 1 - 0.9 * t / env.max_steps if matching else 0.0
        assert float(ts.reward) == pytest.approx(expected, abs=1e-6)


def test_memory_ids_have_minigrids_settings_and_mission():
    for env_id, make in memory.IDS.items():
        env, mg = make(), R.make_reference(env_id)
        mg.reset(seed=0)
        assert (env.width, env.height, env.max_steps) == (mg.width, mg.height, mg.max_steps)
        assert (env.view_size, env.see_through_walls) == (mg.agent_view_size, False)
        assert mg.see_through_walls is False and env.random_length == mg.random_length
        state, _ = env.reset(jax.random.PRNGKey(0))
        assert env.mission_text(state) == mg.mission == Memory.MISSION
    assert Memory.MISSION == "go to the matching object at the end of the hallway"


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(width=9, height=8), "height"),
        (dict(width=9, height=10, random_length=True), "height"),
        (dict(width=9, height=5), "height"),
        (dict(width=6, height=9), "width"),
        (dict(width=6, height=9, random_length=True), "width"),
    ],
)
def test_memory_impossible_sizes_are_refused(kwargs, field):
    with pytest.raises(ValueError, match=field):
        Memory(max_steps=10, **kwargs)


def test_memory_smallest_odd_sizes_generate():
    """Non-square and even-width sizes MiniGrid's layout code accepts generate its layout."""
    for w, h in ((7, 7), (8, 9), (12, 7)):
        for random_length in (False, True):
            env = Memory(width=w, height=h, max_steps=50, random_length=random_length)
            st = jax_reset_states(env, 32, seed=w)
            memory_choices(st.grid, st.agent_pos, st.agent_dir, st.extras.success,
                           st.extras.failure)  # fmt: skip


# ------------------------------------------------------------------------------ Playground


def playground_choices(grids, pos, dirs):
    """Check Playground layouts (19 x 19, rooms of 6); return their random choices."""
    out = collections.defaultdict(list)
    frame = None
    for grid, p, d in zip(grids, pos, dirs, strict=True):
        kind, colour = grid[..., 0], grid[..., 1]
        is_door = kind == DOOR
        assert (grid[is_door][:, 2] == CLOSED).all() and is_door.sum() == 12
        solid = (kind == WALL) | is_door
        frame = solid if frame is None else frame
        assert (frame == solid).all(), "walls and doors differ between layouts"
        n = 0
        for j in range(3):  # rows of rooms, then columns, as _gen_grid loops
            for i in range(3):
                if i + 1 < 3:  # the wall at x = 6 (i + 1), rows 6 j .. 6 j + 6
                    x, ys = 6 * (i + 1), np.arange(6 * j, 6 * j + 7)
                    (y,) = ys[is_door[x, ys]]
                    out[f"door{n}:offset"].append(y - 6 * j)
                    out[f"door{n}:colour"].append(colour[x, y])
                    n += 1
                if j + 1 < 3:  # the wall at y = 6 (j + 1), columns 6 i .. 6 i + 6
                    xs, y = np.arange(6 * i, 6 * i + 7), 6 * (j + 1)
                    (x,) = xs[is_door[xs, y]]
                    out[f"door{n}:offset"].append(x - 6 * i)
                    out[f"door{n}:colour"].append(colour[x, y])
                    n += 1
        objects = np.isin(kind, OBJECTS)
        assert objects.sum() == 12 and kind[tuple(p)] == EMPTY
        for k in OBJECTS:
            out[f"count:{k}"].append((kind == k).sum())
        for c in range(6):
            out[f"colour:{c}"].append((objects & (colour == c)).sum())
        out["agent"].append(p[0] * 19 + p[1])
        out["dir"].append(d)
    out = {k: np.array(v) for k, v in out.items()}
    # the wall cells themselves, once doors are filled in, are MiniGrid's frame
    out["frame"] = frame
    return out


def playground_pairs(grids):
    """Every object's (type, colour) pair, pooled over layouts (each one drawn i.i.d.)."""
    objects = np.isin(grids[..., 0], OBJECTS)
    return grids[objects][:, 0].astype(int) * 8 + grids[objects][:, 1]


@pytest.mark.parametrize("n", [500, pytest.param(2000, marks=pytest.mark.slow)])
def test_playground_layouts_are_drawn_as_minigrid_draws_them(n):
    env = playground.IDS[PLAYGROUND]()
    st = jax_reset_states(env, 2 * n)
    ours = playground_choices(st.grid, st.agent_pos, st.agent_dir)
    ref_layouts = minigrid_resets(R.make_reference(PLAYGROUND), n)
    ref = playground_choices(*ref_layouts)
    np.testing.assert_array_equal(ours.pop("frame"), ref.pop("frame"))
    for k in OBJECTS:
        ours[f"cells:{k}"] = st.grid[..., 0] == k
        ref[f"cells:{k}"] = ref_layouts[0][..., 0] == k
    ours["pairs"], ref["pairs"] = playground_pairs(st.grid), playground_pairs(ref_layouts[0])
    p = compare_all(PLAYGROUND, ours, ref)
    assert len([k for k in p if k.startswith("door")]) == 24


def test_playground_every_cell_is_reachable_through_its_doors():
    """Closed doors open and objects can be picked up: every cell that is not a wall can be
    reached from the agent's (MiniGrid places no locked door)."""
    env = playground.IDS[PLAYGROUND]()
    st = jax_reset_states(env, 128, seed=2)
    kind = jnp.asarray(st.grid[..., 0])
    passable = kind != WALL
    dist = np.asarray(jax.jit(distance_field)(one_cell(st.agent_pos, 19, 19), passable))
    assert (dist[st.grid[..., 0] != WALL] < 19 * 19).all()
    assert ((dist < 19 * 19) == (kind != WALL)).all()


def playground_run(seeds, native: bool, steps: int) -> collections.Counter:
    """Native states copied into MiniGrid or MiniGrid resets converted; biased random
    actions, on past ``max_steps`` (100)."""
    env = playground.IDS[PLAYGROUND]()
    native_states = jax_reset_states(env, len(seeds), seed=7)
    starts, episodes, rollout_env = [], [], env
    for b, seed in enumerate(seeds):
        mg = R.make_reference(PLAYGROUND)
        mg.reset(seed=seed)
        if native:
            state = jax.tree.map(lambda x, b=b: jnp.asarray(x[b]), native_states)
            R.set_minigrid_state(mg, state)
        else:
            converted, state, _ = from_minigrid(mg)
            rollout_env = R.config_env(converted)
            assert rollout_env == R.config_env(env)
        starts.append(state)
        episodes.append(record_through(mg, R.draw_actions(seed, 1, steps)[0], seed))
    outs = replay(f"{PLAYGROUND} {'native' if native else 'converted'}", rollout_env, starts,
                  episodes)  # fmt: skip
    counts = outcome_counts(episodes)
    carried = outs["carrying"][..., 0]
    counts["carrying"] = int((carried != EMPTY).sum())
    counts["doors opened"] = int((outs["grid"][..., 2] == 0)[outs["grid"][..., 0] == DOOR].sum())
    return counts


@pytest.mark.parametrize("native", [True, False], ids=["native", "converted"])
def test_playground_steps_like_minigrid_on_past_the_end(native):
    counts = playground_run(range(6), native, 120)
    assert counts["truncated"] == 6 * 21 and counts["carrying"] > 0, counts


@pytest.mark.slow
@pytest.mark.parametrize("native", [True, False], ids=["native", "converted"])
def test_playground_steps_like_minigrid_many_seeds(native):
    counts = playground_run(range(200, 232), native, STEPS)
    print(dict(counts))
    assert counts["steps"] == 32 * STEPS and counts["truncated"] == 32 * 101
    assert counts["carrying"] > 500 and counts["doors opened"] > 100


def test_playground_settings_and_mission_are_minigrids():
    env, mg = playground.IDS[PLAYGROUND](), R.make_reference(PLAYGROUND)
    mg.reset(seed=0)
    assert (env.width, env.height, env.max_steps) == (mg.width, mg.height, mg.max_steps)
    assert (env.view_size, env.see_through_walls) == (mg.agent_view_size, mg.see_through_walls)
    state, _ = env.reset(jax.random.PRNGKey(0))
    assert env.mission_text(state) == mg.mission == Playground.MISSION == ""


@pytest.mark.parametrize(
    "kwargs, field",
    [(dict(width=9, height=19), "width"), (dict(width=19, height=8), "height")],
)
def test_playground_impossible_sizes_are_refused(kwargs, field):
    with pytest.raises(ValueError, match=field):
        Playground(max_steps=10, **kwargs)


# ------------------------------------------------------------------------------ compile


@pytest.mark.parametrize(
    "make", [memory.IDS["MiniGrid-MemoryS13Random-v0"], playground.IDS[PLAYGROUND]],
    ids=["memory", "playground"],
)  # fmt: skip
def test_step_compiles_once(make):
    env = make()
    chex.clear_trace_counter()  # one count per parametrised case

    @jax.jit
    @chex.assert_max_traces(n=1)
    def step(state, action):
        return env.step(state, action)

    reset = jax.jit(jax.vmap(env.reset), compiler_options=CHEAP)
    states, _ = reset(jax.random.split(jax.random.PRNGKey(0), 4))
    for action in range(8):
        states, ts = jax.vmap(step, in_axes=(0, None))(states, action)
    assert ts.reward.dtype == jnp.float32


@pytest.mark.slow
@pytest.mark.parametrize("env_id", [*memory.IDS, PLAYGROUND])
def test_compile_seconds(env_id):
    make = memory.IDS.get(env_id) or playground.IDS[env_id]
    reset, _, step = compile_seconds(make(), 64)
    assert reset + step < 5
