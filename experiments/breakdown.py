"""Where trained agents still violate: their final policies replayed, split by constraint.

``python -m experiments.breakdown --run DIR/modes/checker [--episodes 2000]``

Each agent of a finished run directory (a mode of an experiment, or any ``--out`` of
:func:`agents.runner.run`) plays the same fixed-seed episodes; the episodes with a violation
and those that reach the goal are counted per sentence template and per colour the sentence
names. An agent that has learned the constraint for some colours and not yet for others
shows it here, where the run's single violation rate cannot. The checker modes need the
checker the run was trained with (``--checker``; by default the experiment's
``DIR/checker``, or the shield's own ``DIR/shield_checker`` for the run it trained). In the
shield modes the shield is on unless ``--policy-alone``.

Each agent's ``stages`` say how far its episodes get: the fraction that carried an object
and that entered each room beyond the first (rooms are split by the walls that run across
the grid), next to the goal's. An agent that never finds the goal shows where it stops.

The results (printed, and ``checkpoint`` in ``--out``) name the checkpoint replayed: the
newest that passes its checksums, which is an older one when the newest is damaged.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import checker as chk
from agents.runner import load_agents
from checker import cli
from checker.store import check_writable_file, params_sha256
from experiments.checker_phases import SHIELD_CHECKER
from jaxgrid import language
from jaxgrid.constants import DOOR, EMPTY, WALL
from jaxgrid.io import read_json, write_json

PROG = "python -m experiments.breakdown"


@dataclasses.dataclass(frozen=True)
class BreakdownConfig:
    """What to replay and how."""

    run: str = ""  # a run directory (run.json, checkpoints/), e.g. an experiment's modes/checker
    checker: str | None = None  # its checker (None: the experiment's checker/, if it has one)
    episodes: int = 2000  # fixed-seed episodes per agent
    seed: int = 0  # seed of the episodes
    policy_alone: bool = False  # shield modes: replay without the shield
    out: str | None = None  # JSON file for the results; None: print only

    def __post_init__(self):
        me = type(self).__name__
        if not self.run or not (Path(self.run) / "run.json").exists():
            raise ValueError(f"{me}.run {self.run!r}: no run.json there (give a directory "
                             "that agents.runner.run wrote, e.g. OUT/modes/checker)")  # fmt: skip
        if self.checker is not None and not (Path(self.checker) / "config.json").exists():
            raise ValueError(f"{me}.checker {self.checker}: no trained checker there")
        if not isinstance(self.episodes, int) or self.episodes < 1:
            raise ValueError(f"{me}.episodes must be an integer >= 1, got {self.episodes!r}")
        if self.out is not None:
            check_writable_file(self.out, f"{me}.out")


def checker_of(cfg: BreakdownConfig):
    """The run's checker: ``--checker``, else the experiment's (``checker/``, or the shield's
    own ``shield_checker/`` when that one's parameters are the run's); None if it had none."""
    digest = read_json(Path(cfg.run) / "run.json").get("checker_sha256")
    if not digest:
        return None
    experiment = Path(cfg.run).parent.parent
    path = Path(cfg.checker or experiment / "checker")
    own = experiment / SHIELD_CHECKER
    if cfg.checker is None and (own / "config.json").exists() and params_sha256(own) == digest:
        path = own
    if not (path / "config.json").exists():
        raise ValueError(f"{cfg.run} was trained with a checker: pass it with --checker")
    return chk.load(path)


def groups(constraints: np.ndarray, template_ids: np.ndarray) -> dict[str, np.ndarray]:
    """Boolean episode masks per ``template <id>: <an example sentence>`` and per
    ``colour <names>`` (the colour words the sentence names, ``none`` if it names none)."""
    sentences = [language.detokenize(c) for c in constraints]
    out = {}
    for t in np.unique(template_ids):
        example = sentences[int(np.flatnonzero(template_ids == t)[0])]
        out[f"template {int(t)}: {example}"] = template_ids == t
    named = np.array([" ".join(w for w in s.split() if w in language.COLOURS) or "none"
                      for s in sentences])  # fmt: skip
    for c in sorted(set(named)):
        out[f"colour {c}"] = named == c
    return out


def dividing_walls(grid) -> jax.Array:
    """bool (..., W): the columns that split the rooms, walls and doors in at least half
    their inner rows (the outer walls excluded)."""
    obj = grid[..., 1:-1, 0]
    wallish = ((obj == WALL) | (obj == DOOR)).mean(-1) >= 0.5
    return wallish.at[..., 0].set(False).at[..., -1].set(False)


def stage_tracker(env, key: jax.Array):
    """``(names, track)``: ``track(states) -> bool (E, K)`` flags whether each episode is
    carrying an object and has passed each room-dividing wall (as many as the scenario's
    first layout from ``key`` has), for :func:`agents.evaluation.play_episodes`."""
    state, _ = env.reset(key)
    walls = int(dividing_walls(state.grid).sum())
    names = ["carried an object"] + [f"entered room {k + 2}" for k in range(walls)]

    def track(states):
        xs = jnp.arange(states.grid.shape[1])
        passed = dividing_walls(states.grid) & (xs < states.agent_pos[:, :1])
        room = passed.sum(-1, keepdims=True)
        carrying = states.carrying[:, :1] != EMPTY
        return jnp.concatenate([carrying, room >= jnp.arange(1, walls + 1)], axis=-1)

    return names, track


def replayed_checkpoint(run_dir: str, agents: dict) -> dict:
    """Which checkpoint ``agents`` (:func:`agents.runner.load_agents`'s) were read from:
    ``chunks`` (its step: the chunks trained, of ``num_chunks``), ``complete``, and
    ``newest``, whether no newer checkpoint is kept (``newest_chunks``): the loader reads an
    older one when the newest fails its checksums, and the results are then of that one."""
    steps = [int(p.name) for p in (Path(run_dir) / "checkpoints").iterdir()
             if p.is_dir() and p.name.isdigit()]  # fmt: skip
    newest = max(steps, default=agents["chunks"])
    return {"chunks": agents["chunks"], "num_chunks": agents["config"].num_chunks,
            "complete": agents["complete"], "newest": agents["chunks"] >= newest,
            "newest_chunks": newest}  # fmt: skip


def run(cfg: BreakdownConfig) -> dict:
    agents = load_agents(cfg.run, checker_of(cfg))
    learner, config = agents["learner"], agents["config"]
    checkpoint = replayed_checkpoint(cfg.run, agents)
    key = jax.random.PRNGKey(cfg.seed)
    reset_key, _ = jax.random.split(key)  # play_episodes draws its layouts from this key
    _, ts = jax.jit(jax.vmap(learner.env.reset))(jax.random.split(reset_key, cfg.episodes))
    masks = groups(np.asarray(ts.observation["constraint"]), np.asarray(ts.info["template_id"]))
    stages, track = stage_tracker(learner.env, reset_key)
    play = jax.jit(lambda p, h: learner.evaluate(p, key, cfg.episodes,
                                                 shielded=not cfg.policy_alone, hparams=h,
                                                 track=track))  # fmt: skip
    rows = []
    for i, seed in enumerate(agents["seeds"]):
        params = jax.tree.map(lambda x, i=i: x[i], agents["params"])
        hparams = {n: v[i] for n, v in agents["hparams"].items()}
        ep = jax.tree.map(np.asarray, play(params, hparams))
        row = {"seed": seed, **{n: float(v) for n, v in hparams.items()},
               "violation_rate": float(ep["violated"].mean()),
               "success_rate": float(ep["success"].mean()), "groups": {},
               "stages": {name: float(ep["tracked"][:, k].mean())
                          for k, name in enumerate(stages)}}  # fmt: skip
        for name, m in masks.items():
            row["groups"][name] = {"episodes": int(m.sum()),
                                   "violation_rate": float(ep["violated"][m].mean()),
                                   "success_rate": float(ep["success"][m].mean())}  # fmt: skip
        rows.append(row)
    print_rows(cfg, rows, checkpoint)
    out = {"config": dataclasses.asdict(cfg), "mode": config.reward_mode,
           "checkpoint": checkpoint, "agents": rows}  # fmt: skip
    if cfg.out:
        write_json(Path(cfg.out), out)
    return out


def print_rows(cfg: BreakdownConfig, rows: list[dict], checkpoint: dict) -> None:
    """Print which checkpoint was replayed (:func:`replayed_checkpoint`), then one column
    per agent of ``rows`` (as :func:`run` makes them): violation and success % overall and
    per group, and the share of episodes that got to each stage."""
    names = list(rows[0]["groups"])
    c = checkpoint
    state = "finished" if c["complete"] else "unfinished"
    older = "" if c["newest"] else (f"; the newest, after {c['newest_chunks']} chunks, fails "
                                    "its checksums")  # fmt: skip
    print(f"{cfg.run}: checkpoint after {c['chunks']} of {c['num_chunks']} chunks ({state}"
          f"{older})")  # fmt: skip
    print(f"{cfg.run}: violation % / success % over {cfg.episodes} episodes per agent")
    swept = [
        k
        for k in rows[0]
        if k not in ("seed", "violation_rate", "success_rate", "groups", "stages")
    ]
    labels = [f"seed {r['seed']}" + "".join(f" {k}={r[k]:g}" for k in swept) for r in rows]
    width = max(len(n) for n in [*names, "all"])
    print(" " * width + "  " + "  ".join(f"{lab:>14}" for lab in labels))

    def cell(g):
        return f"{100 * g['violation_rate']:5.1f} / {100 * g['success_rate']:5.1f}"

    print(f"{'all':<{width}}  " + "  ".join(f"{cell(r):>14}" for r in rows))
    for n in names:
        print(f"{n:<{width}}  " + "  ".join(f"{cell(r['groups'][n]):>14}" for r in rows))
    print("\nepisodes that got so far, %")
    so_far = [{**r["stages"], "reached the goal": r["success_rate"]} for r in rows]
    for n in so_far[0]:
        print(f"{n:<{width}}  " + "  ".join(f"{100 * f[n]:>14.1f}" for f in so_far))


def main(argv=None) -> dict:
    """Replay the run of ``argv`` (default ``sys.argv[1:]``); returns the results.

    A directory that is no run, a checker that is not the run's, or an ``--out`` that cannot
    be written exits with status 2 before anything compiles."""
    cfg = cli.parse(BreakdownConfig, argv, prog=PROG, description=__doc__.split("\n\n")[0])
    return run(cfg)


if __name__ == "__main__":
    cli.run_main(main, PROG)

__all__ = [
    "BreakdownConfig",
    "checker_of",
    "dividing_walls",
    "groups",
    "main",
    "print_rows",
    "replayed_checkpoint",
    "run",
    "stage_tracker",
]
