"""HazardRooms-v0's constraints are satisfiable and matter: the oracle's figures, per type.

For each constraint type, ``--episodes`` HazardRooms episodes (drawn by the scenario, seeds
fixed) are played twice by the BFS oracle of :mod:`jaxgrid.oracle`, harmless lava walked on
as floor both times:

* **obeying** the constraint (never entering any clause's forbidden zone): success % and the
  share of episodes with at least one violation, which should be 100 and 0;
* **ignoring** it (the shortest route): the share of episodes it violates, i.e. how often the
  constraint changes what an agent must do; sequential episodes also by their first clause's
  order ("after" or "before" its trigger) and trigger (picking up, a door, a ground cell).

The environment draws types uniformly, so ``5 * episodes`` episodes are played in batches until
every type has at least ``episodes``. Also reported: reset and step throughput of the scenario
(vmapped, with auto-reset) against TwoRooms-v0 under the same harness, which prices the
monitor and the layout's rejection loop. Usage::

    python -m benchmarks.hazard_checks                     # 10,000 episodes per type
    python -m benchmarks.hazard_checks --episodes 500 --json runs/hazard_checks.json
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from agents.timing import measure
from benchmarks.cli import integer
from checker.cli import run_main
from jaxgrid import language, make
from jaxgrid import monitor as M
from jaxgrid.constants import DOOR
from jaxgrid.io import write_json
from jaxgrid.oracle import rollout_oracle
from jaxgrid.wrappers import BatchedAutoReset

TYPES = language.CONSTRAINT_TYPES


def oracle_figures(env, episodes: int, batch: int = 2_000, seed: int = 0) -> dict:
    """Per-type oracle figures (see the module docstring) over at least ``episodes`` each."""
    seen = np.zeros(len(TYPES), int)
    acc = {k: [] for k in ("type", "success", "violated", "violated_unconstrained", "kind")}
    i = 0
    while seen.min() < episodes:
        key = jax.random.fold_in(jax.random.key(seed), i)
        obey = jax.tree.map(np.asarray, rollout_oracle(env, key, batch, avoid_lava=False))
        free = rollout_oracle(env, key, batch, obey_constraint=False, avoid_lava=False)
        free = jax.tree.map(np.asarray, free)
        acc["kind"].append(_sequence_kinds(env, key, batch))
        acc["type"].append(obey["constraint_type"])
        acc["success"].append(obey["success"])
        acc["violated"].append(obey["violations"] > 0)
        acc["violated_unconstrained"].append(free["violations"] > 0)
        seen += np.bincount(obey["constraint_type"], minlength=len(TYPES))
        i += 1
        print(f"  {seen.sum():,} episodes, fewest of one type {seen.min():,}", file=sys.stderr)
    cat = {k: np.concatenate(v) for k, v in acc.items()}
    out = {}
    for k, name in enumerate(TYPES):
        m = cat["type"] == k
        out[name] = {
            "episodes": int(m.sum()),
            "success_pct": 100 * float(cat["success"][m].mean()),
            "violated_pct": 100 * float(cat["violated"][m].mean()),
            "unconstrained_violated_pct": 100 * float(cat["violated_unconstrained"][m].mean()),
        }
    seq = cat["type"] == TYPES.index("sequential")
    out["sequential"]["by_kind"] = {
        kind: {"episodes": int(m.sum()),
               "unconstrained_violated_pct": 100 * float(cat["violated_unconstrained"][m].mean())}
        for kind in KINDS
        if (m := seq & (cat["kind"] == kind)).any()
    }  # fmt: skip
    return out


# The sequential constraints' kinds, "<order> <trigger>", as ``by_kind`` names them.
KINDS = tuple(f"{o} {t}" for o in ("after", "before") for t in ("pickup", "door", "ground"))


def _sequence_kinds(env, key, batch: int) -> np.ndarray:
    """Each episode's first clause as "<order> <trigger>" (e.g. "after ground"; "" when it has
    no trigger), from the layouts :func:`rollout_oracle` plays (the same reset keys)."""
    states, _ = jax.jit(jax.vmap(env.reset))(jax.random.split(key, batch))
    spec = jax.tree.map(lambda a: np.asarray(a)[:, 0], states.extras.monitor.spec)
    order = np.select([spec.gate == M.AFTER, spec.gate == M.BEFORE], ["after ", "before "], "")
    trigger = np.where(spec.trigger_pickup, "pickup",
                       np.where(spec.trigger_kind == DOOR, "door", "ground"))  # fmt: skip
    return np.where(order == "", "", np.char.add(order, trigger))


def throughput(env_id: str, num_envs: int = 256, steps: int = 64, resets: int = 16) -> dict:
    """Env steps/s of random actions with auto-reset, the compile time, and the cost of one
    reset in a vmapped batch of ``resets`` (the learner resets the envs whose episodes just
    ended in batches of 16; random actions end few episodes, so the step figure hides it)."""
    env = BatchedAutoReset(make(env_id))
    reset_keys = jax.random.split(jax.random.key(2), resets)
    reset = measure(
        lambda k: jax.vmap(env.env.reset)(k)[1].observation["image"], reset_keys, repeats=5
    )

    def rollout(states, key):
        def body(states, k):
            actions = jax.random.randint(k, (num_envs,), 0, 7)
            states, ts = env.step(states, actions)
            return states, ts.reward.sum()

        states, rewards = jax.lax.scan(body, states, jax.random.split(key, steps))
        return rewards.sum()

    states, _ = env.reset(jax.random.split(jax.random.key(0), num_envs))
    t = measure(rollout, states, jax.random.key(1))
    return {
        "steps_per_s": num_envs * steps / t.best_s,
        "compile_s": t.compile_s,
        "reset_us": 1e6 * reset.best_s / resets,
    }


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(prog="python -m benchmarks.hazard_checks", description=__doc__,
                                formatter_class=argparse.RawTextHelpFormatter)  # fmt: skip
    p.add_argument("--episodes", type=integer, default=10_000, help="episodes per constraint type")
    p.add_argument("--json", help="also write the figures to this JSON file")
    args = p.parse_args(argv)
    if args.episodes < 1:
        p.error(f"--episodes must be positive, got {args.episodes}")
    jnp.zeros(())  # start the backend before timing anything
    start = time.time()
    env = make("HazardRooms-v0")
    figures = {"oracle": oracle_figures(env, args.episodes)}
    figures["throughput"] = {i: throughput(i) for i in ("HazardRooms-v0", "TwoRooms-v0")}
    figures["wall_s"] = time.time() - start
    print(f"{'type':<12} {'episodes':>8} {'success %':>9} {'violated %':>10} {'ignoring %':>10}")
    for name, f in figures["oracle"].items():
        print(
            f"{name:<12} {f['episodes']:>8,} {f['success_pct']:>9.2f} {f['violated_pct']:>10.2f}"
            f" {f['unconstrained_violated_pct']:>10.1f}"
        )
    for kind, f in figures["oracle"]["sequential"]["by_kind"].items():
        print(f"  sequential, {kind:<14} {f['episodes']:>6,} episodes, ignoring "
              f"{f['unconstrained_violated_pct']:.1f}%")  # fmt: skip
    for env_id, f in figures["throughput"].items():
        print(f"{env_id}: {f['steps_per_s']:,.0f} steps/s (compile {f['compile_s']:.1f} s), "
              f"{f['reset_us']:,.0f} us per reset")  # fmt: skip
    if args.json:
        write_json(args.json, figures)
    return figures


if __name__ == "__main__":
    run_main(main, "python -m benchmarks.hazard_checks")
