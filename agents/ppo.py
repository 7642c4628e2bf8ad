"""PPO fused into one jitted update: rollout, checker, reward shaping, GAE, optimisation.

``make_train(config, checker) -> train(key)`` in the PureJaxRL style, with a frozen
dataclass config. One update is

1. a ``lax.scan`` over ``num_steps`` steps of ``num_envs`` auto-resetting environments;
   each step also pushes the observation into a per-env window of the last ``n`` frames and,
   in the checker modes, asks the checker for the violation probability of that window;
2. rewards shaped by the reward mode (see :data:`REWARD_MODES`);
3. GAE, where truncated episodes bootstrap from the value of their final observation
   (truncation is never treated as termination);
4. ``update_epochs`` x ``num_minibatches`` clipped-PPO steps.

``train(key)`` scans ``num_updates // eval_every`` chunks of ``eval_every`` updates, each
followed by an evaluation on fixed seeds; it is pure, so ``jax.jit(jax.vmap(train))`` runs
several seeds at once. :mod:`agents.runner` drives the same pieces chunk by chunk from the
host for progress bars, logs and checkpoints.

Where the time goes, and what is done about it:

* Constraints come from a small fixed table of sentences (28 to 140 per scenario). The GRU
  encodes the *table* once per minibatch (and once per rollout), and each sample gathers its
  row by sentence index, instead of running the GRU on every sample. Same gradients.
* The checker's per-frame embedding is computed once per frame and kept in a ring buffer of
  embeddings (2 frame embeddings per env step instead of ``n``), and its sentence features
  are computed once per training run (the checker is frozen). The probabilities equal
  :func:`checker.reward.violation_prob` on the raw frame buffer (tested).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import flax.struct as struct
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax import lax

import jaxgrid
from agents.evaluation import play_episodes, summarise, violation_of
from agents.networks import ActorCritic
from jaxgrid import language
from jaxgrid.constants import EMPTY

from agents.config import REWARD_MODES, PPOConfig, check_checker  # noqa: E402,F401


# ----------------------------------------------------------------------------------------
# Pytrees carried through training
# ----------------------------------------------------------------------------------------
class EnvCarry(struct.PyTreeNode):
    """Everything with a leading ``num_envs`` axis (sharded over devices)."""

    state: Any
    obs: dict
    sentence: jax.Array  # int32: row of the sentence table
    frames: jax.Array  # float32 (E, n - 1, D): checker embeddings of the last n-1 frames
    visited: jax.Array  # bool (E, W*H*2): (cell, carrying) pairs seen this episode, or (E, 1)
    ep_return: jax.Array
    ep_length: jax.Array


class RunnerState(struct.PyTreeNode):
    params: Any
    opt_state: Any
    lagrange: jax.Array  # float32 multiplier of the Lagrangian mode (0 otherwise)
    key: jax.Array
    update: jax.Array  # int32 number of updates done
    env: EnvCarry


class Transition(struct.PyTreeNode):
    image: jax.Array
    direction: jax.Array
    sentence: jax.Array
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    cost_value: jax.Array
    reward: jax.Array  # shaped training reward, truncation bootstrap included
    cost: jax.Array  # Lagrangian cost, truncation bootstrap included
    done: jax.Array


# ----------------------------------------------------------------------------------------
# Building blocks
# ----------------------------------------------------------------------------------------
def sentence_table(env) -> np.ndarray:
    """Token ids (K, L) of every sentence the env's split can produce (one pad row if none)."""
    if not hasattr(env, "constraint_table"):
        return np.zeros((1, language.MAX_LEN), np.int32)
    return np.asarray(env.constraint_table()["tokens"], np.int32)


def sentence_index(tokens: jax.Array | None, table: jax.Array) -> jax.Array:
    """Row of ``table`` equal to each row of ``tokens`` (B, L); 0 when obs has no constraint."""
    if tokens is None:
        return jnp.zeros((), jnp.int32)
    match = jnp.all(tokens[:, None, :] == table[None, :, :], axis=-1)
    return jnp.argmax(match, axis=-1).astype(jnp.int32)


def _pick(obs: dict) -> dict:
    """The parts of an observation that name its sentence."""
    return {k: obs[k] for k in ("constraint", "direction") if k in obs}


def masked_map(mask: jax.Array, fn, inputs, other, chunk: int = 16):
    """``where(mask, fn(inputs), other)`` row by row, calling ``fn`` on the masked rows only.

    ``fn`` maps a batch (pytree, leading axis) to a batch; ``other`` is a pytree of its output
    shapes. Few envs end an episode on a given step, so the masked rows go through ``fn``
    ``chunk`` at a time in a ``while_loop``: one pass in the common case, as many as needed
    when many episodes end together (also under ``vmap``). For row-wise ``fn`` whose rows do
    not depend on the rest of the batch (env resets, the checker's frame embedding) the result
    has the same bits as computing every row; a matmul's rows (the truncation bootstrap's
    values) may round differently in the last place for another number of rows.
    """
    n = mask.shape[0]
    chunk = min(chunk, n)
    rank = jnp.cumsum(mask) - 1  # position of each masked row among the masked rows
    rows = jnp.nonzero(mask, size=n + chunk, fill_value=0)[0]  # masked rows first; the zero
    count = mask.sum()  # tail keeps every slice in range

    def body(state):
        start, out = state
        take = lax.dynamic_slice_in_dim(rows, start, chunk)
        new = fn(jax.tree.map(lambda x: x[take], inputs))
        here = mask & (rank >= start) & (rank < start + chunk)
        pick = jnp.clip(rank - start, 0, chunk - 1)

        def place(a, b):
            return jnp.where(here.reshape((n,) + (1,) * (b.ndim - 1)), a[pick], b)

        return start + chunk, jax.tree.map(place, new, out)

    return lax.while_loop(lambda s: s[0] < count, body, (jnp.int32(0), other))[1]


def shuffle(key: jax.Array, n: int) -> jax.Array:
    """A random permutation of ``range(n)`` for minibatching, from one sort of uint32.

    ``argsort`` of random bits sorts (bits, index) pairs; here the low ``b = bit_length(n-1)``
    bits of each random word are replaced by the index and one array of distinct words is
    sorted (measured 4.5x faster on CPU at n = 32768). Ties among the high ``32 - b`` random
    bits keep index order; a tie only changes which minibatch an item lands in when it
    straddles a minibatch boundary, so the partition into minibatches is uniform to within
    that. Used up to ``n = 2**16`` (at least 16 random bits); larger batches, where ties would
    grow common, fall back to ``argsort`` (and ``jax.random.permutation`` is slower still).
    """
    bits = jax.random.bits(key, (n,))
    b = max(n - 1, 1).bit_length()
    if b > 16:
        return jnp.argsort(bits)
    low = jnp.uint32((1 << b) - 1)
    words = (bits & ~low) | jnp.arange(n, dtype=jnp.uint32)
    return (lax.sort(words) & low).astype(jnp.int32)


class Learner(struct.PyTreeNode):
    """The pure functions of a run, closed over its static configuration.

    ``init(key) -> RunnerState``, ``update(runner) -> (runner, metrics)``,
    ``evaluate(params, key, num_episodes) -> dict`` and ``chunk(runner) -> (runner, metrics)``
    (``eval_every`` updates and one evaluation). Built by :func:`make_learner`.
    """

    config: PPOConfig = struct.field(pytree_node=False)
    env: Any = struct.field(pytree_node=False)
    network: ActorCritic = struct.field(pytree_node=False)
    optimizer: Any = struct.field(pytree_node=False)
    has_language: bool = struct.field(pytree_node=False, default=True)
    checker: Any = None
    table: jax.Array = None  # int32 (K, L)
    # Real tokens of the table's longest sentence. The sentence encoders run this many steps:
    # on the pad tail a GRU's carry is never read (same features and gradients, fewer steps).
    words: int = struct.field(pytree_node=False, default=language.MAX_LEN)

    # -- pieces -------------------------------------------------------------------------
    def _lang_table(self, params):
        if not self.has_language:
            return jnp.zeros((1, self.network.lang_dim), jnp.float32)
        tokens = self.table[:, : self.words]
        return self.network.apply(params, tokens, method=ActorCritic.sentence_features)

    def _policy(self, params, lang_table, image, direction, sentence):
        # A one-hot matmul instead of a gather: its gradient is a matmul, not a CPU scatter.
        lang = jax.nn.one_hot(sentence, lang_table.shape[0], dtype=lang_table.dtype) @ lang_table
        return self.network.apply(params, image, direction, lang)

    def _sentence(self, obs):
        return sentence_index(obs.get("constraint"), self.table) * jnp.ones_like(obs["direction"])

    def _embed(self, images):
        if self.checker is None:
            return jnp.zeros(images.shape[:-3] + (1,), jnp.float32)
        return self.checker.embed_states(images)

    def _step_envs(self, states, action):
        """``vmap(AutoReset(env).step)``, same bits, but only the envs whose episode ended
        generate and observe a fresh episode (AutoReset does so for every env, every step)."""
        env = self.env
        states, ts = jax.vmap(env.step)(states, action)
        key, layout_key = jnp.moveaxis(jax.vmap(jax.random.split)(states.key), 1, 0)
        done = ts.terminated | ts.truncated

        @jax.vmap
        def fresh(keys):
            state = env.generate(keys[0]).replace(key=keys[1])
            return state, env.observe(state)

        old = (states.replace(key=key), ts.observation)
        states, obs = masked_map(done, fresh, (layout_key, key), old)
        info = {**ts.info, "final_observation": ts.observation}
        return states, ts.replace(observation=obs, info=info)

    def _empty_frames(self, num_envs):
        pad = self._embed(jnp.zeros((1, self.env.view_size, self.env.view_size, 3), jnp.uint8))
        # Without a checker one placeholder frame: orbax cannot checkpoint zero-size arrays.
        n = self.checker.config.window - 1 if self.checker is not None else 1
        return jnp.broadcast_to(pad[:, None, :], (num_envs, n, pad.shape[-1]))

    def _push(self, frames, emb, start):
        """Ring buffer of checker embeddings; the start of an episode clears older frames."""
        if self.checker is None or frames.shape[1] == 0:
            return frames
        pad = self._empty_frames(frames.shape[0])
        older = jnp.where(start[:, None, None], pad, frames)
        return jnp.concatenate([older[:, 1:], emb[:, None]], axis=1)

    def _visits(self, states) -> jax.Array:
        """bool (E, W*H*2): one-hot of each env's (cell, carrying or not) for the novelty
        bonus; (E, 1) False when the bonus is off, so that nothing is paid for it."""
        if self.config.novelty_bonus == 0:
            return jnp.zeros((states.agent_pos.shape[0], 1), bool)
        env = self.env
        x, y = states.agent_pos[:, 0], states.agent_pos[:, 1]
        carrying = (states.carrying[:, 0] != EMPTY).astype(jnp.int32)
        cell = (x * env.height + y) * 2 + carrying
        return cell[:, None] == jnp.arange(env.width * env.height * 2)

    def _checker_prob(self, frames, emb, sentence):
        """P(violation) for the window (frames..., emb) of each env."""
        window = jnp.concatenate([frames, emb[:, None]], axis=1)
        lang = self.checker.encode_language(self.table[:, : self.words])[sentence]
        return jax.nn.sigmoid(self.checker.classify(window, lang))

    # -- init ---------------------------------------------------------------------------
    def init(self, key: jax.Array) -> RunnerState:
        c, env = self.config, self.env
        key, net_key, env_key = jax.random.split(key, 3)
        states, ts = jax.vmap(env.reset)(jax.random.split(env_key, c.num_envs))
        obs = ts.observation
        params = self.network.init(
            net_key, obs["image"][:1], obs["direction"][:1], self.table[:1],
            method=ActorCritic.init_all,
        )  # fmt: skip
        frames = self._empty_frames(c.num_envs)
        if self.checker is not None:
            start = jnp.ones((c.num_envs,), bool)
            frames = self._push(frames, self._embed(obs["image"]), start)
        zeros = jnp.zeros((c.num_envs,), jnp.float32)
        carry = EnvCarry(
            state=states, obs=obs, sentence=self._sentence(obs), frames=frames,
            visited=self._visits(states),
            ep_return=zeros, ep_length=zeros.astype(jnp.int32),
        )  # fmt: skip
        return RunnerState(
            params=params,
            opt_state=self.optimizer.init(params),
            lagrange=jnp.float32(c.lagrangian_init if c.reward_mode == "lagrangian" else 0.0),
            key=key,
            update=jnp.zeros((), jnp.int32),
            env=carry,
        )

    # -- rollout ------------------------------------------------------------------------
    def _env_step(self, params, lang_table, carry: EnvCarry, key, penalty=None, novelty=None):
        c = self.config
        penalty = c.penalty if penalty is None else penalty
        novelty = c.novelty_bonus if novelty is None else novelty
        obs = carry.obs
        logits, value, cost_value = self._policy(
            params, lang_table, obs["image"], obs["direction"], carry.sentence
        )
        action = jax.random.categorical(key, logits)
        log_prob = jax.nn.log_softmax(logits)[jnp.arange(action.shape[0]), action]
        states, ts = self._step_envs(carry.state, action)
        done = ts.terminated | ts.truncated
        final = ts.info["final_observation"]
        violation = violation_of(ts)

        alarm = prob = jnp.zeros_like(ts.reward)
        frames = carry.frames
        if self.checker is not None:
            emb = self._embed(final["image"])
            prob = self._checker_prob(carry.frames, emb, carry.sentence)
            alarm = (prob > c.checker_threshold).astype(jnp.float32)
            # Append the returned observation: the final one where the episode goes on; where
            # it ended, the window restarts at the next episode's first observation, which
            # only those few envs embed.
            emb = masked_map(done, self._embed, ts.observation["image"], emb)
            frames = self._push(carry.frames, emb, done)
        signal = prob if c.soft_checker else alarm
        cost = jnp.zeros_like(ts.reward)
        reward = ts.reward
        if c.reward_mode == "shaped":
            reward = reward - penalty * violation.astype(jnp.float32)
        elif c.reward_mode == "checker":
            reward = reward - penalty * signal
        elif c.reward_mode == "lagrangian":
            cost = signal
        # Novelty: the step reached a (cell, carrying) pair new to this episode. Where the
        # episode ended, ``states`` is the next episode's start, whose visit opens a new set.
        hit = self._visits(states)
        new = ~jnp.any(carry.visited & hit, axis=1) & ~done
        bonus = novelty * new.astype(jnp.float32)  # novelty is 0 when the bonus is off
        reward = reward + bonus
        visited = jnp.where(done[:, None], hit, carry.visited | hit)

        # Truncation bootstraps from the final observation's values, only where the episode
        # was cut by the time limit: a step that reaches the goal (or lava) on the last allowed
        # step is both terminated and truncated, and is terminal.
        truncated = ts.truncated & ~ts.terminated

        def final_values(rows):
            _, v, cv = self._policy(params, lang_table, *rows)
            return v, cv

        # Only the truncated envs, a few per step (a lax.cond ran all of them when any was).
        zeros = jnp.zeros_like(value)
        rows = (final["image"], final["direction"], carry.sentence)
        v_final, cv_final = masked_map(truncated, final_values, rows, (zeros, zeros))
        trunc = truncated.astype(jnp.float32)
        transition = Transition(
            image=obs["image"], direction=obs["direction"], sentence=carry.sentence,
            action=action, log_prob=log_prob, value=value, cost_value=cost_value,
            reward=reward + c.gamma * trunc * v_final, cost=cost + c.gamma * trunc * cv_final,
            done=done,
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
            "novelty": bonus.sum(),
        }
        carry = EnvCarry(
            state=states, obs=ts.observation,
            # The constraint is fixed for an episode: look it up where one began.
            sentence=masked_map(done, self._sentence, _pick(ts.observation), carry.sentence),
            frames=frames, visited=visited, ep_return=jnp.where(done, 0.0, ep_return),
            ep_length=jnp.where(done, 0, ep_length),
        )  # fmt: skip
        return carry, (transition, stats)

    # -- learning -----------------------------------------------------------------------
    def _gae(self, values, rewards, dones, last_value):
        c = self.config

        def step(carry, x):
            gae, next_value = carry
            value, reward, done = x
            not_done = 1.0 - done.astype(jnp.float32)
            delta = reward + c.gamma * next_value * not_done - value
            gae = delta + c.gamma * c.gae_lambda * not_done * gae
            return (gae, value), gae

        init = (jnp.zeros_like(last_value), last_value)
        _, adv = lax.scan(step, init, (values, rewards, dones), reverse=True)
        return adv, adv + values

    def _loss(self, params, batch, lagrange):
        c = self.config
        lang_table = self._lang_table(params)
        logits, value, cost_value = self._policy(
            params, lang_table, batch["image"], batch["direction"], batch["sentence"]
        )
        log_probs = jax.nn.log_softmax(logits)
        log_prob = jnp.take_along_axis(log_probs, batch["action"][:, None], axis=-1)[:, 0]
        entropy = -jnp.sum(jnp.exp(log_probs) * log_probs, axis=-1).mean()

        adv = batch["advantage"]
        if c.reward_mode == "lagrangian":
            adv = (adv - lagrange * batch["cost_advantage"]) / (1.0 + lagrange)
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        ratio = jnp.exp(log_prob - batch["log_prob"])
        clipped = jnp.clip(ratio, 1 - c.clip_eps, 1 + c.clip_eps)
        actor_loss = -jnp.minimum(ratio * adv, clipped * adv).mean()

        def value_loss(pred, old, target):
            pred_clipped = old + jnp.clip(pred - old, -c.clip_eps, c.clip_eps)
            return 0.5 * jnp.maximum((pred - target) ** 2, (pred_clipped - target) ** 2).mean()

        v_loss = value_loss(value, batch["value"], batch["target"])
        cv_loss = jnp.zeros(())
        if c.reward_mode == "lagrangian":
            cv_loss = value_loss(cost_value, batch["cost_value"], batch["cost_target"])
        total = actor_loss + c.vf_coef * (v_loss + cv_loss) - c.ent_coef * entropy
        approx_kl = jnp.mean((ratio - 1.0) - jnp.log(ratio))
        return total, {
            "loss": total, "actor_loss": actor_loss, "value_loss": v_loss,
            "cost_value_loss": cv_loss, "entropy": entropy, "approx_kl": approx_kl,
        }  # fmt: skip

    def constraint_ramp(self, update: jax.Array) -> jax.Array:
        """How far the constraint is switched on at update ``update`` (0-based): 0 for the
        first ``penalty_start`` of training, then a linear ramp to 1 over ``penalty_warmup``."""
        c = self.config
        start, warmup = c.penalty_start * c.num_updates, c.penalty_warmup * c.num_updates
        done = (update + 1 - start) / warmup if warmup > 0 else (update + 1 > start) * 1.0
        return jnp.clip(done, 0.0, 1.0)

    def penalty_at(self, update: jax.Array) -> jax.Array:
        """The shaping penalty of update ``update`` (0-based): 0, a ramp, then ``penalty``."""
        return (self.config.penalty * self.constraint_ramp(update)).astype(jnp.float32)

    def novelty_at(self, update: jax.Array) -> jax.Array:
        """The novelty bonus of update ``update``: ``novelty_bonus`` annealed linearly to 0."""
        c = self.config
        return (c.novelty_bonus * (1.0 - update / c.num_updates)).astype(jnp.float32)

    def update(self, runner: RunnerState):
        """One PPO update: rollout, GAE, epochs x minibatches. Returns per-update metrics."""
        c = self.config
        key, rollout_key, perm_key = jax.random.split(runner.key, 3)
        params = runner.params
        lang_table = self._lang_table(params)
        penalty = self.penalty_at(runner.update)
        novelty = self.novelty_at(runner.update)

        def scan_step(carry, k):
            return self._env_step(params, lang_table, carry, k, penalty, novelty)

        env, (traj, stats) = lax.scan(
            scan_step, runner.env, jax.random.split(rollout_key, c.num_steps)
        )
        _, last_value, last_cost_value = self._policy(
            params, lang_table, env.obs["image"], env.obs["direction"], env.sentence
        )
        adv, target = self._gae(traj.value, traj.reward, traj.done, last_value)
        batch = {
            "image": traj.image, "direction": traj.direction, "sentence": traj.sentence,
            "action": traj.action, "log_prob": traj.log_prob, "value": traj.value,
            "advantage": adv, "target": target,
        }  # fmt: skip
        if c.reward_mode == "lagrangian":
            cadv, ctarget = self._gae(traj.cost_value, traj.cost, traj.done, last_cost_value)
            batch.update(cost_value=traj.cost_value, cost_advantage=cadv, cost_target=ctarget)
        flat = jax.tree.map(lambda x: x.reshape((c.batch_size,) + x.shape[2:]), batch)

        def epoch(carry, k):
            params, opt_state = carry
            perm = shuffle(k, c.batch_size)
            shuffled = jax.tree.map(
                lambda x: x[perm].reshape((c.num_minibatches, -1) + x.shape[1:]), flat
            )

            def minibatch(carry, mb):
                params, opt_state = carry
                grads, info = jax.grad(self._loss, has_aux=True)(params, mb, runner.lagrange)
                updates, opt_state = self.optimizer.update(grads, opt_state, params)
                return (optax.apply_updates(params, updates), opt_state), info

            return lax.scan(minibatch, (params, opt_state), shuffled)

        (params, opt_state), info = lax.scan(
            epoch, (params, runner.opt_state), jax.random.split(perm_key, c.update_epochs)
        )
        cost_rate = stats["cost"].sum() / c.batch_size
        # Cost per episode (rollout cost over the episodes it finished): the multiplier reacts
        # to what a constraint budget is about, and is not diluted by long safe stretches.
        episode_cost = stats["cost"].sum() / jnp.maximum(stats["episodes"].sum(), 1)
        lagrange = runner.lagrange
        if c.reward_mode == "lagrangian":
            step = c.lagrangian_lr * (episode_cost - c.cost_target)
            # Held at its start value until the constraint switches on (whatever ``penalty``).
            active = self.constraint_ramp(runner.update) > 0
            lagrange = jnp.where(active, jnp.maximum(0.0, lagrange + step), lagrange)
        metrics = jax.tree.map(jnp.mean, info)
        totals = jax.tree.map(jnp.sum, stats)
        metrics.update(
            {k: totals[k] for k in ("episodes", "successes", "violations", "alarms")},
            episode_return=totals["episode_return"] / jnp.maximum(totals["episodes"], 1),
            cost_rate=cost_rate,
            novelty_rate=totals["novelty"] / c.batch_size,
            episode_cost=episode_cost,
            lagrange=lagrange,
        )
        runner = runner.replace(
            params=params, opt_state=opt_state, lagrange=lagrange, key=key,
            update=runner.update + 1, env=env,
        )  # fmt: skip
        return runner, metrics

    # -- evaluation ---------------------------------------------------------------------
    def act(self, params, obs, key, table=None):
        """Sample actions for a batch of observations (any sentence: the GRU runs on it)."""
        tokens = obs.get("constraint")
        if tokens is None:
            lang = jnp.zeros((obs["direction"].shape[0], self.network.lang_dim), jnp.float32)
        else:
            lang = self.network.apply(params, tokens, method=ActorCritic.sentence_features)
        logits, _, _ = self.network.apply(params, obs["image"], obs["direction"], lang)
        return jax.random.categorical(key, logits)

    def evaluate(self, params, key, num_episodes: int, env=None):
        """Rates of :func:`agents.evaluation.play_episodes` (fixed ``key`` = fixed seeds)."""
        env = self.env if env is None else env
        return play_episodes(env, lambda o, k: self.act(params, o, k), key, num_episodes)

    def chunk(self, runner: RunnerState):
        """``eval_every`` updates, then evaluation on the fixed evaluation seeds."""
        runner, metrics = lax.scan(
            lambda r, _: self.update(r), runner, None, self.config.eval_every
        )
        eval_key = jax.random.PRNGKey(self.config.eval_seed)
        evaluation = summarise(self.evaluate(runner.params, eval_key, self.config.eval_episodes))
        return runner, {"train": metrics, "eval": evaluation}


def make_learner(config: PPOConfig, checker=None) -> Learner:
    """Validate ``config`` (and ``checker``) and build the run's :class:`Learner`."""
    env = config.make_env()
    check_checker(config, checker, env)
    if config.reward_mode in ("none", "shaped"):
        checker = None  # not needed: skip its cost
    num_updates = config.num_updates
    table = sentence_table(env)

    def schedule(count):
        per_update = config.update_epochs * config.num_minibatches
        frac = 1.0 - (count // per_update) / num_updates
        return config.lr * frac if config.anneal_lr else config.lr

    optimizer = optax.chain(
        optax.clip_by_global_norm(config.max_grad_norm),
        optax.adam(schedule, eps=1e-5),
    )
    return Learner(
        config=config,
        env=env,
        network=ActorCritic(num_actions=env.num_actions, conv_channels=config.conv_channels),
        optimizer=optimizer,
        checker=checker,
        has_language=hasattr(env, "constraint_table"),
        table=jnp.asarray(table),
        words=max(1, int((table != language.VOCAB.index(language.PAD)).sum(1).max())),
    )


def make_train(config: PPOConfig, checker=None):
    """PureJaxRL-style: returns a pure ``train(key) -> dict``; jit and vmap it freely.

    The result holds the final ``runner`` state, ``train`` metrics of every update (leading
    axes ``(num_chunks, eval_every)``) and ``eval`` rates after every chunk
    (``(num_chunks,)``); :func:`evaluation_steps` gives the env steps done at each
    evaluation.
    """
    learner = make_learner(config, checker)

    def train(key):
        runner = learner.init(key)
        runner, metrics = lax.scan(lambda r, _: learner.chunk(r), runner, None, config.num_chunks)
        return {"runner": runner, **metrics}

    return train


def evaluation_steps(config: PPOConfig) -> np.ndarray:
    """Env steps done at each of the ``num_chunks`` evaluations of :func:`make_train`."""
    per_chunk = config.eval_every * config.batch_size
    return per_chunk * np.arange(1, config.num_chunks + 1, dtype=np.int64)
