"""What a level's grids can hold, in the kinds the constraint language names.

A constraint (:mod:`jaxgrid.language`) names cells, doors of a colour, lava and floors of a
colour, and objects to pick up, keys, balls and boxes (of any colour or of one). Each level
declares what its episodes can ever hold (:meth:`jaxgrid.environment.Environment.contents`,
a :class:`Contents`), at reset or later (a key hidden in a box counts), so that a sentence
naming what the level never holds is refused by the word before anything compiles
(:meth:`Contents.check`), and a sentence table can be restricted to what it can say
(:meth:`Contents.allows`). A colour a level draws at random is declared even though some
episodes lack it: a constraint on it is then vacuous in those episodes.

The declaration is the level's own, never probed from its code; the tests compare it with
:meth:`Contents.of_grid` over many sampled resets of every registered id.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import numpy as np

from jaxgrid.constants import COLOR_NAMES, OBJECT_TO_IDX
from jaxgrid.language import Clause, Constraint, Target

__all__ = ["ALL_COLOURS", "KINDS", "NOTHING", "Contents"]

#: Every colour name, for a level that draws a kind's colour from all six.
ALL_COLOURS: frozenset[str] = frozenset(COLOR_NAMES)
#: The kinds the language names: cells (door, lava, floor) and objects (key, ball, box).
KINDS: tuple[str, ...] = ("door", "lava", "floor", "key", "ball", "box")
_COLOURED = ("door", "floor", "key", "ball", "box")


@dataclasses.dataclass(frozen=True)
class Contents:
    """The colours each kind can have in a level's episodes (empty: the kind never occurs),
    and whether lava can occur (lava has no colour in the language). Iterables of colour
    names are accepted and stored as frozensets, so a declaration is hashable."""

    door: frozenset[str] = frozenset()
    lava: bool = False
    floor: frozenset[str] = frozenset()
    key: frozenset[str] = frozenset()
    ball: frozenset[str] = frozenset()
    box: frozenset[str] = frozenset()

    def __post_init__(self):
        for kind in _COLOURED:
            value = getattr(self, kind)
            if isinstance(value, str):
                raise ValueError(f"Contents.{kind} takes colour names, got the string {value!r}")
            colours = frozenset(value)
            unknown = sorted(colours - ALL_COLOURS)
            if unknown:
                raise ValueError(
                    f"Contents.{kind}: unknown colour {unknown[0]!r}; colours: "
                    + ", ".join(COLOR_NAMES)
                )
            object.__setattr__(self, kind, colours)
        if not isinstance(self.lava, bool):
            raise ValueError(f"Contents.lava must be a bool, got {self.lava!r}")

    # --- queries ------------------------------------------------------------------------
    def colours(self, kind: str) -> frozenset[str]:
        """The colours ``kind`` can have here (lava: every colour when it can occur)."""
        if kind == "lava":
            return ALL_COLOURS if self.lava else frozenset()
        return getattr(self, kind)

    def has(self, kind: str, colour: str | None = None) -> bool:
        """Whether ``kind`` can occur here, in ``colour`` when one is given."""
        colours = self.colours(kind)
        return bool(colours) and (colour is None or colour in colours)

    def __or__(self, other: Contents) -> Contents:
        return Contents(
            lava=self.lava or other.lava,
            **{k: getattr(self, k) | getattr(other, k) for k in _COLOURED},
        )

    def __le__(self, other: Contents) -> bool:
        """Whether everything this can hold, ``other`` can hold too."""
        return (other.lava or not self.lava) and all(
            getattr(self, k) <= getattr(other, k) for k in _COLOURED
        )

    @property
    def empty(self) -> bool:
        """Whether nothing a constraint names can occur here."""
        return not any(self.colours(k) for k in KINDS)

    @property
    def constrainable(self) -> bool:
        """Whether a constraint can be said here: every clause names cells to enter (a door,
        lava or a floor); keys, balls and boxes only trigger."""
        return bool(self.door or self.lava or self.floor)

    def describe(self) -> str:
        """What a level holds, in words ("yellow doors, lava, yellow keys"; "nothing a
        constraint can name")."""
        parts = []
        for kind in KINDS:
            if kind == "lava":
                parts += ["lava"] if self.lava else []
            elif getattr(self, kind):
                colours = "/".join(c for c in COLOR_NAMES if c in getattr(self, kind))
                parts.append(f"{colours} {kind}{'es' if kind == 'box' else 's'}")
        return ", ".join(parts) or "nothing a constraint can name"

    # --- constraints ----------------------------------------------------------------------
    def _missing_target(self, target: Target) -> str | None:
        """The word naming what a target needs and this lacks, or None."""
        if not self.has(target.kind):
            return target.kind
        if target.colour is not None and not self.has(target.kind, target.colour):
            return target.colour
        return None

    def missing(self, constraint: Constraint | Clause) -> tuple[str, str] | None:
        """``(word, thing)``: the first word of ``constraint`` naming what this never holds
        (a kind, or a colour that kind never has) and the thing it names; None when it holds
        everything the constraint names."""
        clauses = constraint.clauses if isinstance(constraint, Constraint) else (constraint,)
        for clause in clauses:
            needs = [clause.target]
            trig = clause.trigger
            if trig is not None and trig.action == "enter":
                needs.append(trig.target)
            elif trig is not None:
                needs.append(Target(trig.kind, trig.colour))
            for t in needs:
                word = self._missing_target(t)
                if word is not None:
                    what = " ".join(["a"] * (t.kind != "lava") + [t.colour or "", t.kind])
                    what = " ".join(what.split())  # "lava", "a key", "a red door"
                    return word, what
        return None

    def allows(self, constraint: Constraint | Clause) -> bool:
        """Whether this holds everything ``constraint`` names."""
        return self.missing(constraint) is None

    def check(self, constraint: Constraint, where: str) -> None:
        """Raise ``ValueError`` naming the word of ``constraint`` that names what ``where`` (a
        level's name) never holds, and what it does hold."""
        found = self.missing(constraint)
        if found is not None:
            word, what = found
            raise ValueError(
                f"{constraint.sentence!r}: {where} never holds {what} (the word {word!r}); "
                f"it holds {self.describe()}"
            )

    # --- from a grid ----------------------------------------------------------------------
    @classmethod
    def of_grid(cls, grids: np.ndarray | Iterable) -> Contents:
        """What the cells of one or more grids (uint8 ``(..., 3)`` MiniGrid encodings, e.g. a
        batch of resets, or a carried object's triple) hold."""
        cells = np.asarray(grids).reshape(-1, 3)
        kinds, colours = cells[:, 0], cells[:, 1]
        found = {}
        for kind in _COLOURED:
            hit = np.unique(colours[kinds == OBJECT_TO_IDX[kind]])
            found[kind] = frozenset(COLOR_NAMES[int(c)] for c in hit)
        return cls(lava=bool(np.any(kinds == OBJECT_TO_IDX["lava"])), **found)


#: A level with nothing a constraint names (the default declaration).
NOTHING = Contents()
