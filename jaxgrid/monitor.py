"""The exact monitor of :mod:`jaxgrid.language` constraints: a jittable state machine.

It is the single judge of every constrained environment (the paper's scenarios, HazardRooms):
an environment keeps a :class:`Monitor` in its state and reports what :func:`update` returns.

A constraint is encoded once on the host (:func:`encode`) into a :class:`ClauseSpec` of small
integer arrays, one entry per clause slot (:data:`NUM_CLAUSES`; a one-clause constraint leaves
the second slot inactive). At the start of an episode :func:`start` turns the spec and the grid
into a :class:`Monitor`: the forbidden zone and the trigger cells of every clause as boolean
masks (targets are doors, lava and floor, which never move, so the masks hold for the whole
episode), a per-clause event counter and a per-clause "triggered" flag. :func:`update` then
advances it by one environment step and returns the step's cost and violation. Everything is
a handful of array lookups, so the monitor adds little to a vmapped step.

Rules (see :mod:`jaxgrid.language`): an event is the agent entering a cell of its
clause's zone; it is costly when the clause is armed (always, after its trigger, or before
it); a costly event is a violation once the clause's count exceeds its budget (0 for every
type but budget). A trigger updates its flag after the step's events are judged.
"""

from __future__ import annotations

from collections.abc import Iterable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxgrid.constants import BALL, BOX, COLOR_TO_IDX, DOOR, EMPTY, FLOOR, KEY, LAVA
from jaxgrid.language import MAX_BUDGET, MAX_DISTANCE, Clause, Constraint, Target, Trigger

__all__ = [
    "MAX_RADIUS", "NUM_CLAUSES", "ClauseSpec", "Monitor", "empty_slot", "encode", "encode_batch",
    "mentions", "start", "update", "zone_masks",
]  # fmt: skip

#: Clause slots per constraint: a sentence has one clause or two joined by "and".
NUM_CLAUSES = 2
#: Gates: when a clause's events count.
ALWAYS, AFTER, BEFORE = 0, 1, 2
_KINDS = {"door": DOOR, "lava": LAVA, "floor": FLOOR, "key": KEY, "ball": BALL, "box": BOX}
#: Zones reach distance - 1 cells out; zone_masks unrolls up to that many dilations.
MAX_RADIUS = MAX_DISTANCE - 1


@struct.dataclass
class ClauseSpec:
    """int32 arrays ``(..., NUM_CLAUSES)`` describing each clause slot.

    ``active`` (bool), ``target_kind`` / ``target_colour`` (MiniGrid indices; colour -1: any),
    ``radius`` (zone radius, Manhattan), ``budget`` (events allowed), ``gate`` (0 always,
    1 after the trigger, 2 before it), ``trigger_kind`` / ``trigger_colour`` (-1: none / any)
    and ``trigger_pickup`` (bool: picking the object up, else entering its cells).
    """

    active: jax.Array
    target_kind: jax.Array
    target_colour: jax.Array
    radius: jax.Array
    budget: jax.Array
    gate: jax.Array
    trigger_kind: jax.Array
    trigger_colour: jax.Array
    trigger_pickup: jax.Array


@struct.dataclass
class Monitor:
    """Per-episode monitor state; ``zone`` and ``trigger_cells`` are bool ``(C, W, H)``."""

    spec: ClauseSpec
    zone: jax.Array
    trigger_cells: jax.Array
    count: jax.Array  # int32 (C,): costly events so far
    triggered: jax.Array  # bool (C,): the trigger has happened


def _colour(colour: str | None) -> int:
    return -1 if colour is None else COLOR_TO_IDX[colour]


def _check_clause(c: Clause) -> None:
    """Raise ``ValueError`` for a count or distance the monitor would misrepresent: a zone
    wider than :func:`zone_masks` draws, or a negative budget (every event a violation)."""
    for name, value, high in (
        ("count", c.count, MAX_BUDGET),
        ("distance", c.distance, MAX_DISTANCE),
    ):
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= high:
            raise ValueError(f"clause {name} must be an int in 0..{high}, got {value!r}")


def _encode_clause(c: Clause | None) -> tuple:
    if c is None:
        return (False, -1, -1, 0, 0, ALWAYS, -1, -1, False)
    trig: Trigger | None = c.trigger
    if trig is None:
        tkind, tcolour, pickup = -1, -1, False
    elif trig.action == "pickup":
        tkind, tcolour, pickup = _KINDS[trig.kind], _colour(trig.colour), True
    else:
        tkind, tcolour, pickup = _KINDS[trig.target.kind], _colour(trig.target.colour), False
    gate = {None: ALWAYS, "after": AFTER, "before": BEFORE}[c.order]
    return (
        True,
        _KINDS[c.target.kind],
        _colour(c.target.colour),
        c.radius,
        c.count,
        gate,
        tkind,
        tcolour,
        pickup,
    )


def encode(constraint: Constraint | Clause | tuple) -> ClauseSpec:
    """Numpy :class:`ClauseSpec` of a constraint (or one clause, or a tuple of clauses).

    Raises ``ValueError`` for a clause count outside 0..MAX_BUDGET or a distance outside
    0..MAX_DISTANCE (a clause built by hand; parsed ones are always in range).
    """
    if isinstance(constraint, Constraint):
        clauses = constraint.clauses
    elif isinstance(constraint, Clause):
        clauses = (constraint,)
    else:
        clauses = tuple(constraint)
    if not 1 <= len(clauses) <= NUM_CLAUSES:
        raise ValueError(f"a constraint has 1 to {NUM_CLAUSES} clauses, got {len(clauses)}")
    for c in clauses:
        _check_clause(c)
    rows = [_encode_clause(c) for c in clauses] + [_encode_clause(None)] * (
        NUM_CLAUSES - len(clauses)
    )
    cols = list(zip(*rows, strict=True))
    bools = {0, 8}
    return ClauseSpec(
        *(np.array(col, bool if i in bools else np.int32) for i, col in enumerate(cols))
    )


def encode_batch(constraints: Iterable[Constraint]) -> ClauseSpec:
    """Numpy :class:`ClauseSpec` of ``(R, NUM_CLAUSES)`` arrays: row r encodes constraint r."""
    specs = [encode(c) for c in constraints]
    return jax.tree.map(lambda *xs: np.stack(xs), *specs)


def mentions(spec: ClauseSpec, kind: int) -> jax.Array:
    """bool ``(...)``: whether an active clause of ``spec`` (``(..., NUM_CLAUSES)``) targets
    cells of the MiniGrid object ``kind`` (e.g. whether a constraint forbids lava at all)."""
    return jnp.any(jnp.asarray(spec.active) & (jnp.asarray(spec.target_kind) == kind), axis=-1)


def empty_slot() -> ClauseSpec:
    """The encoding of an unused clause slot (numpy scalars)."""
    return jax.tree.map(lambda a: a[-1], encode(Clause("avoid", Target("lava"))))


def _cells(grid: jax.Array, kind: jax.Array, colour: jax.Array) -> jax.Array:
    return (grid[..., 0] == kind) & ((colour < 0) | (grid[..., 1] == colour))


def _dilate(mask: jax.Array) -> jax.Array:
    """``mask`` grown by one cell in the four directions."""
    pad = jnp.pad(mask, 1)
    return mask | pad[:-2, 1:-1] | pad[2:, 1:-1] | pad[1:-1, :-2] | pad[1:-1, 2:]


def zone_masks(
    grid: jax.Array, spec: ClauseSpec, max_radius: int = MAX_RADIUS
) -> tuple[jax.Array, jax.Array]:
    """bool ``(C, W, H)`` forbidden zones and enter-trigger cells of each clause slot.

    ``max_radius`` (static) bounds the zones' radius: a table whose clauses never grow their
    zone passes 0, so no dilation reads the grid at shifted cells (each such read makes XLA
    recompute the layout that produced the grid, in a reset that it fuses).
    """
    if not 0 <= max_radius <= MAX_RADIUS:
        raise ValueError(f"max_radius must be in 0..{MAX_RADIUS}, got {max_radius!r}")

    def one(kind, colour, radius, tkind, tcolour, pickup, active):
        zone = _cells(grid, kind, colour)
        for r in range(1, max_radius + 1):  # static and tiny
            zone = jnp.where(radius >= r, _dilate(zone), zone)
        trig = _cells(grid, tkind, tcolour) & ~pickup & (tkind >= 0)
        return zone & active, trig

    s = spec
    return jax.vmap(one)(
        s.target_kind, s.target_colour, s.radius, s.trigger_kind, s.trigger_colour,
        s.trigger_pickup, s.active,
    )  # fmt: skip


def start(spec: ClauseSpec, grid: jax.Array, max_radius: int = MAX_RADIUS) -> Monitor:
    """A fresh episode's monitor (no events counted, nothing triggered); ``max_radius`` as in
    :func:`zone_masks` (a clause of a larger radius would get a smaller zone)."""
    spec = jax.tree.map(jnp.asarray, spec)
    zone, trig = zone_masks(grid, spec, max_radius)
    return Monitor(
        spec=spec,
        zone=zone,
        trigger_cells=trig,
        count=jnp.zeros(spec.active.shape, jnp.int32),
        triggered=jnp.zeros(spec.active.shape, bool),
    )


def update(
    monitor: Monitor,
    pos_before: jax.Array,
    pos_after: jax.Array,
    carrying_before: jax.Array,
    carrying_after: jax.Array,
) -> tuple[Monitor, jax.Array, jax.Array]:
    """Advance by one step; returns ``(monitor, cost, violation)`` (float32, bool scalars).

    ``cost`` is 1 when any clause had a costly event this step; ``violation`` is True when any
    clause was violated.
    """
    s = monitor.spec
    moved = jnp.any(pos_after != pos_before)
    x, y = pos_after[0], pos_after[1]
    event = moved & monitor.zone[:, x, y]
    armed = jnp.where(
        s.gate == AFTER, monitor.triggered, jnp.where(s.gate == BEFORE, ~monitor.triggered, True)
    )
    costly = s.active & event & armed
    count = monitor.count + costly.astype(jnp.int32)
    violated = costly & (count > s.budget)
    picked = (
        (carrying_before[0] == EMPTY)
        & (carrying_after[0] == s.trigger_kind)
        & ((s.trigger_colour < 0) | (carrying_after[1] == s.trigger_colour))
    )
    fired = (moved & monitor.trigger_cells[:, x, y]) | (s.trigger_pickup & picked)
    monitor = monitor.replace(count=count, triggered=monitor.triggered | fired)
    return monitor, jnp.any(costly).astype(jnp.float32), jnp.any(violated)
