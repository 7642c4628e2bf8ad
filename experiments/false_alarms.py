"""Where a checker alarms: a policy's windows on a scenario, split by the cell in front.

``python -m experiments.false_alarms --checker DIR [--env-id ThreeRoomsKey-v0]
[--policy random|oracle] [--out FILE.json]``

A checker shapes an agent's reward wherever it alarms, so an alarm at something the agent
must pass (a key, a locked door) teaches the agent to avoid it. The test set's AUROC does not
show that: such windows are rare and never positive. Here every window of ``envs`` x
``steps`` auto-reset rollouts is scored and labelled by the monitor (as in
``checker.collect_episodes``), and the alarms are counted per kind of cell in front of the
agent in the window's last frame (doors by state and by whether the sentence names their
colour), as are the violations the checker misses. ``oracle`` is the noisy oracle
(``checker.noisy_oracle_policy``) in its mix of obeying and ignoring the constraint, which
walks through doors; ``random`` rarely leaves the first room.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import numpy as np

import checker as chk
import jaxgrid
from checker import cli
from checker.data import front_cells
from checker.store import check_writable_file, checker_kind
from checker.train import check_window_scenario
from jaxgrid import language
from jaxgrid.constants import COLOR_NAMES, DOOR, OBJECT_NAMES, STATE_NAMES
from jaxgrid.io import write_json

POLICIES = ("random", "oracle")
PROG = "python -m experiments.false_alarms"


@dataclasses.dataclass(frozen=True)
class FalseAlarmConfig:
    """Which checker, on which scenario, under which policy."""

    checker: str = ""  # a trained checker's directory
    env_id: str = "ThreeRoomsKey-v0"  # the scenario its windows come from
    policy: str = "random"  # random | oracle (the noisy oracle, obeying or ignoring)
    epsilon: float = 0.2  # oracle: probability of a random action per step
    envs: int = 64  # rollouts side by side
    steps: int = 2000  # steps per rollout
    seed: int = 3  # seed of the rollouts
    out: str | None = None  # JSON file for the counts; None: print only

    def __post_init__(self):
        me = type(self).__name__
        if not self.checker:
            raise ValueError(f"{me}.checker: a trained checker's directory is required")
        try:
            kind = checker_kind(self.checker)
        except (OSError, ValueError) as e:
            raise ValueError(f"{me}.checker {self.checker}: no trained checker there "
                             f"({e})") from None  # fmt: skip
        if kind != "window":
            raise ValueError(f"{me}.checker {self.checker}: a {kind} checker; this scores the "
                             "windows of a window checker")  # fmt: skip
        if self.env_id not in jaxgrid.registered_ids():
            raise ValueError(f"{me}.env_id {self.env_id!r} is not a registered environment")
        try:
            check_window_scenario(self.env_id, PROG, "its windows are labelled by that door and "
                                  "lava (and the oracle plans around them)")  # fmt: skip
        except ValueError as e:
            raise ValueError(f"{me}.env_id {e}") from None
        if self.policy not in POLICIES:
            raise ValueError(f"{me}.policy must be one of {POLICIES}, got {self.policy!r}")
        if not 0 <= self.epsilon <= 1:
            raise ValueError(f"{me}.epsilon must be in [0, 1], got {self.epsilon!r}")
        for name in ("envs", "steps"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{me}.{name} must be an integer >= 1, got {value!r}")
        if self.out is not None:
            check_writable_file(self.out, f"{me}.out")


def front_groups(front: np.ndarray, named: np.ndarray) -> np.ndarray:
    """A label per window for the cell in front (uint8 ``(N, 3)``): the object's name; a door
    with its state and ``named`` / ``other`` for whether the sentence names its colour
    (``named``: ``(N,)`` colour indices, -1 where the sentence names none)."""
    labels = []
    for (kind, colour, state), n in zip(front.tolist(), named.tolist(), strict=True):
        name = OBJECT_NAMES[kind]
        if kind == DOOR:
            name += f" {STATE_NAMES[state]} {'named' if colour == n else 'other'}"
        labels.append(name)
    return np.array(labels)


def _named_colours(tokens: np.ndarray) -> np.ndarray:
    """The colour index each sentence names (its first colour word), -1 for none."""
    ids = {language.VOCAB.index(c): COLOR_NAMES.index(c) for c in language.COLOURS}
    return np.array([next((ids[t] for t in row if t in ids), -1) for row in tokens.tolist()])


def run(cfg: FalseAlarmConfig) -> dict:
    trained = chk.load(cfg.checker)
    if trained.kind != "window":  # FalseAlarmConfig refuses one; a directory changed since
        raise ValueError(f"{cfg.checker}: a {trained.kind} checker; this scores window checkers")
    env = jaxgrid.make(cfg.env_id)
    if cfg.policy == "random":
        policy, params = chk.random_policy, None
    else:
        policy = chk.noisy_oracle_policy
        params = chk.NoisyOracleParams(epsilon=cfg.epsilon, ignore_prob=0.5, seek_prob=0.0)
    data = chk.collect(env, policy, params, jax.random.PRNGKey(cfg.seed), None,
                       trained.config.window, trained.lookahead, cfg.envs, balance=False,
                       num_steps=cfg.steps, env_id=cfg.env_id)  # fmt: skip
    alarm = chk.predict(trained, data.windows, data.tokens) > trained.threshold
    label = data.labels > 0
    group = front_groups(front_cells(data.windows), _named_colours(data.tokens))
    rows = {}
    for g in sorted(set(group.tolist())):
        m = group == g
        neg = m & ~label
        rows[g] = {"windows": int(m.sum()), "positives": int((m & label).sum()),
                   "false_alarms": int((neg & alarm).sum()),
                   "false_alarm_rate": float((neg & alarm).sum() / max(neg.sum(), 1)),
                   "missed": int((m & label & ~alarm).sum())}  # fmt: skip
    total = {"windows": len(label), "positives": int(label.sum()), "alarms": int(alarm.sum()),
             "true_alarms": int((alarm & label).sum()), "false_alarms": int((alarm & ~label).sum()),
             "missed": int((~alarm & label).sum())}  # fmt: skip
    out = {"config": dataclasses.asdict(cfg), "total": total, "front": rows}
    _print(cfg, total, rows)
    if cfg.out:
        write_json(Path(cfg.out), out)
    return out


def _print(cfg: FalseAlarmConfig, total: dict, rows: dict) -> None:
    print(f"{cfg.checker} on {cfg.env_id}, {cfg.policy} policy: {total['windows']} windows, "
          f"{total['positives']} positive; {total['alarms']} alarms, {total['false_alarms']} "
          f"false, {total['missed']} violations missed")  # fmt: skip
    width = max(len(g) for g in [*rows, "in front"])
    print(f"{'in front':<{width}}  {'windows':>8}  {'positive':>8}  {'missed':>8}  "
          f"{'false alarms':>12}  rate")  # fmt: skip
    for g, r in sorted(rows.items(), key=lambda kv: -kv[1]["false_alarms"]):
        print(f"{g:<{width}}  {r['windows']:>8}  {r['positives']:>8}  {r['missed']:>8}  "
              f"{r['false_alarms']:>12}  {100 * r['false_alarm_rate']:.2f}%")  # fmt: skip


def main(argv=None) -> dict:
    """Count the alarms of ``argv``'s checker (default ``sys.argv[1:]``); returns the counts.

    A checker that is not a window checker, an ``--env-id`` that is none of the paper's
    scenarios, or an ``--out`` that cannot be written exits with status 2 before anything
    compiles."""
    cfg = cli.parse(FalseAlarmConfig, argv, prog=PROG, description=__doc__.split("\n\n")[0])
    return run(cfg)


if __name__ == "__main__":
    cli.run_main(main, PROG)

__all__ = ["FalseAlarmConfig", "POLICIES", "front_groups", "main", "run"]
