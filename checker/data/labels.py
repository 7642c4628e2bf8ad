"""Labels of checker data: what a window, or a frame of a stream, says about violations.

Within one episode, ``obs_t`` is the observation after step ``t`` (``obs_0`` after reset) and
``v_t`` is ``info["violation"]`` of the step that produced ``obs_t`` (``v_0 = 0``). The window
ending at ``obs_t`` is labelled

* ``lookahead = k >= 1`` ("just before", the paper): 1 iff ``v_{t+j} = 1`` for some
  ``j in 1..k``, counting only steps of the same episode; the step that ends the episode
  still counts (entering lethal lava is a violation on the final step), the steps of the
  next episode never do;
* ``lookahead = 0`` ("after", the ablation): 1 iff ``v_t = 1``.

Windows are only those PPO's ring buffer holds. The observation after an episode's final step
is replaced by the next episode's first one (``AutoReset``), so it never ends a window: with
``lookahead = 0`` a violation on a final step (lethal lava, or a door entered on the
truncation step) has no window and yields no positive, while with ``lookahead >= 1`` it
labels the windows before it as usual. Windows whose label horizon ``t+1..t+k`` runs past the
end of the collected rollout are dropped (the last ``k`` positions of every env).

The windows that end at an episode's final observation (:func:`final_labels`) are labelled by
the step that ended it, and full-episode datasets carry per-row episode bookkeeping
(:func:`episode_fields`, :data:`EPISODE_FIELDS`).

A memory checker's streams (:func:`checker.data.collect_streams`) label every frame by the
step out of it, ``lookahead`` 1; :func:`relabel` gives them lookahead 0, the step into it
(:data:`STREAM_LOOKAHEADS`).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

MAX_WINDOW = 64
#: The label timings of a stream (:func:`relabel`): 1, the step out of the frame violates (the
#: paper's just-before label); 0, the step into the frame violated.
STREAM_LOOKAHEADS = (0, 1)
EPISODE_FIELDS = (
    "env_index", "position", "episode", "step", "step_violation", "next_violation", "complete",
)  # fmt: skip


def validate_window(window: Any, lookahead: Any) -> None:
    """``ValueError`` naming the field unless ``1 <= window <= 64`` and ``0 <= lookahead <=
    4 * window`` (both ints)."""
    if not isinstance(window, (int, np.integer)) or isinstance(window, bool):
        raise ValueError(f"window must be an int, got {window!r}")
    if not 1 <= window <= MAX_WINDOW:
        raise ValueError(f"window must be in [1, {MAX_WINDOW}], got {window}")
    if not isinstance(lookahead, (int, np.integer)) or isinstance(lookahead, bool):
        raise ValueError(f"lookahead must be an int, got {lookahead!r}")
    if not 0 <= lookahead <= 4 * window:
        raise ValueError(
            f"lookahead must be in [0, 4 * window] = [0, {4 * window}] for window={window}, "
            f"got {lookahead}"
        )


def compute_labels(start: jax.Array, violation: jax.Array, lookahead: int):
    """Labels and eligibility of every stream position (time-major arrays ``(T, E)``).

    ``start[i]``: position ``i`` holds an episode's first observation (``True`` at 0 and
    after every ``terminated | truncated`` step); ``violation[i]``: the step into position
    ``i`` violated (it belongs to the episode of position ``i - 1``). Returns ``(labels,
    eligible)``, bool ``(T, E)``; see the module docstring.
    """
    start = jnp.asarray(start, bool)
    violation = jnp.asarray(violation, bool)
    t = start.shape[0]
    if lookahead == 0:
        return violation & ~start, jnp.ones_like(start)

    def shifted(x, j):  # x[i + j], False past the end
        return jnp.concatenate([x[j:], jnp.zeros((j,) + x.shape[1:], bool)], axis=0)

    labels = jnp.zeros_like(start)
    alive = jnp.ones_like(start)  # no episode start in positions i+1 .. i+j-1
    for j in range(1, lookahead + 1):
        labels = labels | (alive & shifted(violation, j))
        alive = alive & ~shifted(start, j)
    eligible = (jnp.arange(t) < t - lookahead)[:, None] & jnp.ones_like(start)
    return labels, eligible


def final_labels(start: jax.Array, violation: jax.Array):
    """Labels and eligibility (bool ``(T, E)``) of the windows that end at an episode's final
    observation: position ``i`` is eligible where a step ended an episode there (``start`` at
    ``i > 0``), and its label is that step's violation."""
    start = jnp.asarray(start, bool)
    ended = start & (jnp.arange(start.shape[0]) > 0)[:, None]
    return ended & jnp.asarray(violation, bool), ended


def all_labels(start, violation, lookahead: int, final_windows: bool):
    """The stream's labels and eligibility (:func:`compute_labels`), with the final windows'
    rows (:func:`final_labels`) after them."""
    labels, eligible = compute_labels(start, violation, lookahead)
    if final_windows:
        f_labels, f_eligible = final_labels(start, violation)
        labels = jnp.concatenate([labels, f_labels])
        eligible = jnp.concatenate([eligible, f_eligible])
    return labels, eligible


def episode_fields(start, violation, t_sel, e_sel, keep) -> dict:
    """The :data:`EPISODE_FIELDS` of the rows taken from stream positions ``(t_sel, e_sel)``
    of a time-major ``start``/``violation`` stream ``(T, E)`` whose first ``keep`` positions
    end a window: each row's env, position, episode id, step in its episode, the violation of
    its own and of its next step, and whether its episode ended within the kept positions."""
    start = np.asarray(start, bool)
    violation = np.asarray(violation, bool)
    t_total, num_envs = start.shape
    count = np.cumsum(start, axis=0)  # episodes started so far, per env (>= 1)
    episode = np.arange(num_envs)[None, :] * (t_total + 1) + count
    # Step index within the episode: positions since the last start.
    pos = np.arange(t_total)[:, None]
    last_start = np.maximum.accumulate(np.where(start, pos, 0), axis=0)
    step = pos - last_start
    nxt = np.concatenate([violation[1:], np.zeros((1, num_envs), bool)])
    # Complete: the episode's last observation is among the kept positions (< keep), i.e. a
    # later position <= keep of the same env starts a new episode.
    start_in = start & (pos <= keep)
    later_start = np.flip(np.logical_or.accumulate(np.flip(start_in, 0), axis=0), 0)
    complete = np.concatenate([later_start[1:], np.zeros((1, num_envs), bool)])
    return {
        "env_index": e_sel.astype(np.int32),
        "position": t_sel.astype(np.int32),
        "episode": episode[t_sel, e_sel].astype(np.int64),
        "step": step[t_sel, e_sel].astype(np.int32),
        "step_violation": (violation & ~start)[t_sel, e_sel].astype(np.uint8),
        "next_violation": nxt[t_sel, e_sel].astype(np.uint8),
        "complete": complete[t_sel, e_sel],
    }


def relabel(data: dict, lookahead: int) -> dict:
    """``data`` (:func:`checker.data.collect_streams`) with ``label`` saying what a checker of that
    ``lookahead`` learns: 1 (unchanged), whether the step out of the frame violates, the
    paper's just-before label, which a learner turns into a penalty before the violation; 0,
    whether the step into the frame violated (``violation``). A memory checker can tell the
    latter from the frame and its memory alone, while the former also depends on the action
    not yet taken; a shield, which scores the frame each candidate action leads to, asks the
    latter. The episodes' final frames are not in the streams (the auto-reset replaces them),
    so a checker of lookahead 0 never sees a violation on an episode's last step."""
    if lookahead not in STREAM_LOOKAHEADS or isinstance(lookahead, bool):
        raise ValueError(f"lookahead must be one of {STREAM_LOOKAHEADS}, got {lookahead!r}")
    if lookahead == 1:
        return data
    return {**data, "label": data["violation"].astype(np.int32)}
