"""Layouts of a level generator against MiniGrid 3.2.0's: reset collection and comparisons.

* :func:`jax_resets` / :func:`jax_reset_states`: many vmapped jaxgrid resets (one compile per
  level configuration); :func:`minigrid_resets`: many MiniGrid resets from one seeded RNG
  stream.
* :func:`cell_id`, :func:`only`, :func:`single_cell`: reduce layouts to the cells chosen.
* Two-sample comparisons of one random choice (one category per sample):
  :func:`assert_same_support_and_chi2` (the same support exactly, no pooling) and
  :func:`compare_distributions` (a category seen on one side only fails when that is unlikely,
  rare categories pooled), each with a chi-square homogeneity test at ``alpha``.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest
from scipy.stats import chi2_contingency

from helpers.xla import batch_reset

ALPHA = 1e-4

# ------------------------------------------------------------------------------ sampling


def jax_reset_states(env, n, seed=0):
    """``n`` jaxgrid reset states (keys split from ``PRNGKey(seed)``), as numpy arrays."""
    states, _ = batch_reset(env, jax.random.split(jax.random.PRNGKey(seed), n))
    return jax.tree.map(np.asarray, states)


def jax_resets(env, n, seed=0):
    """``(grids, agent positions, agent directions)`` of ``n`` jaxgrid resets."""
    states, _ = batch_reset(env, jax.random.split(jax.random.PRNGKey(seed), n))
    return np.asarray(states.grid), np.asarray(states.agent_pos), np.asarray(states.agent_dir)


def minigrid_resets(mg, n, seed=0, extra=None):
    """``(grids, agent positions, agent directions)`` of ``n`` resets of MiniGrid env ``mg``,
    and with ``extra`` a fourth array of ``extra(mg)`` after every reset."""
    grids, pos, dirs, extras = [], [], [], []
    mg.reset(seed=seed)  # seed once; later resets continue the same RNG stream
    for i in range(n):
        if i:
            mg.reset()
        grids.append(mg.grid.encode())
        pos.append(tuple(int(c) for c in mg.agent_pos))
        dirs.append(int(mg.agent_dir))
        if extra is not None:
            extras.append(extra(mg))
    out = np.stack(grids), np.array(pos), np.array(dirs)
    return out if extra is None else (*out, np.array(extras))


# ------------------------------------------------------------------------------ cells


def cell_id(xy, height):
    xy = np.asarray(xy)
    return xy[..., 0] * height + xy[..., 1]


def single_cell(grids, mask, what="such object"):
    """``(x, y)`` of the single ``True`` cell of ``mask`` in every grid (asserts there is
    exactly one)."""
    assert (mask.sum(axis=(1, 2)) == 1).all(), f"not exactly one {what} per grid"
    flat = mask.reshape(len(grids), -1).argmax(axis=1)
    return np.stack(np.unravel_index(flat, grids.shape[1:3]), axis=-1)


def only(grids, kind):
    """``(x, y)`` of the single cell of ``kind`` in every grid (asserts there is exactly one)."""
    return single_cell(grids, grids[..., 0] == kind, f"object {kind}")


# ------------------------------------------------------------------------------ statistics


def _table(values) -> dict:
    keys, counts = np.unique(values, return_counts=True)
    return dict(zip(keys.tolist(), counts.tolist(), strict=True))


def _assert_homogeneous(name, counts, mine, theirs, alpha) -> float:
    """Chi-square homogeneity test of the ``(2, K)`` ``counts``; returns the p-value."""
    p = float(chi2_contingency(counts).pvalue)
    tv = 0.5 * np.abs(counts[0] / counts[0].sum() - counts[1] / counts[1].sum()).sum()
    assert p > alpha, f"{name}: chi-square p={p:.2e}, TV={tv:.3f}\n ours {mine}\n ref  {theirs}"
    return p


def assert_same_support_and_chi2(name, ours, ref, alpha=ALPHA):
    """Same support and a two-sample chi-square homogeneity test with p > ``alpha``."""
    ours, ref = np.asarray(ours), np.asarray(ref)
    mine, theirs = _table(ours), _table(ref)
    assert set(mine) == set(theirs), f"{name}: support {sorted(mine)} vs MiniGrid {sorted(theirs)}"
    if len(mine) == 1:
        return
    cats = sorted(mine)
    counts = np.array([[mine[c] for c in cats], [theirs[c] for c in cats]])
    _assert_homogeneous(name, counts, mine, theirs, alpha)


def compare_distributions(name, ours, ref, alpha=ALPHA) -> float:
    """Support check and chi-square homogeneity test; returns the p-value.

    A category drawn k times on one side only fails when seeing it never on the other side has
    Poisson probability below ``alpha`` divided by the number of categories; categories
    expected below 5 samples are merged into one before the chi-square test.
    """
    mine, theirs = _table(ours), _table(ref)
    sizes = {"jaxgrid": len(ours), "MiniGrid": len(ref)}
    for a, b, side, other in (
        (mine, theirs, "jaxgrid", "MiniGrid"),
        (theirs, mine, "MiniGrid", "jaxgrid"),
    ):
        # k draws on one side, none on the other: Poisson P(0) = exp(-k * n_other / n_side),
        # against alpha shared among the categories (Bonferroni)
        scale, share = sizes[other] / sizes[side], alpha / len(set(mine) | set(theirs))
        lone = {c: n for c, n in a.items() if c not in b and np.exp(-n * scale) < share}
        assert not lone, f"{name}: only {side} draws {lone}"
    cats = sorted(set(mine) | set(theirs))
    counts = np.array([[mine.get(c, 0) for c in cats], [theirs.get(c, 0) for c in cats]])
    expected = counts.sum(axis=0) * counts.sum(axis=1, keepdims=True) / counts.sum()
    small = expected.min(axis=0) < 5
    if small.any():
        counts = np.concatenate([counts[:, ~small], counts[:, small].sum(1, keepdims=True)], 1)
    if counts.shape[1] < 2:
        return 1.0
    return _assert_homogeneous(name, counts, mine, theirs, alpha)


def same_occupancy(name, ours, ref, alpha=ALPHA) -> float:
    """Per cell of bool ``(n, W, H)`` masks, a 2x2 homogeneity test at ``alpha / cells``;
    returns the smallest p-value times the number of cells tested."""
    k1, k2 = ours.sum(axis=0), ref.sum(axis=0)
    n1, n2 = len(ours), len(ref)
    cells = np.argwhere((k1 + k2 > 0) & (k1 + k2 < n1 + n2))
    worst = 1.0
    for x, y in cells:
        p = chi2_contingency([[k1[x, y], n1 - k1[x, y]], [k2[x, y], n2 - k2[x, y]]]).pvalue
        assert p > alpha / len(cells), (
            f"{name} cell ({x}, {y}): {k1[x, y]}/{n1} vs MiniGrid {k2[x, y]}/{n2}, p={p:.2e}"
        )
        worst = min(worst, p * len(cells))
    return worst


def compare_all(label, ours, ref) -> dict:
    """:func:`compare_distributions` for every marginal of two dicts of samples, and
    :func:`same_occupancy` for those named ``cells:...`` (bool masks); prints the worst p."""
    assert set(ours) == set(ref), sorted(set(ours) ^ set(ref))
    p = {}
    for name in ours:
        test = same_occupancy if name.startswith("cells:") else compare_distributions
        p[name] = test(f"{label} {name}", ours[name], ref[name])
    worst = min(p, key=p.get)
    print(f"{label}: {len(p)} quantities, smallest p {p[worst]:.3g} ({worst})")
    return p


def id_param(env_id, default):
    """``env_id`` as a pytest parameter, marked slow unless it is in ``default``."""
    return pytest.param(env_id, id=env_id, marks=() if env_id in default else pytest.mark.slow)
