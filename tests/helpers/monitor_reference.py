"""References the jitted monitor is compared against, written from the rules in prose.

:class:`ReferenceMonitor` is a plain-Python monitor of language constraints: it reads a parsed
:class:`~jaxgrid.language.Constraint` (never the numeric encoding the jitted monitor uses) and
a grid as numpy, and judges one step at a time with Python loops, so the two implementations
share nothing but the parser. :func:`paper_rule_step` is the paper scenarios' rule stated
directly on the grid and the constraint's door colour: it shares neither the parser nor the
monitor.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxgrid import sentences
from jaxgrid.constants import COLOR_TO_IDX, DOOR, LAVA, OBJECT_TO_IDX
from jaxgrid.dynamics import get_cell, transition
from jaxgrid.environment import Environment


def _is_target(cell, target) -> bool:
    if cell[0] != OBJECT_TO_IDX[target.kind]:
        return False
    return target.colour is None or cell[1] == COLOR_TO_IDX[target.colour]


def _distance(grid: np.ndarray, pos, target) -> float:
    """Least Manhattan distance from ``pos`` to a target cell (inf without one)."""
    best = float("inf")
    for x in range(grid.shape[0]):
        for y in range(grid.shape[1]):
            if _is_target(grid[x, y], target):
                best = min(best, abs(x - pos[0]) + abs(y - pos[1]))
    return best


class ReferenceMonitor:
    """Judges steps of one episode; ``grid`` is the episode's first grid (uint8 W x H x 3)."""

    def __init__(self, constraint, grid: np.ndarray):
        self.clauses = constraint.clauses
        self.grid = np.asarray(grid)
        # Distance from every cell to each clause's nearest target cell, computed once.
        self.distance = [
            [[_distance(self.grid, (x, y), c.target) for y in range(self.grid.shape[1])]
             for x in range(self.grid.shape[0])]
            for c in self.clauses
        ]  # fmt: skip
        self.count = [0] * len(self.clauses)
        self.triggered = [False] * len(self.clauses)

    def _event(self, i, pos) -> bool:
        clause = self.clauses[i]
        if clause.type == "proximity":
            return self.distance[i][pos[0]][pos[1]] < clause.distance
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
