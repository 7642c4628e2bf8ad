"""Training a checker of either kind, by ``python -m checker`` and by the experiments.

Window checkers (:class:`CheckerTrainConfig`, :func:`train_checker`; noisy-oracle windows or
a behaviour agent's): :func:`train_checker` splits off a test set, then
fits :class:`~checker.model.Checker` with AdamW on binary cross-entropy with logits: one jitted
step per minibatch of a fresh permutation each epoch (the last incomplete minibatch is skipped,
a different one each epoch). A ``lax.scan`` over an epoch was measured 6-7x slower on XLA:CPU
(the convolutions' backward pass inside a while loop), so the epoch loop stays in Python;
dispatch is asynchronous. A validation split drives early stopping on its loss, and the
parameters of the best epoch are returned.

Sentences are few (at most 210 distinct constraints exist), so each minibatch encodes the
table of the dataset's *distinct* token rows once and gathers the codes per row: the same
function and gradients as encoding every row, at a fraction of the GRU's cost.

Memory checkers (:class:`MemoryTrainConfig`, :func:`train_memory_checker`): Adam on whole
streams (:func:`checker.data.collect_streams`), backpropagation through each stream untruncated,
``batch_streams`` streams drawn per update, the rare violations' loss weighted.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import optax

from checker.data import (
    CheckerDataset,
    before_step,
    validate_window,
    with_blocked_counterfactuals,
    with_colour_counterfactuals,
    with_distractors,
)
from checker.data.labels import STREAM_LOOKAHEADS
from checker.memory_model import (
    MemoryChecker,
    MemoryCheckerConfig,
    stream_input_names,
    stream_inputs,
)
from checker.model import Checker, CheckerConfig, TrainedChecker, init_params
from jaxgrid import language

__all__ = [
    "CheckerTrainConfig",
    "MemoryTrainConfig",
    "check_window_scenario",
    "fit_memory_checker",
    "train_checker",
    "train_memory_checker",
    "window_scenarios",
]


def window_scenarios() -> list[str]:
    """The registered ids whose windows a window checker learns: the paper's scenarios
    (:class:`jaxgrid.scenarios.Scenario`), whose constraint forbids a door colour, lava or
    both. The noisy oracle plans around (or seeks) that door and lava, and
    :func:`checker.collect` labels windows by it; other envs have no such constraint."""
    import jaxgrid
    from jaxgrid.scenarios import Scenario

    return [i for i in jaxgrid.registered_ids() if isinstance(jaxgrid.make(i), Scenario)]


def check_window_scenario(env_id: str, command: str, why: str) -> None:
    """``ValueError`` unless ``env_id`` is one of :func:`window_scenarios`, naming them and
    saying why ``command`` needs one (``why``: what it does with the constraint) and what the
    env has instead. Builds no program: a command calls it while checking its flags."""
    import jaxgrid
    from jaxgrid.hazard import HazardRooms

    ids = window_scenarios()
    if env_id in ids:
        return
    if isinstance(jaxgrid.make(env_id), HazardRooms):  # an unknown id: make's ValueError
        instead = (f"{env_id}'s constraints (budgets, sequences, proximity, ...) are learnt by "
                   "a memory checker: python -m checker --kind memory")  # fmt: skip
    elif env_id.startswith("MiniGrid-"):
        instead = f"{env_id} has no constraint, so there is no violation to measure"
    else:
        instead = f"{env_id} is not one of them"
    raise ValueError(f"{env_id}: {command} needs one of the paper's scenarios "
                     f"({', '.join(ids)}), whose constraint forbids a door colour or lava, "
                     f"since {why}; {instead}")  # fmt: skip


@dataclasses.dataclass(frozen=True)
class CheckerTrainConfig:
    """Every setting of :func:`train_checker`, validated on construction (``ValueError``);
    the defaults are the checker of the paper's experiments."""

    window: int = 5  # observations per window, of the data and of the checker
    lookahead: int = 1  # windows are labelled by a violation this many steps ahead (1: next)
    seed: int = 0  # seeds the splits, the initialisation, the augmentations, the batch order
    epochs: int = 40  # at most this many epochs
    batch_size: int = 128  # minibatch size; the training part must hold one
    lr: float = 2e-3  # AdamW's step size, cosine-decayed over the epochs
    weight_decay: float = 1e-4  # AdamW's weight decay
    patience: int = 8  # stop after this many epochs without a lower validation loss
    test_fraction: float = 0.15  # of the windows, split off (stratified) and never trained on
    val_fraction: float = 0.15  # of the windows, held out for early stopping (0: last epoch)
    threshold: float = 0.5  # decision threshold stored in the checker
    # Recoloured negatives added per door-only positive to the training and validation parts
    # (checker.data.with_colour_counterfactuals), so the checker must read the sentence's
    # colour; 0: none. Skipped, with a warning, above lookahead 1 (labels would not be exact).
    counterfactuals: int = 1
    # Also recolour door-and-lava positives whose next step enters the named door (exact only
    # at lookahead 1 and before the step, not in final windows; elsewhere they keep no copy).
    # With blocked and final_windows it removes the false alarms and misses that stopped
    # agents or let them into lava (docs/decisions.md).
    lava_counterfactuals: bool = True
    # Fraction of the training and validation rows copied with keys, balls and boxes strewn
    # over empty cells (checker.data.with_distractors), so the checker ignores objects no
    # constraint names; 0: none. Skipped, with a warning, above lookahead 1.
    distractors: float = 0.5
    # Negatives added per positive with the cell in front shown as a key, ball, box or locked
    # door (checker.data.with_blocked_counterfactuals), so the checker tells an open door from
    # what cannot be entered; 0: none. Final windows get none. Skipped, with a warning, unless
    # lookahead is 1 (labels would not be exact) and the final windows are marked.
    blocked: int = 1
    # Also train on the windows that end at an episode's final observation, labelled by the
    # step that ended it (checker.data.streams, "Final windows"): the checker reward and the shield
    # score such windows, and where a violation ends the episode (lava) it is the only window
    # that shows the step into it.
    final_windows: bool = True

    def __post_init__(self):
        try:
            validate_window(self.window, self.lookahead)
        except ValueError as e:
            raise ValueError(f"CheckerTrainConfig.{e}") from None
        minimum = dict(epochs=1, batch_size=1, patience=1, seed=0, counterfactuals=0, blocked=0)
        for name, low in minimum.items():
            value = getattr(self, name)
            if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < low:
                raise ValueError(f"CheckerTrainConfig.{name} must be an integer >= {low}, "
                                 f"got {value!r}")  # fmt: skip
        if not isinstance(self.final_windows, bool):
            raise ValueError(f"CheckerTrainConfig.final_windows must be a bool, "
                             f"got {self.final_windows!r}")  # fmt: skip
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"CheckerTrainConfig.{f.name} must be finite, got {value!r}")
        checks = (
            ("lr", self.lr > 0, "> 0"),
            ("weight_decay", self.weight_decay >= 0, ">= 0"),
            ("test_fraction", 0 <= self.test_fraction < 1, "in [0, 1)"),
            ("val_fraction", 0 <= self.val_fraction < 1, "in [0, 1)"),
            ("threshold", 0 < self.threshold < 1, "in (0, 1)"),
            ("distractors", 0 <= self.distractors <= 1, "in [0, 1]"),
        )
        for name, ok, rule in checks:
            if not ok:
                raise ValueError(f"CheckerTrainConfig.{name} must be {rule}, "
                                 f"got {getattr(self, name)!r}")  # fmt: skip
        if self.test_fraction + self.val_fraction >= 1:
            raise ValueError(
                f"CheckerTrainConfig.test_fraction + CheckerTrainConfig.val_fraction must be "
                f"< 1, got {self.test_fraction} + {self.val_fraction}"
            )

    def training_rows(self, samples: int) -> int:
        """The rows of ``samples`` windows left to train on by the test and validation splits,
        before augmentation: at least :attr:`batch_size` are needed, which a command checks
        before collecting anything."""
        return int(samples * (1 - self.test_fraction - self.val_fraction))


def _make_fns(config: CheckerConfig, tx, batch_size: int):
    model = Checker(config)

    def logits_fn(params, windows, tok_idx, table):
        codes = model.apply(params, table, method=Checker.encode_language)
        states = model.apply(params, windows, method=Checker.embed_states)
        return model.apply(params, states, codes[tok_idx], method=Checker.classify)

    def loss_fn(params, windows, tok_idx, labels, table, weight):
        logits = logits_fn(params, windows, tok_idx, table)
        loss = optax.sigmoid_binary_cross_entropy(logits, labels)
        return jnp.sum(loss * weight) / jnp.maximum(jnp.sum(weight), 1.0)

    @jax.jit
    def train_step(params, opt_state, idx, windows, tok_idx, labels, table):
        loss, grads = jax.value_and_grad(loss_fn)(
            params, windows[idx], tok_idx[idx], labels[idx], table, jnp.ones(idx.shape)
        )
        updates, opt_state = tx.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, loss

    def epoch(params, opt_state, key, windows, tok_idx, labels, table):
        # A Python loop over jitted steps, not lax.scan: on XLA:CPU the backward pass of the
        # convolutions runs several times slower inside a while loop (measured: 4.0 s vs
        # 0.6 s per epoch of 65 minibatches of 128).
        n = labels.shape[0]
        num_batches = n // batch_size
        perm = jax.random.permutation(key, n)[: num_batches * batch_size]
        perm = perm.reshape(num_batches, batch_size)
        losses = []
        for b in range(num_batches):
            params, opt_state, loss = train_step(
                params, opt_state, perm[b], windows, tok_idx, labels, table
            )
            losses.append(loss)
        return params, opt_state, jnp.mean(jnp.stack(losses))

    @jax.jit
    def eval_batch(params, windows, tok_idx, labels, table, weight):
        logits = logits_fn(params, windows, tok_idx, table)
        loss = optax.sigmoid_binary_cross_entropy(logits, labels)
        correct = ((logits >= 0) == (labels > 0.5)).astype(jnp.float32)
        return jnp.sum(loss * weight), jnp.sum(correct * weight)

    def evaluate(params, windows, tok_idx, labels, table):
        n = len(labels)
        tot_loss = tot_acc = 0.0
        bs = batch_size * 4
        for s in range(0, n, bs):
            w, t, y = windows[s : s + bs], tok_idx[s : s + bs], labels[s : s + bs]
            m = len(y)
            weight = np.ones((bs,), np.float32)
            if m < bs:
                pad = bs - m
                w = np.concatenate([w, np.zeros((pad,) + w.shape[1:], w.dtype)])
                t = np.concatenate([t, np.zeros((pad,), t.dtype)])
                y = np.concatenate([y, np.zeros((pad,), y.dtype)])
                weight[m:] = 0
            lo, ac = eval_batch(params, w, t, y, table, weight)
            tot_loss += float(lo)
            tot_acc += float(ac)
        return tot_loss / max(n, 1), tot_acc / max(n, 1)

    return epoch, evaluate


def train_checker(
    dataset: CheckerDataset,
    settings: CheckerTrainConfig | None = None,
    *,
    model: CheckerConfig | None = None,
    progress: bool = True,
) -> tuple[TrainedChecker, dict, CheckerDataset | None]:
    """Train a checker on ``dataset``; returns ``(TrainedChecker, history, test)``.

    Args:
        dataset: the windows (a :class:`CheckerDataset`) of ``settings.window`` observations,
            labelled ``settings.lookahead`` steps ahead.
        settings: every training setting (default ``CheckerTrainConfig()``). The test part,
            ``test_fraction`` of ``dataset`` (stratified), is split off first and returned
            (``None`` when the fraction is 0); ``val_fraction`` of ``dataset`` is then held
            out of the rest for early stopping.
        model: the checker's sizes; default ``CheckerConfig(window, view_size=V)`` with the
            dataset's view side ``V``.
        progress: show a tqdm progress bar.

    ``history`` holds per-epoch ``train_loss``, ``val_loss``, ``val_accuracy``, the
    ``best_epoch`` (1-based), the sizes of the parts and timings.
    """
    s = CheckerTrainConfig() if settings is None else settings
    if len(dataset) == 0:
        raise ValueError("train_checker: the dataset is empty")
    v = dataset.windows.shape[2]
    lookahead = dataset.meta.get("lookahead", 1)
    if (dataset.window, lookahead) != (s.window, s.lookahead):
        raise ValueError(
            f"train_checker: the dataset's window {dataset.window} and lookahead {lookahead} "
            f"differ from the settings' (CheckerTrainConfig.window={s.window}, "
            f"CheckerTrainConfig.lookahead={s.lookahead})"
        )
    final_windows = bool(dataset.meta.get("final_windows", False))
    if final_windows != s.final_windows:
        raise ValueError(
            f"train_checker: the dataset was collected with final_windows={final_windows}, "
            f"the settings say CheckerTrainConfig.final_windows={s.final_windows}"
        )
    model = CheckerConfig(window=s.window, view_size=v) if model is None else model
    if model.window != dataset.window or model.view_size != v:
        raise ValueError(
            f"model (window={model.window}, view_size={model.view_size}) does not match "
            f"the dataset (window={dataset.window}, view_size={v})"
        )

    t0 = time.perf_counter()
    trainval, test = dataset, None
    if s.test_fraction > 0:
        trainval, test = dataset.split((1 - s.test_fraction, s.test_fraction), seed=s.seed)
    train_ds, val_ds = trainval, None
    val_fraction = s.val_fraction / (1 - s.test_fraction)  # of what the test split left
    if val_fraction > 0:
        train_ds, val_ds = trainval.split((1 - val_fraction, val_fraction), seed=s.seed)
    # Each augmentation keeps labels exact only where ``exact`` holds (see their docstrings).
    for name, amount, augment, offset, exact, why in (
        ("colour counterfactuals", s.counterfactuals,
         functools.partial(with_colour_counterfactuals, lava=s.lava_counterfactuals), 0,
         lookahead <= 1, f"lookahead {lookahead} > 1"),
        ("distractors", s.distractors, with_distractors, 2,
         lookahead <= 1, f"lookahead {lookahead} > 1"),
        ("blocked counterfactuals", s.blocked, with_blocked_counterfactuals, 4,
         lookahead == 1 and before_step(train_ds) is not None,
         f"lookahead {lookahead}" if lookahead != 1 else "unmarked final windows"),
    ):  # fmt: skip
        if not amount:
            continue
        if not exact:
            warnings.warn(
                f"train_checker: no {name} for {why} (the labels would not stay exact)",
                stacklevel=2,
            )
            continue
        train_ds = augment(train_ds, amount, seed=s.seed + offset)
        if val_ds is not None:
            val_ds = augment(val_ds, amount, seed=s.seed + offset + 1)
    if len(train_ds) < s.batch_size:
        raise ValueError(
            f"train_checker: {len(train_ds)} training rows, fewer than "
            f"CheckerTrainConfig.batch_size={s.batch_size}"
        )
    arrays = [train_ds.tokens] + ([val_ds.tokens] if val_ds is not None else [])
    # The GRU encodes each distinct sentence once per step; rows gather their code.
    table = np.unique(np.concatenate(arrays), axis=0).astype(np.int32)
    idx = [language.sentence_index(np.asarray(a, np.int32), table) for a in arrays]
    table = jnp.asarray(table)
    tr = (jnp.asarray(train_ds.windows), jnp.asarray(idx[0]),
          jnp.asarray(train_ds.labels, jnp.float32))  # fmt: skip
    if val_ds is not None:
        va = (val_ds.windows, idx[1], val_ds.labels.astype(np.float32))

    key = jax.random.PRNGKey(s.seed)
    k_init, key = jax.random.split(key)
    params = init_params(model, k_init)
    steps = s.epochs * (len(train_ds) // s.batch_size)
    schedule = optax.cosine_decay_schedule(s.lr, max(steps, 1), alpha=0.05)
    tx = optax.adamw(schedule, weight_decay=s.weight_decay)
    opt_state = tx.init(params)
    epoch_fn, eval_fn = _make_fns(model, tx, s.batch_size)

    history = {"train_loss": [], "val_loss": [], "val_accuracy": [], "epoch_time": []}
    best, best_loss, best_epoch, waited = params, np.inf, 0, 0
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=s.epochs, desc="train checker", unit="epoch", leave=False)
    for ep in range(1, s.epochs + 1):
        te = time.perf_counter()
        key, k = jax.random.split(key)
        params, opt_state, loss = epoch_fn(params, opt_state, k, *tr, table)
        history["train_loss"].append(float(loss))
        if val_ds is not None:
            vl, vacc = eval_fn(params, *va, table)
            history["val_loss"].append(vl)
            history["val_accuracy"].append(vacc)
            if vl < best_loss:
                best, best_loss, best_epoch, waited = params, vl, ep, 0
            else:
                waited += 1
        else:
            best, best_epoch = params, ep
        history["epoch_time"].append(time.perf_counter() - te)
        if bar is not None:
            bar.update(1)
            post = {"loss": f"{float(loss):.4f}"}
            if val_ds is not None:
                post.update(val_loss=f"{history['val_loss'][-1]:.4f}",
                            val_acc=f"{history['val_accuracy'][-1]:.4f}")  # fmt: skip
            bar.set_postfix(post)
        if val_ds is not None and waited >= s.patience:
            break
    if bar is not None:
        bar.close()
    history.update(
        best_epoch=best_epoch,
        best_val_loss=None if val_ds is None else float(best_loss),
        epochs_run=len(history["train_loss"]),
        train_rows=len(train_ds),
        val_rows=0 if val_ds is None else len(val_ds),
        test_rows=0 if test is None else len(test),
        wall_time_s=time.perf_counter() - t0,
    )
    trained = TrainedChecker(
        params=best,
        config=model,
        lookahead=int(dataset.meta.get("lookahead", 1)),
        env_id=str(dataset.meta.get("env_id", "")),
        threshold=float(s.threshold),
    )
    return trained, history, test


# ------------------------------------------------------------------------ memory checker


@dataclasses.dataclass(frozen=True)
class MemoryTrainConfig:
    """Data and optimisation settings of a memory checker (:func:`train_memory_checker`;
    ``streams`` and ``steps`` size what :func:`checker.data.collect_streams` gathers for it);
    the defaults are the memory checker of the HazardRooms experiment."""

    streams: int = 512  # streams collected, for training and again for the test
    steps: int = 160  # frames per stream
    updates: int = 600  # training updates
    batch_streams: int = 16  # streams per update
    lr: float = 1e-3  # Adam step size
    positive_weight: float = 10.0  # violations are rare: weight their loss
    guided: float = 0.0  # share of the actions from the BFS oracle (half the streams obey it)
    # 1: the step out of each frame violates (the paper's just-before label); 0: the step
    # into it did (what a shield asks of a candidate frame)
    lookahead: int = 1
    seed: int = 0  # seeds the streams (the test streams: seed + 1000) and the training

    def __post_init__(self):
        me = type(self).__name__
        for name in ("streams", "steps", "updates", "batch_streams"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{me}.{name} must be an int >= 1, got {value!r}")
        for name in ("lr", "positive_weight"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{me}.{name} must be > 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.guided <= 1.0:
            raise ValueError(f"{me}.guided must be in [0, 1], got {self.guided!r}")
        if self.lookahead not in STREAM_LOOKAHEADS or isinstance(self.lookahead, bool):
            raise ValueError(f"{me}.lookahead must be one of {STREAM_LOOKAHEADS}, got "
                             f"{self.lookahead!r}")  # fmt: skip
        if self.batch_streams > self.streams:
            raise ValueError(
                f"{me}.batch_streams ({self.batch_streams}) exceeds {me}.streams ({self.streams})"
            )


def _memory_loss(model, params, batch, positive_weight):
    logits = model.apply(params, *stream_inputs(model.config, batch))
    y = batch["label"].astype(jnp.float32)
    weight = jnp.where(y > 0, positive_weight, 1.0) * batch["valid"]
    losses = optax.sigmoid_binary_cross_entropy(logits, y)
    return jnp.sum(losses * weight) / jnp.maximum(jnp.sum(weight), 1.0)


def train_memory_checker(
    data: dict, config: MemoryCheckerConfig, train: MemoryTrainConfig, progress=None
):
    """Fit :class:`MemoryChecker` on ``data`` (:func:`checker.data.collect_streams`); returns
    ``(params, losses)``. Each update takes ``batch_streams`` whole streams."""
    model = MemoryChecker(config)
    key = jax.random.PRNGKey(train.seed)
    n = data["starts"].shape[0]
    if train.batch_streams > n:
        raise ValueError(f"batch_streams {train.batch_streams} exceeds the {n} streams collected")
    fields = stream_input_names(config) + ("label", "valid")
    arrays = {k: jnp.asarray(data[k]) for k in fields}
    sample = jax.tree.map(lambda a: a[:1], arrays)
    params = jax.jit(model.init)(key, *stream_inputs(config, sample))
    tx = optax.adam(train.lr)
    opt = tx.init(params)

    @jax.jit
    def update(params, opt, key):
        idx = jax.random.choice(key, n, (train.batch_streams,), replace=False)
        batch = jax.tree.map(lambda a: a[idx], arrays)
        loss_fn = lambda p: _memory_loss(model, p, batch, train.positive_weight)  # noqa: E731
        loss, grads = jax.value_and_grad(loss_fn)(params)
        updates, opt = tx.update(grads, opt, params)
        return optax.apply_updates(params, updates), opt, loss

    losses = []
    for i, k in enumerate(jax.random.split(jax.random.fold_in(key, 1), train.updates)):
        params, opt, loss = update(params, opt, k)
        losses.append(float(loss))
        if progress is not None:
            progress(i, losses[-1])
    return params, np.asarray(losses)


def fit_memory_checker(
    data: dict, config: MemoryCheckerConfig, train: MemoryTrainConfig, desc: str | None = None
):
    """:func:`train_memory_checker` with a progress bar named ``desc`` (None: no bar)."""
    if desc is None:
        return train_memory_checker(data, config, train)
    from tqdm.auto import tqdm

    with tqdm(total=train.updates, desc=desc, unit="update", leave=False) as bar:
        return train_memory_checker(data, config, train, lambda i, loss: bar.update(1))


if __name__ == "__main__":  # not a command: say which one trains a checker
    import sys

    print("error: the checker's command line is `python -m checker`", file=sys.stderr)
    raise SystemExit(2)
