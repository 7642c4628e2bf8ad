"""Auto-labelled checker data, collected fully on device.

Rollouts
--------
:func:`collect` runs ``num_envs`` copies of ``jaxgrid.wrappers.AutoReset(env)`` under ``vmap``
inside ``lax.scan``, the behaviour policy choosing the actions (a function argument, so this
package never imports ``agents``). Each env yields a *stream* of positions ``i = 0, 1, ...``:
position 0 is the reset observation, position ``i >= 1`` the observation returned by step
``i``. After an auto-reset that is the *next* episode's first observation, exactly what the
PPO learner sees.

Windows
-------
The window of position ``i`` is the ring buffer of :mod:`checker.reward` after pushing the
observations of positions ``0..i`` with ``episode_start = terminated | truncated`` (and
``True`` at position 0): the same :func:`checker.reward.push` the PPO step calls, so the
checker is trained on what PPO feeds it. A window holds the last ``window`` observations of
the current episode, oldest first; at the start of an episode the missing older frames are
all-zero ("unseen" cells).

Labels
------
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

Final windows
-------------
PPO's ``checker`` reward scores the window that ends at the observation a step returned,
which on an episode's last step is its final observation (before the reset replaced it), and
the shield scores the window that ends at each candidate observation, final or not. Neither
is a window of the ring buffer, so with the labels above the checker never sees one: on
TwoRooms-Lava, where lava ends the episode, it scored every step into lava as safe. With
``final_windows=True`` (balanced collection only) the windows that end at each episode's final
observation are drawn from too, labelled by the step that ended the episode (1 where it
violated, whatever ``lookahead``): the window of the last frames of an episode and the
observation it ended on, with that episode's sentence. ``extras["final"]`` marks these rows.

Balancing
---------
Violations are rare, so with ``balance=True`` the rollout goes on, in chunks of
``chunk_steps`` steps, until it holds at least ``ceil(num_samples / 2)`` positive windows (or
``max_steps`` steps per env; ``num_steps`` fixes the length instead). Then ``ceil(num_samples
/ 2)`` positives and ``num_samples - ceil(num_samples / 2)`` negatives are drawn uniformly
without replacement from all eligible windows. When one class is short, all of it is taken
and the other fills the rest, so the dataset always has ``min(num_samples, eligible)`` rows
and the achieved positive fraction is recorded as ``meta["positive_fraction"]``; the rate
over all eligible windows is ``meta["natural_positive_rate"]``.

Full episodes
-------------
With ``balance=False`` (or :func:`collect_episodes`) every eligible window is kept, in
env-major order (env 0 positions 0, 1, ..., env 1, ...), and each row also carries
``env_index``, ``position``, ``episode`` (unique id), ``step`` (``t``), ``step_violation``
(``v_t``), ``next_violation`` (``v_{t+1}`` within the episode, whatever ``lookahead``) and
``complete`` (the episode ended within the rollout): what the lead-time metric needs.
"""

from __future__ import annotations

import dataclasses
import functools
import io
import os
import zipfile
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from checker.reward import init_buffer, push
from checker.trained import check_vocab
from jaxgrid import language, sentences
from jaxgrid.constants import BALL, BOX, CLOSED, COLOR_NAMES, DOOR, EMPTY, KEY, LOCKED
from jaxgrid.io import atomic_write, read_json, write_json
from jaxgrid.observation import see_behind, visibility_mask
from jaxgrid.rundir import sha256_bytes, sha256_file
from jaxgrid.wrappers import AutoReset

__all__ = [
    "CheckerDataset",
    "collect",
    "collect_episodes",
    "compute_labels",
    "validate_window",
    "with_blocked_counterfactuals",
    "with_colour_counterfactuals",
    "before_step",
    "front_cells",
    "with_distractors",
]

FORMAT_VERSION = 1
MAX_WINDOW = 64
_CORE = ("windows", "tokens", "labels", "template_id", "constraint_type", "scenario")
_PORTABLE = (KEY, BALL, BOX)  # no constraint names them
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


# --------------------------------------------------------------------------------------
# Dataset container
# --------------------------------------------------------------------------------------


@dataclasses.dataclass
class CheckerDataset:
    """Numpy arrays of ``N`` windows and their labels, plus metadata.

    Attributes:
        windows: uint8 ``(N, n, V, V, 3)``, oldest frame first.
        tokens: int32 ``(N, L)`` constraint token ids.
        labels: uint8 ``(N,)``, 1 = violation within the lookahead (see the module docs).
        template_id: int32 ``(N,)``, ``jaxgrid.sentences.TEMPLATES`` index.
        constraint_type: int32 ``(N,)``, paper type 1-5.
        scenario: str ``(N,)``, the env id each row came from.
        extras: per-row arrays of full-episode datasets (:data:`EPISODE_FIELDS`), else empty.
        meta: JSON-serialisable metadata (env id, split, window, lookahead, rates, counts...).
    """

    windows: np.ndarray
    tokens: np.ndarray
    labels: np.ndarray
    template_id: np.ndarray
    constraint_type: np.ndarray
    scenario: np.ndarray
    extras: dict = dataclasses.field(default_factory=dict)
    meta: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        n = len(self.labels)
        for name in _CORE:
            if len(getattr(self, name)) != n:
                raise ValueError(
                    f"CheckerDataset.{name} has {len(getattr(self, name))} rows, labels has {n}"
                )
        for name, arr in self.extras.items():
            if len(arr) != n:
                raise ValueError(f"CheckerDataset.extras[{name!r}] has {len(arr)} rows, not {n}")

    def __len__(self) -> int:
        return len(self.labels)

    @property
    def window(self) -> int:
        return int(self.windows.shape[1])

    @property
    def positive_fraction(self) -> float:
        return float(np.mean(self.labels)) if len(self) else 0.0

    def subset(self, index: np.ndarray) -> CheckerDataset:
        """Rows ``index`` (an int or bool array) as a new dataset; metadata counts updated."""
        index = np.asarray(index)
        arrays = {name: getattr(self, name)[index] for name in _CORE}
        extras = {k: v[index] for k, v in self.extras.items()}
        meta = dict(self.meta)
        meta["num_samples"] = int(len(arrays["labels"]))
        meta["num_positive"] = int(np.sum(arrays["labels"]))
        meta["positive_fraction"] = float(np.mean(arrays["labels"])) if len(index) else 0.0
        return CheckerDataset(**arrays, extras=extras, meta=meta)

    def split(self, fractions: Sequence[float], seed: int = 0) -> tuple[CheckerDataset, ...]:
        """Random disjoint parts of sizes ``fractions`` (summing to 1).

        Balanced datasets are split per class (stratified), so each part keeps the positive
        fraction; full-episode datasets are split by whole episodes.
        """
        fractions = [float(f) for f in fractions]
        if not fractions or any(f < 0 for f in fractions) or abs(sum(fractions) - 1) > 1e-6:
            raise ValueError(f"split fractions must be >= 0 and sum to 1, got {fractions}")
        rng = np.random.default_rng(seed)
        parts: list[list[np.ndarray]] = [[] for _ in fractions]
        if "episode" in self.extras:
            groups = [np.unique(self.extras["episode"])]
            keys = self.extras["episode"]
        else:
            groups = [np.flatnonzero(self.labels == c) for c in (0, 1)]
            keys = None
        for members in groups:
            members = rng.permutation(members)
            bounds = np.round(np.cumsum([0.0] + fractions) * len(members)).astype(int)
            for p in range(len(fractions)):
                chosen = members[bounds[p] : bounds[p + 1]]
                parts[p].append(chosen if keys is None else np.flatnonzero(np.isin(keys, chosen)))
        out = []
        for p in parts:
            idx = (
                np.sort(np.concatenate(p))
                if keys is not None
                else rng.permutation(np.concatenate(p))
            )
            out.append(self.subset(idx))
        return tuple(out)

    # ---------------------------------------------------------------- persistence
    @staticmethod
    def _paths(path: str | os.PathLike) -> tuple[str, str]:
        base = os.fspath(path)
        if base.endswith(".npz"):
            base = base[:-4]
        elif base.endswith(".json"):
            base = base[:-5]
        return base + ".npz", base + ".json"

    def save(self, path: str | os.PathLike) -> tuple[str, str]:
        """Write ``<path>.npz`` (arrays) and ``<path>.json`` (metadata with the npz's sha256);
        returns both paths. Each is written atomically, the arrays first."""
        npz, js = self._paths(path)
        arrays = {name: getattr(self, name) for name in _CORE}
        arrays.update({f"extra_{k}": v for k, v in self.extras.items()})
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        atomic_write(npz, buf.getvalue())
        meta = {
            "format_version": FORMAT_VERSION,
            "npz_sha256": sha256_bytes(buf.getvalue()),
            **self.meta,
            "vocab": list(sentences.PAPER.vocab),
            "max_len": sentences.PAPER.max_len,
        }
        write_json(js, meta)
        return npz, js

    @classmethod
    def load(cls, path: str | os.PathLike) -> CheckerDataset:
        """Read a dataset written by :meth:`save` (``path`` with or without extension).

        ``FileNotFoundError`` names a missing file; ``ValueError`` names the file if it was made
        for another vocabulary or ``MAX_LEN``, or is damaged: the npz must match the sha256
        recorded in the JSON (a dataset saved before checksums were recorded is read without
        that check).
        """
        npz, js = cls._paths(path)
        for p in (js, npz):
            if not os.path.isfile(p):
                raise FileNotFoundError(f"checker dataset file not found: {p}")
        meta = read_json(js)
        check_vocab(meta, f"dataset {js}")
        recorded = meta.get("npz_sha256")
        if recorded is not None and sha256_file(npz) != recorded:
            raise ValueError(f"{npz}: damaged dataset file (truncated or changed: its sha256 "
                             f"differs from the one in {js}); delete both files and collect "
                             "the data again")  # fmt: skip
        try:
            with np.load(npz, allow_pickle=False) as z:
                arrays = {name: z[name] for name in _CORE}
                extras = {k[len("extra_") :]: z[k] for k in z.files if k.startswith("extra_")}
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as e:
            raise ValueError(f"{npz}: damaged dataset file ({type(e).__name__}: {e})") from e
        own = ("vocab", "max_len", "format_version", "npz_sha256")
        meta = {k: v for k, v in meta.items() if k not in own}
        return cls(**arrays, extras=extras, meta=meta)


# --------------------------------------------------------------------------------------
# Labels
# --------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------
# Rollout on device
# --------------------------------------------------------------------------------------


def _record(state, ts, start, violation):
    c = state.extras.constraint
    return {
        "image": ts.observation["image"].astype(jnp.uint8),
        # The observation the step ended on, before an auto-reset replaced it.
        "final_image": ts.info["final_observation"]["image"].astype(jnp.uint8),
        "start": start,
        "violation": violation,
        "tokens": ts.observation["constraint"].astype(jnp.uint8),
        "template_id": c.template_id.astype(jnp.int8),
        "constraint_type": c.type_id.astype(jnp.int8),
    }


@functools.partial(jax.jit, static_argnames=("num_envs",))
def _reset(env, key, *, num_envs):
    states, ts = jax.vmap(env.reset)(jax.random.split(key, num_envs))
    ones = jnp.ones((num_envs,), bool)
    rec = _record(states, ts, ones, jnp.zeros((num_envs,), bool))
    return (states, ts.observation), jax.tree.map(lambda x: x[None], rec)


@functools.partial(jax.jit, static_argnames=("policy_fn", "num_steps"))
def _rollout(env, policy_fn, policy_params, carry, key, *, num_steps):
    def body(carry, k):
        states, obs = carry
        actions = policy_fn(policy_params, obs, states, k).astype(jnp.int32)
        states, ts = jax.vmap(env.step)(states, actions)
        done = ts.terminated | ts.truncated
        rec = _record(states, ts, done, ts.info["violation"].astype(bool))
        return (states, ts.observation), rec

    carry, recs = lax.scan(body, carry, jax.random.split(key, num_steps))
    return carry, recs


def final_labels(start: jax.Array, violation: jax.Array):
    """Labels and eligibility (bool ``(T, E)``) of the windows that end at an episode's final
    observation: position ``i`` is eligible where a step ended an episode there (``start`` at
    ``i > 0``), and its label is that step's violation."""
    start = jnp.asarray(start, bool)
    ended = start & (jnp.arange(start.shape[0]) > 0)[:, None]
    return ended & jnp.asarray(violation, bool), ended


def _all_labels(start, violation, lookahead, final_windows):
    """The stream's labels and eligibility, with the final windows' rows after them."""
    labels, eligible = compute_labels(start, violation, lookahead)
    if final_windows:
        f_labels, f_eligible = final_labels(start, violation)
        labels = jnp.concatenate([labels, f_labels])
        eligible = jnp.concatenate([eligible, f_eligible])
    return labels, eligible


@functools.partial(jax.jit, static_argnames=("num_samples", "lookahead", "final_windows"))
def _select_balanced(start, violation, key, *, num_samples, lookahead, final_windows=False):
    labels, eligible = _all_labels(start, violation, lookahead, final_windows)
    flat_l, flat_e = labels.reshape(-1), eligible.reshape(-1)
    pos, neg = flat_e & flat_l, flat_e & ~flat_l
    n_pos_avail, n_neg_avail = jnp.sum(pos), jnp.sum(neg)
    half = (num_samples + 1) // 2
    n_pos = jnp.minimum(n_pos_avail, jnp.maximum(half, num_samples - n_neg_avail))
    n_neg = jnp.minimum(n_neg_avail, num_samples - n_pos)
    u = jax.random.uniform(key, flat_l.shape)

    def ranks(mask):  # rank of each member by u, members first
        order = jnp.argsort(jnp.where(mask, u, 2.0))
        return jnp.zeros_like(order).at[order].set(jnp.arange(order.size, dtype=order.dtype))

    r_pos, r_neg = ranks(pos), ranks(neg)
    slot = jnp.where(
        pos & (r_pos < n_pos), r_pos, jnp.where(neg & (r_neg < n_neg), n_pos + r_neg, num_samples)
    )
    counts = {
        "eligible": jnp.sum(flat_e),
        "positive_eligible": n_pos_avail,
        "num_positive": n_pos,
        "num_negative": n_neg,
    }
    return slot.reshape(labels.shape).astype(jnp.int32), labels, counts


@functools.partial(jax.jit, static_argnames=("num_slots", "window"))
def _gather_windows(image, start, slot, final_image=None, final_slot=None, *, num_slots, window):
    """Replay the stream through :func:`push`, writing each position's window to its slot
    (and, with ``final_image``, the window that ends at each position's final observation
    to its ``final_slot``)."""
    e, v = image.shape[1], image.shape[2]
    out = jnp.zeros((num_slots, window, v, v, 3), jnp.uint8)

    def body(carry, x):
        buf, out = carry
        img, st, sl, *final = x
        if final:  # the finished episode's frames, then the observation it ended on
            f_img, f_sl = final
            out = out.at[f_sl].set(push(buf, f_img, jnp.zeros_like(st)), mode="drop")
        buf = push(buf, img, st)
        out = out.at[sl].set(buf, mode="drop")
        return (buf, out), None

    xs = (image, start, slot) + (() if final_image is None else (final_image, final_slot))
    (_, out), _ = lax.scan(body, (init_buffer(e, window, v), out), xs)
    return out


def _check_env(env) -> AutoReset:
    wrapped = env if isinstance(env, AutoReset) else AutoReset(env)
    try:
        _, ts = jax.eval_shape(wrapped.reset, jax.random.PRNGKey(0))
    except Exception as e:  # pragma: no cover - depends on the env
        raise ValueError(f"collect: env.reset failed under eval_shape: {e}") from e
    if "constraint" not in ts.observation or "violation" not in ts.info:
        raise ValueError(
            "collect needs a constrained scenario env (observation['constraint'] and "
            "info['violation']), e.g. jaxgrid.make('TwoRooms-v0')"
        )
    return wrapped


def _check_positive_int(name: str, value: Any) -> int:
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
        raise ValueError(f"{name} must be a positive int, got {value!r}")
    return int(value)


def _env_name(env, env_id: str | None) -> str:
    if env_id is not None:
        return str(env_id)
    inner = env.env if isinstance(env, AutoReset) else env
    return type(inner).__name__


def _stream(env, policy_fn, policy_params, key, num_envs, num_steps, chunk_steps, enough):
    """Run the rollout in chunks; ``enough(recs_of_chunk) -> bool`` stops it early.

    Returns the concatenated time-major records (position 0 = reset) on device.
    """
    k_reset, key = jax.random.split(key)
    carry, first = _reset(env, k_reset, num_envs=num_envs)
    recs = [first]
    steps = 0
    while steps < num_steps:
        n = min(chunk_steps, num_steps - steps)
        key, k = jax.random.split(key)
        carry, chunk = _rollout(env, policy_fn, policy_params, carry, k, num_steps=n)
        recs.append(chunk)
        steps += n
        if enough is not None and enough(chunk):
            break
    return jax.tree.map(lambda *xs: jnp.concatenate(xs, axis=0), *recs), steps


def collect(
    env,
    policy_fn: Callable,
    policy_params: Any,
    key: jax.Array,
    num_samples: int | None = None,
    window: int = 5,
    lookahead: int = 1,
    num_envs: int = 256,
    balance: bool = True,
    *,
    num_steps: int | None = None,
    max_steps: int = 4096,
    chunk_steps: int = 64,
    env_id: str | None = None,
    final_windows: bool = False,
) -> CheckerDataset:
    """Roll out ``policy_fn`` in ``num_envs`` auto-reset copies of ``env`` and label windows.

    Args:
        env: a constrained scenario (e.g. ``jaxgrid.make("TwoRooms-v0")``), raw or wrapped in
            ``AutoReset``.
        policy_fn: ``policy_fn(policy_params, obs, state, key) -> int32 (num_envs,)`` actions;
            hashable (it is a static argument of the compiled rollout).
        policy_params: pytree passed to ``policy_fn``.
        key: PRNG key of the whole collection.
        num_samples: rows wanted (``balance=True``); ignored with ``balance=False``.
        window: observations per window (1-64).
        lookahead: label horizon ``k`` in ``0..4 * window`` (see the module docstring).
        num_envs: parallel envs.
        balance: balanced subsample (True) or every window of full episodes (False).
        num_steps: steps per env; default: as many as needed for ``ceil(num_samples / 2)``
            positives (``balance=True``, at most ``max_steps``), required when
            ``balance=False``.
        max_steps: cap on steps per env when ``num_steps`` is not given.
        chunk_steps: steps per compiled chunk when collecting until enough positives.
        env_id: recorded as ``meta["env_id"]`` and ``scenario`` (default: the env's class).
        final_windows: also draw from the windows that end at an episode's final observation,
            labelled by the step that ended it (see "Final windows"); ``balance=True`` only.

    Every argument is validated (``ValueError`` naming it) before anything is compiled.
    """
    validate_window(window, lookahead)
    window, lookahead = int(window), int(lookahead)
    num_envs = _check_positive_int("num_envs", num_envs)
    chunk_steps = _check_positive_int("chunk_steps", chunk_steps)
    max_steps = _check_positive_int("max_steps", max_steps)
    if balance:
        num_samples = _check_positive_int("num_samples", num_samples)
    if num_steps is not None:
        num_steps = _check_positive_int("num_steps", num_steps)
    elif not balance:
        raise ValueError("num_steps is required with balance=False (full episodes)")
    if not isinstance(final_windows, bool):
        raise ValueError(f"final_windows must be a bool, got {final_windows!r}")
    if final_windows and not balance:
        raise ValueError("final_windows needs balance=True (full episodes keep the stream's "
                         "own windows only)")  # fmt: skip
    wrapped = _check_env(env)
    name = _env_name(env, env_id)
    split = getattr(wrapped.env, "split", None)

    enough = None
    target = num_steps if num_steps is not None else max_steps
    if balance and num_steps is None:
        needed = (num_samples + 1) // 2
        found = [0]

        def enough(chunk):
            # Exact count of positives for k in {0, 1}, a lower bound for k > 1.
            new = chunk["violation"] & (~chunk["start"] if lookahead == 0 else True)
            if final_windows:  # a violation that ends an episode also has its final window
                new = new.astype(jnp.int32) + (chunk["violation"] & chunk["start"])
            found[0] += int(jnp.sum(new))
            return found[0] >= needed

    recs, steps = _stream(
        wrapped, policy_fn, policy_params, key, num_envs, target, chunk_steps, enough
    )
    key_sel = jax.random.fold_in(key, 1)
    t_total = recs["start"].shape[0]
    labels, eligible = _all_labels(recs["start"], recs["violation"], lookahead, final_windows)
    n_elig = int(jnp.sum(eligible))
    n_pos_elig = int(jnp.sum(labels & eligible))
    meta = {
        "env_id": name,
        "split": split,
        "window": window,
        "lookahead": lookahead,
        "view_size": int(recs["image"].shape[2]),
        "balanced": bool(balance),
        "num_envs": num_envs,
        "steps_per_env": int(steps),
        "num_episodes_started": int(jnp.sum(recs["start"])),
        "num_violations": int(jnp.sum(recs["violation"])),
        "eligible_windows": n_elig,
        "natural_positive_rate": n_pos_elig / max(n_elig, 1),
        "final_windows": final_windows,
    }

    if balance:
        slot, _, counts = _select_balanced(
            recs["start"],
            recs["violation"],
            key_sel,
            num_samples=num_samples,
            lookahead=lookahead,
            final_windows=final_windows,
        )
        count = int(counts["num_positive"]) + int(counts["num_negative"])
    else:
        keep = t_total - lookahead
        t_idx = jnp.arange(t_total)[:, None]
        e_idx = jnp.arange(num_envs)[None, :]
        slot = jnp.where(t_idx < keep, e_idx * keep + t_idx, num_envs * keep).astype(jnp.int32)
        count = num_envs * keep
    num_slots = num_samples if balance else count
    finals = (recs["final_image"], slot[t_total:]) if final_windows else ()
    windows = _gather_windows(
        recs["image"], recs["start"], slot[:t_total], *finals, num_slots=num_slots, window=window
    )
    # Which stream position went to each slot (final windows: rows t_total.. of the labels).
    flat = slot.reshape(-1)
    pos_of_slot = (
        jnp.full((num_slots,), -1, jnp.int32)
        .at[flat]
        .set(jnp.arange(flat.size, dtype=jnp.int32), mode="drop")
    )
    pos_of_slot = np.asarray(pos_of_slot[:count])
    t_sel, e_sel = pos_of_slot // num_envs, pos_of_slot % num_envs
    # A final window belongs to the episode of the position before (the record at its own
    # position is the next episode's first observation, with that episode's sentence).
    t_src = np.where(t_sel >= t_total, t_sel - t_total - 1, t_sel)
    host = jax.device_get({k: v for k, v in recs.items() if k not in ("image", "final_image")})
    labels_np = np.asarray(labels)
    windows = np.asarray(windows[:count])
    arrays = {
        "windows": windows,
        "tokens": host["tokens"][t_src, e_sel].astype(np.int32),
        "labels": labels_np[t_sel, e_sel].astype(np.uint8),
        "template_id": host["template_id"][t_src, e_sel].astype(np.int32),
        "constraint_type": host["constraint_type"][t_src, e_sel].astype(np.int32),
        "scenario": np.full((count,), name),
    }
    extras = {}
    if balance:
        perm = np.random.default_rng(np.asarray(jax.random.key_data(key_sel)).ravel()).permutation(
            count
        )
        arrays = {k: v[perm] for k, v in arrays.items()}
    else:
        keep = t_total - lookahead
        extras = _episode_fields(host["start"], host["violation"], t_sel, e_sel, keep)
    if final_windows:
        is_final = t_sel >= t_total
        meta["final_windows_drawn"] = int(np.sum(is_final))
        meta["final_windows_positive"] = int(np.sum(labels_np[t_sel, e_sel] & is_final))
        extras["final"] = is_final[perm]  # which rows end after their labelled step
    ds = CheckerDataset(**arrays, extras=extras, meta=meta)
    ds.meta.update(
        num_samples=len(ds),
        num_positive=int(np.sum(ds.labels)),
        positive_fraction=ds.positive_fraction,
    )
    return ds


def _episode_fields(start, violation, t_sel, e_sel, keep) -> dict:
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


def collect_episodes(
    env,
    policy_fn: Callable,
    policy_params: Any,
    key: jax.Array,
    num_steps: int,
    window: int = 5,
    lookahead: int = 1,
    num_envs: int = 64,
    *,
    env_id: str | None = None,
) -> CheckerDataset:
    """Every window of ``num_envs`` envs over ``num_steps`` steps (``collect(balance=False)``)."""
    return collect(
        env,
        policy_fn,
        policy_params,
        key,
        None,
        window,
        lookahead,
        num_envs,
        balance=False,
        num_steps=num_steps,
        env_id=env_id,
    )


# --------------------------------------------------------------------------------------
# Counterfactual negatives
# --------------------------------------------------------------------------------------


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
        name: np.concatenate([getattr(dataset, name), getattr(extra, name)])[order]
        for name in _CORE
    }
    extras = {k: np.concatenate([v, extra.extras[k]])[order] for k, v in dataset.extras.items()}
    out = CheckerDataset(**merged, extras=extras, meta=dict(dataset.meta))
    out.meta.update(
        num_samples=len(out),
        num_positive=int(np.sum(out.labels)),
        positive_fraction=out.positive_fraction,
        **{counter: len(extra) + int(dataset.meta.get(counter, 0))},
    )
    return out


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


# --------------------------------------------------------------------------------------
# Distractor objects
# --------------------------------------------------------------------------------------


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
