"""The checker measured as a classifier: plain numpy, JSON-ready floats.

* :func:`binary_metrics`: accuracy, precision, recall, F1 at a threshold, AUROC, ECE;
* :func:`auroc`: exact rank statistic (Mann-Whitney U) with average ranks for ties, so a
  tie between a positive and a negative counts one half;
* :func:`expected_calibration_error`: 10 equal-width bins of the predicted probability;
  the weighted mean of ``|mean label - mean probability|`` per bin;
* :func:`lead_time`: on full episodes (:func:`checker.data.collect_episodes`), the steps
  between the first alarm and the first violation of each violating episode, and the
  false-alarm rate on episodes without violation;
* :func:`per_group`: the same metrics per constraint template (or type);
* :func:`colour_counterfactual`: does the checker read the sentence? Each door-only positive
  is paired with the same window under a sentence naming another door colour, a true
  negative by the monitor's definition;
* :func:`evaluate`: all of it for a :class:`~checker.TrainedChecker` and a dataset, with
  jitted batched inference;
* the memory checker's, on whole streams: :func:`predict_streams`, and :func:`evaluate_streams`
  (AUROC overall, per constraint type, on budget violations later than any window can count,
  :func:`late_violation_mask`, and on counting itself).

Undefined values (AUROC with one class only, precision with no predicted positive, ...) are
``None`` so the result stays valid JSON.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from checker.memory_model import MemoryChecker, MemoryCheckerConfig, stream_input_names
from jaxgrid import hazard_language as HL

__all__ = [
    "auroc",
    "binary_metrics",
    "evaluate",
    "evaluate_streams",
    "expected_calibration_error",
    "late_violation_mask",
    "lead_time",
    "per_group",
    "predict",
    "predict_streams",
    "colour_counterfactual",
]


def _f(x) -> float | None:
    """Plain float, or None for NaN/inf/None."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def auroc(labels, scores) -> float | None:
    """Area under the ROC curve, exact, ties counted one half; None if a class is absent."""
    y = np.asarray(labels).astype(bool).ravel()
    s = np.asarray(scores, np.float64).ravel()
    if y.shape != s.shape:
        raise ValueError(f"labels {y.shape} and scores {s.shape} differ in shape")
    n_pos, n_neg = int(y.sum()), int((~y).sum())
    if n_pos == 0 or n_neg == 0:
        return None
    order = np.argsort(s, kind="mergesort")
    sorted_s = s[order]
    # Average 1-based ranks over runs of equal scores.
    boundaries = np.flatnonzero(np.diff(sorted_s)) + 1
    starts = np.concatenate([[0], boundaries])
    ends = np.concatenate([boundaries, [len(s)]])
    avg = (starts + ends + 1) / 2.0  # mean of ranks starts+1 .. ends
    ranks = np.empty(len(s))
    ranks[order] = np.repeat(avg, ends - starts)
    u = ranks[y].sum() - n_pos * (n_pos + 1) / 2.0
    return float(u / (n_pos * n_neg))


def expected_calibration_error(labels, probs, num_bins: int = 10) -> float | None:
    """ECE over ``num_bins`` equal-width bins of ``probs`` in [0, 1] (p = 1 in the last bin)."""
    y = np.asarray(labels, np.float64).ravel()
    p = np.asarray(probs, np.float64).ravel()
    if len(y) == 0:
        return None
    idx = np.clip((p * num_bins).astype(int), 0, num_bins - 1)
    total = 0.0
    for b in range(num_bins):
        m = idx == b
        if m.any():
            total += m.mean() * abs(y[m].mean() - p[m].mean())
    return float(total)


def binary_metrics(labels, probs, threshold: float = 0.5) -> dict:
    """Accuracy, precision, recall, F1 (predicted positive iff ``prob >= threshold``), AUROC,
    ECE (10 bins), Brier score, counts."""
    y = np.asarray(labels).astype(bool).ravel()
    p = np.asarray(probs, np.float64).ravel()
    pred = p >= threshold
    tp = int(np.sum(pred & y))
    fp = int(np.sum(pred & ~y))
    fn = int(np.sum(~pred & y))
    tn = int(np.sum(~pred & ~y))
    n = len(y)
    precision = tp / (tp + fp) if tp + fp else None
    recall = tp / (tp + fn) if tp + fn else None
    if precision is None or recall is None:
        f1 = None
    else:
        f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return {
        "n": n,
        "positives": int(y.sum()),
        "positive_rate": _f(y.mean()) if n else None,
        "threshold": float(threshold),
        "accuracy": _f((tp + tn) / n) if n else None,
        "precision": _f(precision),
        "recall": _f(recall),
        "f1": _f(f1),
        "auroc": auroc(y, p),
        "ece": expected_calibration_error(y, p),
        "brier": _f(np.mean((p - y) ** 2)) if n else None,
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "tn": tn,
    }


def per_group(groups, labels, probs, threshold: float = 0.5) -> dict:
    """``{str(group): binary_metrics}`` for every distinct value of ``groups``."""
    g = np.asarray(groups).ravel()
    out = {}
    for value in np.unique(g):
        m = g == value
        r = binary_metrics(np.asarray(labels)[m], np.asarray(probs)[m], threshold)
        out[str(value.item() if hasattr(value, "item") else value)] = {
            k: r[k] for k in ("n", "positives", "accuracy", "precision", "recall", "f1", "auroc")
        }
    return out


def lead_time(episodes, probs, threshold: float = 0.5) -> dict:
    """Lead time of alarms on full episodes.

    ``episodes`` is a dataset from :func:`checker.data.collect_episodes` (rows carry
    ``episode``, ``step``, ``next_violation`` and ``complete``) and ``probs`` the checker's
    probability for each row. Only complete episodes count. For a violating episode with its
    first violation on step ``t_v`` (the step that produces ``obs_{t_v}``), the first alarm is
    the first window ending at ``obs_t``, ``t <= t_v``, with ``prob >= threshold``, and the
    lead time is ``t_v - t``: 1 means the alarm fired on the observation just before the
    violating step, 0 after it (possible only if the violation did not end the episode).

    Returns counts, ``detected_before`` (fraction of violating episodes with an alarm at
    ``t < t_v``), ``detected`` (``t <= t_v``), mean / median / histogram of the lead time over
    detected episodes, ``false_alarm_rate`` (fraction of complete episodes *without* violation
    that raise any alarm) and ``false_alarm_window_rate`` (fraction of their windows that
    alarm).
    """
    ex = episodes.extras
    for name in ("episode", "step", "next_violation", "complete"):
        if name not in ex:
            raise ValueError(
                f"lead_time needs a full-episode dataset (collect_episodes); missing {name!r}"
            )
    p = np.asarray(probs, np.float64).ravel()
    keep = np.asarray(ex["complete"], bool)
    ep = np.asarray(ex["episode"])[keep]
    step = np.asarray(ex["step"])[keep]
    nxt = np.asarray(ex["next_violation"], bool)[keep]
    alarm = p[keep] >= threshold
    order = np.lexsort((step, ep))
    ep, step, nxt, alarm = ep[order], step[order], nxt[order], alarm[order]
    uniq, first = np.unique(ep, return_index=True)
    bounds = np.append(first, len(ep))
    leads, missed, fa_eps, clean_eps, clean_windows, clean_alarms = [], 0, 0, 0, 0, 0
    for i in range(len(uniq)):
        s, e = bounds[i], bounds[i + 1]
        v = np.flatnonzero(nxt[s:e])
        if len(v):
            t_v = int(step[s + v[0]]) + 1
            cand = np.flatnonzero(alarm[s:e] & (step[s:e] <= t_v))
            if len(cand):
                leads.append(t_v - int(step[s + cand[0]]))
            else:
                missed += 1
        else:
            clean_eps += 1
            clean_windows += e - s
            clean_alarms += int(alarm[s:e].sum())
            fa_eps += bool(alarm[s:e].any())
    n_viol = len(leads) + missed
    leads_a = np.asarray(leads)
    hist = {str(k): int(v) for k, v in zip(*np.unique(leads_a, return_counts=True), strict=True)}
    return {
        "threshold": float(threshold),
        "episodes": int(len(uniq)),
        "violating_episodes": n_viol,
        "detected": _f(len(leads) / n_viol) if n_viol else None,
        "detected_before": _f(np.sum(leads_a >= 1) / n_viol) if n_viol else None,
        "mean_lead_time": _f(leads_a.mean()) if len(leads) else None,
        "median_lead_time": _f(np.median(leads_a)) if len(leads) else None,
        "lead_time_histogram": hist,
        "clean_episodes": clean_eps,
        "false_alarm_rate": _f(fa_eps / clean_eps) if clean_eps else None,
        "false_alarm_window_rate": _f(clean_alarms / clean_windows) if clean_windows else None,
    }


@functools.partial(jax.jit, static_argnames=())
def _logits(trained, windows, tokens):
    return trained.logits(windows, tokens)


def predict(trained, windows, tokens, batch_size: int = 2048) -> np.ndarray:
    """Probabilities (float64 numpy) of all rows, in fixed-size jitted batches."""
    windows = np.asarray(windows)
    tokens = np.asarray(tokens)
    n = len(windows)
    out = np.empty((n,), np.float64)
    bs = max(1, min(batch_size, n))
    for s in range(0, n, bs):
        w, t = windows[s : s + bs], tokens[s : s + bs]
        m = len(w)
        if m < bs:  # pad so every call has the compiled shape
            w = np.concatenate([w, np.zeros((bs - m,) + w.shape[1:], w.dtype)])
            t = np.concatenate([t, np.zeros((bs - m,) + t.shape[1:], t.dtype)])
        logits = np.asarray(_logits(trained, jnp.asarray(w), jnp.asarray(t)), np.float64)
        out[s : s + m] = 1.0 / (1.0 + np.exp(-logits[:m]))
    return out


def colour_counterfactual(trained, dataset, threshold: float | None = None, seed: int = 0):
    """The checker on door-only positives vs. the same windows with the colour word changed.

    For a positive row whose template forbids a door only (no lava clause), the violation is
    entering a door of the named colour; under the same sentence naming another of the five
    door colours, that step is no violation, so the recoloured row is a true negative.
    Returns ``n`` (positives used), ``auroc`` (positives vs. their counterfactuals),
    ``flip_rate`` (fraction of detected positives that fall below the threshold once
    recoloured), and the mean probabilities of both; ``None`` entries if there is no such row.
    """
    from jaxgrid import language

    thr = trained.threshold if threshold is None else float(threshold)
    lava_free = np.array([not t.has_lava for t in language.TEMPLATES])
    tid = np.asarray(dataset.template_id)
    rows = np.flatnonzero((np.asarray(dataset.labels) > 0) & lava_free[np.clip(tid, 0, None)])
    if len(rows) == 0:
        return {"n": 0, "auroc": None, "flip_rate": None, "mean_prob": None,
                "mean_prob_counterfactual": None}  # fmt: skip
    tokens = np.array(dataset.tokens[rows])
    colour_ids = np.array([language.VOCAB.index(c) for c in language.DOOR_COLOURS])
    rng = np.random.default_rng(seed)
    is_colour = np.isin(tokens, np.array([language.VOCAB.index(c) for c in language.COLOURS]))
    for r in range(len(rows)):
        j = np.flatnonzero(is_colour[r])[0]  # door-only sentences name exactly one colour
        tokens[r, j] = rng.choice(colour_ids[colour_ids != tokens[r, j]])
    windows = dataset.windows[rows]
    p_true = predict(trained, windows, dataset.tokens[rows])
    p_cf = predict(trained, windows, tokens)
    detected = p_true >= thr
    labels = np.concatenate([np.ones(len(rows)), np.zeros(len(rows))])
    return {
        "n": int(len(rows)),
        "auroc": auroc(labels, np.concatenate([p_true, p_cf])),
        "flip_rate": _f(np.mean(p_cf[detected] < thr)) if detected.any() else None,
        "mean_prob": _f(p_true.mean()),
        "mean_prob_counterfactual": _f(p_cf.mean()),
    }


def evaluate(trained, dataset, threshold: float | None = None, batch_size: int = 2048) -> dict:
    """All metrics of ``trained`` on ``dataset``; plain floats/ints/None, JSON-serialisable.

    Keys: the :func:`binary_metrics` entries, ``per_template``, ``per_constraint_type``,
    ``colour_counterfactual``, ``dataset`` (a few metadata entries) and, for full-episode
    datasets, ``lead_time``.
    ``threshold`` defaults to ``trained.threshold``.
    """
    if trained.config.window != dataset.window:
        raise ValueError(
            f"checker window {trained.config.window} != dataset window {dataset.window}"
        )
    thr = trained.threshold if threshold is None else float(threshold)
    probs = predict(trained, dataset.windows, dataset.tokens, batch_size)
    out = binary_metrics(dataset.labels, probs, thr)
    out["per_template"] = per_group(dataset.template_id, dataset.labels, probs, thr)
    out["per_constraint_type"] = per_group(dataset.constraint_type, dataset.labels, probs, thr)
    out["colour_counterfactual"] = colour_counterfactual(trained, dataset, thr)
    out["dataset"] = {
        k: dataset.meta.get(k)
        for k in ("env_id", "split", "window", "lookahead", "natural_positive_rate", "balanced")
    }
    if "episode" in dataset.extras:
        out["lead_time"] = lead_time(dataset, probs, thr)
    return out


# ------------------------------------------------------------------ the memory checker


def predict_streams(params, config: MemoryCheckerConfig, data: dict, batch: int = 64):
    """Violation probabilities ``(N, T)`` of every frame of ``data``."""
    model = MemoryChecker(config)
    apply = jax.jit(lambda p, *x: jax.nn.sigmoid(model.apply(p, *x)))
    out = []
    for i in range(0, data["starts"].shape[0], batch):
        part = (data[k][i : i + batch] for k in stream_input_names(config))
        out.append(np.asarray(apply(params, *part)))
    return np.concatenate(out)


def late_violation_mask(data: dict, late: int, lookahead: int = 1) -> np.ndarray:
    """bool ``(N, T)``: frames of the episodes whose first violation comes more than ``late``
    steps after their first costly event (a budget counted beyond a window of ``late``
    frames). Streams begin with a reset, so every episode is seen from its start.
    ``lookahead`` says what ``data["label"]`` marks (:func:`checker.data.relabel`)."""
    shift = lookahead
    starts, cost, labels = data["starts"], data["cost"] > 0, data["label"] > 0
    mask = np.zeros(starts.shape, bool)
    for e in range(starts.shape[0]):
        begins = [*np.flatnonzero(starts[e]), starts.shape[1]]
        for a, b in zip(begins[:-1], begins[1:], strict=False):
            # frame t's cost is the step into it; a lookahead-1 label is the step out of it
            # (t + 1): such labels, unlike ``violation``, keep an episode's final step
            first_cost = np.flatnonzero(cost[e, a:b])
            first_violation = np.flatnonzero(labels[e, a:b]) + shift
            if len(first_cost) and len(first_violation):
                mask[e, a:b] = first_violation[0] - first_cost[0] > late
    return mask


def evaluate_streams(probs, data: dict, late: int = 10, lookahead: int = 1) -> dict:
    """AUROC of ``probs`` against the labels: overall, per constraint type, on late budget
    violations (:func:`late_violation_mask`) and on the budget frames whose labelled step
    costs (``costly_budget``: is this entry one too many?), with the positive counts behind
    each. ``lookahead`` says what ``data["label"]`` marks (:func:`checker.data.relabel`)."""
    y, valid = data["label"] > 0, data["valid"]
    report = {"auroc": auroc(y[valid], probs[valid]), "positives": int(y[valid].sum())}
    per_type = {}
    for i, name in enumerate(HL.CONSTRAINT_TYPES):
        m = valid & (data["ctype"] == i)
        per_type[name] = {"auroc": auroc(y[m], probs[m]), "positives": int(y[m].sum())}
    report["per_type"] = per_type
    budget = data["ctype"] == HL.CONSTRAINT_TYPES.index("budget")
    m = valid & budget & late_violation_mask(data, late, lookahead)
    report["late_budget"] = {"late": late, "auroc": auroc(y[m], probs[m]),
                             "positives": int(y[m].sum())}  # fmt: skip
    # Counting itself: among budget frames whose labelled step costs, which ones exceed the
    # budget? A checker that does not count cannot rank these (AUROC near 0.5).
    step_cost = data["next_cost"] if lookahead == 1 else data["cost"]
    m = valid & budget & (step_cost > 0)
    report["costly_budget"] = {"auroc": auroc(y[m], probs[m]), "positives": int(y[m].sum())}
    return report
