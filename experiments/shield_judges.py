"""Which checker makes a good shield: the shield judges under a policy that seeks violations.

``python -m experiments.shield_judges --checkers DIR [DIR ...] [--env TwoRooms-v0]``

The noisy BFS oracle of :mod:`checker.policies` plays every episode in ``seek`` mode (it
heads through the forbidden door, or across forbidden lava, whenever one is on its way: do
violations get through?) and then in ``obey`` mode (it plans around them: does the shield
obstruct a safe agent?), with a random action 10% of the time; then a uniformly random
policy plays (what an agent at its first update does: does the shield keep it safe?). Each
plays alone and behind each judge: the
ground-truth monitor (:mod:`agents.shield`'s ``monitor``) and each trained checker given,
e.g. one trained on just-before labels (lookahead 1) and one on "after" labels (lookahead 0).
Where the shield blocks the oracle's action, a uniformly random allowed action is taken.
For each player and judge it reports the episodes with a violation (%), the successes
(%) and the blocked actions per step, over the same fixed-seed episodes, and writes them as
JSON. The oracle plans by the constraint of the paper's scenarios (a forbidden door colour,
lava), so ``--env`` must be one of them and each checker a window checker: anything else is
refused by name before anything compiles.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
from jax import lax

import checker as chk
import jaxgrid
from agents.evaluation import violation_of
from agents.shield import make_shield
from checker import cli
from checker.store import check_writable_file, checker_kind
from checker.train import check_window_scenario
from jaxgrid.io import write_json

PROG = "python -m experiments.shield_judges"


@dataclasses.dataclass(frozen=True)
class JudgeConfig:
    """The stress test's settings."""

    checkers: tuple[str, ...] = ()  # trained checkers' directories, each judged as a shield
    env: str = "TwoRooms-v0"  # jaxgrid id of the constrained scenario
    episodes: int = 512  # fixed-seed episodes per judge
    threshold: float = 0.5  # checker probability above which an action is blocked
    epsilon: float = 0.1  # the oracle's probability of a random action
    seed: int = 0  # seed of the episodes
    out: str | None = None  # JSON file for the results; None: print only

    def __post_init__(self):
        me = type(self).__name__
        if self.env not in jaxgrid.registered_ids():
            raise ValueError(f"{me}.env: unknown environment id {self.env!r}")
        try:  # the oracle plays, and the monitor judges, the scenarios' constraint only
            check_window_scenario(self.env, PROG, "its oracle seeks or avoids that door and lava")
        except ValueError as e:
            raise ValueError(f"{me}.env {e}") from None
        if not isinstance(self.episodes, int) or self.episodes < 1:
            raise ValueError(f"{me}.episodes must be an integer >= 1, got {self.episodes!r}")
        if not 0 < self.threshold < 1:
            raise ValueError(f"{me}.threshold must be in (0, 1), got {self.threshold!r}")
        if not 0 <= self.epsilon <= 1:
            raise ValueError(f"{me}.epsilon must be in [0, 1], got {self.epsilon!r}")
        for path in self.checkers:
            try:
                kind = checker_kind(path)
            except (OSError, ValueError) as e:
                raise ValueError(f"{me}.checkers {path}: no trained checker there ({e})") from None
            if kind != "window":  # its sentences are HazardRooms', not the scenarios'
                raise ValueError(f"{me}.checkers {path}: a {kind} checker, which reads "
                                 "HazardRooms-v0's sentences; the oracle plays the paper's "
                                 "scenarios, whose shields are window checkers")  # fmt: skip
        if self.out is not None:
            check_writable_file(self.out, f"{me}.out")


def play(env, shield, params: chk.NoisyOracleParams, key: jax.Array, episodes: int) -> dict:
    """The oracle's episodes behind ``shield`` (None: alone): violation and success rates
    and blocked actions per step (scalars; jittable)."""
    reset_key, act_key = jax.random.split(key)
    states, ts = jax.vmap(env.reset)(jax.random.split(reset_key, episodes))
    memory = () if shield is None else shield.start(ts.observation)
    zeros = jnp.zeros((episodes,), jnp.int32)

    def body(carry, t):
        states, memory, alive, violations, success, blocked = carry
        k_oracle, k_random = jax.random.split(jax.random.fold_in(act_key, t))
        action = chk.noisy_oracle_policy(params, None, states, k_oracle)
        if shield is not None:
            allowed, _ = shield.allowed_now(memory, states)
            ok = jnp.take_along_axis(allowed, action[:, None], axis=1)[:, 0]
            fallback = jax.random.categorical(k_random, jnp.where(allowed, 0.0, -1e9))
            action = jnp.where(ok, action, fallback)
            blocked = blocked + (~allowed).sum(1) * alive
        states, ts = jax.vmap(env.step)(states, action)
        if shield is not None:
            memory = shield.observe(memory, ts.observation, action)
        violations = violations + violation_of(ts).astype(jnp.int32) * alive
        success = success | (alive & (ts.reward > 0))
        alive = alive & ~(ts.terminated | ts.truncated)
        return (states, memory, alive, violations, success, blocked), alive.sum()

    carry = (states, memory, jnp.ones((episodes,), bool), zeros, jnp.zeros((episodes,), bool),
             zeros)  # fmt: skip
    (_, _, _, violations, success, blocked), alive = lax.scan(
        body, carry, jnp.arange(env.max_steps)
    )
    steps = alive.sum() + episodes  # steps taken: each alive episode took one per step
    return {
        "violation_rate": (violations > 0).mean(),
        "success_rate": success.mean(),
        "blocked_per_step": blocked.sum() / steps,
    }


def run(cfg: JudgeConfig) -> dict:
    env = jaxgrid.make(cfg.env)
    key = jax.random.PRNGKey(cfg.seed)
    judges = {"none": None, "monitor": make_shield(env, "monitor")}
    for path in cfg.checkers:
        trained = chk.load(path)
        name = f"checker {path} (lookahead {trained.lookahead})"
        judges[name] = make_shield(env, "checker", trained, cfg.threshold)
    results: dict = {}
    players = (("seek", 1.0, cfg.epsilon), ("obey", 0.0, cfg.epsilon), ("random", 0.0, 1.0))
    for mode, seek, epsilon in players:
        params = chk.NoisyOracleParams(epsilon=epsilon, ignore_prob=0.0, seek_prob=seek,
                                       salt=cfg.seed)  # fmt: skip
        for name, shield in judges.items():
            go = jax.jit(lambda k, s=shield, p=params: play(env, s, p, k, cfg.episodes))
            r = {k: float(v) for k, v in go(key).items()}
            results.setdefault(mode, {})[name] = r
            print(f"{mode}, shield {name}: violations {100 * r['violation_rate']:.1f}%, "
                  f"success {100 * r['success_rate']:.1f}%, blocked "
                  f"{r['blocked_per_step']:.2f}/step")  # fmt: skip
    out = {"config": dataclasses.asdict(cfg), "oracle": results}
    if cfg.out:
        write_json(Path(cfg.out), out)
    return out


def main(argv=None) -> dict:
    """Run the stress test of ``argv`` (default ``sys.argv[1:]``); returns the results.

    A flag that names no scenario of the oracle, a checker that is not a window checker, or an
    ``--out`` that cannot be written exits with status 2 before anything compiles."""
    cfg = cli.parse(JudgeConfig, argv, prog=PROG, description=__doc__.split("\n\n")[0])
    return run(cfg)


if __name__ == "__main__":
    cli.run_main(main, PROG)

__all__ = ["JudgeConfig", "main", "play", "run"]
