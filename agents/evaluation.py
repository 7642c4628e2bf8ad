"""Evaluation episodes: a batch of fresh episodes played once each, on device.

Episodes start from fixed evaluation seeds (the same keys for every method, so methods are
compared on the same episodes), run with the raw ``env.step`` (no auto-reset) for at most
``max_steps`` steps, and report per episode whether it reached the goal, whether it violated its
constraint at least once, and its return in **environment reward only** (shaping never
enters evaluation). Beside violations it reports the field's cost metrics: the episode cost
(the sum of ``info["cost"]``) and the longest run of consecutive costly steps, which an
average cost hides (ten costly steps in a row, say crossing a lava field, cost as much as
ten scattered ones).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jax import lax


def violation_of(ts) -> jax.Array:
    """Ground-truth violation flags of a (batched) timestep; zeros for envs without one."""
    return ts.info.get("violation", jnp.zeros_like(ts.terminated))


def cost_of(ts) -> jax.Array:
    """The monitor's float32 cost of a (batched) timestep (1 where a costly event happened,
    within a budget or not); zeros for envs without a constraint."""
    return ts.info.get("cost", jnp.zeros_like(ts.reward))


def spend(budget: jax.Array, cost: jax.Array, limit) -> jax.Array:
    """A Saute agent's remaining safety budget after a step of cost ``cost``: ``budget``
    (1 at an episode's start) less ``cost / limit``, its share of the episode's cost limit,
    kept in [-1, 1] (the policy observes it; below 0 the budget is overspent). With
    ``limit`` 0 any cost spends it all."""
    return jnp.clip(budget - cost / jnp.maximum(limit, 1e-8), -1.0, 1.0)


def play_episodes(
    env,
    act: Callable[[dict, jax.Array], jax.Array],
    key: jax.Array,
    num_episodes: int,
    shield=None,
    memory=None,
    track: Callable | None = None,
    cost_limit=None,
) -> dict[str, jax.Array]:
    """Play ``num_episodes`` episodes in parallel with ``act(obs_batch, key) -> actions``.

    With a ``shield`` (:class:`agents.shield.Shield`) the actions come from
    ``act(obs_batch, key, allowed)``, ``allowed`` the shield's bool (E, A) mask of the step.
    With a policy ``memory`` (a pytree, its start value), ``act`` takes it last and returns
    ``(actions, memory)``; each env plays one episode, so it is never reset. With a
    ``cost_limit`` (a Saute policy's), ``act`` also takes ``budget=`` the episode's remaining
    safety budget (E,) (:func:`spend` of the monitor's costs so far).

    Layouts come from ``jax.random.split(key, num_episodes)``; action sampling uses keys
    folded from ``key`` too, so a fixed key gives the same episodes for the same policy.
    Returns ``(num_episodes,)`` arrays: ``success`` (bool, positive env reward), ``violated``
    (bool, at least one violation), ``violations`` (int32), ``reward`` (float32, env return),
    ``length`` (int32), ``cost`` (float32, the sum of ``info["cost"]``) and ``costly_run``
    (int32, the longest run of consecutive steps with a positive cost). With
    ``track(states) -> bool (E, K)``, also ``tracked`` (bool (E, K)): whether each flag held
    after any step of the episode (where agents get to).
    """
    reset_key, act_key = jax.random.split(key)
    states, ts = jax.vmap(env.reset)(jax.random.split(reset_key, num_episodes))
    zeros_i = jnp.zeros((num_episodes,), jnp.int32)
    zeros_f = jnp.zeros((num_episodes,), jnp.float32)
    alive = jnp.ones((num_episodes,), bool)
    track = (lambda states: jnp.zeros((num_episodes, 0), bool)) if track is None else track

    stateful = memory is not None

    def body(carry, t):
        (states, memory, (policy_memory, left)), obs, alive, ret, viol, length, seen, costs = carry
        args = (obs, jax.random.fold_in(act_key, t))
        if shield is not None:
            allowed, _ = shield.allowed_now(memory, states)
            args = args + (allowed,)
        given = {} if cost_limit is None else {"budget": left}
        if stateful:
            actions, policy_memory = act(*args, policy_memory, **given)
        else:
            actions = act(*args, **given)
        states, ts = jax.vmap(env.step)(states, actions)
        if cost_limit is not None:
            left = spend(left, cost_of(ts), cost_limit)
        if shield is not None:
            memory = shield.observe(memory, ts.observation, actions)
        live = alive.astype(jnp.int32)
        ret = ret + ts.reward * alive
        viol = viol + violation_of(ts).astype(jnp.int32) * live
        length = length + live
        seen = seen | (track(states) & alive[:, None])
        costs = _costs_after(costs, cost_of(ts), alive)
        alive = alive & ~(ts.terminated | ts.truncated)
        carry = ((states, memory, (policy_memory, left)), ts.observation, alive, ret, viol,
                 length, seen, costs)  # fmt: skip
        return carry, None

    budget = () if cost_limit is None else jnp.ones((num_episodes,), jnp.float32)
    policy_memory = (() if memory is None else memory, budget)
    memory = () if shield is None else shield.start(ts.observation)
    seen = jnp.zeros_like(track(states))
    costs = (zeros_f, zeros_i, zeros_i)  # episode cost, current costly run, longest run
    carry = ((states, memory, policy_memory), ts.observation, alive, zeros_f, zeros_i, zeros_i,
             seen, costs)  # fmt: skip
    (_, _, _, ret, viol, length, seen, costs), _ = lax.scan(body, carry, jnp.arange(env.max_steps))
    out = {
        "success": ret > 0,
        "violated": viol > 0,
        "violations": viol,
        "reward": ret,
        "length": length,
        "cost": costs[0],
        "costly_run": costs[2],
    }
    return out if seen.shape[1] == 0 else {**out, "tracked": seen}


def _costs_after(costs, step_cost, alive):
    """``(episode cost, current run, longest run)`` after a step of cost ``step_cost``; only
    live steps count (a finished episode's env keeps stepping)."""
    cost, run, longest = costs
    run = jnp.where(alive & (step_cost > 0), run + 1, 0)
    return cost + step_cost * alive, run, jnp.maximum(longest, run)


def summarise(episodes: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """Rates over a batch of :func:`play_episodes` results: violation %, reward, success %,
    length, the mean episode cost (``mean_cost``), and the longest run of consecutive costly
    steps, its mean over episodes (``mean_costly_run``) and its maximum (``max_costly_run``,
    float32 like the others)."""
    run = episodes["costly_run"].astype(jnp.float32)
    return {
        "violation_rate": jnp.mean(episodes["violated"].astype(jnp.float32)),
        "mean_reward": jnp.mean(episodes["reward"]),
        "success_rate": jnp.mean(episodes["success"].astype(jnp.float32)),
        "mean_length": jnp.mean(episodes["length"].astype(jnp.float32)),
        "mean_cost": jnp.mean(episodes["cost"]),
        "mean_costly_run": jnp.mean(run),
        "max_costly_run": jnp.max(run),
    }
