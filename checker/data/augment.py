"""Augmentations of checker datasets: rows whose labels are known exactly without a rollout.

* :func:`with_colour_counterfactuals`: positives under a sentence naming another door colour,
  negatives (the checker must read the sentence);
* :func:`with_blocked_counterfactuals`: positives whose cell in front shows what cannot be
  entered, negatives (an open door is not a key or a locked door);
* :func:`with_distractors`: copies with objects no constraint names strewn about, same labels.

Each refuses a lookahead at which its labels would not stay exact.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from checker.data.files import CORE, CheckerDataset
from jaxgrid import language, sentences
from jaxgrid.constants import BALL, BOX, CLOSED, COLOR_NAMES, DOOR, EMPTY, KEY, LOCKED
from jaxgrid.observation import see_behind, visibility_mask

_PORTABLE = (KEY, BALL, BOX)  # no constraint names them


def front_cells(windows: np.ndarray) -> np.ndarray:
    """The cell in front of the agent in each window's last frame: a ``(N, 3)`` view of
    ``windows`` ``(N, window, V, V, 3)`` (the agent sits at ``(V // 2, V - 1)``, facing up), so
    assigning to it edits the windows."""
    v = windows.shape[2]
    return windows[:, -1, v // 2, v - 2]


def before_step(dataset: CheckerDataset) -> np.ndarray | None:
    """bool ``(N,)``: the rows whose window ends before the step their label judges (every
    row without final windows; with them, the rows ``extras["final"]`` does not mark), or
    ``None`` for a final-windows dataset that does not record which rows are final."""
    if not dataset.meta.get("final_windows", False):
        return np.ones(len(dataset), bool)
    if "final" not in dataset.extras:
        return None
    return ~np.asarray(dataset.extras["final"], bool)


def with_colour_counterfactuals(
    dataset: CheckerDataset, per_positive: int = 1, seed: int = 0, lava: bool = False
) -> CheckerDataset:
    """``dataset`` plus, for each door-only positive, ``per_positive`` recoloured negatives.

    A positive window of a door-only constraint ("do not use the red door") precedes the
    agent entering a door of the named colour. The same window under the same template naming
    another door colour precedes no violation: the monitor, relabelling the window for that
    sentence, says 0 (within a lookahead of 0 or 1 steps the agent enters at most one door).
    Rollout data rarely holds such windows otherwise (the behaviour agent seldom walks
    through a permitted door while its window looks like a forbidden one), and without them
    a checker can learn to ignore the sentence and alarm in front of every door (the
    measurement is in ``docs/decisions.md``).

    With ``lava``, door-and-lava positives are recoloured too, where the violation is the
    door: with lookahead 1, when the cell in front (last frame) of a window that ends before
    its step (not a final window, :func:`before_step`) is a door of the named colour, the next
    step enters that door and not lava. Without these copies a TwoRooms-Lava checker alarmed
    on 10% of the windows facing a permitted open door under door-and-lava sentences
    (``docs/decisions.md``).

    The new colour is drawn among the (template, colour) combinations of the dataset's
    language split (``meta["split"]``), so the held-out combinations stay unseen. Rows are
    appended in a seeded random order; ``meta["counterfactual_negatives"]`` counts them.
    Raises ``ValueError`` for ``per_positive < 0`` or a lookahead above 1, where the
    relabelling would not be exact.
    """
    if not isinstance(per_positive, int | np.integer) or per_positive < 0:
        raise ValueError(f"per_positive must be an int >= 0, got {per_positive!r}")
    lookahead = dataset.meta.get("lookahead", 1)
    if lookahead > 1:
        raise ValueError(
            f"colour counterfactuals need lookahead 0 or 1 (exact relabelling), got {lookahead}"
        )
    split = dataset.meta.get("split") or "all"
    combos = sentences.split_combinations(split)
    by_template: dict[int, list[str]] = {}
    for t, c in combos:
        by_template.setdefault(t, []).append(c)
    colour_ids = {language.VOCAB.index(c): c for c in language.COLOURS}
    # The door the agent faces in each window's last frame (colour -1: no door).
    front = front_cells(dataset.windows).astype(np.int64)
    door_ahead = np.where(front[:, 0] == DOOR, front[:, 1], -1)
    ahead = before_step(dataset) if lava and lookahead == 1 else None
    if ahead is None:  # no door-and-lava copy would be exact
        ahead = np.zeros(len(dataset), bool)
    rng = np.random.default_rng(seed)
    rows, tokens = [], []
    for r in np.flatnonzero(dataset.labels > 0):
        t = int(dataset.template_id[r])
        if t < 0:
            continue
        named = [colour_ids[i] for i in dataset.tokens[r] if i in colour_ids]
        others = [c for c in by_template.get(t, []) if c not in named]
        if len(named) != 1 or not others:
            continue
        if sentences.TEMPLATES[t].has_lava and not (
            ahead[r] and door_ahead[r] == COLOR_NAMES.index(named[0])
        ):
            continue
        for c in rng.choice(others, size=min(per_positive, len(others)), replace=False):
            rows.append(r)
            tokens.append(sentences.PAPER.tokenize(sentences.render(t, str(c))))
    if not rows:
        return dataset
    rows = np.asarray(rows)
    extra = dataset.subset(rows)
    extra.tokens = np.stack(tokens).astype(dataset.tokens.dtype)
    extra.labels = np.zeros_like(extra.labels)
    return _append(dataset, extra, rng, "counterfactual_negatives")


def _append(dataset: CheckerDataset, extra: CheckerDataset, rng, counter: str) -> CheckerDataset:
    """``dataset`` and ``extra`` shuffled together; ``meta[counter]`` counts added rows."""
    order = rng.permutation(len(dataset) + len(extra))
    merged = {
        name: np.concatenate([getattr(dataset, name), getattr(extra, name)])[order] for name in CORE
    }
    extras = {k: np.concatenate([v, extra.extras[k]])[order] for k, v in dataset.extras.items()}
    out = CheckerDataset(**merged, extras=extras, meta=dict(dataset.meta))
    return out.counted(**{counter: len(extra) + int(dataset.meta.get(counter, 0))})


def with_blocked_counterfactuals(
    dataset: CheckerDataset, per_positive: int = 1, seed: int = 0
) -> CheckerDataset:
    """``dataset`` plus, for each positive, ``per_positive`` negatives whose way is blocked.

    With lookahead 1 a positive window precedes a step that enters the cell in front of the
    agent (a forbidden door, or lava): only moving forward enters a cell. The same window with
    that cell of its last frame shown as a key, ball or box, or as a locked door (half of the
    rows each; any colour), precedes no violation: nothing steps onto a portable object, and
    a locked door opens before it is entered. A locked door hides what is behind it, so the
    frame's hidden cells are recomputed (MiniGrid's ``process_vis``); the window is one the
    env can show. Doors-only rollouts never show a key or a locked door where a forbidden
    door would be, and a checker trained without such windows can take either for the door
    (the measurement is in ``docs/decisions.md``). ``meta["blocked_negatives"]`` counts the
    rows. Final windows' positives already entered the cell and get no copy. Raises
    ``ValueError`` for ``per_positive < 0``, a lookahead other than 1, or a dataset with final
    windows that does not say which rows are final (:func:`before_step`).
    """
    if not isinstance(per_positive, int | np.integer) or per_positive < 0:
        raise ValueError(f"per_positive must be an int >= 0, got {per_positive!r}")
    if dataset.meta.get("lookahead", 1) != 1:
        raise ValueError(
            f"blocked counterfactuals need lookahead 1, got {dataset.meta['lookahead']}"
        )
    ahead = before_step(dataset)
    if ahead is None:
        raise ValueError("blocked counterfactuals need to know which rows are final windows "
                         "(extras['final'], recorded by collect)")  # fmt: skip
    rows = np.repeat(np.flatnonzero((dataset.labels > 0) & ahead), per_positive)
    if len(rows) == 0:
        return dataset
    rng = np.random.default_rng(seed)
    n = len(rows)
    extra = dataset.subset(rows)
    w = extra.windows.copy()  # (N, window, V, V, 3)
    v = w.shape[2]
    lock = rng.random(n) < 0.5
    kind = np.where(lock, DOOR, rng.choice(_PORTABLE, n))
    front_cells(w)[:] = np.stack([kind, rng.integers(0, len(COLOR_NAMES), n),
                                  np.where(lock, LOCKED, 0)], -1)  # fmt: skip
    # Hidden cells (all zero) stay hidden and pass no light on; the agent's cell (which shows
    # what it carries) is where light starts, whatever it holds.
    last = w[:, -1]
    clear = np.asarray(see_behind(last)) & (last[..., 0] != 0)
    clear[:, v // 2, v - 1] = True
    seen = np.asarray(jax.vmap(visibility_mask)(jnp.asarray(clear)))
    w[:, -1] = np.where(seen[..., None], last, 0)
    extra.windows = w.astype(dataset.windows.dtype)
    extra.labels = np.zeros_like(extra.labels)
    return _append(dataset, extra, rng, "blocked_negatives")


def with_distractors(
    dataset: CheckerDataset, fraction: float = 0.5, cell_rate: float = 0.1, seed: int = 0
) -> CheckerDataset:
    """``dataset`` plus noisy copies of a ``fraction`` of its rows, with the same labels.

    In a copy, each empty cell of each frame becomes, with probability
    ``cell_rate``, a key, ball or box of a random colour, and in half of the copies the agent's
    own cell shows it carrying one (the same object through the window). The constraint
    language only names doors and lava, so such objects never change whether a violation
    follows, and the copies keep their labels. A checker trained on TwoRooms alone never sees
    a key: on ThreeRooms-Key it alarmed on 8% of the steps facing the key, with a median
    probability of 0.92, which taught its agents not to pick the key up.
    ``meta["distractor_rows"]`` counts the copies. Raises ``ValueError`` for a fraction or a
    rate outside [0, 1], or a lookahead above 1: further ahead, an object on the agent's path
    or a locked door could stop a violation the label promises.
    """
    for name, value in (("fraction", fraction), ("cell_rate", cell_rate)):
        if not 0 <= value <= 1:
            raise ValueError(f"{name} must be in [0, 1], got {value!r}")
    if dataset.meta.get("lookahead", 1) > 1:
        raise ValueError(
            f"distractors need lookahead 0 or 1 (exact labels), got {dataset.meta['lookahead']}"
        )
    rng = np.random.default_rng(seed)
    rows = np.flatnonzero(rng.random(len(dataset)) < fraction)
    if len(rows) == 0:
        return dataset
    extra = dataset.subset(rows)
    w = extra.windows.copy()  # (N, window, V, V, 3)
    objects = rng.choice(_PORTABLE, size=w.shape[:-1])
    colours = rng.integers(0, len(COLOR_NAMES), size=w.shape[:-1])
    noisy = (w[..., 0] == EMPTY) & (rng.random(w.shape[:-1]) < cell_rate)
    w[..., 0] = np.where(noisy, objects, w[..., 0])
    w[..., 1] = np.where(noisy, colours, w[..., 1])
    w[..., 2] = np.where(noisy, 0, w[..., 2])
    v = w.shape[2]
    carry = rng.random(len(rows)) < 0.5
    held = np.stack([rng.choice(_PORTABLE, len(rows)), rng.integers(0, len(COLOR_NAMES), len(rows)),
                     np.zeros(len(rows), int)], -1)  # fmt: skip
    agent = w[:, :, v // 2, v - 1]  # (N, window, 3)
    empty_handed = agent[..., 0] == EMPTY  # frames where the agent carries nothing
    put = carry[:, None] & empty_handed
    w[:, :, v // 2, v - 1] = np.where(put[..., None], held[:, None, :], agent)
    # Closed doors shown locked in half of the copies: neither can be entered on the next
    # step, so the labels stay exact for lookaheads 0 and 1.
    closed = (w[..., 0] == DOOR) & (w[..., 2] == CLOSED)
    lock = (rng.random(len(rows)) < 0.5)[:, None, None, None] & closed
    w[..., 2] = np.where(lock, LOCKED, w[..., 2])
    extra.windows = w.astype(dataset.windows.dtype)
    return _append(dataset, extra, rng, "distractor_rows")
