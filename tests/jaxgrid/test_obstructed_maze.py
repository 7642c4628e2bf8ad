"""ObstructedMaze, generated natively with boxes that hold keys, against MiniGrid 3.2.0.

* Layouts: vmapped jaxgrid resets and MiniGrid resets (one seeded RNG stream) are reduced to
  the generator's random choices, what every box holds included (``state.extras.contents``
  against ``box.contains``): agent cell, direction and pose; per-cell occupancy by object
  type; colour and state per type; the colours of the keys, loose and boxed; the number of
  keys (v0 layouts lose one when a later blocking ball covers it); the target ball's cell;
  locked doors with their key colours. Each marginal must have the same support and pass a
  two-sample chi-square test (``helpers.layout_stats``, alpha and pooling stated there).
* Steps: MiniGrid resets converted by ``from_minigrid`` (the native level, box contents in
  ``state.extras``) and stepped by both with the same actions, every field compared after
  every step up to MiniGrid's episode end. The actions are biased random play that, facing a
  box, key, ball or door, mostly picks up, toggles or drops (chosen from MiniGrid's state and
  recorded), so that boxes are opened, carried and dropped and keys revealed and used.
* Box semantics by hand, the registered defaults and mission, and bad configurations.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import minigrid_reference as R
from helpers.layout_stats import cell_id, compare_all, id_param, jax_reset_states, minigrid_resets
from helpers.xla import compile_seconds
from minigrid.core.world_object import Box, Key

import jaxgrid
from jaxgrid.compat import from_minigrid
from jaxgrid.constants import (
    BALL,
    BOX,
    COLOR_TO_IDX,
    DIR_TO_VEC,
    DOOR,
    DROP,
    EMPTY,
    FORWARD,
    KEY,
    LEFT,
    LOCKED,
    PICKUP,
    RIGHT,
    TOGGLE,
)
from jaxgrid.levels import FixedLevel, ObstructedMaze1D, ObstructedMazeFull
from jaxgrid.levels.obstructed import IDS

DEFAULT_LAYOUTS = {"MiniGrid-ObstructedMaze-1Dlhb-v0", "MiniGrid-ObstructedMaze-Full-v0"}
DEFAULT_STEPS = {"MiniGrid-ObstructedMaze-1Dlh-v0", "MiniGrid-ObstructedMaze-2Q-v1"}
N_DEFAULT, N_SLOW = 1500, 3000  # MiniGrid resets per id (jaxgrid: twice as many)
SEEDS, SLOW_SEEDS, STEPS = 8, 30, 200
BLUE = COLOR_TO_IDX["blue"]


# ------------------------------------------------------------------------------ layouts


def _box_contents(mg) -> np.ndarray:
    """uint8 ``(W, H, 3)``: the encoding of what each box of ``mg`` holds (empty elsewhere)."""
    out = np.zeros((mg.width, mg.height, 3), np.uint8)
    out[..., 0] = EMPTY
    for i in range(mg.width):
        for j in range(mg.height):
            obj = mg.grid.get(i, j)
            if obj is not None and obj.type == "box" and obj.contains is not None:
                out[i, j] = obj.contains.encode()
    return out


def _extra(mg) -> np.ndarray:
    """What every box holds, flattened, then the target ball's cell (one row per reset)."""
    return np.concatenate([_box_contents(mg).ravel(), np.asarray(mg.obj.cur_pos, np.uint8)])


def choices(grids, pos, dirs, contents, targets) -> dict:
    """Structure checks; the random choices, one sample per layout (or per object)."""
    n, w, h, _ = grids.shape
    kind, colour, state = grids[..., 0], grids[..., 1], grids[..., 2]
    rows = np.arange(n)
    assert (kind[rows, pos[:, 0], pos[:, 1]] == EMPTY).all(), "agent on an object"
    boxed = kind == BOX
    assert (contents[..., 0][boxed] == KEY).all(), "a box without its key"
    assert (contents[..., 0][~boxed] == EMPTY).all(), "contents where no box is"
    target = grids[rows, targets[:, 0], targets[:, 1]]
    assert (target[:, 0] == BALL).all() and (target[:, 1] == BLUE).all(), "target off its ball"
    assert ((kind == BALL) & (colour == BLUE)).sum(axis=(1, 2)).tolist() == [1] * n
    out = {
        "agent cell": cell_id(pos, h),
        "agent direction": dirs,
        "agent pose": cell_id(pos, h) * 4 + dirs,
        "target cell": cell_id(targets, h),
        "keys available": (kind == KEY).sum(axis=(1, 2)) + boxed.sum(axis=(1, 2)),
    }
    for k, name in ((DOOR, "door"), (KEY, "key"), (BALL, "ball"), (BOX, "box")):
        out[f"cells:{name}"] = kind == k
        b, x, y = np.nonzero(kind == k)
        if len(b):
            out[f"{name} colour and state"] = colour[b, x, y] * 3 + state[b, x, y]
    locked = (kind == DOOR) & (state == LOCKED)
    out["locked door colours"] = np.sort(np.where(locked, colour, 9).reshape(n, -1), axis=1)[
        :, : locked.sum(axis=(1, 2)).max()
    ] @ (10 ** np.arange(locked.sum(axis=(1, 2)).max()))
    keys = np.where(kind == KEY, colour, np.where(boxed, contents[..., 1], 9)).reshape(n, -1)
    out["key colours"] = np.sort(keys, axis=1)[:, :4] @ (10 ** np.arange(4))
    return out


def _ours(env, n):
    st = jax_reset_states(env, n)
    return st.grid, st.agent_pos, st.agent_dir, st.extras.contents, st.extras.pos


@pytest.mark.parametrize("env_id", [id_param(i, DEFAULT_LAYOUTS) for i in IDS])
def test_layout_distribution(env_id):
    n = N_DEFAULT if env_id in DEFAULT_LAYOUTS else N_SLOW
    ours = choices(*_ours(jaxgrid.make(env_id), 2 * n))
    grids, pos, dirs, extra = minigrid_resets(R.make_reference(env_id), n, extra=_extra)
    contents = extra[:, :-2].reshape(grids.shape)
    targets = extra[:, -2:].astype(np.int64)
    ref = choices(grids, pos, dirs, contents, targets)
    compare_all(env_id, ours, ref)


def test_v0_loses_keys_under_balls_and_v1_never():
    """MiniGrid's v0 Full adds each key before the next blocking ball, which may cover it; v1
    adds the keys last. Both rates are compared with MiniGrid by the layout tests."""
    counts = {}
    for version in ("v0", "v1"):
        env = jaxgrid.make(f"MiniGrid-ObstructedMaze-Full-{version}")
        grids, *_, contents, _ = _ours(env, 500)
        kind = grids[..., 0]
        counts[version] = ((kind == KEY) | (kind == BOX)).sum(axis=(1, 2))
    assert (counts["v1"] == 8).all()
    assert (counts["v0"] < 8).mean() > 0.05 and (counts["v0"] >= 4).all()


# ------------------------------------------------------------------------------- steps


def play(mg, seed, num_steps):
    """Biased random play chosen from MiniGrid's state (stepping ``mg``): facing an object or
    a door it mostly picks up, toggles or drops; returns the actions, padded to ``num_steps``."""
    rng = np.random.default_rng(seed)
    actions = []
    for _ in range(num_steps):
        front = mg.grid.get(*mg.front_pos)
        if front is not None and front.type != "wall" and rng.random() < 0.6:
            action = rng.choice([PICKUP, TOGGLE, TOGGLE, DROP, LEFT, RIGHT])
        elif front is None and mg.carrying is not None and rng.random() < 0.15:
            action = DROP
        else:
            action = rng.choice(7, p=R.ACTION_PROBS)
        actions.append(int(action))
        *_, terminated, truncated, _ = mg.step(int(action))
        if terminated or truncated:
            break
    tail = R.draw_actions(seed, 1, num_steps)[0][len(actions) :]
    return np.concatenate([np.array(actions, np.int32), tail]).astype(np.int32)


def differential(env_id, seeds, num_steps=STEPS):
    mg = R.make_reference(env_id)
    states, episodes, env = [], [], None
    for seed in seeds:
        mg.reset(seed=seed)
        actions = play(mg, seed, num_steps)
        mg.reset(seed=seed)
        env, state, _ = from_minigrid(mg)
        assert type(env) is type(jaxgrid.make(env_id)) and env == jaxgrid.make(env_id)
        states.append(state)
        episodes.append(R.record_episode(mg, actions, seed=seed, encode_every_step=True))
    actions = np.stack([ep.actions for ep in episodes])
    obs0, outs = R.jax_rollout(env, R.stack(states), jnp.asarray(actions))
    R.compare(f"{env_id} own step", episodes, obs0, outs)
    return R.coverage(episodes)


@pytest.mark.parametrize("env_id", [id_param(i, DEFAULT_STEPS) for i in IDS])
def test_converted_episodes_step_like_minigrid(env_id):
    seeds = range(SEEDS) if env_id in DEFAULT_STEPS else range(100, 100 + SLOW_SEEDS)
    stats = differential(env_id, seeds)
    print(f"{env_id}: 0 mismatches, {stats}")
    assert stats["pickups"] > 0 and stats["drops"] > 0 and stats["grid_changes"] > 0
    if IDS[env_id]().key_in_box:
        assert stats["box_opened"] > 0


# --------------------------------------------------------------------------- box rules


def _state_with_box(mg, holds):
    """``mg`` (1Dlh, reset) with a box holding ``holds`` right in front of the agent."""
    mg.reset(seed=3)
    for i in range(mg.width):
        for j in range(mg.height):
            obj = mg.grid.get(i, j)
            if obj is not None and obj.type in ("box", "key"):
                mg.grid.set(i, j, None)
    mg.agent_pos, mg.agent_dir = (2, 2), 0  # facing (3, 2), inside the left room
    mg.grid.set(3, 2, Box("grey", contains=holds))
    return mg


@pytest.mark.parametrize("holds", [Key("purple"), None], ids=["key", "empty"])
def test_boxes_keep_what_they_hold_when_opened_or_carried(holds):
    """Open in place; pick up, carry, drop elsewhere and open: the contents appear where the
    box stands, as in MiniGrid; an empty box leaves an empty cell."""
    mg = _state_with_box(R.make_reference("MiniGrid-ObstructedMaze-1Dlh-v0"), holds)
    env, state, _ = from_minigrid(mg)
    where = state.extras.contents[3, 2]
    assert tuple(np.asarray(where)) == (tuple(holds.encode()) if holds else (EMPTY, 0, 0))
    revealed = tuple(holds.encode()) if holds else (EMPTY, 0, 0)
    # opened in place: the contents on the box's cell; carried, dropped at (2, 3), opened and
    # picked up: the contents in the agent's hands
    for actions in ([TOGGLE, FORWARD], [PICKUP, RIGHT, DROP, TOGGLE, PICKUP]):
        mg = _state_with_box(R.make_reference("MiniGrid-ObstructedMaze-1Dlh-v0"), holds)
        env, state, _ = from_minigrid(mg)
        episode = R.record_episode(mg, actions, encode_every_step=True)
        obs0, outs = R.jax_rollout(env, R.stack([state]), jnp.asarray([actions]))
        R.compare("box rules", [episode], obs0, outs)
        grid, carried = np.asarray(outs["grid"])[0, -1], np.asarray(outs["carrying"])[0, -1]
        got = grid[3, 2] if actions[0] == TOGGLE else carried
        assert tuple(got) == revealed


@pytest.mark.parametrize(
    "env_id", ["MiniGrid-ObstructedMaze-1Dl-v0", "MiniGrid-ObstructedMaze-Full-v1"]
)
def test_picking_up_the_blue_ball_succeeds_like_minigrid(env_id):
    """The agent put next to the target, facing it: the pickup pays ``1 - 0.9 t / max_steps``
    and terminates, with every field as MiniGrid's."""
    mg = R.make_reference(env_id)
    successes = 0
    for seed in range(6):
        mg.reset(seed=seed)
        x, y = mg.obj.cur_pos
        for d, (dx, dy) in enumerate(DIR_TO_VEC):  # stand on a free neighbour, facing the ball
            if mg.grid.get(x - dx, y - dy) is None:
                mg.agent_pos, mg.agent_dir = (x - dx, y - dy), d
                break
        env, state, _ = from_minigrid(mg)
        actions = [PICKUP, DROP]  # MiniGrid's episode ends at the pickup
        episode = R.record_episode(mg, actions)
        obs0, outs = R.jax_rollout(env, R.stack([state]), jnp.asarray([actions]))
        R.compare(f"{env_id} success", [episode], obs0, outs)
        successes += int(
            np.asarray(outs["terminated"])[0, 0] and np.asarray(outs["reward"])[0, 0] > 0
        )
    assert successes == 6


# ------------------------------------------------------------------------ configuration


@pytest.mark.parametrize("env_id", list(IDS))
def test_make_matches_minigrids_defaults_and_mission(env_id):
    env, mg = jaxgrid.make(env_id), R.make_reference(env_id)
    mg.reset(seed=0)
    got = (env.width, env.height, env.max_steps, env.view_size, env.see_through_walls)
    assert got == (mg.width, mg.height, mg.max_steps, mg.agent_view_size, mg.see_through_walls)
    state, _ = env.reset(jax.random.PRNGKey(0))
    assert env.mission_text(state) == mg.mission == "pick up the blue ball"
    converted, _, _ = from_minigrid(mg)
    assert converted == env
    if any(getattr(o, "contains", None) for o in mg.grid.grid):  # MiniGridEnv.step drops them
        with pytest.raises(ValueError, match=r"Box holding a key .* without base_step=True"):
            from_minigrid(mg, base_step=True)
    else:
        assert isinstance(from_minigrid(mg, base_step=True)[0], FixedLevel)


@pytest.mark.parametrize(
    "cls, overrides, message",
    [
        (ObstructedMaze1D, dict(room_size=5), r"room_size must be an int >= 6"),
        (ObstructedMaze1D, dict(room_size=7, width=13, height=7), r"room_size must be 6"),
        (ObstructedMaze1D, dict(key_in_box=1), r"key_in_box must be a bool"),
        (ObstructedMazeFull, dict(num_quarters=0), r"num_quarters must be an int in 1\.\.4"),
        (ObstructedMazeFull, dict(num_quarters=5), r"num_quarters must be an int in 1\.\.4"),
        (ObstructedMazeFull, dict(agent_room=(3, 0)), r"agent_room must be a \(column, row\)"),
        (ObstructedMazeFull, dict(keys_after_doors="yes"), r"keys_after_doors must be a bool"),
    ],
)
def test_bad_configuration_raises_naming_the_field(cls, overrides, message):
    env_id = (
        "MiniGrid-ObstructedMaze-1Dl-v0"
        if cls is ObstructedMaze1D
        else "MiniGrid-ObstructedMaze-Full-v0"
    )
    with pytest.raises(ValueError, match=message):
        jaxgrid.make(env_id, **overrides)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", list(IDS))
def test_compile_seconds(env_id):
    """``jit(vmap(reset))`` and ``jit(vmap(step))`` compile times (the suite's XLA flags)."""
    reset, run, step = compile_seconds(jaxgrid.make(env_id), 64)
    assert reset + step < 10
