"""PPO fused into one jitted update, in the PureJaxRL style: ``make_train(config) -> train``.

One update is

1. a ``lax.scan`` of :func:`agents.rollout.env_step` over ``num_steps`` steps of
   ``num_envs`` auto-resetting environments (policy, checker, reward shaping, truncation
   bootstrap);
2. :func:`agents.losses.gae`;
3. ``update_epochs`` x ``num_minibatches`` steps of :func:`agents.losses.ppo_loss` (in
   ``cpo``, after :func:`agents.losses.cpo_step`, the value heads' only);
4. the cost's Lagrange multiplier (a gradient step, or the PID controller's).

One thing, the learner of every reward mode (:data:`agents.config.MODES`), hence its length.

``train(key)`` scans :attr:`PPOConfig.num_chunks` chunks of ``eval_every`` updates, each
followed by an evaluation on fixed seeds; it is pure, so ``jax.jit(jax.vmap(train))`` runs
several seeds at once. :mod:`agents.runner` drives the same :class:`Learner` chunk by chunk
from the host for progress bars, logs and checkpoints.

Constraints come from a small fixed table of sentences, so the sentence GRUs encode the
table (once per rollout and once per minibatch) and each sample gathers its row.
"""

from __future__ import annotations

import functools
from typing import Any

import flax.struct as struct
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax import lax

from agents import checker_carry, rollout
from agents.config import SWEEPABLE, PPOConfig, check_checker
from agents.evaluation import play_episodes, summarise
from agents.losses import PIDState, cpo_step, gae, pid_update, ppo_loss, shuffle
from agents.networks import (
    ActorCritic,
    apply_policy,
    start_memory,
    table_features,
    table_rows,
    value_heads_only,
)
from agents.rollout import EnvCarry, Transition
from agents.shield import make_shield, mask_logits
from checker.protocol import CheckerProtocol
from jaxgrid import language
from jaxgrid.constrained import ConstrainedEnvironment, language_table, sentence_tokens
from jaxgrid.sentences import PAPER
from jaxgrid.wrappers import BatchedAutoReset


class RunnerState(struct.PyTreeNode):
    params: Any
    opt_state: Any
    lagrange: jax.Array  # float32 Lagrange multiplier of the cost (0 in modes without one)
    key: jax.Array
    update: jax.Array  # int32 number of updates done
    env: EnvCarry
    # float32 values of the swept hyperparameters (names of SWEEPABLE) where they differ
    # between the agents of one program; every other one is the config's constant.
    hparams: dict = struct.field(default_factory=dict)
    # float32 training success rate of the last update (read only with a penalty gate)
    success: jax.Array = struct.field(default_factory=lambda: jnp.zeros((), jnp.float32))
    # the PID Lagrangian's controller memory (None in the other modes: no leaves, so their
    # state and checkpoints are as they were)
    pid: PIDState | None = None


class Learner(struct.PyTreeNode):
    """The pure functions of a run, closed over its static configuration.

    ``init(key) -> RunnerState``; ``rollout(runner) -> (env, Transition, stats)``;
    ``update(runner) -> (runner, metrics)``; ``chunk(runner) -> (runner, metrics)``
    (``eval_every`` updates and one evaluation); ``act`` and ``evaluate`` for a trained
    policy. Built by :func:`make_learner`.
    """

    config: PPOConfig = struct.field(pytree_node=False)
    env: Any = struct.field(pytree_node=False)  # the raw env; training steps it batched
    network: ActorCritic = struct.field(pytree_node=False)
    optimizer: Any = struct.field(pytree_node=False)
    has_language: bool = struct.field(pytree_node=False, default=True)
    checker: CheckerProtocol | None = None
    shield: Any = None  # agents.shield.Shield in the shield modes
    table: jax.Array = None  # int32 (K, L): the env's sentence table
    # Real tokens of the table's longest sentence. The sentence encoders run this many steps:
    # on the pad tail a GRU's carry is never read (same features and gradients, fewer steps).
    words: int = struct.field(pytree_node=False, default=PAPER.max_len)

    # -- pieces -------------------------------------------------------------------------
    @property
    def envs(self) -> BatchedAutoReset:
        """The env batch training steps: auto-reset only where an episode ended."""
        return BatchedAutoReset(self.env)

    def lang_table(self, params) -> jax.Array:
        """(K, lang_dim): the policy's sentence features of every row of the table."""
        tokens = self.table[:, : self.words] if self.has_language else None
        return table_features(self.network, params, tokens)

    def policy(self, params, lang_table=None):
        """The policy ``(image, direction, sentence row, memory) -> (logits, value,
        cost_value, memory)`` (:func:`agents.networks.apply_policy`)."""
        lang_table = self.lang_table(params) if lang_table is None else lang_table
        return functools.partial(apply_policy, self.network, params, lang_table)

    def forward(self, params, mb: dict):
        """``(logits, value, cost_value)`` of a training minibatch, flat (B, ...).

        Memoryless: every sample on its own. Recurrent: ``mb`` holds (T, E_mb) sequences,
        ``memory0`` (E_mb, M) the memory before their first step and ``start`` (T, E_mb) the
        steps that begin an episode (memory reset); the memory is recomputed through time,
        so gradients reach the steps that wrote it.
        """
        budget = mb.get("budget")  # Saute's observed budget (None in the other modes)
        if not self.config.recurrent:
            memory = start_memory(self.network, mb["image"].shape[0])
            policy = self.policy(params)
            return policy(mb["image"], mb["direction"], mb["sentence"], memory, budget)[:3]
        # The observation features and the memory's input terms of every step at once (batched
        # passes); only the memory runs step by step, the heads again batched.
        lang_table = self.lang_table(params)
        flat = lambda x: x.reshape((-1,) + x.shape[2:])  # noqa: E731
        rows = flat(mb["sentence"])
        lang = table_rows(lang_table, rows)
        net = self.network
        budget = None if budget is None else flat(budget)
        feats = net.apply(
            params, flat(mb["image"]), flat(mb["direction"]), lang, budget,
            method=ActorCritic.observe,
        ).reshape(mb["sentence"].shape + (-1,))  # fmt: skip

        inputs = net.apply(params, feats, method=ActorCritic.memory_inputs)

        def one(memory, x):
            inputs, start = x
            memory = jnp.where(start[:, None], 0.0, memory)
            memory = net.apply(params, inputs, memory, method=ActorCritic.remember)
            return memory, memory

        _, memories = lax.scan(one, mb["memory0"], (inputs, mb["start"]))
        return net.apply(params, flat(feats), flat(memories), method=ActorCritic.read)

    def constraint_ramp(self, update: jax.Array) -> jax.Array:
        """How far the constraint is switched on at update ``update`` (0-based): 0 for the
        first ``penalty_start`` of training, then a linear ramp to 1 over ``penalty_warmup``."""
        c = self.config
        start, warmup = c.penalty_start * c.num_updates, c.penalty_warmup * c.num_updates
        done = (update + 1 - start) / warmup if warmup > 0 else (update + 1 > start) * 1.0
        return jnp.clip(done, 0.0, 1.0)

    def penalty_at(self, update: jax.Array, penalty: jax.Array | float | None = None):
        """The shaping penalty of update ``update`` (0-based): 0, a ramp, then ``penalty``
        (None: the config's)."""
        penalty = self.config.penalty if penalty is None else penalty
        return (penalty * self.constraint_ramp(update)).astype(jnp.float32)

    def penalty_of(self, runner: RunnerState):
        """The runner's penalty this update: :meth:`penalty_at`, times the success gate
        (``penalty_gate``) where there is one."""
        penalty = self.penalty_at(runner.update, self.hparam(runner, "penalty"))
        if self.config.penalty_gate > 0:
            penalty = penalty * jnp.minimum(1.0, runner.success / self.config.penalty_gate)
        return penalty

    def hparam(self, runner: RunnerState, name: str):
        """The agent's value of hyperparameter ``name``: traced where swept, else the
        config's constant (so that a run without a sweep compiles the same program)."""
        return runner.hparams[name] if name in runner.hparams else getattr(self.config, name)

    def shield_for(self, hparams: dict):
        """The shield at the agent's swept ``checker_threshold`` where ``hparams`` (a
        :class:`RunnerState`'s) holds one (None outside the shield modes)."""
        if self.shield is None or "checker_threshold" not in hparams:
            return self.shield
        return self.shield.replace(threshold=hparams["checker_threshold"])

    def novelty_at(self, update: jax.Array) -> jax.Array:
        """The novelty bonus of update ``update``: ``novelty_bonus`` annealed linearly to 0
        over the first ``novelty_anneal`` of the updates, 0 after."""
        c = self.config
        fraction = jnp.maximum(0.0, 1.0 - update / (c.novelty_anneal * c.num_updates))
        return (c.novelty_bonus * fraction).astype(jnp.float32)

    # -- init ---------------------------------------------------------------------------
    def init(self, key: jax.Array, hparams: dict | None = None) -> RunnerState:
        """A fresh run from ``key``; ``hparams`` {name: value} sets swept hyperparameters
        (names of :data:`agents.config.SWEEPABLE`) for this agent."""
        hparams = dict(hparams or {})
        unknown = sorted(set(hparams) - set(SWEEPABLE))
        if unknown:
            raise ValueError(f"cannot sweep {unknown}: sweepable are {', '.join(SWEEPABLE)}")
        c, env = self.config, self.env
        key, net_key, env_key = jax.random.split(key, 3)
        states, ts = self.envs.reset(jax.random.split(env_key, c.num_envs))
        obs = ts.observation
        params = self.network.init(
            net_key, obs["image"][:1], obs["direction"][:1], self.table[:1],
            method=ActorCritic.init_all,
        )  # fmt: skip
        sentence = rollout.sentence_rows(obs, self.table)
        lang = None
        if self.checker is not None:
            lang = self.checker.encode_language(self.table[:, : self.words])[sentence]
        emb = checker_carry.embed(self.checker, obs["image"])
        frames = checker_carry.start_memory(self.checker, emb, lang)
        zeros, zero = jnp.zeros((c.num_envs,), jnp.float32), jnp.float32(0.0)
        carry = EnvCarry(
            state=states, obs=obs, sentence=sentence,
            frames=frames, visited=rollout.config_visits(states, env, c),
            ep_return=zeros, ep_length=zeros.astype(jnp.int32), alarmed=zeros > 0,
            memory=start_memory(self.network, c.num_envs),
            budget=zeros + 1.0 if c.mode.budget else None,
        )  # fmt: skip
        return RunnerState(
            params=params,
            opt_state=self.optimizer.init(params),
            lagrange=jnp.float32(c.lagrangian_init if c.mode.multiplier else 0.0),
            key=key,
            update=jnp.zeros((), jnp.int32),
            env=carry,
            hparams={k: jnp.asarray(v, jnp.float32) for k, v in hparams.items()},
            success=jnp.zeros((), jnp.float32),
            pid=PIDState(zero, zero) if c.mode.multiplier == "pid" else None,
        )

    # -- rollout and update -------------------------------------------------------------
    def rollout(self, runner: RunnerState, key: jax.Array, lang_table=None):
        """``num_steps`` env steps with the runner's policy and the schedules of its update.

        Returns ``(env carry, Transition (T, E), statistics (T,))``.
        """
        step = functools.partial(
            rollout.env_step, config=self.config, env=self.envs,
            policy=self.policy(runner.params, lang_table), table=self.table, words=self.words,
            checker=self.checker, shield=self.shield_for(runner.hparams),
            penalty=self.penalty_of(runner), novelty=self.novelty_at(runner.update),
            threshold=self.hparam(runner, "checker_threshold"),
            limit=self.hparam(runner, "cost_limit"),
        )  # fmt: skip
        keys = jax.random.split(key, self.config.num_steps)
        env, (traj, stats) = lax.scan(step, runner.env, keys)
        return env, traj, stats

    def collect(self, runner: RunnerState, key: jax.Array, lang_table=None):
        """A rollout and its training batch: ``(env carry, Transition, statistics, batch)``
        (:meth:`rollout`, the last observation's values, :meth:`training_batch`)."""
        lang_table = self.lang_table(runner.params) if lang_table is None else lang_table
        env, traj, stats = self.rollout(runner, key, lang_table)
        _, last_value, last_cost_value, _ = self.policy(runner.params, lang_table)(
            env.obs["image"], env.obs["direction"], env.sentence, env.memory, env.budget
        )
        batch = self.training_batch(traj, last_value, last_cost_value, runner.env.memory)
        return env, traj, stats, batch

    def update(self, runner: RunnerState):
        """One PPO update: rollout, GAE, epochs x minibatches. Returns per-update metrics."""
        c = self.config
        key, rollout_key, perm_key = jax.random.split(runner.key, 3)
        params = runner.params
        env, traj, stats, batch = self.collect(runner, rollout_key, self.lang_table(params))
        penalty = self.penalty_of(runner)
        blocked_weight = penalty if self.shield is not None else 0.0
        ent_coef = self.hparam(runner, "ent_coef")
        # A swept learning rate scales the optimiser's step (Adam's step is linear in it).
        lr_scale = runner.hparams["lr"] / c.lr if "lr" in runner.hparams else None

        def samples(mb):  # per-sample arrays, flat (B, ...)
            flat = {k: v for k, v in mb.items() if k not in ("memory0", "start")}
            if c.recurrent:
                flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), flat)
            return flat

        # FOCOPS moves its multiplier on this rollout's cost before its epochs; the
        # Lagrangians move theirs after, for the next update.
        early = c.mode.policy_update == "focops"
        lagrange, pid = self.multiplier(runner, stats) if early else (runner.lagrange, None)

        def loss(params, mb, lagrange):
            out = self.forward(params, mb)
            policy = lambda p, *x: out  # noqa: E731  (computed from ``params`` above)
            return ppo_loss(policy, params, samples(mb), lagrange, c, blocked_weight, ent_coef)

        step_stats = {}
        if c.mode.policy_update == "cpo":
            # The trust-region step moves the policy; the epochs below then fit the value
            # heads alone, on its features, so that they move it no further. The constraint's
            # excess is per step, the surrogates' scale: per episode, over the mean length.
            excess = self.episode_cost(stats) - self.hparam(runner, "cost_limit")
            excess = excess * jnp.maximum(stats["episodes"].sum(), 1) / c.batch_size
            logits_of = lambda p: self.forward(p, batch)[0]  # noqa: E731
            params, step_stats = cpo_step(
                logits_of, params, samples(batch), excess, c, self.fisher_part(batch)
            )

        def epoch(carry, k):
            params, opt_state = carry
            shuffled = self.minibatches(batch, k)

            def minibatch(carry, mb):
                params, opt_state = carry
                grads, info = jax.grad(loss, has_aux=True)(params, mb, lagrange)
                if c.mode.policy_update == "cpo":
                    grads = value_heads_only(grads)
                updates, opt_state = self.optimizer.update(grads, opt_state, params)
                if lr_scale is not None:
                    updates = jax.tree.map(lambda u: u * lr_scale, updates)
                return (optax.apply_updates(params, updates), opt_state), info

            return lax.scan(minibatch, (params, opt_state), shuffled)

        (params, opt_state), info = lax.scan(
            epoch, (params, runner.opt_state), jax.random.split(perm_key, c.update_epochs)
        )
        if not early:
            lagrange, pid = self.multiplier(runner, stats)
        metrics = self._statistics(info, stats, lagrange)
        metrics.update(step_stats)
        runner = runner.replace(
            params=params, opt_state=opt_state, lagrange=lagrange, key=key,
            update=runner.update + 1, env=env, pid=pid,
        )  # fmt: skip
        if c.penalty_gate > 0:  # the gate's success rate (held where no episode finished)
            episodes = metrics["episodes"]
            success = metrics["successes"] / jnp.maximum(episodes, 1)
            runner = runner.replace(success=jnp.where(episodes > 0, success, runner.success))
        return runner, metrics

    def fisher_part(self, batch: dict):
        """CPO's Fisher-vector products average over every ``cpo_fisher_every``-th sample
        (whole env sequences of a recurrent policy): ``(logits_of, old logits)`` of that part,
        or None for the whole batch."""
        every = self.config.cpo_fisher_every
        if every == 1:
            return None
        if self.config.recurrent:
            part = {k: v[:, ::every] for k, v in batch.items() if k != "memory0"}
            part["memory0"] = batch["memory0"][::every]
            old = part["logits"].reshape((-1,) + part["logits"].shape[2:])
        else:
            part = jax.tree.map(lambda x: x[::every], batch)
            old = part["logits"]
        return (lambda p: self.forward(p, part)[0]), old

    def minibatches(self, batch: dict, key: jax.Array) -> dict:
        """``batch`` shuffled and split into ``num_minibatches`` (leading axis): samples
        (memoryless), or whole env sequences (recurrent: (nm, T, E / nm, ...))."""
        c = self.config
        if not c.recurrent:
            perm = shuffle(key, c.batch_size)
            return jax.tree.map(
                lambda x: x[perm].reshape((c.num_minibatches, -1) + x.shape[1:]), batch
            )
        perm = shuffle(key, c.num_envs)
        nm = c.num_minibatches

        def split(x):
            x = x[:, perm].reshape((x.shape[0], nm, -1) + x.shape[2:])
            return jnp.moveaxis(x, 1, 0)

        out = {k: split(v) for k, v in batch.items() if k != "memory0"}
        out["memory0"] = batch["memory0"][perm].reshape((nm, -1) + batch["memory0"].shape[1:])
        return out

    def training_batch(self, traj: Transition, last_value, last_cost_value, memory0=None) -> dict:
        """The training batch: transitions, advantages and targets, flat (T * E, ...); for a
        recurrent policy (T, E, ...) sequences with ``start`` flags and the memory
        ``memory0`` (E, M) the rollout began with."""
        c = self.config
        adv, target = gae(traj.value, traj.reward, traj.done, last_value, c.gamma, c.gae_lambda)
        batch = {
            "image": traj.image, "direction": traj.direction, "sentence": traj.sentence,
            "action": traj.action, "log_prob": traj.log_prob, "value": traj.value,
            "advantage": adv, "target": target,
        }  # fmt: skip
        if traj.allowed is not None:
            batch["allowed"] = traj.allowed
        if traj.budget is not None:
            batch["budget"] = traj.budget
        if traj.logits is not None:
            batch["logits"] = traj.logits
        if c.mode.cost_critic:
            cadv, ctarget = gae(
                traj.cost_value, traj.cost, traj.done, last_cost_value, c.gamma, c.gae_lambda
            )
            batch.update(cost_value=traj.cost_value, cost_advantage=cadv, cost_target=ctarget)
        if c.recurrent:
            # A step begins an episode where the previous one ended; step 0 continues the
            # memory the rollout began with.
            start = jnp.concatenate([jnp.zeros_like(traj.done[:1]), traj.done[:-1]])
            return {**batch, "start": start, "memory0": memory0}
        return jax.tree.map(lambda x: x.reshape((c.batch_size,) + x.shape[2:]), batch)

    def episode_cost(self, stats: dict) -> jax.Array:
        """A rollout's cost per episode: its cost over the episodes it finished. The
        constraints hold it, so that they react to what a constraint budget is about, and are
        not diluted by long safe stretches."""
        return stats["cost"].sum() / jnp.maximum(stats["episodes"].sum(), 1)

    def multiplier(self, runner: RunnerState, stats: dict):
        """``(the next Lagrange multiplier, the next PID state)`` after a rollout's ``stats``:
        a gradient step on its cost per episode over the limit, or the PID controller's."""
        c = self.config
        episode_cost = self.episode_cost(stats)
        lagrange, pid = runner.lagrange, runner.pid
        # Held at its start value until the constraint switches on (whatever ``penalty``).
        active = self.constraint_ramp(runner.update) > 0
        limit = self.hparam(runner, "cost_limit")
        if c.mode.multiplier == "gradient":
            step = c.lagrangian_lr * (episode_cost - limit)
            lagrange = jnp.where(active, jnp.maximum(0.0, lagrange + step), lagrange)
            if c.mode.policy_update == "focops":
                lagrange = jnp.minimum(lagrange, c.focops_nu_max)
        elif c.mode.multiplier == "pid":
            # The first update has no previous cost: no derivative. The controller follows
            # the cost from the start, and moves the multiplier once the constraint is on.
            previous = jnp.where(runner.update == 0, episode_cost, pid.cost)
            new, moved = pid_update(
                pid.replace(cost=previous), episode_cost, limit, c.pid_kp, c.pid_ki, c.pid_kd
            )
            lagrange = jnp.where(active, new, lagrange)
            pid = moved.replace(integral=jnp.where(active, moved.integral, pid.integral))
        return lagrange, pid

    def _statistics(self, info: dict, stats: dict, lagrange: jax.Array) -> dict:
        """The update's metrics: the losses' means, the rollout's totals and rates."""
        c = self.config
        cost_rate = stats["cost"].sum() / c.batch_size
        episode_cost = self.episode_cost(stats)
        metrics = jax.tree.map(jnp.mean, info)
        totals = jax.tree.map(jnp.sum, stats)
        metrics.update(
            {k: totals[k] for k in ("episodes", "successes", "violations", "alarms", "blocked")},
            blocked_rate=totals["blocked_mass"] / c.batch_size,
            episode_return=totals["episode_return"] / jnp.maximum(totals["episodes"], 1),
            cost_rate=cost_rate,
            novelty_rate=totals["novelty"] / c.batch_size,
            episode_cost=episode_cost,
            env_cost=totals["env_cost"],  # the env's info["cost"], whatever the mode uses
            lagrange=lagrange,
        )
        return metrics

    # -- evaluation ---------------------------------------------------------------------
    def act(self, params, obs, key, allowed=None, memory=None, budget=None):
        """Sample actions for a batch of observations (any sentence: the GRU runs on it),
        among the ``allowed`` ones (bool (B, A)) when given.

        A recurrent policy needs ``memory`` (B, M) (zeros at an episode's start,
        :func:`agents.networks.start_memory`) and returns ``(actions, memory)``. A Saute
        policy reads ``budget`` (B,), the episode's remaining safety budget
        (:func:`agents.evaluation.spend`; None: all of it, as at an episode's start).
        """
        if self.config.recurrent and memory is None:
            raise ValueError("a recurrent policy acts with its memory: act(..., memory=...)")
        tokens = obs.get("constraint")
        batch = obs["direction"].shape[0]
        if tokens is None:
            lang = jnp.zeros((batch, self.network.lang_dim), jnp.float32)
        else:
            lang = self.network.apply(params, tokens, method=ActorCritic.sentence_features)
        given = memory is not None
        memory = start_memory(self.network, batch) if memory is None else memory
        logits, _, _, memory = self.network.apply(
            params, obs["image"], obs["direction"], lang, memory, budget, method=ActorCritic.step
        )
        if allowed is not None:
            logits = mask_logits(logits, allowed)
        actions = jax.random.categorical(key, logits)
        return (actions, memory) if given else actions

    def evaluate(
        self,
        params,
        key,
        num_episodes: int,
        env=None,
        shielded: bool = True,
        hparams=None,
        track=None,
    ):
        """Per-episode results of :func:`agents.evaluation.play_episodes` (fixed ``key`` =
        fixed episodes) on the raw env (or ``env``): in the shield modes with the shield on
        (as deployed; at the agent's swept threshold in ``hparams``, if any) unless
        ``shielded`` is False (the policy alone). ``track``: as in ``play_episodes``. A Saute
        policy's budget is spent by the monitor's cost, at the agent's ``cost_limit``
        (evaluation runs no checker)."""
        env = self.env if env is None else env
        memory = start_memory(self.network, num_episodes) if self.config.recurrent else None
        limit = None
        if self.config.mode.budget:
            limit = (hparams or {}).get("cost_limit", self.config.cost_limit)
        if self.shield is None or not shielded:
            act = lambda o, k, *m, **b: self.act(params, o, k, None, *m, **b)  # noqa: E731
            return play_episodes(env, act, key, num_episodes, memory=memory, track=track,
                                 cost_limit=limit)  # fmt: skip
        shield = self.shield_for(hparams or {}).replace(env=env)
        act = lambda o, k, allowed, *m: self.act(params, o, k, allowed, *m)  # noqa: E731
        return play_episodes(env, act, key, num_episodes, shield=shield, memory=memory,
                             track=track)  # fmt: skip

    def chunk(self, runner: RunnerState):
        """``eval_every`` updates, then evaluation on the fixed evaluation seeds."""
        runner, metrics = lax.scan(
            lambda r, _: self.update(r), runner, None, self.config.eval_every
        )
        eval_key = jax.random.PRNGKey(self.config.eval_seed)
        evaluation = summarise(
            self.evaluate(runner.params, eval_key, self.config.eval_episodes,
                          hparams=runner.hparams)
        )  # fmt: skip
        return runner, {"train": metrics, "eval": evaluation}


def make_learner(config: PPOConfig, checker=None) -> Learner:
    """Validate ``config`` (and ``checker``) and build the run's :class:`Learner`."""
    env = config.make_env()
    if isinstance(env, ConstrainedEnvironment) and not env.every_sentence_in_table:
        raise ValueError(
            f"{config.env_id}: the learner encodes the env's table of sentences once per "
            "minibatch, and this env also says sentences outside it (conjunctions drawn at "
            "reset); give it a fixed list, e.g. env_kwargs=(('sentences', (...)),)"
        )
    check_checker(config, checker, env)
    if not config.uses_checker:
        checker = None  # not needed: skip its cost
    shield = None
    if config.shield_judge is not None:
        shield = make_shield(env, config.shield_judge, checker, config.checker_threshold)
    table = sentence_tokens(env)

    def schedule(count):
        per_update = config.update_epochs * config.num_minibatches
        frac = 1.0 - (count // per_update) / config.num_updates
        return config.lr * frac if config.anneal_lr else config.lr

    optimizer = optax.chain(
        optax.clip_by_global_norm(config.max_grad_norm),
        optax.adam(schedule, eps=1e-5),
    )
    return Learner(
        config=config,
        env=env,
        network=ActorCritic(
            num_actions=env.num_actions,
            conv_channels=config.conv_channels,
            cell_dim=config.cell_dim,
            vocab_size=language_table(env).vocab_size,
            recurrent=config.recurrent,
            film_codes=config.film_codes,
            memory_skip=config.memory_skip,
            budget_input=config.mode.budget,
        ),
        optimizer=optimizer,
        checker=checker,
        shield=shield,
        has_language=isinstance(env, ConstrainedEnvironment),
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
