"""Run Farama MiniGrid 3.2.0 (the reference) and jaxgrid side by side, fast.

The expensive parts of a differential test are (a) compiling jaxgrid's step and (b) stepping
MiniGrid in Python. So:

* MiniGrid episodes are *recorded* for pre-drawn action sequences (:func:`record_episode`):
  observation image, direction, reward, terminated, truncated, the full ``grid.encode()``,
  the agent's position and the carried object after every step.
* jaxgrid replays a whole batch of those action sequences in ONE jitted ``vmap(lax.scan)``
  (:func:`jax_rollout`). The step only depends on ``(width, height, max_steps, view_size,
  see_through_walls)``, so the static argument is a bare :class:`jaxgrid.environment.Environment`
  with that configuration and the function compiles once per configuration, not once per
  converted episode (a ``FixedLevel`` carries its layout as a static field).
* :func:`compare` checks every field up to MiniGrid's episode end and reports the first
  mismatching (seed, step, action, field).

With ``constrained=`` (a function of the configuration giving a constrained level of the same
configuration, ``jaxgrid.make(id, constraints=...)``), jaxgrid replays the converted states
with a constraint drawn for each (:meth:`~jaxgrid.constrained.ConstrainedLevel.with_constraint`)
through the constrained level's step: MiniGrid's rules must hold with a constraint on.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
from minigrid.core.grid import Grid  # importing minigrid registers its ids
from minigrid.core.mission import MissionSpace
from minigrid.core.world_object import WorldObj
from minigrid.minigrid_env import MiniGridEnv

from helpers.xla import CHEAP
from jaxgrid.compat import from_minigrid
from jaxgrid.constants import ACTION_NAMES, DROP, EMPTY_CELL, PICKUP, TOGGLE
from jaxgrid.environment import Environment

# Actions biased towards the ones that change the world (forward/toggle/pickup).
ACTION_PROBS = np.array([0.12, 0.12, 0.34, 0.12, 0.08, 0.18, 0.04])

FIELDS = (
    "image",
    "direction",
    "reward",
    "terminated",
    "truncated",
    "grid",
    "agent_pos",
    "carrying",
)


def make_reference(env_id: str, **kwargs) -> MiniGridEnv:
    """The unwrapped MiniGrid env (no gymnasium checker wrappers: faster, same dynamics)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # MultiRoom-N4-S5-v0's deprecation notice
        return gym.make(env_id, **kwargs).unwrapped


def draw_actions(seed: int, num_episodes: int, num_steps: int) -> np.ndarray:
    """int32 ``(num_episodes, num_steps)`` biased random actions."""
    rng = np.random.default_rng(seed)
    return rng.choice(7, size=(num_episodes, num_steps), p=ACTION_PROBS).astype(np.int32)


def pad_actions(actions, num_steps: int, fill) -> np.ndarray:
    """int32 ``(num_steps,)``: ``actions`` (cut to ``num_steps``), then ``fill``'s actions
    from the same index on (``fill`` holds at least ``num_steps``)."""
    actions = list(actions)[:num_steps]
    return np.array(actions + list(fill[len(actions) : num_steps]), np.int32)


def _carried(mg: MiniGridEnv) -> np.ndarray:
    return np.asarray(mg.carrying.encode() if mg.carrying else EMPTY_CELL, np.uint8)


@dataclasses.dataclass
class Episode:
    """A recorded MiniGrid episode; step arrays are padded to the action sequence's length."""

    seed: int
    actions: np.ndarray  # (T,)
    length: int  # steps MiniGrid took before the episode ended (or T)
    obs0: np.ndarray  # reset image
    dir0: int
    grid0: np.ndarray  # grid.encode() before the first step
    steps: dict  # field -> (T, ...) array


def record_episode(
    mg: MiniGridEnv,
    actions,
    *,
    seed: int = -1,
    base_step: bool = False,
    encode_every_step: bool = False,
) -> Episode:
    """Step the (already reset / set up) MiniGrid env ``mg`` with ``actions`` until it ends.

    ``base_step=True`` calls ``MiniGridEnv.step`` itself, bypassing a level's override (levels
    such as KeyCorridor only add a level-specific reward/termination on top of it).
    ``grid.encode()`` is only re-run after pickup/drop/toggle unless ``encode_every_step``:
    ``MiniGridEnv.step`` changes the grid on no other action (forward only moves the agent).
    """
    step = functools.partial(MiniGridEnv.step, mg) if base_step else mg.step
    obs = mg.gen_obs()
    num = len(actions)
    w, h, v = mg.width, mg.height, mg.agent_view_size
    steps = {
        "image": np.zeros((num, v, v, 3), np.uint8),
        "direction": np.zeros(num, np.int32),
        "reward": np.zeros(num, np.float64),
        "terminated": np.zeros(num, bool),
        "truncated": np.zeros(num, bool),
        "grid": np.zeros((num, w, h, 3), np.uint8),
        "agent_pos": np.zeros((num, 2), np.int32),
        "carrying": np.zeros((num, 3), np.uint8),
    }
    grid = grid0 = mg.grid.encode()
    length = num
    for t, action in enumerate(actions):
        o, reward, terminated, truncated, _ = step(int(action))
        if encode_every_step or action in (PICKUP, DROP, TOGGLE):
            grid = mg.grid.encode()
        steps["image"][t] = o["image"]
        steps["direction"][t] = o["direction"]
        steps["reward"][t] = reward
        steps["terminated"][t] = terminated
        steps["truncated"][t] = truncated
        steps["grid"][t] = grid
        steps["agent_pos"][t] = mg.agent_pos
        steps["carrying"][t] = _carried(mg)
        if terminated or truncated:
            length = t + 1
            break
    return Episode(
        seed, np.asarray(actions), length, obs["image"], int(obs["direction"]), grid0, steps
    )


def config_env(env: Environment) -> Environment:
    """The bare configuration ``step``/``observe`` depend on (hashable; one compile each)."""
    return Environment(
        width=env.width,
        height=env.height,
        max_steps=env.max_steps,
        view_size=env.view_size,
        see_through_walls=env.see_through_walls,
    )


@functools.partial(jax.jit, static_argnums=0, compiler_options=CHEAP)
def jax_rollout(env: Environment, states, actions):
    """``vmap`` over episodes of a ``lax.scan`` of ``env.step`` over ``actions`` ``(B, T)``.

    Returns ``(reset observations, per-step outputs)`` with the same field names as
    :class:`Episode` (arrays ``(B, T, ...)``). ``env`` may also be a level with its own
    ``step`` (one compile per level configuration).
    """

    def episode(state, acts):
        def body(s, a):
            s, ts = env.step(s, a)
            out = {
                "image": ts.observation["image"],
                "direction": ts.observation["direction"],
                "reward": ts.reward,
                "terminated": ts.terminated,
                "truncated": ts.truncated,
                "grid": s.grid,
                "agent_pos": s.agent_pos,
                "carrying": s.carrying,
            }
            return s, out

        obs0 = env.observe(state)
        return obs0, jax.lax.scan(body, state, acts)[1]

    return jax.vmap(episode)(states, actions)


def stack(trees):
    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)


def compare(label: str, episodes: list[Episode], obs0, outs) -> None:
    """Assert jaxgrid's outputs equal the recorded MiniGrid episodes up to each episode's end."""
    obs0 = jax.tree.map(np.asarray, obs0)
    outs = jax.tree.map(np.asarray, outs)
    for b, ep in enumerate(episodes):
        where = f"{label} seed {ep.seed}"
        if not np.array_equal(obs0["image"][b], ep.obs0):
            raise AssertionError(f"{where}: reset image differs{_diff(obs0['image'][b], ep.obs0)}")
        if int(obs0["direction"][b]) != ep.dir0:
            raise AssertionError(f"{where}: reset direction differs")
    num_steps = episodes[0].actions.shape[0]
    valid = np.arange(num_steps)[None, :] < np.array([ep.length for ep in episodes])[:, None]
    bad = np.zeros_like(valid)
    per_field = {}
    for field in FIELDS:
        ours = outs[field]
        ref = np.stack([ep.steps[field] for ep in episodes])
        if field == "reward":
            ok = np.abs(ours.astype(np.float64) - ref) <= 1e-6
        else:
            ok = ours.reshape(ours.shape[:2] + (-1,)) == ref.reshape(ref.shape[:2] + (-1,))
            ok = ok.all(axis=-1)
        per_field[field] = ~ok & valid
        bad |= per_field[field]
    if not bad.any():
        return
    b, t = np.argwhere(bad)[0]  # first episode with a mismatch, its first bad step
    ep = episodes[b]
    fields = [f for f in FIELDS if per_field[f][b, t]]
    action = int(ep.actions[t])
    lines = [
        f"{label} seed {ep.seed}: first mismatch at step {t + 1} "
        f"(action {action} {ACTION_NAMES[action]}, previous actions "
        f"{ep.actions[max(0, t - 8) : t].tolist()}) in {fields}"
    ]
    for f in fields:
        ours, ref = outs[f][b, t], ep.steps[f][t]
        lines.append(f"  {f}: jaxgrid {_short(ours)} vs minigrid {_short(ref)}{_diff(ours, ref)}")
    raise AssertionError("\n".join(lines))


def _short(x) -> str:
    x = np.asarray(x)
    return repr(x.tolist()) if x.size <= 3 else f"array{x.shape}"


def _diff(ours, ref) -> str:
    ours, ref = np.asarray(ours), np.asarray(ref)
    if ours.ndim < 3 or ours.shape != ref.shape:
        return ""
    idx = np.argwhere((ours != ref).any(axis=-1))[:6]
    cells = ", ".join(f"[{i},{j}] {ours[i, j].tolist()} != {ref[i, j].tolist()}" for i, j in idx)
    return f" (cells {cells})"


def differential_run(
    mg: MiniGridEnv,
    seeds,
    num_steps: int,
    *,
    label: str = "",
    base_step: bool = False,
    setup=None,
    action_seed: int = 0,
    encode_every_step: bool = False,
    constrained=None,
) -> list[Episode]:
    """Reset ``mg`` with each seed (then ``setup(mg, seed)`` if given), convert it with
    ``from_minigrid``, record MiniGrid and replay jaxgrid over the same actions; compare.
    ``constrained`` replays through a constrained level (see the module docstring).

    Returns the recorded episodes (for coverage statistics).
    """
    seeds = list(seeds)
    actions = draw_actions(action_seed, len(seeds), num_steps)
    states, episodes, cfg = [], [], None
    for seed, acts in zip(seeds, actions, strict=True):
        mg.reset(seed=seed)
        if setup is not None:
            setup(mg, seed)
        env, state, _ = from_minigrid(mg, base_step=base_step)
        cfg = cfg or config_env(env)
        assert config_env(env) == cfg, "levels of one id must share a configuration"
        states.append(state)
        episodes.append(
            record_episode(
                mg, acts, seed=seed, base_step=base_step, encode_every_step=encode_every_step
            )
        )
    env, states = cfg, stack(states)
    if constrained is not None:
        env, states = with_constraints(constrained(cfg), states, action_seed)
    obs0, outs = jax_rollout(env, states, jnp.asarray(actions))
    compare(label or (mg.spec.id if mg.spec else type(mg).__name__), episodes, obs0, outs)
    return episodes


def with_constraints(env, states, seed: int):
    """``(env, states)``: the level's ``states`` (a batch) as ``env``'s, a constraint drawn for
    each from keys of ``seed``; ``env`` a constrained level of their configuration."""
    assert config_env(env) == config_env(env.level), "the constrained level's configuration"
    keys = jax.random.split(jax.random.key(seed), jax.tree.leaves(states)[0].shape[0])
    return env, jax.vmap(env.with_constraint)(states, keys)


def set_minigrid_state(mg: MiniGridEnv, state) -> None:
    """Make the (reset) MiniGrid env ``mg`` hold jaxgrid's ``state`` (grid, pose, hands, t)."""
    mg.grid, _ = Grid.decode(np.asarray(state.grid))
    mg.agent_pos = tuple(int(c) for c in np.asarray(state.agent_pos))
    mg.agent_dir = int(state.agent_dir)
    carrying = np.asarray(state.carrying)
    if carrying[0] == EMPTY_CELL[0]:
        mg.carrying = None
    else:
        mg.carrying = WorldObj.decode(*(int(c) for c in carrying))
    mg.step_count = int(state.step_count)


class BlankEnv(MiniGridEnv):
    """A MiniGrid env of any size whose state is set from outside (see :func:`reference_for`)."""

    def __init__(self, width: int, height: int, **kwargs):
        super().__init__(
            mission_space=MissionSpace(mission_func=lambda: ""),
            width=width,
            height=height,
            **kwargs,
        )

    def _gen_grid(self, width, height):
        self.grid = Grid(width, height)
        self.agent_pos, self.agent_dir = (0, 0), 0
        self.mission = ""


def reference_for(env: Environment, state) -> MiniGridEnv:
    """A MiniGrid env with ``env``'s configuration holding jaxgrid's ``state``."""
    mg = BlankEnv(
        env.width,
        env.height,
        max_steps=env.max_steps,
        agent_view_size=env.view_size,
        see_through_walls=env.see_through_walls,
    )
    mg.reset(seed=0)
    set_minigrid_state(mg, state)
    return mg


def check_steps(env: Environment, state, actions, label: str = ""):
    """Step jaxgrid from ``state`` and MiniGrid from the same state with ``actions``; compare.

    Returns jaxgrid's ``(reset observation, per-step outputs)`` for one episode, as numpy, and
    MiniGrid's episode length.
    """
    actions = np.asarray(actions, np.int32)
    episode = record_episode(reference_for(env, state), actions)
    obs0, outs = jax_rollout(config_env(env), stack([state]), jnp.asarray(actions)[None])
    compare(label or "check_steps", [episode], obs0, outs)
    first = lambda x: np.asarray(x)[0]
    return jax.tree.map(first, obs0), jax.tree.map(first, outs), episode.length


def outcomes(episodes: list[Episode]) -> tuple[int, int]:
    """``(successes, failures)``: episodes MiniGrid ended with a positive / zero reward."""
    ends = [(ep.steps["terminated"][ep.length - 1], ep.steps["reward"][ep.length - 1])
            for ep in episodes]  # fmt: skip
    return sum(bool(t and r > 0) for t, r in ends), sum(bool(t and r == 0) for t, r in ends)


def coverage(episodes: list[Episode]) -> dict:
    """How much of the dynamics a batch of recorded episodes exercised."""
    stats = dict(
        episodes=len(episodes),
        steps=0,
        goal=0,
        lava=0,
        truncated=0,
        both=0,
        grid_changes=0,
        pickups=0,
        drops=0,
        unlocks=0,
        box_opened=0,
    )
    for ep in episodes:
        n = ep.length
        s = ep.steps
        stats["steps"] += n
        term, trunc = s["terminated"][:n], s["truncated"][:n]
        stats["goal"] += int((term & (s["reward"][:n] > 0)).sum())
        stats["lava"] += int((term & (s["reward"][:n] == 0)).sum())
        stats["truncated"] += int(trunc.sum())
        stats["both"] += int((term & trunc).sum())
        grids = np.concatenate([ep.grid0[None], s["grid"][:n]])
        changed = (grids[1:] != grids[:-1]).any(axis=(1, 2, 3))
        stats["grid_changes"] += int(changed.sum())
        carry = np.concatenate([[1], s["carrying"][:n, 0]])
        stats["pickups"] += int(((carry[1:] != 1) & (carry[:-1] == 1)).sum())
        stats["drops"] += int(((carry[1:] == 1) & (carry[:-1] != 1)).sum())
        doors = grids[..., 0] == 4
        locked = (doors & (grids[..., 2] == 2)).sum(axis=(1, 2))
        stats["unlocks"] += int((locked[1:] < locked[:-1]).sum())
        boxes = (grids[..., 0] == 7).sum(axis=(1, 2)) + (carry == 7)
        stats["box_opened"] += int((boxes[1:] < boxes[:-1]).sum())
    return stats
