"""Cost of the checker per env step: ``python -m benchmarks.checker_cost``.

Times a jitted ``lax.scan`` of ``--steps`` steps of ``AutoReset(env)`` under ``vmap`` with
random actions, with and without the checker's per-step work (``push`` + ``violation_prob``),
for each ``--envs`` count, with :mod:`agents.timing`'s protocol (compiled ahead, compile
time reported apart, each call closed by ``block_until_ready``); the best of ``--repeats``
calls is reported. Parameters are fresh (the cost does not depend on their values) unless
``--checker DIR`` is given.
"""

from __future__ import annotations

import dataclasses
import functools
import json

import jax
import jax.numpy as jnp
from jax import lax

from agents import timing
from checker import cli
from checker.model import CheckerConfig, new_checker
from checker.reward import init_buffer, push, violation_prob
from checker.store import load
from jaxgrid.wrappers import AutoReset


def _run(env, trained, key, *, num_envs, steps, use_checker):
    states, ts = jax.vmap(env.reset)(jax.random.split(key, num_envs))
    buf = push(
        init_buffer(num_envs, trained.config.window, env.view_size),
        ts.observation["image"],
        jnp.ones((num_envs,), bool),
    )

    def body(carry, k):
        states, buf, acc = carry
        actions = jax.random.randint(k, (num_envs,), 0, env.num_actions)
        states, ts = jax.vmap(env.step)(states, actions)
        if use_checker:
            buf = push(buf, ts.observation["image"], ts.terminated | ts.truncated)
            acc = acc + violation_prob(trained, buf, ts.observation["constraint"])
        else:
            acc = acc + ts.reward
        return (states, buf, acc), None

    carry = (states, buf, jnp.zeros((num_envs,), jnp.float32))
    (_, _, acc), _ = lax.scan(body, carry, jax.random.split(key, steps))
    return acc


def measure(env, trained, num_envs: int, steps: int, repeats: int = 3) -> dict:
    """Seconds per scan of ``steps`` steps with and without the checker, and derived costs."""
    env = env if isinstance(env, AutoReset) else AutoReset(env)
    out = {"num_envs": num_envs, "steps": steps}
    for name, use in (("env_only", False), ("env_plus_checker", True)):
        run = functools.partial(_run, env, num_envs=num_envs, steps=steps, use_checker=use)
        t = timing.measure(run, trained, jax.random.PRNGKey(0), repeats=repeats)
        out[f"{name}_compile_s"] = t.compile_s
        out[f"{name}_s"] = t.best_s
    n = num_envs * steps
    out["env_us_per_env_step"] = out["env_only_s"] / n * 1e6
    out["checker_us_per_env_step"] = (out["env_plus_checker_s"] - out["env_only_s"]) / n * 1e6
    out["slowdown"] = out["env_plus_checker_s"] / out["env_only_s"]
    return out


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """The checker's cost per env step, with and without it, for each number of envs."""

    env: str = "TwoRooms-v0"  # the environment id
    envs: tuple[int, ...] = (256, 1024, 4096)  # numbers of parallel envs, one timing each
    steps: int = 64  # steps per timed scan
    repeats: int = 3  # timed calls; the best is reported
    checker: str | None = None  # a trained checker's directory; None: fresh parameters

    def __post_init__(self):
        import jaxgrid

        if self.env not in jaxgrid.registered_ids():
            raise ValueError(f"BenchConfig.env: unknown environment id {self.env!r}")
        if not self.envs or min(self.envs) < 1:
            raise ValueError(f"BenchConfig.envs: every count must be >= 1, got {self.envs}")
        for name in ("steps", "repeats"):
            if getattr(self, name) < 1:
                raise ValueError(f"BenchConfig.{name} must be >= 1, got {getattr(self, name)}")


def main(argv=None) -> list[dict]:
    import jaxgrid

    prog = "python -m benchmarks.checker_cost"
    args = cli.parse(BenchConfig, argv, prog=prog, description=__doc__)
    env = jaxgrid.make(args.env)
    trained = (
        load(args.checker)
        if args.checker
        else new_checker(CheckerConfig(view_size=env.view_size), jax.random.PRNGKey(0))
    )
    rows = []
    print(f"{args.env}, {jax.devices()[0]}, {args.steps} steps per scan, best of {args.repeats}")
    print(f"{'envs':>6} {'env us/step':>11} {'checker us/step':>16} {'slowdown':>9}")
    for n in args.envs:
        r = measure(env, trained, n, args.steps, args.repeats)
        rows.append(r)
        print(
            f"{n:>6} {r['env_us_per_env_step']:>11.2f} {r['checker_us_per_env_step']:>16.2f} "
            f"{r['slowdown']:>8.2f}x"
        )
    print(json.dumps(rows))
    return rows


if __name__ == "__main__":
    cli.run_main(main, "python -m benchmarks.checker_cost")
