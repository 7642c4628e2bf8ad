"""checker.memory: the recurrent checker's memory, its data's labels and its metrics.

* The memory is zeroed exactly at episode starts: frames before a start cannot change a logit
  after it, while without a start a frame thirty steps back still does (what a window of
  five cannot do).
* Streams from ``BatchedAutoReset(HazardRooms)``: each frame's label is the violation of the step
  taken from it, starts where episodes begin, tokens constant within an episode.
* The late-violation mask and the per-type report on hand-made streams; bad configuration.
"""

from __future__ import annotations

import dataclasses

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import checker
import jaxgrid
from checker import memory as MC
from checker import memory_model as MM
from checker.protocol import NO_ACTION
from jaxgrid.constants import FORWARD

SMALL = MM.MemoryCheckerConfig(
    word_dim=8, gru_dim=8, cell_dim=4, conv_channels=4, state_dim=8, memory_dim=16, mlp_dim=16
)


def _random_frames(key, b, t):
    k1, k2, k3 = jax.random.split(key, 3)
    obj = jax.random.randint(k1, (b, t, 7, 7), 0, 11)
    col = jax.random.randint(k2, (b, t, 7, 7), 0, 6)
    st = jax.random.randint(k3, (b, t, 7, 7), 0, 3)
    return jnp.stack([obj, col, st], -1).astype(jnp.uint8)


@pytest.fixture(scope="module")
def model_and_params():
    model = MM.MemoryChecker(SMALL)
    frames = _random_frames(jax.random.PRNGKey(0), 1, 4)
    starts = jnp.zeros((1, 4), bool)
    tokens = jnp.zeros((1, 4, SMALL.max_len), jnp.int32)
    return model, jax.jit(model.init)(jax.random.PRNGKey(1), frames, starts, tokens)


def test_memory_resets_at_starts_and_reaches_far_back(model_and_params):
    model, params = model_and_params
    t = 40
    a = _random_frames(jax.random.PRNGKey(2), 1, t)
    b = a.at[0, :10].set(_random_frames(jax.random.PRNGKey(3), 1, 10)[0])  # other first frames
    tokens = jnp.ones((1, t, SMALL.max_len), jnp.int32).at[..., 5:].set(0)
    apply = jax.jit(model.apply)
    starts = jnp.zeros((1, t), bool).at[0, 0].set(True)
    la, lb = apply(params, a, starts, tokens), apply(params, b, starts, tokens)
    assert np.abs(np.asarray(la - lb))[0, 35:].max() > 1e-6  # 25+ steps back still matters
    restart = starts.at[0, 10].set(True)  # a new episode at frame 10
    la, lb = apply(params, a, restart, tokens), apply(params, b, restart, tokens)
    np.testing.assert_array_equal(np.asarray(la)[0, 10:], np.asarray(lb)[0, 10:])
    assert np.abs(np.asarray(la - lb))[0, :10].max() > 1e-6


@pytest.fixture(scope="module")
def streams():
    env = jaxgrid.make("HazardRooms-v0")
    return MC.collect_streams(env, jax.random.PRNGKey(0), 16, 60)


def test_stream_labels_are_the_next_steps_violation(streams):
    d = streams
    assert d["frames"].shape == (16, 60, 7, 7, 3) and d["tokens"].shape[:2] == (16, 60)
    assert d["starts"][:, 0].all()
    # a frame that is not a start was produced by the step taken from the frame before it
    inner = ~d["starts"][:, 1:]
    np.testing.assert_array_equal(d["label"][:, :-1][inner], d["violation"][:, 1:][inner])
    assert (d["violation"][d["starts"]] == 0).all() and (d["cost"][d["starts"]] == 0).all()
    # the constraint is one sentence per episode
    same = (d["tokens"][:, 1:] == d["tokens"][:, :-1]).all(-1)
    assert same[inner].all()
    assert d["label"].sum() > 0  # the behaviour policy does violate
    np.testing.assert_array_equal(d["next_cost"][:, :-1][inner], d["cost"][:, 1:][inner])


def test_stream_actions_lead_into_each_frame(streams):
    """``action`` is the action taken into each frame: none into an episode's first, one the
    behaviour takes otherwise, and a step forward wherever the step into the frame cost (only
    entering a cell is a constraint event)."""
    d = streams
    assert (d["action"][d["starts"]] == NO_ACTION).all()
    inner = d["action"][~d["starts"]]
    assert set(np.unique(inner).tolist()) == {a for a, p in enumerate(MC.BEHAVIOUR) if p > 0}
    assert 0.45 < (inner == FORWARD).mean() < 0.65  # BEHAVIOUR's 0.55, over ~900 steps
    costly = d["cost"] > 0
    assert costly.sum() > 0 and (d["action"][costly] == FORWARD).all()


def test_a_checker_of_actions_reads_the_action_into_each_frame(tmp_path):
    trained = MM.new_memory_checker(dataclasses.replace(SMALL, actions=True), jax.random.PRNGKey(6))
    frames = _random_frames(jax.random.PRNGKey(7), 2, 6)
    starts = jnp.zeros((2, 6), bool).at[:, 0].set(True)
    tokens = jnp.ones((2, 6, SMALL.max_len), jnp.int32)
    a = jnp.full((2, 6), FORWARD, jnp.int32).at[:, 0].set(NO_ACTION)
    logits = jax.jit(trained.logits)
    la, lb = (
        np.asarray(logits(frames, starts, tokens, a)),
        logits(frames, starts, tokens, a.at[:, 3].set(0)),
    )
    np.testing.assert_array_equal(la[:, :3], np.asarray(lb)[:, :3])  # the past is unchanged
    assert np.abs(la[:, 3:] - np.asarray(lb)[:, 3:]).min() > 0  # that step and every later one
    with pytest.raises(ValueError, match="reads the action into each frame"):
        trained.logits(frames, starts, tokens)
    checker.save(trained, tmp_path / "m")
    assert checker.load(tmp_path / "m").config.actions


def test_guided_streams_follow_the_oracle_on_alternate_halves(streams):
    """``guided=1``: even streams follow the oracle that obeys the constraint, so none of them
    violates; odd streams plan through hazards. Both reach the goal far more often than the
    random behaviour, whose streams are ``streams`` (same env, key and sizes)."""
    env = jaxgrid.make("HazardRooms-v0")
    d = MC.collect_streams(env, jax.random.PRNGKey(0), 16, 60, guided=1.0)
    assert d["frames"].shape == streams["frames"].shape
    assert d["label"][0::2].sum() == 0 and d["label"][1::2].sum() > 0
    # episodes that end before the stream does: the oracle reaches the goal in well under 60
    assert d["starts"][:, 1:].sum() > 2 * streams["starts"][:, 1:].sum()
    with pytest.raises(ValueError, match="guided"):
        MC.collect_streams(env, jax.random.PRNGKey(0), 4, 4, guided=1.5)
    with pytest.raises(ValueError, match="guided"):
        MC.MemoryTrainConfig(guided=-0.1)


def test_into_labels_are_the_violation_of_the_step_into_each_frame(streams):
    into = MC.relabel(streams, 0)
    assert MC.relabel(streams, 1) is streams
    np.testing.assert_array_equal(into["label"], streams["violation"])
    assert into["label"].dtype == np.int32 and into["label"][streams["starts"]].sum() == 0
    # the same violations, one frame later, except those on an episode's last step
    inner = ~streams["starts"][:, 1:]
    np.testing.assert_array_equal(into["label"][:, 1:][inner], streams["label"][:, :-1][inner])
    with pytest.raises(ValueError, match="lookahead must be one of"):
        MC.relabel(streams, 2)
    with pytest.raises(ValueError, match="MemoryTrainConfig.lookahead must be one of"):
        MC.MemoryTrainConfig(lookahead=2)


def test_late_mask_and_report_read_into_labels_one_frame_later():
    """The hand-made streams below, labelled on the frame after each violating step."""
    d = _budget_streams(1, 30)
    d["cost"][0, [3, 13]] = 1  # costly steps lead into frames 3 and 13 ...
    d["label"][0, 13] = 1  # ... and the second was one too many: 10 steps later, not late
    assert not MC.late_violation_mask(d, late=10, lookahead=0).any()
    assert MC.late_violation_mask(d, late=10, lookahead=1).all()  # read as frame 14
    report = MC.evaluate_streams(np.where(d["cost"] > 0, 0.5, 0.0), d, 10, lookahead=0)
    assert report["costly_budget"] == {"auroc": 0.5, "positives": 1}
    report = MC.evaluate_streams(d["label"] * 0.9, d, 10, lookahead=0)
    assert report["costly_budget"]["auroc"] == 1.0 and report["late_budget"]["auroc"] is None


def _budget_streams(n, t):
    """``n`` hand-made budget streams of ``t`` frames, each one episode with nothing in it."""
    d = {
        "starts": np.zeros((n, t), bool),
        "cost": np.zeros((n, t)),
        "violation": np.zeros((n, t), np.int32),
        "label": np.zeros((n, t), np.int32),
        "valid": np.ones((n, t), bool),
        "ctype": np.full((n, t), 1),  # budget
        "next_cost": np.zeros((n, t)),
    }
    d["starts"][:, 0] = True
    return d


def test_late_mask_and_report_on_hand_made_streams():
    d = _budget_streams(2, 30)
    d["starts"][1, 20] = True
    d["cost"][0, 3] = 1  # first costly event at step 3 ...
    d["label"][0, 17] = 1  # ... the violating step 18: 15 steps later
    d["cost"][1, 5] = 1
    d["label"][1, 9] = 1  # violation 5 steps after the first cost
    mask = MC.late_violation_mask(d, late=10)
    assert mask[0].all() and not mask[1].any()
    probs = np.where(d["label"] > 0, 0.9, 0.1)
    report = MC.evaluate_streams(probs, d, late=10)
    assert report["auroc"] == 1.0 and report["per_type"]["budget"]["auroc"] == 1.0
    assert report["per_type"]["avoid"]["auroc"] is None  # no such episodes
    assert report["late_budget"] == {"late": 10, "auroc": 1.0, "positives": 1}
    assert report["costly_budget"]["auroc"] is None  # no costly next step marked
    d["next_cost"][0, [2, 17]] = 1  # a first entry (within budget) and the one too many
    report = MC.evaluate_streams(np.where(d["next_cost"] > 0, 0.5, 0.0), d, late=10)
    assert report["costly_budget"] == {"auroc": 0.5, "positives": 1}  # not counting: a tie


@pytest.mark.parametrize("actions", [False, True])
def test_training_lowers_the_loss(streams, actions):
    config = dataclasses.replace(SMALL, actions=actions)
    params, losses = MC.train_memory_checker(
        streams, config, MC.MemoryTrainConfig(updates=40, batch_streams=8, lr=3e-3)
    )
    assert losses[-10:].mean() < losses[:5].mean()
    probs = MC.predict_streams(params, config, streams)
    assert probs.shape == streams["label"].shape and ((probs >= 0) & (probs <= 1)).all()


@pytest.mark.parametrize(
    "field, value",
    [("memory_dim", 0), ("view_size", 6), ("gru_dim", 2.5), ("mlp_dim", True), ("actions", 1)],
)
def test_bad_config_names_the_field(field, value):
    with pytest.raises(ValueError, match=f"MemoryCheckerConfig.{field}"):
        MM.MemoryCheckerConfig(**{field: value})


def test_too_many_streams_per_batch_is_refused(streams):
    with pytest.raises(ValueError, match="batch_streams 64 exceeds the 16 streams"):
        MC.train_memory_checker(streams, SMALL, MC.MemoryTrainConfig(batch_streams=64))


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--envs", "0"], "--envs must be an int >= 1, got 0"),
        (["--updates", "0"], "--updates must be an int >= 1, got 0"),
        (["--batch-streams", "0"], "--batch-streams must be an int >= 1, got 0"),
        (["--late", "0"], "--late must be at least 1, got 0"),
        (["--envs", "8", "--batch-streams", "16"], "--batch-streams (16) exceeds --envs (8)"),
    ],
)
def test_cli_refuses_bad_flags_before_any_work(argv, message, capsys):
    with pytest.raises(SystemExit):
        MC.main(argv)
    assert message in capsys.readouterr().err


def test_memoryless_ablation_reads_each_frame_alone(model_and_params):
    model, params = model_and_params
    ablation = MM.MemoryChecker(dataclasses.replace(SMALL, memory=False))
    a = _random_frames(jax.random.PRNGKey(4), 1, 12)
    b = a.at[0, :6].set(_random_frames(jax.random.PRNGKey(5), 1, 6)[0])
    starts = jnp.zeros((1, 12), bool).at[0, 0].set(True)
    tokens = jnp.zeros((1, 12, SMALL.max_len), jnp.int32)
    la, lb = ablation.apply(params, a, starts, tokens), ablation.apply(params, b, starts, tokens)
    np.testing.assert_array_equal(np.asarray(la)[0, 6:], np.asarray(lb)[0, 6:])
    with pytest.raises(ValueError, match="MemoryCheckerConfig.memory must be a bool"):
        MM.MemoryCheckerConfig(memory=1)


def test_run_reports_settings_and_every_split(monkeypatch):
    monkeypatch.setattr(
        MC, "collect_streams", lambda env, key, n, t, guided=0.0: _fake_streams(n, t)
    )
    report = MC.run(
        num_envs=4,
        num_steps=12,
        config=SMALL,
        train=MC.MemoryTrainConfig(updates=2, batch_streams=2, lookahead=0),
    )
    assert report["train_config"]["lookahead"] == 0
    assert report["train_config"]["updates"] == 2 and report[
        "checker_config"
    ] == dataclasses.asdict(SMALL)
    keys = {"auroc", "positives", "per_type", "late_budget", "costly_budget"}
    assert set(report["train"]) == keys
    assert "heldout" in report and report["wall_s"] > 0


def _fake_streams(n, t):
    rng = np.random.default_rng(0)
    starts = np.zeros((n, t), bool)
    starts[:, 0] = True
    return {
        "frames": np.asarray(_random_frames(jax.random.PRNGKey(6), n, t)),
        "tokens": np.zeros((n, t, SMALL.max_len), np.int32),
        "starts": starts,
        "label": (rng.random((n, t)) < 0.2).astype(np.int32),
        "cost": np.zeros((n, t)),
        "violation": np.zeros((n, t), np.int32),
        "ctype": np.ones((n, t), np.int32),
        "template": np.zeros((n, t), np.int32),
        "valid": np.ones((n, t), bool),
        "next_cost": np.zeros((n, t)),
    }


def test_saved_memory_checker_loads_back_and_refuses_damage(tmp_path):
    trained = MM.new_memory_checker(
        SMALL, jax.random.PRNGKey(3), env_id="HazardRooms-v0", lookahead=0
    )
    checker.save(trained, tmp_path / "m")
    back = checker.load(tmp_path / "m")  # the one loader tells the two kinds apart
    assert isinstance(back, MM.TrainedMemoryChecker) and back.config == SMALL
    assert back.lookahead == 0 and back.shield_actions == (FORWARD,)
    chex.assert_trees_all_equal(back.params, trained.params)
    params = tmp_path / "m" / "params.msgpack"
    params.write_bytes(params.read_bytes()[:-7])
    with pytest.raises(ValueError, match="damaged parameter file"):
        checker.load(tmp_path / "m")


@pytest.mark.parametrize("actions", [False, True])
def test_stream_steps_equal_the_checker_over_the_whole_stream(actions):
    """``stream_start`` then ``stream_step`` frame by frame (what PPO carries per env) gives
    the logits of the stream read at once."""
    config = dataclasses.replace(SMALL, actions=actions)
    trained = MM.new_memory_checker(config, jax.random.PRNGKey(4))
    rng = np.random.default_rng(0)
    frames = jnp.asarray(rng.integers(0, 6, (3, 9, 7, 7, 3)), jnp.uint8)
    tokens = jnp.asarray(rng.integers(1, 20, (3, 9, SMALL.max_len)), jnp.int32)
    tokens = jnp.broadcast_to(tokens[:, :1], tokens.shape)  # one sentence per stream
    starts = jnp.zeros((3, 9), bool).at[:, 0].set(True)
    moves = jnp.asarray(rng.integers(0, NO_ACTION, (3, 9)), jnp.int32).at[:, 0].set(NO_ACTION)
    whole = jax.jit(trained.logits)(frames, starts, tokens, moves)  # jitted: eager is slower
    emb = jax.jit(trained.embed_states)(frames, moves)
    lang = jax.jit(trained.encode_language)(tokens)
    memory = jax.jit(trained.stream_start)(emb[:, 0], lang[:, 0])
    step = jax.jit(trained.stream_step)
    for t in range(1, 9):
        logit, memory = step(memory, emb[:, t], lang[:, t])
        np.testing.assert_allclose(logit, whole[:, t], atol=1e-5)
