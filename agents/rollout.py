"""One step of the training rollout: policy, env, checker, reward shaping, bootstrap, stats.

:func:`env_step` advances ``num_envs`` auto-resetting environments by one step and returns
the :class:`Transition` PPO learns from. Each step also carries the checker's memory per env
(:class:`checker.protocol.CheckerProtocol`'s carry, :mod:`agents.checker_carry`), advanced by
one frame per step: for the window checker its embeddings of the last ``window - 1`` frames,
so that it embeds each frame once (not ``window`` times), for the memory checker its GRU
state.
Everything here is a pure function of arrays, the network's apply function and the frozen
checker; :mod:`agents.train` scans it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import flax.struct as struct
import jax
import jax.numpy as jnp

from agents import shield as shield_mod
from agents.checker_carry import embed
from agents.config import PPOConfig
from agents.evaluation import cost_of, spend, violation_of
from checker.protocol import CheckerProtocol
from jaxgrid import language
from jaxgrid.constants import EMPTY, FORWARD
from jaxgrid.wrappers import BatchedAutoReset, masked_map


class EnvCarry(struct.PyTreeNode):
    """Everything with a leading ``num_envs`` axis (sharded over devices)."""

    state: Any
    obs: dict
    sentence: jax.Array  # int32: row of the sentence table
    # float32: the checker's carry of the episode up to the current observation (its
    # stream_start / stream_step: the embeddings of the last n - 1 frames (E, n - 1, D) of a
    # window checker, the GRU state (E, H) of a memory checker); a placeholder without one
    frames: jax.Array
    # bool (E, W*H*2): (cell, carrying) pairs seen this episode, then with novelty_changes
    # (E, W*H) more: the cells changed this episode; (E, 1) without the novelty bonus
    visited: jax.Array
    ep_return: jax.Array
    ep_length: jax.Array
    alarmed: jax.Array  # bool (E,): the checker alarmed at the episode's previous step
    # float32 (E, M): the policy's memory of the episode so far (zeros at its start; M = 1,
    # a placeholder, for a memoryless policy)
    memory: jax.Array = None
    # float32 (E,): Saute's remaining safety budget of the episode (1 at its start; None in
    # the other modes)
    budget: jax.Array | None = None


class Transition(struct.PyTreeNode):
    image: jax.Array
    direction: jax.Array
    sentence: jax.Array
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    cost_value: jax.Array
    reward: jax.Array  # shaped training reward, truncation bootstrap included
    cost: jax.Array  # the constrained modes' cost, truncation bootstrap included
    done: jax.Array
    allowed: jax.Array | None = None  # bool (E, A): the shield's mask (shield modes only)
    budget: jax.Array | None = None  # float32 (E,): the observed safety budget (saute only)
    # float32 (E, A): the acting policy's logits, where the update bounds the KL to it
    logits: jax.Array | None = None


# (image, direction, sentence row, memory[, budget]) -> (logits, value, cost_value, memory),
# parameters bound (agents.networks.apply_policy).
BoundPolicy = Callable[..., tuple[jax.Array, jax.Array, jax.Array, jax.Array]]


def sentence_rows(obs: dict, table: jax.Array) -> jax.Array:
    """int32 (E,): each env's row of the sentence table (0 for envs without a constraint)."""
    rows = language.sentence_index(obs["constraint"], table) if "constraint" in obs else 0
    return rows * jnp.ones_like(obs["direction"])


def _rows(mask: jax.Array, x: jax.Array) -> jax.Array:
    """``mask`` (E,) shaped to broadcast against ``x`` (E, ...)."""
    return mask.reshape(mask.shape + (1,) * (x.ndim - 1))


def visits(
    states,
    width: int,
    height: int,
    enabled: bool,
    changes: bool = False,
    before=None,
    carrying: bool = True,
) -> jax.Array:
    """bool (E, W*H*2): one-hot of each env's (cell, carrying or not) for the novelty bonus;
    (E, 1) False when the bonus is off, so that nothing is paid for it. With ``carrying``
    False every pair is read as not carrying: the bonus pays for cells only. With ``changes``,
    (E, W*H) more columns: the cells whose contents differ from ``before`` (the states before
    the step; None at an episode's start, where nothing has changed yet)."""
    if not enabled:
        return jnp.zeros((states.agent_pos.shape[0], 1), bool)
    x, y = states.agent_pos[:, 0], states.agent_pos[:, 1]
    held = (states.carrying[:, 0] != EMPTY).astype(jnp.int32) if carrying else 0
    cell = (x * height + y) * 2 + held
    hit = cell[:, None] == jnp.arange(width * height * 2)
    if not changes:
        return hit
    num = states.grid.shape[0]
    if before is None:
        changed = jnp.zeros((num, width * height), bool)
    else:  # grid[x, y] flattens to x * height + y, as the cells above
        changed = jnp.any(states.grid != before.grid, axis=-1).reshape(num, width * height)
    return jnp.concatenate([hit, changed], axis=1)


def config_visits(states, env, c, before=None) -> jax.Array:
    """:func:`visits` with the novelty settings of the PPO config ``c``: the learner's start
    and every step ask it the same way."""
    return visits(
        states,
        env.width,
        env.height,
        c.novelty_bonus != 0,
        c.novelty_changes,
        before,
        carrying=c.novelty_carrying,
    )


def novel(visited: jax.Array, hit: jax.Array, width: int, height: int) -> jax.Array:
    """float32 (E,): how many of this step's ``hit`` (:func:`visits`) are new to the episode's
    ``visited``: the (cell, carrying) pair (0 or 1), plus the changed cells not changed
    before (a step changes at most one)."""
    cells = width * height * 2
    if hit.shape[1] == 1:  # the bonus is off: (E, 1) False
        return jnp.zeros(hit.shape[:1], jnp.float32)
    new = ~jnp.any(visited[:, :cells] & hit[:, :cells], axis=1)
    changed = jnp.sum(hit[:, cells:] & ~visited[:, cells:], axis=1)
    return new.astype(jnp.float32) + changed.astype(jnp.float32)


def env_step(
    carry: EnvCarry,
    key: jax.Array,
    *,
    config: PPOConfig,
    env: BatchedAutoReset,
    policy: BoundPolicy,
    table: jax.Array,
    words: int,
    checker: CheckerProtocol | None = None,
    shield=None,
    penalty: jax.Array | float,
    novelty: jax.Array | float,
    threshold: jax.Array | float | None = None,
    limit: jax.Array | float | None = None,
) -> tuple[EnvCarry, tuple[Transition, dict]]:
    """One rollout step of every env: act, step, shape the reward, bootstrap truncations.

    ``table`` is the int32 (K, L) sentence table, ``words`` its longest sentence's length
    (the checker's GRU reads that many tokens). The training reward is the env reward minus
    ``penalty`` times the ground-truth violation (``shaped``) or the checker's alarm
    (``checker``; its probability with ``soft_checker``; with ``alarm_onset`` only where the
    previous step of the episode did not alarm; with ``alarm_forward`` the previous step's
    alarm where this step moves forward); the modes with a cost critic (``lagrangian``) put
    that signal in the cost instead, or with ``cost_source="monitor"`` the monitor's cost.
    The novelty bonus pays ``novelty`` for a (cell, carrying) pair new to the episode (with
    ``novelty_changes``, also for a cell's first change in it). With a ``shield``
    (:class:`agents.shield.Shield`) the action is sampled from the policy restricted to the
    allowed actions, and the mask is kept in the transition.
    In ``saute`` the cost spends the episode's safety budget (:func:`agents.evaluation.spend`,
    at cost limit ``limit``; None: ``cost_limit``), which the policy observes; once it is
    overspent, every step's training reward is ``-saute_penalty``.
    Where an episode was cut by the time limit (not terminated), the reward and
    cost add ``gamma`` times the final observation's values, so GAE treats the step as
    terminal without losing the future. ``threshold`` (None: ``checker_threshold``) and
    ``limit`` may be traced per-agent values. Returns the next carry and (transition,
    statistics).
    """
    c = config
    obs = carry.obs
    logits, value, cost_value, memory = policy(
        obs["image"], obs["direction"], carry.sentence, carry.memory, carry.budget
    )
    # The checker's sentence codes: the table is encoded once (XLA hoists it out of the scan).
    codes = None if checker is None else checker.encode_language(table[:, :words])
    lang = None if checker is None else codes[carry.sentence]
    allowed, blocked = None, jnp.zeros(logits.shape[:1])
    if shield is not None:
        allowed, _ = shield.allowed(carry.state, carry.frames, lang)
        blocked = shield_mod.blocked_mass(logits, allowed)
        logits = shield_mod.mask_logits(logits, allowed)
    action = jax.random.categorical(key, logits)
    log_prob = jax.nn.log_softmax(logits)[jnp.arange(action.shape[0]), action]
    states, ts = env.step(carry.state, action)
    done = ts.terminated | ts.truncated
    final = ts.info["final_observation"]
    violation = violation_of(ts)

    alarm = prob = jnp.zeros_like(ts.reward)
    frames = carry.frames
    if checker is not None:
        emb = embed(checker, final["image"], action)
        logit, frames = checker.stream_step(carry.frames, emb, lang)
        prob = jax.nn.sigmoid(logit)
        threshold = c.checker_threshold if threshold is None else threshold
        alarm = (prob > threshold).astype(jnp.float32)
    signal = prob if c.soft_checker else alarm
    if c.alarm_onset:  # only the step that raises an alarm, not its repeats while it stays
        signal = signal * ~carry.alarmed
    if c.alarm_forward:  # the previous step's alarm, on a step that tries to enter a cell
        signal = (carry.alarmed & (action == FORWARD)).astype(jnp.float32)
    cost = jnp.zeros_like(ts.reward)
    reward = ts.reward
    monitored = c.cost_from == "monitor"
    if c.mode.penalty:  # shaped (the monitor's violations), checker (the alarms)
        reward = reward - penalty * (violation.astype(jnp.float32) if monitored else signal)
    elif c.mode.cost_critic or c.mode.budget:
        cost = cost_of(ts) if monitored else signal
    if c.end_episode and c.mode.penalty:
        # The learner ends the episode where the signal fired: a terminal step, then a fresh
        # episode, as if the env had ended it.
        ended = (violation if monitored else alarm > 0) & ~done
        states, restarted = env.restart(states, ts.observation, ended)
        ts = ts.replace(observation=restarted, terminated=ts.terminated | ended)
        done = done | ended
    # The constraint is fixed for an episode: look it up only where one began.
    picked = {k: ts.observation[k] for k in ("constraint", "direction") if k in ts.observation}
    sentence = masked_map(done, lambda o: sentence_rows(o, table), picked, carry.sentence)
    if checker is not None:
        # The memory holds the returned observation: the final one where the episode goes on;
        # where it ended, the next episode's first observation, which only those few envs
        # embed, read with the new episode's sentence.
        emb = masked_map(done, lambda i: embed(checker, i), ts.observation["image"], emb)
        fresh = checker.stream_start(emb, codes[sentence])
        frames = jax.tree.map(lambda f, o: jnp.where(_rows(done, f), f, o), fresh, frames)
    # Novelty: the step reached a (cell, carrying) pair new to this episode (or changed a cell
    # for the first time in it). Where the episode ended, ``states`` is the next episode's
    # start, whose visit opens a new set with nothing changed yet.
    hit = config_visits(states, env, c, carry.state)
    new = jnp.where(done, 0.0, novel(carry.visited, hit, env.width, env.height))
    if c.novelty_claim:  # at most K bonuses per episode; the goal pays those not yet earned
        left = jnp.maximum(c.novelty_claim - carry.visited.sum(axis=1), 0).astype(jnp.float32)
        new = jnp.minimum(new, left) + jnp.where(ts.terminated & (ts.reward > 0), left, 0.0)
    bonus = novelty * new  # novelty is 0 when the bonus is off
    reward = reward + bonus
    budget = carry.budget
    if c.mode.budget:  # the step's cost spends the budget; overspent, the reward is cut
        budget = spend(budget, cost, c.cost_limit if limit is None else limit)
        reward = jnp.where(budget < 0, -c.saute_penalty, reward)
    start = hit.at[:, env.width * env.height * 2 :].set(False)  # a new episode: no change yet
    visited = jnp.where(done[:, None], start, carry.visited | hit)

    # A step that reaches the goal (or lava) on the last allowed step is both terminated and
    # truncated, and is terminal: only cut episodes bootstrap, and only they run the policy.
    truncated = ts.truncated & ~ts.terminated

    def final_values(rows):
        _, v, cv, _ = policy(*rows)
        return v, cv

    zeros = jnp.zeros_like(value)
    rows = (final["image"], final["direction"], carry.sentence, memory, budget)
    v_final, cv_final = masked_map(truncated, final_values, rows, (zeros, zeros))
    trunc = truncated.astype(jnp.float32)
    transition = Transition(
        image=obs["image"], direction=obs["direction"], sentence=carry.sentence,
        action=action, log_prob=log_prob, value=value, cost_value=cost_value,
        reward=reward + c.gamma * trunc * v_final, cost=cost + c.gamma * trunc * cv_final,
        done=done, allowed=allowed, budget=carry.budget,
        logits=None if c.mode.policy_update == "ppo" else logits,
    )  # fmt: skip
    ep_return = carry.ep_return + ts.reward
    ep_length = carry.ep_length + 1
    stats = {
        "episodes": done.sum(),
        "episode_return": jnp.where(done, ep_return, 0.0).sum(),
        "successes": (done & (ts.reward > 0)).sum(),
        "violations": violation.sum(),
        "alarms": alarm.sum(),
        "cost": cost.sum(),
        "env_cost": cost_of(ts).sum(),  # the env's own cost (info["cost"]), whatever the mode
        "novelty": bonus.sum(),
        "blocked": jnp.zeros((), jnp.int32) if allowed is None else (~allowed).sum(),
        "blocked_mass": blocked.sum(),
    }
    carry = EnvCarry(
        state=states, obs=ts.observation, sentence=sentence, frames=frames, visited=visited,
        ep_return=jnp.where(done, 0.0, ep_return), ep_length=jnp.where(done, 0, ep_length),
        alarmed=(alarm > 0) & ~done, memory=jnp.where(done[:, None], 0.0, memory),
        budget=None if budget is None else jnp.where(done, 1.0, budget),
    )  # fmt: skip
    return carry, (transition, stats)
