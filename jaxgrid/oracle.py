"""A privileged BFS policy that solves every scenario without violating its constraint.

:func:`oracle_action` reads the full state (grid, carried object, the episode's constraint
and monitor, :class:`~jaxgrid.constrained.ConstrainedExtras`) and returns the next MiniGrid
action. It is pure ``jnp``: jittable, vmappable, with no Python branching on traced values.
It is used to check that every generated episode is solvable without a violation, as an
expert for tests, and to measure how often the unconstrained shortest route would break the
constraint.

Planning is a breadth-first distance field over the ``(W, H)`` grid, computed by relaxing
shifted copies of the field in a ``lax.while_loop`` until nothing changes (at most ``W * H``
sweeps). Cells the agent may plan through (:func:`passable_cells`): empty, floor, goal, doors
that are open or closed (closed ones get toggled open) unless their colour is forbidden,
locked doors only while carrying a key of their colour. Lava and forbidden doors are never
entered. The target is the goal when it is reachable under these rules, else a key (the agent
then picks it up and unlocks the door with it). Acting from the field:

* the best neighbour is the one with the smallest distance (ties: fewest turns away);
* if it is in front: ``pickup`` if it holds the key, ``toggle`` if it is a closed or locked
  door, else ``forward``;
* otherwise turn towards it (``right`` if it is one clockwise turn away, else ``left``).

:func:`rollout_oracle` runs a batch of episodes with the raw ``env.step`` and returns
per-episode success, violation count, length and constraint type.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax import lax

from jaxgrid import monitor as M
from jaxgrid.constants import (
    DIR_TO_VEC,
    DOOR,
    EMPTY,
    FLOOR,
    FORWARD,
    GOAL,
    KEY,
    LAVA,
    LEFT,
    LOCKED,
    OPEN,
    PICKUP,
    RIGHT,
    TOGGLE,
)
from jaxgrid.constrained import ConstrainedExtras, DoorConstraint
from jaxgrid.dynamics import front_pos, get_cell
from jaxgrid.types import State

__all__ = ["distance_field", "oracle_action", "passable_cells", "rollout_oracle"]


def _unreachable(shape) -> int:
    """Distance given to cells from which the target cannot be reached."""
    return shape[0] * shape[1] + 1


def distance_field(target: jax.Array, passable: jax.Array) -> jax.Array:
    """BFS distances (in moves) to the nearest ``target`` cell through ``passable`` cells.

    ``target`` and ``passable`` are bool ``(..., W, H)``; leading axes are independent fields.
    Target cells have distance 0 whether passable or not (a key is reached by facing it);
    unreachable cells get ``W * H + 1``. Cells outside the grid count as walls.
    """
    inf = _unreachable(target.shape[-2:])
    dist0 = jnp.where(target, 0, inf).astype(jnp.int32)
    relax = passable & ~target

    def sweep(dist):
        # Smallest neighbour distance: four shifted copies, padded with "unreachable".
        pad = jnp.pad(dist, [(0, 0)] * (dist.ndim - 2) + [(1, 1), (1, 1)], constant_values=inf)
        nb = jnp.minimum(
            jnp.minimum(pad[..., :-2, 1:-1], pad[..., 2:, 1:-1]),
            jnp.minimum(pad[..., 1:-1, :-2], pad[..., 1:-1, 2:]),
        )
        return jnp.where(relax, jnp.minimum(dist, nb + 1), dist)

    def cond(carry):
        i, dist, prev_changed = carry
        return prev_changed & (i < target.shape[-2] * target.shape[-1])

    def body(carry):
        i, dist, _ = carry
        new = sweep(dist)
        return i + 1, new, jnp.any(new != dist)

    _, dist, _ = lax.while_loop(cond, body, (0, dist0, jnp.array(True)))
    return dist


def passable_cells(
    grid: jax.Array,
    carrying: jax.Array,
    forbidden_colour: jax.Array,
    *,
    avoid_lava: bool | jax.Array = True,
) -> jax.Array:
    """bool ``(W, H)``: cells the oracle may plan through.

    ``forbidden_colour`` is the colour index of doors never to enter (-1 for none). Locked
    doors are passable only while ``carrying`` a key of the same colour; lava only with
    ``avoid_lava=False`` (a Python or traced bool).
    """
    kind, colour, door_state = grid[..., 0], grid[..., 1], grid[..., 2]
    has_key = (carrying[0] == KEY) & (carrying[1] == colour)
    door_ok = (kind == DOOR) & (colour != forbidden_colour) & ((door_state != LOCKED) | has_key)
    walkable = (kind == EMPTY) | (kind == FLOOR) | (kind == GOAL) | door_ok
    return walkable | ((kind == LAVA) & ~jnp.asarray(avoid_lava))


def oracle_action(
    state: State,
    env=None,
    *,
    obey_constraint: bool | jax.Array = True,
    avoid_lava: bool | jax.Array = True,
) -> jax.Array:
    """Next action (int32) of the BFS oracle; see the module docstring.

    Args:
        state: a single (unbatched) state; ``vmap`` for batches. If its constraint is a
            :class:`~jaxgrid.constrained.DoorConstraint` (the paper's scenarios), doors of its
            ``door_colour`` are never entered (a caller may plan with another colour by
            replacing it); any other constraint's monitor zones (:mod:`jaxgrid.monitor`) are
            never entered.
        env: unused (everything is read from ``state``); accepted so the call mirrors
            ``env.step(state, action)``.
        obey_constraint: bool (may be traced); ``False`` plans as if no door were forbidden.
        avoid_lava: bool (may be traced); ``False`` plans through lava as if it were floor.
    """
    del env
    grid = state.grid
    kind = grid[..., 0]
    # Static: the type of the state's extras and constraint (the pytree's structure).
    extras = state.extras if isinstance(state.extras, ConstrainedExtras) else None
    forbidden = jnp.int32(-1)
    if extras is not None and isinstance(extras.constraint, DoorConstraint):
        forbidden = jnp.where(obey_constraint, extras.constraint.door_colour, forbidden)

    passable = passable_cells(grid, state.carrying, forbidden, avoid_lava=avoid_lava)
    if extras is not None and not isinstance(extras.constraint, DoorConstraint):
        passable = passable & ~(jnp.any(extras.monitor.zone, 0) & obey_constraint)
    # Field 0 leads to the goal, field 1 to a key (used when the goal is out of reach).
    targets = jnp.stack([kind == GOAL, kind == KEY])
    dist = distance_field(targets, jnp.broadcast_to(passable, targets.shape))

    width, height = kind.shape
    x, y = state.agent_pos[0], state.agent_pos[1]
    inf = _unreachable((width, height))
    goal_reachable = dist[0, x, y] < inf
    field = jnp.where(goal_reachable, dist[0], dist[1])

    # Distances of the four neighbours (index = direction), unreachable outside the grid.
    nbr = state.agent_pos[None, :] + jnp.asarray(DIR_TO_VEC)  # (4, 2)
    inside = (nbr[:, 0] >= 0) & (nbr[:, 0] < width) & (nbr[:, 1] >= 0) & (nbr[:, 1] < height)
    nx = jnp.clip(nbr[:, 0], 0, width - 1)
    ny = jnp.clip(nbr[:, 1], 0, height - 1)
    nd = jnp.where(inside, field[nx, ny], inf)

    # Best direction: smallest distance, then fewest turns (0, 1 or 2) from the current one.
    rel = (jnp.arange(4) - state.agent_dir) % 4  # 1 = one right turn, 3 = one left turn
    turns = jnp.minimum(rel, 4 - rel)
    best = jnp.argmin(nd * 4 + turns)
    rel_best = rel[best]

    front = get_cell(grid, front_pos(state))
    closed_door = (front[0] == DOOR) & (front[2] != OPEN)
    act_ahead = jnp.where(front[0] == KEY, PICKUP, jnp.where(closed_door, TOGGLE, FORWARD))
    return jnp.where(rel_best == 0, act_ahead, jnp.where(rel_best == 1, RIGHT, LEFT)).astype(
        jnp.int32
    )


def rollout_oracle(
    env,
    key: jax.Array,
    num_episodes: int,
    max_steps: int | None = None,
    *,
    obey_constraint: bool = True,
    avoid_lava: bool = True,
) -> dict[str, jax.Array]:
    """Run ``num_episodes`` oracle episodes (one each, no auto-reset) in parallel.

    Resets are ``vmap``-ed from ``jax.random.split(key, num_episodes)`` (so the layouts equal
    ``jax.vmap(env.reset)`` of the same keys); then the oracle and the raw ``env.step`` run in
    a ``lax.while_loop`` that stops once every episode is done or after ``max_steps`` steps
    (default ``env.max_steps``). Steps after an episode's end are masked out. Returns arrays
    of shape ``(num_episodes,)``:

    * ``success``: bool, the episode reached the goal (positive reward);
    * ``violations``: int32, steps whose ``info["violation"]`` was set (0 if there is none);
    * ``length``: int32, steps taken until the episode ended (``max_steps`` if it did not);
    * ``done``: bool, the episode terminated or was truncated within ``max_steps``;
    * ``constraint_type``: int32, paper type 1-5 (0 for envs without a constraint); for a
      HazardRooms constraint, its index in :data:`jaxgrid.language.CONSTRAINT_TYPES`;
    * ``door_colour`` and ``forbids_lava``: the episode's constraint (-1 / False if none).

    The loop is jitted once per environment configuration, episode count and horizon; the
    oracle flags are traced, so constrained and unconstrained runs share one compilation.
    """
    horizon = env.max_steps if max_steps is None else int(max_steps)
    return _rollout(
        env,
        key,
        jnp.asarray(obey_constraint),
        jnp.asarray(avoid_lava),
        num_episodes=int(num_episodes),
        horizon=horizon,
    )


@functools.partial(jax.jit, static_argnames=("num_episodes", "horizon"))
def _rollout(env, key, obey_constraint, avoid_lava, *, num_episodes, horizon):
    # ``env`` is a pytree: its static configuration keys the compilation cache.
    states, _ = jax.vmap(env.reset)(jax.random.split(key, num_episodes))
    policy = jax.vmap(
        lambda s: oracle_action(s, obey_constraint=obey_constraint, avoid_lava=avoid_lava)
    )
    zeros_b = jnp.zeros((num_episodes,), bool)
    zeros_i = jnp.zeros((num_episodes,), jnp.int32)

    def cond(carry):
        t, _, done, *_ = carry
        return (t < horizon) & ~jnp.all(done)

    def body(carry):
        t, states, done, success, violations, length = carry
        states, ts = jax.vmap(env.step)(states, policy(states))
        active = ~done
        violation = ts.info.get("violation", zeros_b)
        success = success | (active & (ts.reward > 0))
        violations = violations + (active & violation).astype(jnp.int32)
        length = length + active.astype(jnp.int32)
        done = done | ts.terminated | ts.truncated
        return t + 1, states, done, success, violations, length

    carry = (0, states, zeros_b, zeros_b, zeros_i, zeros_i)
    _, states, done, success, violations, length = lax.while_loop(cond, body, carry)
    extras = states.extras
    if not isinstance(extras, ConstrainedExtras):
        ctype, colour, lava = zeros_i, zeros_i - 1, zeros_b
    elif not isinstance(extras.constraint, DoorConstraint):  # a rich constraint: its type id
        ctype, colour, lava = extras.constraint.type_id, zeros_i - 1, zeros_b
    else:
        c = extras.constraint
        ctype, colour, lava = c.type_id, c.door_colour, M.mentions(extras.monitor.spec, LAVA)
    return {
        "success": success,
        "violations": violations,
        "length": length,
        "done": done,
        "constraint_type": ctype,
        "door_colour": colour,
        "forbids_lava": lava,
    }
