"""References the jitted monitor is compared against, written from the rules in prose.

:class:`ReferenceMonitor` is a plain-Python monitor of language constraints: it reads a parsed
:class:`~jaxgrid.language.Constraint` (never the numeric encoding the jitted monitor uses) and
a grid as numpy, and judges one step at a time with Python loops, so the two implementations
share nothing but the parser. :func:`paper_rule_step` is the paper scenarios' rule stated
directly on the grid and the constraint's door colour: it shares neither the parser nor the
monitor. :func:`play` records a batch of random episodes of any constrained environment and
:func:`compare` judges every step of them with :class:`ReferenceMonitor` (HazardRooms and the
constrained MiniGrid levels alike).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrid import language as L
from jaxgrid import sentences
from jaxgrid.constants import COLOR_TO_IDX, DOOR, FLOOR, LAVA, OBJECT_TO_IDX
from jaxgrid.dynamics import get_cell, transition
from jaxgrid.environment import Environment


def _is_target(cell, target) -> bool:
    if cell[0] != OBJECT_TO_IDX[target.kind]:
        return False
    return target.colour is None or cell[1] == COLOR_TO_IDX[target.colour]


def _target_cells(grid: np.ndarray, target) -> list[tuple[int, int]]:
    return [(x, y) for x in range(grid.shape[0]) for y in range(grid.shape[1])
            if _is_target(grid[x, y], target)]  # fmt: skip


class ReferenceMonitor:
    """Judges steps of one episode; ``grid`` is the episode's first grid (uint8 W x H x 3)."""

    def __init__(self, constraint, grid: np.ndarray):
        self.clauses = constraint.clauses
        self.grid = np.asarray(grid)
        # Each clause's target cells, found once; distances to them are taken where asked.
        self.targets = [_target_cells(self.grid, c.target) for c in self.clauses]
        self.count = [0] * len(self.clauses)
        self.triggered = [False] * len(self.clauses)

    def _event(self, i, pos) -> bool:
        clause = self.clauses[i]
        if clause.type == "proximity":
            near = (abs(x - pos[0]) + abs(y - pos[1]) for x, y in self.targets[i])
            return min(near, default=float("inf")) < clause.distance
        return _is_target(self.grid[pos[0], pos[1]], clause.target)

    def _trigger(self, trig, moved, pos, carrying_before, carrying_after) -> bool:
        if trig is None:
            return False
        if trig.action == "enter":
            return moved and _is_target(self.grid[pos[0], pos[1]], trig.target)
        picked = carrying_before[0] == OBJECT_TO_IDX["empty"] and (
            carrying_after[0] == OBJECT_TO_IDX[trig.kind]
        )
        colour_ok = trig.colour is None or carrying_after[1] == COLOR_TO_IDX[trig.colour]
        return bool(picked and colour_ok)

    def step(self, pos_before, pos_after, carrying_before, carrying_after) -> tuple[float, bool]:
        """``(cost, violation)`` of one step."""
        moved = tuple(pos_before) != tuple(pos_after)
        cost, violation = 0.0, False
        for i, c in enumerate(self.clauses):
            event = moved and self._event(i, pos_after)
            if c.order == "after":
                armed = self.triggered[i]
            elif c.order == "before":
                armed = not self.triggered[i]
            else:
                armed = True
            if event and armed:
                cost = 1.0
                self.count[i] += 1
                if self.count[i] > c.count:
                    violation = True
            if self._trigger(c.trigger, moved, pos_after, carrying_before, carrying_after):
                self.triggered[i] = True
        return cost, violation


def paper_rule_step(env, state, action) -> dict:
    """One step of a paper scenario by the paper's rule, written without the monitor: the
    step's ``observation``, ``reward``, ``terminated``, ``truncated``, ``info`` and the agent's
    ``agent_pos``, and whether it ``teleported``. JAX, vmappable.

    The rule: a violation is the agent entering a door of the forbidden colour (the
    constraint's ``door_colour``), or lava when the sentence has a lava clause (its template's,
    from the paper's table); lava not forbidden teleports the agent next to the goal and does
    not end the episode. It reads neither the monitor nor the parsed sentence.
    """
    c = state.extras.constraint
    has_lava = np.array([t.has_lava for t in sentences.TEMPLATES])
    forbids_lava = jnp.asarray(has_lava)[c.template_id]
    new, reward, terminated, truncated = transition(state, action, env.max_steps)
    entered = jnp.any(new.agent_pos != state.agent_pos)
    cell = get_cell(new.grid, new.agent_pos)
    into_lava = entered & (cell[0] == LAVA)
    door = entered & (cell[0] == DOOR) & (cell[1] == c.door_colour)
    violation = door | (into_lava & forbids_lava)
    teleport = into_lava & ~forbids_lava
    new = new.replace(agent_pos=jnp.where(teleport, state.extras.teleport_pos, new.agent_pos))
    paper_type = jnp.asarray([t.paper_type for t in sentences.TEMPLATES])[c.template_id]
    return {
        "observation": {**Environment.observe(env, new), "constraint": c.tokens},
        "reward": reward,
        "terminated": terminated & ~teleport,
        "truncated": truncated,
        "info": {
            "violation": violation,
            "cost": violation.astype(jnp.float32),
            "constraint_type": paper_type,
            "template_id": c.template_id,
        },
        "agent_pos": new.agent_pos,
        "teleported": teleport,
    }


# left, right, forward, pickup, drop, toggle: forward-heavy so agents travel and pass doors.
ACTION_PROBS = np.array([0.12, 0.12, 0.56, 0.06, 0.04, 0.10])


def _targets(grid: jax.Array) -> jax.Array:
    """The cells a constraint can name (door, lava and floor kinds and colours): fixed for an
    episode, which the jitted monitor relies on and :func:`play` checks."""
    kind = grid[..., 0]
    named = (kind == DOOR) | (kind == LAVA) | (kind == FLOOR)
    return jnp.where(named[..., None], grid[..., :2], 0)


@functools.partial(jax.jit, static_argnames=("env", "n", "steps"))
def play(env, key, n: int, steps: int | None = None):
    """``n`` random episodes of ``env`` (one each, no auto-reset) for ``steps`` steps (default
    ``env.max_steps``): the first states and, per step and env, what the reference reads
    (positions, hands), the env's ``cost`` and ``violation``, whether the episode is still
    on, and whether the nameable cells are still those of the first grid."""
    k_reset, k_act = jax.random.split(key)
    states, _ = jax.vmap(env.reset)(jax.random.split(k_reset, n))
    first = states
    targets0 = jax.vmap(_targets)(states.grid)

    def body(carry, k):
        states, done = carry
        actions = jax.random.choice(k, 6, (n,), p=jnp.asarray(ACTION_PROBS))
        new, ts = jax.vmap(env.step)(states, actions)
        out = {
            "pos_before": states.agent_pos,
            "pos_after": new.agent_pos,
            "carrying_before": states.carrying,
            "carrying_after": new.carrying,
            "cost": ts.info["cost"],
            "violation": ts.info["violation"],
            "active": ~done,
            "targets_kept": jnp.all(jax.vmap(_targets)(new.grid) == targets0, axis=(1, 2, 3)),
        }
        return (new, done | ts.terminated | ts.truncated), out

    keys = jax.random.split(k_act, env.max_steps if steps is None else steps)
    _, out = jax.lax.scan(body, (states, jnp.zeros((n,), bool)), keys)
    return first, out


def compare(env, seed: int, n: int, steps: int | None = None):
    """Judge every step of :func:`play`'s episodes with :class:`ReferenceMonitor` from the
    first grid and the states, and assert it agrees with the env's ``cost`` and
    ``violation``. Returns the number of steps judged per
    :data:`~jaxgrid.language.CONSTRAINT_TYPES` type and the recorded steps."""
    first, out = play(env, jax.random.key(seed), n, steps)
    first, out = jax.tree.map(np.asarray, (first.replace(key=None), out))
    assert out["targets_kept"][out["active"]].all(), "a nameable cell changed in an episode"
    counted = np.zeros(len(L.CONSTRAINT_TYPES), int)
    for e in range(n):
        sentence = L.detokenize(first.extras.constraint.tokens[e])
        constraint = L.parse(sentence)
        ref = ReferenceMonitor(constraint, first.grid[e])
        for t in range(out["active"].shape[0]):
            if not out["active"][t, e]:
                break
            cost, violation = ref.step(
                out["pos_before"][t, e], out["pos_after"][t, e],
                out["carrying_before"][t, e], out["carrying_after"][t, e],
            )  # fmt: skip
            got = (float(out["cost"][t, e]), bool(out["violation"][t, e]))
            assert got == (cost, violation), (sentence, e, t)
            counted[constraint.type_id] += 1
    return counted, out
