"""Layout fidelity: every native MiniGrid id's resets against MiniGrid 3.2.0's generator.

For each id, ``--resets`` MiniGrid resets (one RNG stream, seed fixed) and as many jaxgrid
resets (vmapped, keys split from one seed) are reduced to the same statistics:

* **per-cell occupancy by object type**: for every object type and every cell, how often the
  cell holds that type (a 2x2 chi-square test per cell; Bonferroni over the cells tested);
* **object counts**: per object type, and per (type, colour, state), the number in a layout;
* **agent**: start cell and direction;
* **goal**: its cell (ids with one goal);
* **shortest path**: BFS steps from the agent to the goal through every cell that is not a
  wall or lava (``-1`` when unreachable; ids with one goal).

Each categorical statistic gets a two-sample chi-square homogeneity test, categories
expected below 5 samples pooled into one; a category that one side draws often and the other
never is reported as such (its p-value is the Poisson chance of never drawing it). The id's
*worst statistic* is its smallest p-value, multiplied by the number of statistics tested for
the id (Bonferroni): an id **fails** when that adjusted p-value is below ``--alpha``
(1e-3 by default, per id). The generators' own test files read each level's random choices
more finely (room chains, door offsets, missions); this report applies one yardstick to all.
Usage::

    python -m benchmarks.layout_fidelity                      # every id, 2,000 resets each
    python -m benchmarks.layout_fidelity --ids MiniGrid-FourRooms-v0 --resets 500
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

import jax
import numpy as np
from scipy.stats import chi2_contingency

from benchmarks.cli import integer, real, require
from checker.cli import run_main
from jaxgrid.constants import GOAL, LAVA, OBJECT_NAMES, WALL
from jaxgrid.io import write_json
from jaxgrid.registry import make, registered_ids

CHUNK = 500  # jaxgrid resets per vmapped call


def native_ids() -> list[str]:
    """Every registered id that is a MiniGrid id (generated natively)."""
    return [i for i in registered_ids() if i.startswith("MiniGrid-")]


def minigrid_layouts(env_id: str, n: int, seed: int = 0):
    """``(grids (n, W, H, 3), agent cells (n, 2), directions (n,))`` of MiniGrid resets."""
    import gymnasium as gym
    import minigrid  # noqa: F401  (registers the ids)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # deprecation notices of legacy ids
        mg = gym.make(env_id).unwrapped
    grids, pos, dirs = [], [], []
    mg.reset(seed=seed)
    for i in range(n):
        if i:
            mg.reset()
        grids.append(mg.grid.encode())
        pos.append(tuple(int(c) for c in mg.agent_pos))
        dirs.append(int(mg.agent_dir))
    return np.stack(grids), np.array(pos), np.array(dirs)


def jaxgrid_layouts(env_id: str, n: int, seed: int = 0):
    """The same arrays for ``n`` jaxgrid resets of ``env_id``."""
    env = make(env_id)
    reset = jax.jit(jax.vmap(env.reset))
    keys = jax.random.split(jax.random.PRNGKey(seed), n)
    parts = [reset(keys[i : i + CHUNK])[0] for i in range(0, n, CHUNK)]
    cat = lambda f: np.concatenate([np.asarray(f(s)) for s in parts])
    return cat(lambda s: s.grid), cat(lambda s: s.agent_pos), cat(lambda s: s.agent_dir)


def path_lengths(grids: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """BFS steps from the agent to the (single) goal over cells that are neither wall nor
    lava; ``-1`` when the goal is unreachable."""
    out = np.full(len(grids), -1)
    for i, (grid, start) in enumerate(zip(grids, pos, strict=True)):
        kind = grid[..., 0]
        free = (kind != WALL) & (kind != LAVA)
        dist = np.full(kind.shape, -1)
        dist[tuple(start)] = 0
        frontier = [tuple(start)]
        while frontier and out[i] < 0:
            nxt = []
            for x, y in frontier:
                if kind[x, y] == GOAL:
                    out[i] = dist[x, y]
                    break
                for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                    a, b = x + dx, y + dy
                    if 0 <= a < kind.shape[0] and 0 <= b < kind.shape[1]:
                        if free[a, b] and dist[a, b] < 0:
                            dist[a, b] = dist[x, y] + 1
                            nxt.append((a, b))
            frontier = nxt
    return out


def statistics(grids, pos, dirs) -> tuple[dict, dict]:
    """``(categorical, occupancy)``: name -> one value per layout, and object name -> bool
    ``(n, W, H)`` occupancy masks."""
    n, _, height, _ = grids.shape
    kind = grids[..., 0]
    cat = {"agent cell": pos[:, 0] * height + pos[:, 1], "agent direction": dirs}
    occupancy = {}
    for k in np.unique(kind):
        name = OBJECT_NAMES[k]
        occupancy[name] = kind == k
        cat[f"count {name}"] = (kind == k).sum(axis=(1, 2))
    triples = grids.reshape(n, -1, 3).astype(np.int64)
    codes = triples[..., 0] * 100 + triples[..., 1] * 10 + triples[..., 2]
    for code in np.unique(codes):
        k, colour, state = code // 100, code // 10 % 10, code % 10
        if k != WALL and OBJECT_NAMES[k] not in ("empty", "unseen"):
            cat[f"count {OBJECT_NAMES[k]} c{colour} s{state}"] = (codes == code).sum(axis=1)
    goals = (kind == GOAL).sum(axis=(1, 2))
    if (goals == 1).all():
        flat = (kind == GOAL).reshape(n, -1).argmax(axis=1)
        cat["goal cell"] = flat  # x * height + y, as the agent's
        cat["shortest path"] = path_lengths(grids, pos)
    return cat, occupancy


def categorical_p(ours: np.ndarray, ref: np.ndarray) -> float:
    """Two-sample chi-square p-value of one categorical statistic (see the module docstring)."""
    cats, inverse = np.unique(np.concatenate([ours, ref]), return_inverse=True)
    counts = np.zeros((2, len(cats)), np.int64)
    np.add.at(counts[0], inverse[: len(ours)], 1)
    np.add.at(counts[1], inverse[len(ours) :], 1)
    lone = 1.0
    for side, other in ((0, 1), (1, 0)):
        only = counts[side][counts[other] == 0]
        if only.size:  # Poisson chance that the other side never draws it
            scale = counts[other].sum() / counts[side].sum()
            lone = min(lone, float(np.exp(-only.max() * scale)) * len(cats))
    expected = counts.sum(axis=0) * counts.sum(axis=1, keepdims=True) / counts.sum()
    small = expected.min(axis=0) < 5
    if small.any():
        counts = np.concatenate([counts[:, ~small], counts[:, small].sum(1, keepdims=True)], 1)
    chi = 1.0 if counts.shape[1] < 2 else float(chi2_contingency(counts).pvalue)
    return min(lone, chi)


def occupancy_p(ours: np.ndarray, ref: np.ndarray) -> tuple[float, int]:
    """Smallest per-cell 2x2 p-value times the cells tested, and the cells tested."""
    k1, k2 = ours.sum(axis=0), ref.sum(axis=0)
    n1, n2 = len(ours), len(ref)
    cells = np.argwhere((k1 + k2 > 0) & (k1 + k2 < n1 + n2))
    worst = 1.0
    for x, y in cells:
        table = [[k1[x, y], n1 - k1[x, y]], [k2[x, y], n2 - k2[x, y]]]
        worst = min(worst, float(chi2_contingency(table).pvalue))
    return min(1.0, worst * max(len(cells), 1)), len(cells)


def compare(ours, ref) -> dict:
    """Every statistic's p-value (cells Bonferroni-adjusted) for two sets of layouts."""
    (cat1, occ1), (cat2, occ2) = statistics(*ours), statistics(*ref)
    p = {}
    for name in sorted(set(cat1) | set(cat2)):
        a = cat1.get(name, np.zeros(len(ours[0]), int))  # a count never seen is 0 throughout
        b = cat2.get(name, np.zeros(len(ref[0]), int))
        p[name] = categorical_p(a, b)
    for name in sorted(set(occ1) | set(occ2)):
        a = occ1.get(name, np.zeros(ours[0].shape[:3], bool))
        b = occ2.get(name, np.zeros(ref[0].shape[:3], bool))
        p[f"cells {name}"] = occupancy_p(a, b)[0]
    return p


def fidelity(env_id: str, resets: int, alpha: float, seed: int = 0) -> dict:
    """One id's report: the worst statistic, its adjusted p-value and the verdict."""
    t0 = time.perf_counter()
    ref = minigrid_layouts(env_id, resets, seed)
    ours = jaxgrid_layouts(env_id, resets, seed)
    p = compare(ours, ref)
    worst = min(p, key=p.get)
    adjusted = min(1.0, p[worst] * len(p))
    return {
        "resets": resets,
        "statistics": len(p),
        "worst": worst,
        "worst_p": p[worst],
        "worst_p_adjusted": adjusted,
        "passed": adjusted >= alpha,
        "seconds": round(time.perf_counter() - t0, 1),
        "p": p,
    }


def table(report: dict) -> str:
    """The report as a Markdown table, one row per id."""
    rows = [
        "| id | statistics | worst statistic | adjusted p | verdict |",
        "|---|---:|---|---:|---|",
    ]
    for env_id, r in report["ids"].items():
        verdict = "pass" if r["passed"] else "**fail**"
        rows.append(
            f"| {env_id} | {r['statistics']} | {r['worst']} | {r['worst_p_adjusted']:.3g} "
            f"| {verdict} |"
        )
    return "\n".join(rows)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.layout_fidelity",
                                     description=__doc__.split("\n\n")[0])  # fmt: skip
    parser.add_argument("--ids", nargs="*", default=None, help="ids to check (default: all)")
    parser.add_argument("--resets", type=integer, default=2000, help="resets per side and id")
    parser.add_argument("--alpha", type=real, default=1e-3, help="per-id significance")
    parser.add_argument("--seed", type=integer, default=0, help="seed of both sides' resets")
    parser.add_argument("--json", default=None, help="write the report here")
    args = parser.parse_args(argv)
    if args.resets < 20:
        parser.error(f"--resets must be at least 20, got {args.resets}")
    if not 0 < args.alpha < 1:
        parser.error(f"--alpha must lie in (0, 1), got {args.alpha}")
    if args.seed < 0:  # MiniGrid's reset refuses it
        parser.error(f"--seed must be >= 0, got {args.seed}")
    ids = args.ids or native_ids()
    unknown = [i for i in ids if i not in native_ids()]
    if unknown:
        parser.error(f"not a native MiniGrid id: {unknown[0]!r}; ids: {', '.join(native_ids())}")
    require("minigrid", "the reference (MiniGrid's own resets)")
    report = {"alpha": args.alpha, "resets": args.resets, "ids": {}}
    for k, env_id in enumerate(ids):
        r = fidelity(env_id, args.resets, args.alpha, args.seed)
        report["ids"][env_id] = r
        verdict = "pass" if r["passed"] else "FAIL"
        print(
            f"[{k + 1}/{len(ids)}] {env_id}: {verdict}, worst {r['worst']} "
            f"(adjusted p {r['worst_p_adjusted']:.3g}, {r['statistics']} statistics, "
            f"{r['seconds']} s)",
            file=sys.stderr,
        )
    failed = [i for i, r in report["ids"].items() if not r["passed"]]
    report["failed"] = failed
    report["tests"] = sum(r["statistics"] for r in report["ids"].values())
    print(table(report))
    print(f"\n{len(ids) - len(failed)}/{len(ids)} ids pass at alpha {args.alpha} per id")
    if args.json:
        write_json(args.json, report)
    return report


if __name__ == "__main__":
    run_main(main, "python -m benchmarks.layout_fidelity")
