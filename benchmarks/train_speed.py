"""Training throughput of the fused PPO, per reward mode, against the PureJaxRL-style baseline.

One thing, one benchmark's protocol, configurations and report, hence its length.

``python -m benchmarks.train_speed`` prints one JSON line per reward mode::

    {"mode": "checker", "sps": ..., "compile_s": ..., "device": ..., "baseline_sps": ...,
     "ratio": ..., "num_envs": 256, "num_steps": 128, "epochs": 4, "minibatches": 8, ...}

Every reward mode, the constrained-RL baselines included; where ``lagrangian`` is timed too,
each line has ``time_vs_lagrangian``, the median over rounds of its seconds per env step over
``lagrangian``'s (2.0: twice as slow). ``--cost-source`` sets the cost source of the modes
that can use either (``agents.config.COST_SOURCES``; default: each mode's own).

Protocol (compile ahead, then time; :mod:`agents.timing`):

* ours: :func:`agents.train.make_learner` on ``--env`` (TwoRooms-v0), one learner per mode;
  the checker modes use a freshly initialised checker (its cost does not depend on its
  weights). The timed executable is ``jit(lax.scan(learner.update))`` over ``U`` updates, the
  form training runs in (:meth:`Learner.chunk` scans updates too); it is compiled ahead,
  which is ``compile_s``, and the runner state is donated;
* baseline: :func:`agents.baseline.make_train` (NAVIX DoorKey-8x8, PureJaxRL's
  ``ppo_minigrid`` structure) with the same envs x steps x epochs x minibatches and ``U``
  updates, also compiled ahead and then run (its ``train`` includes a negligible init);
* ``--timesteps`` env steps are timed per mode, split into ``--repeats`` short calls of
  ``U`` updates each (default: 20 calls of 3 updates). Each repeat is one round that runs the
  baseline, then every mode, back to back, so that the ratio ``mode sps / baseline sps`` of a
  round shares the machine's load of those few seconds; ``sps`` and ``ratio`` are medians
  over rounds (``sps_all``/``ratio_all`` list them), ``sps_overall`` is all timed steps over
  all timed seconds. Every call ends with ``block_until_ready``; nothing else is timed.

``--profile`` adds a ``breakdown`` to each line, seconds per update; each piece is compiled
on its own from the learner's public API, the pieces are timed in ``min(--repeats, 5)``
interleaved rounds and every figure (differences included) is a median over rounds:

* ``update_s``: one ``learner.update``; ``rollout_s``: one ``learner.rollout`` alone;
  ``optimisation_s`` = update - rollout (GAE, shuffles, epochs x minibatches);
* ``env_step_s``: bare env steps (random actions, the learner's auto-reset wrapper
  :class:`jaxgrid.wrappers.BatchedAutoReset`);
* ``policy_and_bookkeeping_s``: rollout without checker - env steps (policy forward pass,
  action sampling, truncation bootstrap, sentence lookup, episode statistics);
* ``checker_s``: rollout of this mode - rollout without checker (0 for none/shaped);
* ``loss_forward_s``: :func:`agents.losses.ppo_loss` alone over epochs x minibatches
  minibatches, without gradients; ``backward_optimizer_gae_shuffle_s`` = optimisation - loss
  forward.

For the baseline, ``baseline_breakdown`` has its seconds per update and NAVIX's bare env
steps per update. With ``--baseline-network`` as well, the jaxgrid learner's line adds
``ratio_bound``: the ratio an environment that cost nothing would give the same learner,
``1 / (1 - env_fraction)``, since only the env's share of an update can shrink.

``--ops N`` adds ``ops``: the timed executable run twice under ``jax.profiler``, and the
``N`` XLA kernels and the ``N`` places (pass and Flax module, e.g. ``backward:
ActorCritic/cells``) that took the most of it, in ms per update (:mod:`benchmarks.xla_ops`).
``--mlp`` and ``--cell-dim N`` time other sizes of the policy (no convolution; N features
per view cell).

Progress goes to stderr; stdout has the JSON lines only. Quote the ratios, not the absolute
numbers, and mind the load (``load_avg_1m_at_start``): another process on the machine slows
the baseline's large multi-threaded matmuls more than our many small ops, so contention
raises the ratio (figures in ``docs/decisions.md``). ``taskset -c 0 python -m
benchmarks.train_speed`` pins both to one core for a steadier comparison.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
from typing import Any

import jax
import jax.numpy as jnp
from jax import lax

from agents.config import COST_SOURCES, REWARD_MODES, PPOConfig
from agents.timing import compile_ahead, timed
from benchmarks.cli import integer, require
from checker.cli import run_main
from jaxgrid.io import write_jsonl

MODES = REWARD_MODES
DEFAULTS = {
    "env": "TwoRooms-v0",
    "num_envs": 256,
    "num_steps": 128,
    "epochs": 4,
    "minibatches": 8,
    "timesteps": 2_000_000,
    "repeats": 20,
}


# --baseline-network: the baseline's learner on jaxgrid's DoorKey-8x8 (same sizes).
JAXGRID_DOORKEY = "MiniGrid-DoorKey-8x8-v0"
SAME_LEARNER = "purejaxrl-jaxgrid"


def ratio_bound(env_fraction: float) -> float:
    """The most a faster environment can speed up a learner whose env steps take
    ``env_fraction`` (in [0, 1)) of its update: the rest of the update stays (Amdahl)."""
    if not 0 <= env_fraction < 1:
        raise ValueError(f"env_fraction must be in [0, 1), got {env_fraction!r}")
    return 1.0 / (1.0 - env_fraction)


def _log(*args) -> None:
    print(*args, file=sys.stderr, flush=True)


def device_description() -> str:
    from agents.baseline import device_description as describe

    return describe()


def _median(xs):
    return float(statistics.median(xs))


# ----------------------------------------------------------------------------------------
# Ours
# ----------------------------------------------------------------------------------------
def make_checker(env, kind: str = "window"):
    """A freshly initialised checker for ``env`` (the speed does not depend on its weights):
    the window checker, or (``kind`` "memory") the recurrent one."""
    if kind == "memory":
        from checker import memory_model

        config = memory_model.MemoryCheckerConfig(view_size=env.view_size)
        return memory_model.new_memory_checker(config, jax.random.PRNGKey(0))
    from checker.model import CheckerConfig, new_checker

    return new_checker(CheckerConfig(view_size=env.view_size), jax.random.PRNGKey(0))


def make_config(mode: str, sizes: dict, updates: int):
    source = sizes.get("cost_source")  # for the modes that can use either source only
    either = len(PPOConfig(reward_mode=mode).mode.sources) > 1
    return PPOConfig(
        cost_source=source if either else None,
        env_id=sizes["env"],
        reward_mode=mode,
        num_envs=sizes["num_envs"],
        num_steps=sizes["num_steps"],
        update_epochs=sizes["epochs"],
        num_minibatches=sizes["minibatches"],
        **({"conv_channels": ()} if sizes.get("mlp") else {}),
        **({"cell_dim": sizes["cell_dim"]} if sizes.get("cell_dim") else {}),
        film_codes=bool(sizes.get("film_codes")),
        # the speeds measured so far: no novelty bonus, alarms charged where raised
        novelty_bonus=0.0,
        alarm_forward=False,
        penalty_warmup=0.1,
        # The LR schedule anneals over the timed updates; eval_every=1 allows tiny runs.
        total_timesteps=updates * sizes["num_envs"] * sizes["num_steps"],
        eval_every=1,
    )


class Ours:
    """One reward mode: its learner, a runner state, and ``jit(scan of U updates)``."""

    def __init__(self, mode: str, sizes: dict, updates: int, checker=None):
        from agents.train import make_learner

        self.mode, self.updates = mode, updates
        self.config = make_config(mode, sizes, updates)
        self.learner = make_learner(self.config, checker if self.config.uses_checker else None)
        self.runner = jax.block_until_ready(jax.jit(self.learner.init)(jax.random.PRNGKey(0)))
        learner = self.learner

        def run(runner):
            runner, metrics = lax.scan(lambda r, _: learner.update(r), runner, None, updates)
            return runner, metrics["loss"][-1]

        self.compiled, self.compile_s = compile_ahead(run, self.runner, donate_argnums=0)

    def run(self) -> tuple[float, float]:
        """Time one call of ``U`` updates; returns (env steps, seconds)."""
        (self.runner, _), dt = timed(self.compiled, self.runner)
        return self.updates * self.config.batch_size, dt


# ----------------------------------------------------------------------------------------
# Baseline
# ----------------------------------------------------------------------------------------
class Baseline:
    """PureJaxRL-style PPO, ``U`` updates per call: on NAVIX DoorKey-8x8 (the baseline), or
    on another env (``env_name``: a jaxgrid id, the same learner on our env)."""

    def __init__(self, sizes: dict, updates: int, env_name: str | None = None):
        from agents import baseline

        batch = sizes["num_envs"] * sizes["num_steps"]
        self.config = {
            "TOTAL_TIMESTEPS": updates * batch,
            "NUM_ENVS": sizes["num_envs"],
            "NUM_STEPS": sizes["num_steps"],
            "UPDATE_EPOCHS": sizes["epochs"],
            "NUM_MINIBATCHES": sizes["minibatches"],
            **({"ENV_NAME": env_name} if env_name else {}),
        }
        self.steps, self.calls = updates * batch, 0
        train = baseline.make_train(self.config)
        self.compiled, self.compile_s = compile_ahead(train, jax.random.PRNGKey(0))

    def run(self) -> tuple[float, float]:
        self.calls += 1
        _, dt = timed(self.compiled, jax.random.PRNGKey(self.calls))
        return self.steps, dt


# ----------------------------------------------------------------------------------------
# Profile: where the time of one update goes
# ----------------------------------------------------------------------------------------
def _rollout_fn(learner):
    """One ``learner.rollout``, every output reduced so that XLA keeps all of its work."""

    def rollout(runner):
        env, traj, stats = learner.rollout(runner, runner.key)
        return jax.tree.map(lambda x: x.astype(jnp.float32).sum(), (traj, stats, env.obs))

    return rollout


def _env_only_fn(env, num_envs: int, num_steps: int, num_actions: int, gymnax: bool = False):
    """Bare env steps with random actions, same horizon as one rollout.

    ``env`` is batched (``reset(keys)``, ``step(states, actions)``, as
    :class:`jaxgrid.wrappers.BatchedAutoReset`) or, with ``gymnax``, a single gymnax-style env
    that is vmapped here.
    """

    def run(key):
        keys = jax.random.split(key, num_envs)
        if gymnax:
            _, states = jax.vmap(env.reset)(keys)
        else:
            states, _ = env.reset(keys)

        def body(states, k):
            actions = jax.random.randint(k, (num_envs,), 0, num_actions)
            if gymnax:
                obs, states, reward, done, _ = jax.vmap(env.step)(
                    jax.random.split(k, num_envs), states, actions
                )
            else:
                states, ts = env.step(states, actions)
                obs, reward = ts.observation, ts.reward
            # Use the observation too, or XLA would drop its computation.
            used = sum(x.astype(jnp.float32).sum() for x in jax.tree.leaves(obs))
            return states, reward.sum() + used

        _, rewards = lax.scan(body, states, jax.random.split(key, num_steps))
        return rewards.sum()

    return run


def _loss_forward_fn(learner):
    """:func:`agents.losses.ppo_loss` over ``epochs x minibatches`` minibatches, no gradients.

    Each step slices its own minibatch out of a full-size batch (built from the current
    observations), so that XLA cannot hoist the network out of the loop. The policy is the
    learner's, as its update calls the loss.
    """
    from agents.losses import ppo_loss

    c = learner.config
    size = c.batch_size // c.num_minibatches

    def run(runner):
        obs = runner.env.obs
        tile = lambda x: jnp.tile(x, (c.num_steps,) + (1,) * (x.ndim - 1))  # noqa: E731
        zeros = jnp.zeros((c.batch_size,), jnp.float32)
        batch = {
            "image": tile(obs["image"]), "direction": tile(obs["direction"]),
            "sentence": tile(runner.env.sentence), "action": jnp.zeros_like(zeros, jnp.int32),
            "log_prob": zeros, "value": zeros, "target": zeros, "cost_value": zeros,
            "cost_target": zeros, "cost_advantage": zeros,
            "advantage": jax.random.normal(runner.key, (c.batch_size,)),
        }  # fmt: skip
        if c.mode.budget:  # Saute observes its budget
            batch["budget"] = zeros + 1.0
        if c.mode.policy_update != "ppo":  # the acting policy's logits, for the KL
            batch["logits"] = jnp.zeros((c.batch_size, learner.env.num_actions), jnp.float32)

        def body(total, i):
            start = (i % c.num_minibatches) * size
            mb = jax.tree.map(lambda x: lax.dynamic_slice_in_dim(x, start, size), batch)
            policy = lambda params, *x: learner.forward(params, mb)  # noqa: E731
            loss, _ = ppo_loss(policy, runner.params, mb, runner.lagrange, c)
            return total + loss, None

        steps = jnp.arange(c.update_epochs * c.num_minibatches)
        return lax.scan(body, jnp.zeros(()), steps)[0]

    return run


def _interleaved(pieces: dict, repeats: int) -> list[dict]:
    """Compile each ``name: (fn, arg)`` ahead, then time them all in turn, ``repeats`` rounds.

    ``fn`` is a plain function (compiled here) or an already compiled executable.
    """
    compiled = {
        name: (fn if isinstance(fn, jax.stages.Compiled) else compile_ahead(fn, arg)[0], arg)
        for name, (fn, arg) in pieces.items()
    }
    return [
        {name: timed(fn, arg)[1] for name, (fn, arg) in compiled.items()} for _ in range(repeats)
    ]


def profile_ours(ours: Ours, repeats: int, cache: dict) -> dict:
    """Seconds per update of the pieces of ``ours``'s update.

    The pieces are timed in interleaved rounds and every figure, differences included, is a
    median over rounds, so that a change of the machine's load hits all pieces alike.
    """
    from agents.train import make_learner
    from jaxgrid.wrappers import BatchedAutoReset

    learner, c = ours.learner, ours.config
    runner = ours.runner
    if "env" not in cache:
        env = BatchedAutoReset(c.make_env())
        fn = _env_only_fn(env, c.num_envs, c.num_steps, env.num_actions)
        cache["env"] = (fn, jax.random.PRNGKey(1))
        # The same rollout without any checker work (the none/shaped modes' rollout).
        plain = make_learner(make_config("none", sizes_of(c), ours.updates))
        cache["plain"] = (_rollout_fn(plain), jax.jit(plain.init)(jax.random.PRNGKey(0)))
    pieces = {
        "update": (learner.update, runner),
        "rollout": (_rollout_fn(learner), runner),
        "plain": cache["plain"],
        "env": cache["env"],
        "forward": (_loss_forward_fn(learner), runner),
    }
    rounds = _interleaved(pieces, repeats)
    derived = {
        "update_s": lambda t: t["update"],
        "rollout_s": lambda t: t["rollout"],
        "optimisation_s": lambda t: t["update"] - t["rollout"],
        "env_step_s": lambda t: t["env"],
        "policy_and_bookkeeping_s": lambda t: (
            (t["plain"] if c.uses_checker else t["rollout"]) - t["env"]
        ),
        "checker_s": lambda t: t["rollout"] - t["plain"] if c.uses_checker else 0.0,
        "loss_forward_s": lambda t: t["forward"],
        "backward_optimizer_gae_shuffle_s": lambda t: t["update"] - t["rollout"] - t["forward"],
    }
    out = {k: round(_median([f(t) for t in rounds]), 4) for k, f in derived.items()}
    parts = list(derived)[3:]
    out["fractions"] = {k[:-2]: round(out[k] / out["update_s"], 3) for k in parts}
    return out


def sizes_of(c) -> dict:
    """The sizes :func:`make_config` takes that give back ``c``'s (env, batch, network)."""
    return {
        "env": c.env_id, "num_envs": c.num_envs, "num_steps": c.num_steps,
        "epochs": c.update_epochs, "minibatches": c.num_minibatches,
        "mlp": c.conv_channels == (), "cell_dim": c.cell_dim, "film_codes": c.film_codes,
        "cost_source": c.cost_source,
    }  # fmt: skip


def profile_baseline(baseline: Baseline, sizes: dict, updates: int, repeats: int) -> dict:
    from agents.baseline import make_env

    env = make_env()
    fn = _env_only_fn(env, sizes["num_envs"], sizes["num_steps"], env.num_actions(), True)
    pieces = {
        "env": (fn, jax.random.PRNGKey(1)),
        "train": (baseline.compiled, jax.random.PRNGKey(7)),
    }
    rounds = _interleaved(pieces, repeats)
    update_s = _median([t["train"] for t in rounds]) / updates
    env_s = _median([t["env"] for t in rounds])
    return {
        "update_s": round(update_s, 4),
        "env_step_s": round(env_s, 4),
        "env_fraction": round(_median([t["env"] * updates / t["train"] for t in rounds]), 3),
    }


# ----------------------------------------------------------------------------------------
# CLI
# ----------------------------------------------------------------------------------------
def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.train_speed",
        description="Env steps/s of the fused PPO per reward mode vs the PureJaxRL baseline.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument(
        "--modes",
        nargs="+",
        default=list(MODES),
        choices=MODES,
        metavar="MODE",
        help=f"reward modes to time, of {', '.join(MODES)}",
    )
    p.add_argument("--env", default=DEFAULTS["env"], help="jaxgrid env id")
    p.add_argument(
        "--timesteps",
        type=integer,
        default=DEFAULTS["timesteps"],
        help="env steps timed per mode, over all repeats",
    )
    p.add_argument("--num-envs", type=integer, default=DEFAULTS["num_envs"], help="parallel envs")
    p.add_argument(
        "--num-steps", type=integer, default=DEFAULTS["num_steps"], help="rollout length per update"
    )
    p.add_argument(
        "--epochs", type=integer, default=DEFAULTS["epochs"], help="epochs over each batch"
    )
    p.add_argument(
        "--minibatches", type=integer, default=DEFAULTS["minibatches"], help="minibatches per epoch"
    )
    p.add_argument(
        "--repeats",
        type=integer,
        default=DEFAULTS["repeats"],
        help="timed calls per mode; sps and ratio are medians",
    )
    p.add_argument(
        "--baseline",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also time the PureJaxRL baseline (needs navix)",
    )
    p.add_argument(
        "--baseline-network",
        action="store_true",
        default=False,
        help="also time the baseline's learner (PureJaxRL MLP) on jaxgrid's "
        f"{JAXGRID_DOORKEY}, in the same rounds",
    )
    p.add_argument(
        "--profile",
        action="store_true",
        default=False,
        help="add a per-update time breakdown to each line",
    )
    p.add_argument(
        "--ops",
        type=integer,
        default=0,
        metavar="N",
        help="add the N costliest XLA kernels and model places of an update "
        "(profiler trace; 0: off)",
    )
    p.add_argument(
        "--mlp",
        action="store_true",
        default=False,
        help="time the policy without its convolution (PPOConfig.conv_channels=())",
    )
    p.add_argument(
        "--cell-dim",
        type=integer,
        default=PPOConfig().cell_dim,
        metavar="N",
        help="features per view cell (PPOConfig.cell_dim)",
    )
    p.add_argument(
        "--film-codes",
        action="store_true",
        help="the sentence also scales the cells' one-hot codes (PPOConfig.film_codes)",
    )
    p.add_argument(
        "--cost-source",
        default=None,
        choices=COST_SOURCES,
        help="cost source of the modes that can use either (None: each mode's own)",
    )
    p.add_argument("--out", default=None, help="also write the JSON lines to this file")
    return p  # fmt: skip


def parse_args(argv=None) -> argparse.Namespace:
    p = _parser()
    args = p.parse_args(argv)
    for name in ("timesteps", "num_envs", "num_steps", "epochs", "minibatches", "repeats"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.ops < 0:
        p.error(f"--ops must be >= 0, got {args.ops}")
    if args.cell_dim < 1:
        p.error(f"--cell-dim must be >= 1, got {args.cell_dim}")
    if args.num_envs % args.minibatches:
        p.error(f"--minibatches ({args.minibatches}) must divide --num-envs ({args.num_envs})")
    import jaxgrid

    try:
        jaxgrid.make(args.env)
    except ValueError as e:
        p.error(f"--env: {e}")
    if args.baseline:  # on by default: the ratio to it is what this benchmark reports
        require("navix", "--baseline (PureJaxRL on NAVIX)", instead="pass --no-baseline")
    args.modes = list(dict.fromkeys(args.modes))
    return args


def main(argv=None) -> list[dict[str, Any]]:
    args = parse_args(argv)
    sizes = {
        "env": args.env, "num_envs": args.num_envs, "num_steps": args.num_steps,
        "epochs": args.epochs, "minibatches": args.minibatches, "mlp": args.mlp,
        "cell_dim": args.cell_dim, "film_codes": args.film_codes,
        "cost_source": args.cost_source,
    }  # fmt: skip
    batch = args.num_envs * args.num_steps
    updates = max(1, args.timesteps // batch // args.repeats)
    timed = updates * batch * args.repeats
    device = device_description()
    load = round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None
    _log(
        f"train_speed: {args.env}, {args.num_envs} envs x {args.num_steps} steps, "
        f"{args.epochs} epochs x {args.minibatches} minibatches; {args.repeats} repeats x "
        f"{updates} updates = {timed} steps per mode; {device}"
    )

    checker = None
    if any(make_config(m, sizes, 1).uses_checker for m in args.modes):
        import jaxgrid

        checker = make_checker(jaxgrid.make(args.env))

    baseline = None
    if args.baseline:
        _log("compiling baseline (purejaxrl-navix) ...")
        baseline = Baseline(sizes, updates)
        _log(f"  baseline compile {baseline.compile_s:.1f}s")
    learners = {}
    for mode in args.modes:
        _log(f"compiling mode {mode} ...")
        learners[mode] = Ours(mode, sizes, updates, checker)
        _log(f"  {mode} compile {learners[mode].compile_s:.1f}s")

    same_learner = None
    if args.baseline_network:
        _log(f"compiling the baseline's learner on jaxgrid {JAXGRID_DOORKEY} ...")
        same_learner = Baseline(sizes, updates, env_name=JAXGRID_DOORKEY)
        _log(f"  compile {same_learner.compile_s:.1f}s")
    contenders = ([("baseline", baseline)] if baseline is not None else []) + list(learners.items())
    if same_learner is not None:
        contenders.append((SAME_LEARNER, same_learner))
    runs = {name: [] for name, _ in contenders}  # (env steps, seconds) per call
    for r in range(args.repeats):
        for name, bench in contenders:
            runs[name].append(bench.run())
        last = ", ".join(f"{name} {v[-1][0] / v[-1][1]:,.0f}" for name, v in runs.items())
        _log(f"repeat {r + 1}/{args.repeats}: {last} sps")
    sps = {name: [n / dt for n, dt in v] for name, v in runs.items()}
    overall = {name: sum(n for n, _ in v) / sum(dt for _, dt in v) for name, v in runs.items()}
    base_sps = sps.get("baseline", [])

    cache, base_profile = {}, None
    profile_repeats = min(args.repeats, 5)
    if args.profile and baseline is not None:
        _log("profiling baseline ...")
        base_profile = profile_baseline(baseline, sizes, updates, profile_repeats)

    lines = []
    for mode, ours in learners.items():
        line = {
            "mode": mode,
            "sps": round(_median(sps[mode]), 1),
            "compile_s": round(ours.compile_s, 2),
            "device": device,
            "env": args.env,
            "num_envs": args.num_envs,
            "num_steps": args.num_steps,
            "epochs": args.epochs,
            "minibatches": args.minibatches,
            "network": "mlp" if args.mlp else "conv",
            "cell_dim": ours.config.cell_dim,
            "film_codes": ours.config.film_codes,
            "timesteps": timed,
            "repeats": args.repeats,
            "updates_per_call": updates,
            "sps_overall": round(overall[mode], 1),
            "sps_all": [round(s, 1) for s in sps[mode]],
            "load_avg_1m_at_start": load,
        }
        if "lagrangian" in sps:
            per_step = [b / s for s, b in zip(sps[mode], sps["lagrangian"], strict=True)]
            line["time_vs_lagrangian"] = round(_median(per_step), 3)
        if baseline is not None:
            ratios = [s / b for s, b in zip(sps[mode], base_sps, strict=True)]
            line.update(
                baseline="purejaxrl-navix (Navix-DoorKey-8x8-v0)",
                baseline_sps=round(_median(base_sps), 1),
                baseline_sps_overall=round(overall["baseline"], 1),
                baseline_compile_s=round(baseline.compile_s, 2),
                baseline_sps_all=[round(s, 1) for s in base_sps],
                ratio=round(_median(ratios), 3),
                ratio_all=[round(x, 3) for x in ratios],
            )
        if args.profile:
            _log(f"profiling mode {mode} ...")
            line["breakdown"] = profile_ours(ours, profile_repeats, cache)
            if base_profile is not None:
                line["baseline_breakdown"] = base_profile
        if args.ops:
            from benchmarks.xla_ops import profile_ops

            _log(f"tracing mode {mode} ...")
            try:
                line["ops"] = profile_ops(
                    ours.run, ours.compiled.as_text(), 2, ours.updates, args.ops
                )
            except RuntimeError as e:  # no trace, or one naming no instruction
                line["ops"] = {"error": str(e)}
        lines.append(line)
        print(json.dumps(line), flush=True)

    if same_learner is not None:
        line = {"mode": SAME_LEARNER, "env": JAXGRID_DOORKEY,
                "sps": round(_median(sps[SAME_LEARNER]), 1),
                "sps_overall": round(overall[SAME_LEARNER], 1),
                "compile_s": round(same_learner.compile_s, 2), "device": device,
                "sps_all": [round(x, 1) for x in sps[SAME_LEARNER]]}  # fmt: skip
        if baseline is not None:  # the same learner on NAVIX: the env's share of the speed
            ratios = [x / b for x, b in zip(sps[SAME_LEARNER], base_sps, strict=True)]
            line.update(baseline="purejaxrl-navix (Navix-DoorKey-8x8-v0)",
                        baseline_sps=round(_median(base_sps), 1),
                        ratio=round(_median(ratios), 3))  # fmt: skip
            if base_profile is not None:
                line["ratio_bound"] = round(ratio_bound(base_profile["env_fraction"]), 3)
        lines.append(line)
        print(json.dumps(line), flush=True)

    if args.out:
        write_jsonl(args.out, lines)
        _log(f"wrote {args.out}")
    return lines


if __name__ == "__main__":
    run_main(main, "python -m benchmarks.train_speed")
