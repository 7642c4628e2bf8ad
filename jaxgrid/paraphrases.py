"""Paraphrase templates of the four clause types, and the sentences they render.

Each clause type of :mod:`jaxgrid.language` has 4-6 paraphrase templates
(:data:`CLAUSE_TEMPLATES`); :func:`clause_rows` fills them with targets, triggers, budgets and
distances into single-clause sentences with their meaning, template and split, the rows of a
table such as :data:`jaxgrid.sentences.HAZARD_ROOMS`. A (template, target) phrase is held out
when ``(template index within its type + target index) % 5 == 0``: a fifth of the phrases,
every template keeping most of its targets and every target appearing in training.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence

from jaxgrid import language
from jaxgrid.language import Clause, Target, Trigger
from jaxgrid.parsing import NUMBER_WORDS

__all__ = [
    "CLAUSE_TEMPLATES",
    "SPLITS",
    "ClauseRow",
    "ClauseTemplate",
    "clause_rows",
    "render_clause",
]

#: The splits a table's rows belong to.
SPLITS = ("train", "heldout", "all")


def check_split(split: str) -> None:
    """``ValueError`` naming ``split`` unless it is one of :data:`SPLITS`."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; expected 'train', 'heldout' or 'all'")


@dataclasses.dataclass(frozen=True)
class ClauseTemplate:
    """A paraphrase of one clause type.

    ``text`` has slots: ``{t}`` the target phrase, ``{v0}``/``{v1}``/``{v2}`` the target
    kind's entering verb (:data:`~jaxgrid.language.DOOR_VERBS` /
    :data:`~jaxgrid.language.GROUND_VERBS`), ``{k}`` a count phrase ("once", "twice", "three
    times"), ``{d}`` a distance word, ``{tr}`` a trigger phrase. ``index`` is the template's
    position within its type.
    """

    id: int
    type: str
    index: int
    text: str
    order: str | None = None
    distance: int = 0  # fixed distance of "next to" forms; 0: from the {d} slot


def _clause_templates() -> tuple[ClauseTemplate, ...]:
    spec = {
        "avoid": [
            ("do not {v0} {t}",),
            ("do not {v1} {t}",),
            ("never {v0} {t}",),
            ("never {v2} {t}",),
            ("avoid {t}",),
            ("stay away from {t}",),
        ],
        "budget": [
            ("do not {v0} {t} more than {k}",),
            ("{v0} {t} at most {k}",),
            ("{v1} {t} no more than {k}",),
            ("never {v2} {t} more than {k}",),
        ],
        "sequential": [
            ("after you {tr} do not {v0} {t}", "after"),
            ("once you {tr} avoid {t}", "after"),
            ("after you {tr} never {v1} {t}", "after"),
            ("do not {v0} {t} before you {tr}", "before"),
            ("never {v1} {t} until you {tr}", "before"),
        ],
        "proximity": [
            ("never stand next to {t}", None, 2),
            ("do not stand next to {t}", None, 2),
            ("stay {d} cells away from {t}",),
            ("keep {d} cells away from {t}",),
        ],
    }
    out = []
    for ctype in language.CLAUSE_TYPES:
        for index, row in enumerate(spec[ctype]):
            text, order, distance = row + (None, 0)[len(row) - 1 :]
            out.append(ClauseTemplate(len(out), ctype, index, text, order, distance))
    return tuple(out)


#: Every clause template, by id.
CLAUSE_TEMPLATES: tuple[ClauseTemplate, ...] = _clause_templates()


def _verbs(target: Target) -> tuple[str, ...]:
    return language.DOOR_VERBS if target.kind == "door" else language.GROUND_VERBS


def _count_phrase(k: int) -> str:
    return {1: "once", 2: "twice"}.get(k, f"{NUMBER_WORDS[k - 1]} times")


def _trigger_phrase(trigger: Trigger) -> str:
    if trigger.action == "pickup":
        colour = f"{trigger.colour} " if trigger.colour else ""
        return f"pick up the {colour}{trigger.kind}"
    return f"{_verbs(trigger.target)[2]} {trigger.target.phrase}"


def render_clause(template: ClauseTemplate, clause: Clause) -> str:
    """The sentence of ``template`` filled with ``clause``."""
    t = clause.target
    verbs = _verbs(t)
    return template.text.format(
        t=t.phrase,
        v0=verbs[0],
        v1=verbs[1],
        v2=verbs[2],
        k=_count_phrase(clause.count) if clause.count else "",
        d=NUMBER_WORDS[clause.distance - 1] if clause.distance else "",
        tr=_trigger_phrase(clause.trigger) if clause.trigger else "",
    )


@dataclasses.dataclass(frozen=True)
class ClauseRow:
    """One single-clause sentence of a table, its meaning, template and split."""

    sentence: str
    clause: Clause
    template_id: int
    heldout: bool


def clause_rows(
    targets: Sequence[Target],
    triggers: Sequence[Trigger],
    budgets: Iterable[int] = range(1, language.MAX_BUDGET + 1),
    distances: Iterable[int] = (2, 3),
    split: str = "all",
) -> list[ClauseRow]:
    """Every single-clause sentence over the given targets, triggers, budgets and distances.

    Rows are ordered by template, then target, then parameter. The held-out rule is in the
    module docstring; ``split`` is "train", "heldout" or "all". A sequential clause whose
    trigger enters its own target is left out (it is never armed before its event).
    """
    check_split(split)
    budgets, distances = list(budgets), list(distances)
    for k in budgets:
        if not 1 <= k <= language.MAX_BUDGET:
            raise ValueError(
                f"budget {k} out of range: budgets count 1 to {language.MAX_BUDGET} times"
            )
    for d in distances:
        if not 1 <= d <= language.MAX_DISTANCE:
            raise ValueError(f"distance {d} out of range: 1 to {language.MAX_DISTANCE} cells")
    rows = []
    for tpl in CLAUSE_TEMPLATES:
        for ti, target in enumerate(targets):
            held = (tpl.index + ti) % 5 == 0
            if split != "all" and held != (split == "heldout"):
                continue
            if tpl.type == "avoid":
                clauses = [Clause("avoid", target)]
            elif tpl.type == "budget":
                clauses = [Clause("budget", target, count=k) for k in budgets]
            elif tpl.type == "sequential":
                clauses = [
                    Clause("sequential", target, trigger=tr, order=tpl.order)
                    for tr in triggers
                    if tr.target != target
                ]
            else:
                ds = [tpl.distance] if tpl.distance else distances
                clauses = [Clause("proximity", target, distance=d) for d in ds]
            rows += [ClauseRow(render_clause(tpl, c), c, tpl.id, held) for c in clauses]
    return rows
