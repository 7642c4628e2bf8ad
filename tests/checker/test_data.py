"""checker.data: labels against an independent monitor of the same rollout, balanced collection,
save/load and splits, augmentations (colour counterfactuals, distractors, blocked fronts), and
clear errors for bad collection arguments."""

from __future__ import annotations

from collections import Counter

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.checker_cases import ENVS, SEEK, STEPS, expected_labels
from helpers.xla import CHEAP

import checker
import jaxgrid
from checker import CheckerDataset, NoisyOracleParams, noisy_oracle_policy
from checker.data import compute_labels
from jaxgrid import language, sentences
from jaxgrid import monitor as M
from jaxgrid.constants import BALL, BOX, COLOR_TO_IDX, DIR_TO_VEC, DOOR, KEY, LAVA, LOCKED
from jaxgrid.sentences import PAPER
from jaxgrid.wrappers import AutoReset

# ----------------------------------------------------------------------------------- labels


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


# ------------------------------------------------------------------------------- collection


def test_collect_balanced(env):
    ds = checker.collect(
        env, noisy_oracle_policy, SEEK, jax.random.PRNGKey(5), 40, window=4, lookahead=1,
        num_envs=ENVS, chunk_steps=STEPS,
    )  # fmt: skip
    assert len(ds) == 40 and ds.labels.sum() == 20
    assert ds.windows.shape == (40, 4, 5, 5, 3) and ds.windows.dtype == np.uint8
    assert ds.tokens.shape == (40, PAPER.max_len) and ds.tokens.dtype == np.int32
    assert 0 < ds.meta["natural_positive_rate"] < 0.5
    assert ds.meta["num_positive"] == 20 and ds.meta["split"] == "train"
    for tok, tid in zip(ds.tokens, ds.template_id, strict=True):  # tokens and template agree
        assert PAPER.find(language.detokenize(tok)).template_id == tid
    assert set(ds.scenario) == {"TwoRooms"}


def _turn_or_walk(params, obs, state, key):
    """Deterministic in observation and state: forward twice in three steps, else a turn."""
    del params, key
    mix = obs["image"].astype(jnp.int32).sum((1, 2, 3)) + 7 * state.step_count
    return jnp.array([0, 1, 2, 2, 2])[mix % 5]


def _expected_windows(env, key, num_envs, steps, window):
    """Every window of the stream and every final window, replayed step by step with
    ``AutoReset`` as (window bytes, label, tokens) counts; labels with lookahead 1."""
    wrapped = AutoReset(env)
    k_reset, _ = jax.random.split(key)
    states, ts = jax.vmap(wrapped.reset)(jax.random.split(k_reset, num_envs))
    step = jax.jit(jax.vmap(wrapped.step))
    obs = [np.asarray(ts.observation["image"])]
    tokens = [np.asarray(ts.observation["constraint"], np.uint8)]
    finals, done, viol = [None], [np.ones(num_envs, bool)], [np.zeros(num_envs, bool)]
    for _ in range(steps):
        states, ts = step(states, _turn_or_walk(None, ts.observation, states, None))
        obs.append(np.asarray(ts.observation["image"]))
        tokens.append(np.asarray(ts.observation["constraint"], np.uint8))
        finals.append(np.asarray(ts.info["final_observation"]["image"]))
        done.append(np.asarray(ts.terminated | ts.truncated))
        viol.append(np.asarray(ts.info["violation"], bool))
    blank = np.zeros_like(obs[0][0])
    expected, final_expected = Counter(), Counter()
    for e in range(num_envs):
        episode = []  # frames of the current episode so far
        for t in range(steps + 1):
            if t > 0 and done[t][e]:  # the finished episode's final window
                frames = ([blank] * window + episode + [finals[t][e]])[-window:]
                key_ = (np.stack(frames).tobytes(), int(viol[t][e]), tokens[t - 1][e].tobytes())
                expected[key_] += 1
                final_expected[key_] += 1
                episode = []
            episode.append(obs[t][e])
            if t < steps:  # lookahead 1: the last position's label is beyond the rollout
                label = int(viol[t + 1][e])  # the step into t + 1 ends t's episode or not
                frames = ([blank] * window + episode)[-window:]
                expected[(np.stack(frames).tobytes(), label, tokens[t][e].tobytes())] += 1
    return expected, final_expected


def test_final_windows_are_the_finished_episodes_with_their_last_step():
    """With final_windows, every window of the stream and every window that ends at an
    episode's final observation (labelled by the step that ended it, with the finished
    episode's sentence) is drawn, each once, when the samples asked for exceed them."""
    env, key, num_envs, steps, window = jaxgrid.make("TwoRoomsLava-v0"), jax.random.key(3), 8, 48, 3
    expected, final_expected = _expected_windows(env, key, num_envs, steps, window)
    final_positives = sum(n for (_, lab, _), n in final_expected.items() if lab)
    assert final_positives >= 2, "the walker should die in lava in this rollout"
    ds = checker.collect(env, _turn_or_walk, None, key, 4 * num_envs * steps, window,
                         lookahead=1, num_envs=num_envs, num_steps=steps,
                         final_windows=True)  # fmt: skip
    keys = [(w.tobytes(), int(lab), tok.astype(np.uint8).tobytes())
            for w, lab, tok in zip(ds.windows, ds.labels, ds.tokens, strict=True)]  # fmt: skip
    assert Counter(keys) == expected
    # extras["final"] marks exactly the final windows.
    assert Counter(k for k, f in zip(keys, ds.extras["final"], strict=True) if f) == final_expected
    assert ds.meta["final_windows_positive"] == final_positives
    without = checker.collect(env, _turn_or_walk, None, key, 4 * num_envs * steps, window,
                              lookahead=1, num_envs=num_envs, num_steps=steps)  # fmt: skip
    assert len(ds) - len(without) == ds.meta["final_windows_drawn"] > final_positives
    with pytest.raises(ValueError, match="final_windows needs balance=True"):
        checker.collect(env, _turn_or_walk, None, key, None, window, num_steps=steps,
                        balance=False, final_windows=True)  # fmt: skip


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


@pytest.mark.parametrize(
    "window, lookahead, field",
    [(0, 1, "window"), (65, 1, "window"), (5, -1, "lookahead"), (2, 9, "lookahead"),
     (2.0, 1, "window"), (5, True, "lookahead")],
)  # fmt: skip
def test_collect_rejects_bad_window_and_lookahead(env, window, lookahead, field):
    with pytest.raises(ValueError, match=f"^{field}"):
        checker.collect(env, noisy_oracle_policy, SEEK, jax.random.PRNGKey(0), 10, window,
                        lookahead)  # fmt: skip


def test_collect_rejects_bad_args():
    with pytest.raises(ValueError, match="num_samples"):
        checker.collect(jaxgrid.make("TwoRooms-v0"), noisy_oracle_policy, SEEK,
                        jax.random.PRNGKey(0), 0)  # fmt: skip
    with pytest.raises(ValueError, match="constrained scenario"):
        checker.collect(jaxgrid.make("MiniGrid-Empty-5x5-v0"), checker.random_policy, None,
                        jax.random.PRNGKey(0), 10)  # fmt: skip
    with pytest.raises(ValueError, match="ignore_prob"):
        NoisyOracleParams(ignore_prob=1.5)


# ---------------------------------------------------------------------------- augmentations


def test_colour_counterfactuals_relabel_door_positives(toy):
    """Each door-only positive gains one recoloured copy labelled 0, never a held-out phrase."""
    train, _ = toy
    train = train.subset(np.arange(len(train)))
    train.meta["split"] = "train"
    out = checker.with_colour_counterfactuals(train, per_positive=1, seed=3)
    lava_free = np.array([not t.has_lava for t in sentences.TEMPLATES])
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
        sentence = language.detokenize(np.frombuffer(t, np.int32))
        colour = language.parse(sentence).clauses[0].target.colour
        assert lab == 0 and w in positive_windows
        assert colour != colour_of[int(window[-1, 2, 3, 1])]
        assert not sentences.is_heldout(PAPER.find(sentence).template_id, colour)
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


def _states_before_violations(env, envs: int = 16, steps: int = 48):
    """Pre-step states (batched) of a seek-mode oracle rollout whose next step violates."""
    reset = jax.jit(jax.vmap(env.reset), compiler_options=CHEAP)
    step = jax.jit(jax.vmap(env.step), compiler_options=CHEAP)
    policy = jax.jit(
        lambda s, o: noisy_oracle_policy(SEEK, o, s, jax.random.PRNGKey(0)), compiler_options=CHEAP
    )
    states, ts = reset(jax.random.split(jax.random.PRNGKey(5), envs))
    alive, found = np.ones(envs, bool), []
    for _ in range(steps):
        new, ts = step(states, policy(states, ts.observation))
        hit = alive & np.asarray(ts.info["violation"], bool)
        found += [jax.tree.map(lambda a, i=i: a[i], states) for i in np.flatnonzero(hit)]
        alive &= ~np.asarray(ts.terminated | ts.truncated)
        states = new
    assert len(found) >= 4, "the seek-mode oracle should violate in this rollout"
    return jax.tree.map(lambda *a: jnp.stack(a), *found)


@pytest.mark.parametrize("env_id", ["TwoRooms-v0", "TwoRoomsLava-v0"])
def test_blocked_counterfactual_windows_precede_no_violation(env_id):
    """What with_blocked_counterfactuals writes is what the env shows with the cell in front
    replaced, and from that state no action violates: the labels 0 are exact."""
    env = jaxgrid.make(env_id)
    states = _states_before_violations(env)
    n, v = len(states.agent_pos), env.view_size
    images = np.asarray(jax.jit(jax.vmap(env.observe), compiler_options=CHEAP)(states)["image"])
    ds = CheckerDataset(
        windows=images[:, None], tokens=np.zeros((n, PAPER.max_len), np.int32),
        labels=np.ones(n, np.uint8), template_id=np.zeros(n, np.int32),
        constraint_type=np.ones(n, np.int32), scenario=np.array([env_id] * n),
        meta={"lookahead": 1, "final_windows": False},
    )  # fmt: skip
    out = checker.with_blocked_counterfactuals(ds, per_positive=4, seed=0)
    new = out.windows[out.labels == 0][:, 0]  # (4n, V, V, 3)
    assert len(new) == 4 * n and out.meta["blocked_negatives"] == 4 * n
    front = new[:, v // 2, v - 2]
    # Each is one of the positives' images with the front cell replaced and, behind a locked
    # door, cells hidden: every other cell is as before or hidden.
    same = (images[None] == new[:, None]).all(-1) | (new[:, None] == 0).all(-1)  # (4n, n, V, V)
    same[:, :, v // 2, v - 2] = True
    src = np.argmax(same.all((2, 3)), axis=1)
    assert same.all((2, 3))[np.arange(len(new)), src].all()
    portable = np.isin(front[:, 0], (KEY, BALL, BOX)) & (front[:, 2] == 0)
    locked = (front[:, 0] == DOOR) & (front[:, 2] == LOCKED)
    assert np.all(portable | locked) and portable.any() and locked.any()
    assert len(np.unique(front[:, 1])) > 1  # of any colour
    assert (new[locked] == 0).all(-1).sum() > (images[src][locked] == 0).all(-1).sum()
    # The same cell in each source state's grid; every action from there is safe.
    fpos = np.asarray(states.agent_pos + jnp.asarray(DIR_TO_VEC)[states.agent_dir])[src]
    grid = np.asarray(states.grid)[src]
    grid[np.arange(len(src)), fpos[:, 0], fpos[:, 1]] = front
    blocked = jax.tree.map(lambda a: a[src], states).replace(grid=jnp.asarray(grid))
    shown = np.asarray(jax.jit(jax.vmap(env.observe), compiler_options=CHEAP)(blocked)["image"])
    np.testing.assert_array_equal(shown, new)
    every = jax.jit(jax.vmap(jax.vmap(env.step, (None, 0)), (0, None)), compiler_options=CHEAP)
    _, ts = every(blocked, jnp.arange(7, dtype=jnp.int32))
    assert not np.asarray(ts.info["violation"]).any()


def test_lava_sentence_counterfactuals_only_where_the_door_is_ahead():
    """With lava=True, door-and-lava positives facing the named door are recoloured; from
    that state, with the new colour forbidden, no action violates. Lava-ahead positives,
    lava=False and inexact settings (lookahead 0, final windows) give them no copy."""
    env = jaxgrid.make("TwoRoomsLava-v0")
    states = _states_before_violations(env, envs=32)
    c = states.extras.constraint
    v = env.view_size
    images = np.asarray(jax.jit(jax.vmap(env.observe), compiler_options=CHEAP)(states)["image"])
    front = images[:, v // 2, v - 2]
    lava_sentence = np.asarray(M.mentions(states.extras.monitor.spec, LAVA))
    door_ahead = lava_sentence & (front[:, 0] == DOOR) & (front[:, 1] == np.asarray(c.door_colour))
    lava_ahead = lava_sentence & (front[:, 0] == LAVA)
    assert door_ahead.sum() >= 2 and lava_ahead.sum() >= 2, "rollout should violate both ways"
    n = len(images)
    ds = CheckerDataset(
        windows=images[:, None], tokens=np.asarray(c.tokens), labels=np.ones(n, np.uint8),
        template_id=np.asarray(c.template_id), constraint_type=np.asarray(c.type_id),
        scenario=np.array(["lava"] * n), extras={"origin": np.arange(n)},
        meta={"lookahead": 1, "final_windows": False, "split": "train"},
    )  # fmt: skip
    out = checker.with_colour_counterfactuals(ds, per_positive=1, seed=0, lava=True)
    new = out.labels == 0
    src = out.extras["origin"][new]
    assert set(src[lava_sentence[src]]) == set(np.flatnonzero(door_ahead))
    # Each copy's sentence names another colour; from its state with that colour forbidden
    # (lava still forbidden), every action is safe.
    colours = [language.parse(language.detokenize(t)).clauses[0].target for t in out.tokens[new]]
    recoloured = jnp.asarray([COLOR_TO_IDX[p.colour] for p in colours], jnp.int32)
    assert np.all(np.asarray(recoloured) != np.asarray(c.door_colour)[src])
    moved = jax.tree.map(lambda a: a[src], states)
    spec = M.encode_batch(language.parse(language.detokenize(t)) for t in out.tokens[new])
    moved = moved.replace(extras=moved.extras.replace(
        constraint=moved.extras.constraint.replace(door_colour=recoloured),
        monitor=jax.vmap(M.start)(spec, moved.grid)))  # fmt: skip
    every = jax.jit(jax.vmap(jax.vmap(env.step, (None, 0)), (0, None)), compiler_options=CHEAP)
    _, ts = every(moved, jnp.arange(7, dtype=jnp.int32))
    assert not np.asarray(ts.info["violation"]).any()
    # Without lava=True, or where the labels would not be exact, lava sentences keep no copy.
    for meta, lava in (({}, False), ({"lookahead": 0}, True), ({"final_windows": True}, True)):
        inexact = ds.subset(np.arange(n))
        inexact.meta.update(meta)
        out = checker.with_colour_counterfactuals(inexact, per_positive=1, seed=0, lava=lava)
        assert not lava_sentence[out.extras["origin"][out.labels == 0]].any()
    # Marked final windows: only the rows before their step are recoloured.
    marked = ds.subset(np.arange(n))
    marked.meta["final_windows"] = True
    marked.extras["final"] = np.arange(n) == np.flatnonzero(door_ahead)[0]
    out = checker.with_colour_counterfactuals(marked, per_positive=1, seed=0, lava=True)
    src = out.extras["origin"][out.labels == 0]
    assert set(src[lava_sentence[src]]) == set(np.flatnonzero(door_ahead)[1:])


def test_blocked_counterfactuals_refuse_inexact_labels(toy):
    train, _ = toy
    for meta, match in (({"lookahead": 0}, "lookahead"), ({"lookahead": 2}, "lookahead"),
                        ({"final_windows": True}, "which rows are final")):  # fmt: skip
        bad = train.subset(np.arange(len(train)))
        bad.meta.update(meta)
        with pytest.raises(ValueError, match=match):
            checker.with_blocked_counterfactuals(bad)
    with pytest.raises(ValueError, match="per_positive"):
        checker.with_blocked_counterfactuals(train, per_positive=-1)
    assert len(checker.with_blocked_counterfactuals(train, per_positive=0)) == len(train)
