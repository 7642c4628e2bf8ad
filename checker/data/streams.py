"""Checker data collected fully on device: labelled windows for the window checker
(:func:`collect`, :func:`collect_episodes`) and whole streams for the memory checker
(:func:`collect_streams`); their labels are :mod:`checker.data.labels`'.

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
Each window is labelled ``lookahead`` steps ahead as :mod:`checker.data.labels` defines it
(:func:`~checker.data.labels.all_labels`).

Final windows
-------------
PPO's ``checker`` reward scores the window that ends at the observation a step returned,
which on an episode's last step is its final observation (before the reset replaced it), and
the shield scores the window that ends at each candidate observation, final or not. Neither
is a window of the ring buffer, so with the stream's own labels the checker never sees one: on
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

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from checker.data.files import CheckerDataset
from checker.data.labels import all_labels, episode_fields, validate_window
from checker.protocol import NO_ACTION
from checker.reward import init_buffer, push
from jaxgrid.oracle import oracle_action
from jaxgrid.wrappers import AutoReset, BatchedAutoReset

# Behaviour policy over MiniGrid's actions (left, right, forward, pickup, drop, toggle, done):
# mostly forward, doors opened and the key picked up now and then, never drop or done.
BEHAVIOUR = (0.15, 0.15, 0.55, 0.075, 0.0, 0.075, 0.0)


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


@functools.partial(jax.jit, static_argnames=("num_samples", "lookahead", "final_windows"))
def _select_balanced(start, violation, key, *, num_samples, lookahead, final_windows=False):
    labels, eligible = all_labels(start, violation, lookahead, final_windows)
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
    labels, eligible = all_labels(recs["start"], recs["violation"], lookahead, final_windows)
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
        extras = episode_fields(host["start"], host["violation"], t_sel, e_sel, keep)
    if final_windows:
        is_final = t_sel >= t_total
        meta["final_windows_drawn"] = int(np.sum(is_final))
        meta["final_windows_positive"] = int(np.sum(labels_np[t_sel, e_sel] & is_final))
        extras["final"] = is_final[perm]  # which rows end after their labelled step
    return CheckerDataset(**arrays, extras=extras, meta=meta).counted()


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


def collect_streams(
    env, key: jax.Array, num_envs: int, num_steps: int, guided: float = 0.0
) -> dict:
    """``num_envs`` streams of ``num_steps`` frames of ``BatchedAutoReset(env)`` (fresh
    layouts drawn only where an episode ended) under :data:`BEHAVIOUR`, from fresh resets.

    ``guided`` > 0 takes each step's action, with that probability, from the BFS oracle
    (:func:`jaxgrid.oracle.oracle_action`) instead: half of the streams follow the oracle
    that obeys the constraint, half the one that plans through lava and forbidden doors. A
    random policy seldom leaves its first room; guided streams pass doors, carry the key and
    reach the goal, where trained agents go, and violate there too. 0 (the default) draws
    every action from :data:`BEHAVIOUR`, as before the option existed.

    Returns numpy arrays, ``(N, T, ...)``:

    ``frames`` (uint8 images), ``tokens``, ``starts`` (the frame is an episode's first),
    ``action`` (the action that led into the frame; :data:`NO_ACTION` at a start),
    ``label`` (the next step violates: ``info["violation"]`` of the step taken from this
    frame, which belongs to this frame's episode even when that step ends it), ``next_cost``
    (that step's ``info["cost"]``), ``cost`` and
    ``violation`` (of the step that produced the frame; 0 at a start), ``ctype`` and
    ``template`` (``info``'s ``constraint_type`` and ``template_id``) and ``valid`` (True
    everywhere: the scan runs the step out of every frame, the last one included, so every
    frame has its label; the training loss and the metrics take it as a mask).
    """
    if not 0.0 <= guided <= 1.0:
        raise ValueError(f"guided must be a probability in [0, 1], got {guided!r}")
    wrapped = BatchedAutoReset(env)
    k_reset, k_run = jax.random.split(key)
    probs = jnp.asarray(BEHAVIOUR)

    @jax.jit
    def run(k_reset, k_run):
        states, ts = wrapped.reset(jax.random.split(k_reset, num_envs))

        def body(carry, k):
            states, ts, start, last = carry
            actions = jax.random.choice(k, len(BEHAVIOUR), (num_envs,), p=probs)
            if guided > 0:  # static: without guidance the streams are drawn as before
                obey = jnp.arange(num_envs) % 2 == 0  # alternate streams obey the constraint
                expert = jax.vmap(lambda s, o: oracle_action(s, obey_constraint=o, avoid_lava=o))(
                    states, obey
                )
                follow = jax.random.bernoulli(jax.random.fold_in(k, 1), guided, (num_envs,))
                actions = jnp.where(follow, expert, actions)
            new_states, new_ts = wrapped.step(states, actions)
            frame = {
                "frames": ts.observation["image"],
                "tokens": ts.observation["constraint"],
                "starts": start,
                "action": jnp.where(start, NO_ACTION, last),
                "cost": jnp.where(start, 0.0, ts.info["cost"]),
                "violation": jnp.where(start, 0, ts.info["violation"]).astype(jnp.int32),
                "ctype": ts.info["constraint_type"],
                "template": ts.info["template_id"],
                "label": new_ts.info["violation"].astype(jnp.int32),
                "next_cost": new_ts.info["cost"],
            }
            ended = new_ts.terminated | new_ts.truncated
            return (new_states, new_ts, ended, actions), frame

        first = (states, ts, jnp.ones(num_envs, bool), jnp.full(num_envs, NO_ACTION, jnp.int32))
        _, frames = jax.lax.scan(body, first, jax.random.split(k_run, num_steps))
        return jax.tree.map(lambda a: jnp.swapaxes(a, 0, 1), frames)

    out = {k: np.asarray(v) for k, v in run(k_reset, k_run).items()}
    out["valid"] = np.ones(out["starts"].shape, bool)  # every frame has its next step here
    return out
