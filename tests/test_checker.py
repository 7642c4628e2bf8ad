"""Tests of the constraint checker: labels against the monitor, the ring buffer across
auto-resets, the model's interface, training on a toy set, save/load, metrics against hand
computations, and clear errors for bad inputs."""

from __future__ import annotations

import json
import os
from collections import Counter

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import checker
import jaxgrid
from checker import (
    Checker,
    CheckerConfig,
    CheckerDataset,
    NoisyOracleParams,
    TrainedChecker,
    init_buffer,
    noisy_oracle_policy,
    push,
    violation_prob,
)
from checker.data import compute_labels
from checker.metrics import (
    auroc,
    binary_metrics,
    evaluate,
    expected_calibration_error,
    lead_time,
)
from checker.model import init_params
from checker.reward import sentence_codes, sentence_table
from checker.train import train_checker
from jaxgrid import language
from jaxgrid.constants import BLUE, DOOR, RED
from jaxgrid.wrappers import AutoReset

# One compiled rollout chunk serves every collection below: same env, policy, envs and steps.
ENVS, STEPS = 4, 64
SEEK = NoisyOracleParams(epsilon=0.0, ignore_prob=0.0, seek_prob=1.0)  # deterministic
TINY = CheckerConfig(
    window=3, word_dim=8, gru_dim=16, state_dim=16, cell_dim=8, conv_channels=8,
    temporal_channels=16, mlp_dim=32,
)  # fmt: skip


# ---------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def env():
    return jaxgrid.make("TwoRooms-v0")


@pytest.fixture(scope="module")
def episodes(env):
    """Full-episode datasets for lookahead 0, 1 and 2 of one deterministic rollout."""
    key = jax.random.PRNGKey(3)
    return {
        k: checker.collect_episodes(env, noisy_oracle_policy, SEEK, key, STEPS, 4, k, ENVS)
        for k in (0, 1, 2)
    }


@pytest.fixture(scope="module")
def replay(env):
    """The same rollout as ``episodes``, replayed step by step in Python.

    ``collect`` resets ``vmap(AutoReset(env).reset)`` over ``split(split(key)[0], ENVS)``;
    the seek-mode oracle with ``epsilon = 0`` is deterministic, so the policy's key is moot.
    """
    auto = AutoReset(env)
    k_reset, _ = jax.random.split(jax.random.PRNGKey(3))
    states, ts = jax.jit(jax.vmap(auto.reset))(jax.random.split(k_reset, ENVS))
    step = jax.jit(jax.vmap(auto.step))
    policy = jax.jit(lambda s, o: noisy_oracle_policy(SEEK, o, s, jax.random.PRNGKey(0)))
    images, starts, viols, monitor = [ts.observation["image"]], [np.ones(ENVS, bool)], [], []
    viols.append(np.zeros(ENVS, bool))
    monitor.append(np.zeros(ENVS, bool))
    for _ in range(STEPS):
        prev = states
        states, ts = step(states, policy(states, ts.observation))
        done = np.asarray(ts.terminated | ts.truncated)
        images.append(ts.observation["image"])
        starts.append(done)
        viols.append(np.asarray(ts.info["violation"]))
        # Independent monitor: the agent moved onto a door of the forbidden colour (TwoRooms
        # has no lava). Only checkable where the episode did not end (state not reset).
        pos = np.asarray(states.agent_pos)
        grid = np.asarray(states.grid)
        cell = grid[np.arange(ENVS), pos[:, 0], pos[:, 1]]
        moved = np.any(pos != np.asarray(prev.agent_pos), axis=1)
        colour = np.asarray(prev.extras.constraint.door_colour)
        monitor.append(moved & (cell[:, 0] == DOOR) & (cell[:, 1] == colour) & ~done)
    return {
        "image": np.stack([np.asarray(i) for i in images]),  # (T+1, E, V, V, 3)
        "start": np.stack(starts),
        "violation": np.stack(viols),
        "monitor": np.stack(monitor),
    }


def expected_labels(start, violation, k):
    """Labels by explicit loops over each env's episodes (the definition, written plainly)."""
    t_total, num_envs = start.shape
    out = {}
    for e in range(num_envs):
        for i in range(t_total - k):
            if k == 0:
                out[i, e] = bool(violation[i, e] and not start[i, e])
                continue
            label = False
            for j in range(1, k + 1):
                if any(start[i + m, e] for m in range(1, j)):
                    break  # step i + j belongs to a later episode
                label |= bool(violation[i + j, e])
            out[i, e] = label
    return out


@pytest.fixture(scope="module")
def toy():
    """A synthetic set: label 1 iff the newest frame's front cell is a door of the colour the
    sentence names (red or blue doors; sentences name red or blue)."""
    rng = np.random.default_rng(0)
    n = 1536
    windows = np.zeros((n, TINY.window, 5, 5, 3), np.uint8)
    windows[..., 0] = 1  # empty cells
    door_colour = rng.choice([RED, BLUE], n)
    has_door = rng.random(n) < 0.75
    windows[has_door, -1, 2, 3] = np.stack(
        [np.full(has_door.sum(), DOOR), door_colour[has_door], np.zeros(has_door.sum())], -1
    )
    said = rng.choice(["red", "blue"], n)
    template = rng.integers(0, 7, n)
    tokens = np.stack(
        [language.tokenize(language.render(int(t), c)) for t, c in zip(template, said, strict=True)]
    )
    labels = has_door & (door_colour == np.where(said == "red", RED, BLUE))
    ds = CheckerDataset(
        windows=windows, tokens=tokens, labels=labels.astype(np.uint8),
        template_id=template.astype(np.int32), constraint_type=np.ones(n, np.int32),
        scenario=np.full(n, "toy"), meta={"lookahead": 1, "env_id": "toy", "window": 3},
    )  # fmt: skip
    return ds.split((0.75, 0.25), seed=0)


@pytest.fixture(scope="module")
def trained_toy(toy):
    train, _ = toy
    return train_checker(
        train, TINY, seed=0, lr=3e-3, batch_size=64, epochs=25, patience=25, progress=False
    )


# ---------------------------------------------------------------------------- labels


def test_monitor_replay_matches_info(replay):
    """Our replay's independent door check agrees with info["violation"] of the scenario."""
    v, m, s = replay["violation"], replay["monitor"], replay["start"]
    np.testing.assert_array_equal(v & ~s, m)
    assert m.sum() >= 3, "the seek-mode oracle should violate in this rollout"


@pytest.mark.parametrize("k", [0, 1, 2])
def test_labels_match_monitor(episodes, replay, k):
    ds = episodes[k]
    exp = expected_labels(replay["start"], replay["violation"], k)
    assert len(ds) == len(exp) == ENVS * (STEPS + 1 - k)
    pos, env_i = ds.extras["position"], ds.extras["env_index"]
    got = {(int(p), int(e)): bool(lab) for p, e, lab in zip(pos, env_i, ds.labels, strict=True)}
    assert got == exp
    # Rows are the same positions as the replay: the newest frame is the replay's image.
    np.testing.assert_array_equal(ds.windows[:, -1], replay["image"][pos, env_i])


def test_labels_exact_steps(episodes, replay):
    """Each violating step t labels the window ending at obs_t (k=0) and obs_{t-1} (k=1)."""
    viol_pos = np.argwhere(replay["monitor"])
    assert len(viol_pos)
    for k, offset in ((0, 0), (1, 1)):
        ds = episodes[k]
        pos, env_i = ds.extras["position"], ds.extras["env_index"]
        rows = {(int(p), int(e)): bool(x) for p, e, x in zip(pos, env_i, ds.labels, strict=True)}
        for i, e in viol_pos:
            assert rows[int(i) - offset, int(e)], (k, i, e)
        # No other positives: one window per violating step (no two violations adjacent here).
        assert sum(rows.values()) == int(replay["violation"][1:].sum() if k else len(viol_pos))


def test_compute_labels_terminal_and_boundaries():
    # One env, positions 0..7. Episode A = 0..3 (its final step 4 enters lava: a terminal
    # violation, recorded at position 4, which already starts episode B); B = 4..7 with a
    # door violation on step into position 6.
    start = np.array([1, 0, 0, 0, 1, 0, 0, 0], bool)[:, None]
    viol = np.array([0, 0, 0, 0, 1, 0, 1, 0], bool)[:, None]
    lab1, el1 = compute_labels(start, viol, 1)
    np.testing.assert_array_equal(np.asarray(lab1[:, 0]), [0, 0, 0, 1, 0, 1, 0, 0])
    np.testing.assert_array_equal(np.asarray(el1[:, 0]), [1] * 7 + [0])
    lab0, el0 = compute_labels(start, viol, 0)
    # k=0: the terminal violation has no window of its own (position 4 is B's first obs).
    np.testing.assert_array_equal(np.asarray(lab0[:, 0]), [0, 0, 0, 0, 0, 0, 1, 0])
    assert bool(np.all(el0))
    lab2, el2 = compute_labels(start, viol, 2)
    # Position 3 sees step 4 (A's last); position 2 too; position 3 must not see step 5 (B).
    np.testing.assert_array_equal(np.asarray(lab2[:, 0]), [0, 0, 1, 1, 1, 1, 0, 0])
    np.testing.assert_array_equal(np.asarray(el2[:, 0]), [1] * 6 + [0, 0])
    # A violation right after a reset never labels the previous episode's windows.
    start = np.array([1, 0, 1, 0], bool)[:, None]
    viol = np.array([0, 0, 0, 1], bool)[:, None]
    lab2, _ = compute_labels(start, viol, 2)
    np.testing.assert_array_equal(np.asarray(lab2[:2, 0]), [0, 0])  # 1 would cross into ep 2


# ---------------------------------------------------------------------------- ring buffer


def test_push_order_and_clearing():
    buf = init_buffer(2, 3, 5)
    assert buf.shape == (2, 3, 5, 5, 3) and buf.dtype == jnp.uint8
    frames = [np.full((2, 5, 5, 3), i + 1, np.uint8) for i in range(5)]
    starts = [[1, 1], [0, 0], [0, 1], [0, 0], [1, 0]]
    for f, s in zip(frames, starts, strict=True):
        buf = push(buf, f, jnp.asarray(s, bool))
    b = np.asarray(buf)[..., 0, 0, 0]
    # env 0: episode started at frame 5 -> [0, 0, 5]; env 1: started at frame 3 -> [3, 4, 5].
    np.testing.assert_array_equal(b, [[0, 0, 5], [3, 4, 5]])
    jitted = jax.jit(push)(buf, frames[0], jnp.zeros(2, bool))
    np.testing.assert_array_equal(np.asarray(jitted)[..., 0, 0, 0], [[0, 5, 1], [4, 5, 1]])


def test_ring_buffer_across_auto_resets(episodes, replay):
    """Collected windows (built with push) equal windows rebuilt by hand from the replay:
    oldest -> newest, zeros before the episode's first observation, never two episodes."""
    ds = episodes[1]
    img, start = replay["image"], replay["start"]
    n = ds.window
    assert replay["start"][1:].any(), "the rollout should cross an auto-reset"
    for row in range(len(ds)):
        p, e = int(ds.extras["position"][row]), int(ds.extras["env_index"][row])
        first = max(i for i in range(p + 1) if start[i, e])  # this episode's first position
        want = np.zeros((n, 5, 5, 3), np.uint8)
        for slot, i in enumerate(range(p - n + 1, p + 1)):
            if i >= first:
                want[slot] = img[i, e]
        np.testing.assert_array_equal(ds.windows[row], want)
        assert ds.extras["step"][row] == p - first


# ---------------------------------------------------------------------------- collection


def test_collect_balanced(env):
    ds = checker.collect(
        env, noisy_oracle_policy, SEEK, jax.random.PRNGKey(5), 40, window=4, lookahead=1,
        num_envs=ENVS, chunk_steps=STEPS,
    )  # fmt: skip
    assert len(ds) == 40 and ds.labels.sum() == 20
    assert ds.windows.shape == (40, 4, 5, 5, 3) and ds.windows.dtype == np.uint8
    assert ds.tokens.shape == (40, language.MAX_LEN) and ds.tokens.dtype == np.int32
    assert 0 < ds.meta["natural_positive_rate"] < 0.5
    assert ds.meta["num_positive"] == 20 and ds.meta["split"] == "train"
    for tok, tid in zip(ds.tokens, ds.template_id, strict=True):  # tokens and template agree
        assert language.parse(language.detokenize(tok)).template_id == tid
    assert set(ds.scenario) == {"TwoRooms"}


def test_dataset_save_load_split(tmp_path, episodes):
    ds = episodes[1]
    npz, js = ds.save(tmp_path / "d")
    back = CheckerDataset.load(tmp_path / "d.npz")
    for name in ("windows", "tokens", "labels", "template_id", "constraint_type", "scenario"):
        np.testing.assert_array_equal(getattr(back, name), getattr(ds, name))
    for name, arr in ds.extras.items():
        np.testing.assert_array_equal(back.extras[name], arr)
    assert back.meta["lookahead"] == 1 and back.meta["env_id"] == ds.meta["env_id"]
    parts = ds.split((0.5, 0.5), seed=1)  # by episode for full-episode data
    assert sum(len(p) for p in parts) == len(ds)
    assert not set(parts[0].extras["episode"]) & set(parts[1].extras["episode"])


# ---------------------------------------------------------------------------- model


def test_model_shapes_jit_and_decomposition():
    cfg = TINY
    params = init_params(cfg, jax.random.PRNGKey(0))
    m = Checker(cfg)
    b = 6
    w = jax.random.randint(jax.random.PRNGKey(1), (b, cfg.window, 5, 5, 3), 0, 6).astype(jnp.uint8)
    toks = jnp.asarray(sentence_table()[:b])
    apply = jax.jit(m.apply, static_argnames="method")  # eager Flax RNNs compile op by op
    logits = apply(params, w, toks)
    assert logits.shape == (b,) and logits.dtype == jnp.float32
    lang = apply(params, toks, method=Checker.encode_language)
    states = apply(params, w, method=Checker.embed_states)
    assert lang.shape == (b, cfg.gru_dim) and states.shape == (b, cfg.window, cfg.state_dim)
    again = apply(params, states, lang, method=Checker.classify)
    np.testing.assert_allclose(np.asarray(logits), np.asarray(again), rtol=1e-5, atol=1e-6)
    # Padding is ignored: more trailing pads give the same sentence code.
    longer = jnp.concatenate([toks, jnp.zeros((b, 4), jnp.int32)], axis=1)
    np.testing.assert_allclose(
        np.asarray(apply(params, longer, method=Checker.encode_language)), np.asarray(lang),
        rtol=1e-5, atol=1e-6,
    )  # fmt: skip
    # Any leading shape for embed_states.
    assert apply(params, w[0, 0], method=Checker.embed_states).shape == (cfg.state_dim,)


def test_violation_prob_table_path_matches_direct():
    tc = checker.trained.new_checker(TINY, jax.random.PRNGKey(2))
    table = sentence_table()
    n = table.shape[0] + 30  # larger than the table: the lookup path
    rng = np.random.default_rng(0)
    toks = jnp.asarray(table[rng.integers(0, len(table), n)])
    buf = jnp.asarray(rng.integers(0, 6, (n, TINY.window, 5, 5, 3)), jnp.uint8)
    direct = jax.nn.sigmoid(jax.jit(TrainedChecker.logits)(tc, buf, toks))
    p = jax.jit(violation_prob)(tc, buf, toks)
    assert p.shape == (n,) and p.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(p), np.asarray(direct), rtol=1e-5, atol=1e-6)
    # A row that is no sentence of the grammar gets NaN, loudly; the others are unaffected.
    odd = toks.at[0].set(jnp.arange(1, language.MAX_LEN + 1) % language.vocab_size())
    codes = np.asarray(jax.jit(sentence_codes)(tc, odd))
    assert np.isnan(codes[0]).all() and np.isfinite(codes[1:]).all()


# ---------------------------------------------------------------------------- training


def test_training_separates_toy_set(toy, trained_toy):
    _, test = toy
    trained, history = trained_toy
    m = evaluate(trained, test)
    assert m["auroc"] > 0.95, m
    assert history["best_epoch"] >= 1 and len(history["train_loss"]) == history["epochs_run"]
    json.dumps(m)  # plain JSON


def test_save_load_roundtrip(tmp_path, toy, trained_toy):
    _, test = toy
    trained, _ = trained_toy
    checker.save(trained, tmp_path / "ck")
    back = checker.load(tmp_path / "ck")
    assert isinstance(back, TrainedChecker)
    assert back.config == trained.config and back.lookahead == trained.lookahead
    w, t = jnp.asarray(test.windows[:64]), jnp.asarray(test.tokens[:64])
    # Jittable with the checker as an argument (params traced, config static).
    logits = jax.jit(TrainedChecker.logits)
    np.testing.assert_array_equal(np.asarray(logits(back, w, t)), np.asarray(logits(trained, w, t)))
    probs = jax.jit(TrainedChecker.probs)(back, w, t)
    np.testing.assert_allclose(np.asarray(probs), jax.nn.sigmoid(logits(trained, w, t)), rtol=1e-6)


# ---------------------------------------------------------------------------- metrics


def test_auroc_with_ties_by_hand():
    # Pairs (pos, neg): (.8,.8) tie = 1/2, (.8,.1) = 1, (.3,.8) = 0, (.3,.1) = 1 -> 2.5 / 4.
    assert auroc([1, 0, 1, 0], [0.8, 0.8, 0.3, 0.1]) == pytest.approx(0.625)
    assert auroc([1, 1, 0], [0.5, 0.5, 0.5]) == pytest.approx(0.5)
    assert auroc([0, 1], [0.1, 0.9]) == 1.0 and auroc([1, 0], [0.1, 0.9]) == 0.0
    assert auroc([1, 1], [0.1, 0.2]) is None


def test_binary_metrics_and_ece_by_hand():
    y = [1, 1, 1, 0, 0, 0]
    p = [0.9, 0.6, 0.2, 0.7, 0.1, 0.0]
    m = binary_metrics(y, p, 0.5)
    # tp=2 (0.9, 0.6), fn=1, fp=1 (0.7), tn=2
    assert (m["tp"], m["fn"], m["fp"], m["tn"]) == (2, 1, 1, 2)
    assert m["accuracy"] == pytest.approx(4 / 6)
    assert m["precision"] == pytest.approx(2 / 3) and m["recall"] == pytest.approx(2 / 3)
    assert m["f1"] == pytest.approx(2 / 3)
    # ECE: bins [0.9] acc 1 conf .9; [.6] 1 vs .6; [.2] 1 vs .2; [.7] 0 vs .7; [.1] 0 vs .1;
    # [0.0] 0 vs 0 -> (0.1 + 0.4 + 0.8 + 0.7 + 0.1 + 0) / 6
    assert expected_calibration_error(y, p) == pytest.approx(2.1 / 6)
    none = binary_metrics([0, 0], [0.1, 0.2])
    assert none["precision"] is None and none["auroc"] is None
    json.dumps(none)


def test_lead_time_by_hand():
    # Episode 1: steps 0..4, violation on step 4 (next_violation at step 3); first alarm at 2.
    # Episode 2: no violation, alarm at step 1 -> a false alarm. Episode 3: violation on step 2,
    # no alarm -> missed. Episode 4: incomplete -> ignored.
    ep = [1] * 5 + [2] * 3 + [3] * 3 + [4] * 2
    step = [0, 1, 2, 3, 4, 0, 1, 2, 0, 1, 2, 0, 1]
    nxt = [0, 0, 0, 1, 0, 0, 0, 0, 0, 1, 0, 0, 0]
    complete = [True] * 11 + [False] * 2
    probs = [0.1, 0.2, 0.7, 0.9, 0.1, 0.0, 0.6, 0.1, 0.1, 0.2, 0.1, 0.9, 0.9]
    n = len(ep)
    ds = CheckerDataset(
        windows=np.zeros((n, 1, 5, 5, 3), np.uint8), tokens=np.zeros((n, 13), np.int32),
        labels=np.asarray(nxt, np.uint8), template_id=np.zeros(n, np.int32),
        constraint_type=np.zeros(n, np.int32), scenario=np.full(n, "x"),
        extras={"episode": np.asarray(ep), "step": np.asarray(step),
                "next_violation": np.asarray(nxt, np.uint8), "complete": np.asarray(complete)},
    )  # fmt: skip
    lt = lead_time(ds, probs, 0.5)
    assert lt["episodes"] == 3 and lt["violating_episodes"] == 2 and lt["clean_episodes"] == 1
    assert lt["mean_lead_time"] == 2.0 and lt["lead_time_histogram"] == {"2": 1}
    assert lt["detected"] == 0.5 and lt["detected_before"] == 0.5
    assert lt["false_alarm_rate"] == 1.0 and lt["false_alarm_window_rate"] == pytest.approx(1 / 3)


# ---------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    "window, lookahead, field",
    [(0, 1, "window"), (65, 1, "window"), (5, -1, "lookahead"), (2, 9, "lookahead"),
     (2.0, 1, "window"), (5, True, "lookahead")],
)  # fmt: skip
def test_collect_rejects_bad_window_and_lookahead(env, window, lookahead, field):
    with pytest.raises(ValueError, match=f"^{field}"):
        checker.collect(env, noisy_oracle_policy, SEEK, jax.random.PRNGKey(0), 10, window,
                        lookahead)  # fmt: skip


def test_bad_config_and_args():
    with pytest.raises(ValueError, match="gru_dim"):
        CheckerConfig(gru_dim=0)
    with pytest.raises(ValueError, match="view_size"):
        CheckerConfig(view_size=4)
    with pytest.raises(ValueError, match="num_samples"):
        checker.collect(jaxgrid.make("TwoRooms-v0"), noisy_oracle_policy, SEEK,
                        jax.random.PRNGKey(0), 0)  # fmt: skip
    with pytest.raises(ValueError, match="constrained scenario"):
        checker.collect(jaxgrid.make("MiniGrid-Empty-5x5-v0"), checker.random_policy, None,
                        jax.random.PRNGKey(0), 10)  # fmt: skip
    with pytest.raises(ValueError, match="ignore_prob"):
        NoisyOracleParams(ignore_prob=1.5)


def test_missing_files_and_other_vocabulary(tmp_path, episodes, trained_toy):
    with pytest.raises(FileNotFoundError, match="nope"):
        CheckerDataset.load(tmp_path / "nope.npz")
    with pytest.raises(FileNotFoundError, match="nockpt"):
        checker.load(tmp_path / "nockpt")
    episodes[0].save(tmp_path / "d")
    meta = json.loads((tmp_path / "d.json").read_text())
    meta["vocab"] = meta["vocab"] + ["purple_ish"]
    (tmp_path / "d.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="another constraint vocabulary"):
        CheckerDataset.load(tmp_path / "d")
    checker.save(trained_toy[0], tmp_path / "ck")
    cfg = json.loads((tmp_path / "ck" / "config.json").read_text())
    cfg["max_len"] = 20
    (tmp_path / "ck" / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(ValueError, match="another constraint vocabulary"):
        checker.load(tmp_path / "ck")
    os.remove(tmp_path / "ck" / "params.msgpack")
    with pytest.raises(FileNotFoundError, match="params.msgpack"):
        checker.load(tmp_path / "ck")


@pytest.mark.parametrize(
    "flags, name",
    [(["--window", "0"], "--window"), (["--lookahead", "30"], "--lookahead"),
     (["--epochs", "0"], "--epochs"), (["--env", "Nope-v0"], "--env"),
     (["--lr", "-1"], "--lr")],
)  # fmt: skip
def test_cli_rejects_bad_flags(tmp_path, capsys, flags, name):
    from checker.train import main

    with pytest.raises(SystemExit) as exc:
        main(["--out", str(tmp_path / "o"), *flags])
    assert exc.value.code != 0
    assert name in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_colour_counterfactual_on_toy(toy, trained_toy):
    """Recolouring the sentence of a detected positive turns it into a (true) negative."""
    _, test = toy
    cf = checker.colour_counterfactual(trained_toy[0], test)
    assert cf["n"] == int(test.labels.sum())
    assert cf["auroc"] > 0.9 and cf["mean_prob"] > cf["mean_prob_counterfactual"]


def test_colour_counterfactuals_relabel_door_positives(toy):
    """Each door-only positive gains one recoloured copy labelled 0, never a held-out phrase."""
    train, _ = toy
    train = train.subset(np.arange(len(train)))
    train.meta["split"] = "train"
    out = checker.with_colour_counterfactuals(train, per_positive=1, seed=3)
    lava_free = np.array([not t.has_lava for t in language.TEMPLATES])
    door_pos = int(np.sum((train.labels > 0) & lava_free[train.template_id]))
    assert door_pos > 0 and len(out) == len(train) + door_pos
    assert out.meta["counterfactual_negatives"] == door_pos
    assert int(out.labels.sum()) == int(train.labels.sum())

    # The original rows are all still there; each new row is a positive's window with a
    # sentence naming another colour than the door the toy's label looks at: a true negative.
    def as_rows(ds):
        return Counter(zip(map(bytes, ds.windows), map(bytes, ds.tokens), ds.labels, strict=True))

    rows = as_rows(out)
    rows.subtract(as_rows(train))
    assert all(n >= 0 for n in rows.values()) and sum(rows.values()) == door_pos
    positive_windows = {bytes(w) for w, lab in zip(train.windows, train.labels, strict=True) if lab}
    colour_of = {i: language.COLOURS[i] for i in range(len(language.COLOURS))}
    for (w, t, lab), n in rows.items():
        if n == 0:
            continue
        window = np.frombuffer(w, np.uint8).reshape(train.windows.shape[1:])
        c = language.parse(language.detokenize(np.frombuffer(t, np.int32)))
        assert lab == 0 and w in positive_windows
        assert c.colour != colour_of[int(window[-1, 2, 3, 1])]
        assert not language.is_heldout(c.template_id, c.colour)
    bad = train.subset(np.arange(len(train)))
    bad.meta["lookahead"] = 2
    with pytest.raises(ValueError, match="lookahead"):
        checker.with_colour_counterfactuals(bad)
    with pytest.raises(ValueError, match="per_positive"):
        checker.with_colour_counterfactuals(train, per_positive=-1)


def test_distractors_only_touch_empty_cells_and_closed_doors(toy):
    """Copies keep their labels and sentences; only empty cells (now keys, balls or boxes),
    the agent's empty hands and closed doors (now locked) change; bad arguments fail."""
    train, _ = toy
    train = train.subset(np.arange(len(train)))
    train.windows[::3, :, 2, 3, 2] = np.where(train.windows[::3, :, 2, 3, 0] == DOOR, 1, 0)
    train.extras["origin"] = np.arange(len(train))  # travels with each copy
    out = checker.with_distractors(train, fraction=0.5, cell_rate=0.3, seed=1)
    added = len(out) - len(train)
    assert 0.4 * len(train) < added < 0.6 * len(train) and out.meta["distractor_rows"] == added
    origin = out.extras["origin"]
    counts = np.bincount(origin, minlength=len(train))
    assert set(np.unique(counts)) == {1, 2}
    seen_object = seen_lock = seen_carry = False
    for row in range(len(out)):
        src = origin[row]
        assert (
            out.labels[row] == train.labels[src] and out.template_id[row] == train.template_id[src]
        )
        np.testing.assert_array_equal(out.tokens[row], train.tokens[src])
        new, old = out.windows[row], train.windows[src]
        changed = np.any(new != old, axis=-1)
        if not changed.any():
            continue
        before, after = old[changed], new[changed]
        strewn = (before[:, 0] == 1) & np.isin(after[:, 0], (5, 6, 7)) & (after[:, 2] == 0)
        locked = (before[:, 0] == DOOR) & (before[:, 2] == 1) & (after[:, 2] == 2)
        locked &= np.all(before[:, :2] == after[:, :2], axis=-1)
        assert np.all(strewn | locked)
        seen_object |= strewn.any()
        seen_lock |= locked.any()
        seen_carry |= bool(changed[:, 2, 4].any())
    assert seen_object and seen_lock and seen_carry
    assert len(checker.with_distractors(train, fraction=0.0)) == len(train)
    with pytest.raises(ValueError, match="fraction"):
        checker.with_distractors(train, fraction=1.5)
    with pytest.raises(ValueError, match="cell_rate"):
        checker.with_distractors(train, cell_rate=-0.1)
    train.meta["lookahead"] = 2
    with pytest.raises(ValueError, match="lookahead"):
        checker.with_distractors(train)


@pytest.mark.slow
def test_cli_end_to_end_small(tmp_path):
    """``python -m checker.train`` on a small budget writes a loadable checker + metrics."""
    from checker.train import main

    out = tmp_path / "ck"
    report = main([
        "--env", "TwoRooms-v0", "--out", str(out), "--samples", "400", "--epochs", "2",
        "--num-envs", "32", "--heldout-samples", "100", "--transfer-samples", "100",
        "--episode-envs", "4", "--episode-steps", "32", "--no-progress",
    ])  # fmt: skip
    back = checker.load(out)
    assert back.env_id == "TwoRooms-v0" and back.lookahead == 1
    saved = json.loads((out / "metrics.json").read_text())
    assert set(saved["metrics"]) == {
        "test", "heldout_language", "full_episodes", "transfer_ThreeRoomsKey-v0",
    }  # fmt: skip
    assert saved["timing_s"]["collect_plus_train"] > 0 and report["samples"] == 400
