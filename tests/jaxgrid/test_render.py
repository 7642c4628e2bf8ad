"""jaxgrid.render and jaxgrid.video: shapes, MiniGrid's look, text, GIFs, README examples."""

from __future__ import annotations

import runpy
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.xla import CHEAP

import jaxgrid
from jaxgrid.ascii import parse_ascii
from jaxgrid.render import render, render_ansi, render_view, tile_atlas
from jaxgrid.video import VIOLATION_RGB, caption_frames, record_episodes

ROOT = Path(__file__).resolve().parents[2]
render_jit = jax.jit(
    render, static_argnums=1, static_argnames=("tile_size", "highlight"), compiler_options=CHEAP
)
render_view_jit = jax.jit(render_view, static_argnums=(1, 2, 3), compiler_options=CHEAP)


def test_render_shape_dtype_and_batch():
    env = jaxgrid.make("TwoRooms-v0")
    reset = jax.jit(jax.vmap(env.reset), compiler_options=CHEAP)
    states, _ = reset(jax.random.split(jax.random.PRNGKey(1), 5))
    batch = jax.jit(jax.vmap(lambda s: render(s, env, tile_size=8)), compiler_options=CHEAP)(states)
    assert batch.shape == (5, 7 * 8, 9 * 8, 3) and batch.dtype == jnp.uint8
    for i in range(5):  # vmapped == one by one
        one = jax.tree.map(lambda x, i=i: x[i], states)
        img = render_jit(one, env, tile_size=8)
        assert img.shape == (56, 72, 3) and img.dtype == jnp.uint8
        np.testing.assert_array_equal(batch[i], img)
    state = one
    # The highlight only lightens pixels; without env nothing is highlighted.
    plain = render_jit(state, None, tile_size=8)
    np.testing.assert_array_equal(plain, render_jit(state, env, tile_size=8, highlight=False))
    assert (np.asarray(img) >= np.asarray(plain)).all() and (img != plain).any()


@pytest.fixture(scope="module")
def minigrid():
    pytest.importorskip("minigrid")
    import gymnasium as gym
    import minigrid  # noqa: F401  (registers MiniGrid ids)

    return gym


def test_uniform_tiles_match_minigrid(minigrid):
    """Wall, empty floor, goal and lava tiles within 10/255 of minigrid's Grid.render_tile."""
    from minigrid.core.grid import Grid
    from minigrid.core.world_object import Goal, Lava, Wall

    for ts in (8, 32):
        index, tiles, _ = tile_atlas(ts)
        for obj in (Wall(), None, Goal(), Lava()):
            code = obj.encode() if obj is not None else (1, 0, 0)
            for hl in (False, True):
                ref = Grid.render_tile(obj, highlight=hl, tile_size=ts).astype(np.uint8)
                ours = tiles[int(hl), index[(code[0] * 6 + code[1]) * 3 + code[2]]]
                diff = np.abs(ours.astype(int) - ref.astype(int)).max()
                assert diff <= 10, (obj, hl, ts, diff)


def test_full_frames_match_minigrid_get_frame(minigrid):
    """Whole frames (agent, doors, keys, lava, view highlight) equal minigrid's get_frame."""
    from jaxgrid.compat import from_minigrid

    rng = np.random.default_rng(0)
    worst = 0
    for env_id in (
        "MiniGrid-DoorKey-6x6-v0",
        "MiniGrid-LavaGapS6-v0",
        "MiniGrid-KeyCorridorS3R2-v0",
    ):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mg = minigrid.make(env_id).unwrapped
        mg.reset(seed=int(rng.integers(1000)))
        for _ in range(12):
            env, state, _ = from_minigrid(mg, base_step=True)  # only rendered
            view = (env.view_size, env.see_through_walls)  # static: one compile per level size
            for hl in (False, True):
                ref = mg.get_frame(highlight=hl, tile_size=12)
                ours = np.asarray(render_view_jit(state, view, 12, hl))
                assert ours.shape == ref.shape
                worst = max(worst, np.abs(ours.astype(int) - ref.astype(int)).max())
            _, _, term, trunc, _ = mg.step(
                int(rng.choice(7, p=[0.2, 0.2, 0.4, 0.05, 0.05, 0.1, 0]))
            )
            if term or trunc:
                break
    assert worst <= 10


def test_render_ansi_arrow_and_round_trip():
    text = """
        ##########
        ##..>>##G.
        ##..KYLY..
        ##AB_RV.##
        ##########
    """
    level = jaxgrid.from_ascii(text)
    state, _ = level.reset(jax.random.PRNGKey(0))
    out = render_ansi(state)
    assert ">>" in out
    grid, pos, direction = parse_ascii(out)
    np.testing.assert_array_equal(grid, np.asarray(state.grid))
    assert pos == (2, 1) and direction == 0
    state = state.replace(agent_dir=jnp.int32(3))
    assert "^^" in render_ansi(state)
    assert "\x1b[" in render_ansi(state, color=True)


def test_gif_written_and_readable(tmp_path):
    iio = pytest.importorskip("imageio.v3")
    env = jaxgrid.make("TwoRooms-v0")  # the example's env: its compiled step is reused
    policy = lambda obs, state, key: jax.random.randint(key, (), 0, 3)
    frames = record_episodes(
        env, policy, jax.random.PRNGKey(3), 2, tmp_path / "ep.gif", tile_size=16, max_steps=5
    )
    assert frames.dtype == np.uint8 and frames.shape[0] == 2 * (1 + 5 + 3)  # reset, 5, hold 3
    assert frames.shape[1] > 7 * 16 and frames.shape[2] == 9 * 16  # a caption strip below
    back = iio.imread(tmp_path / "ep.gif")
    assert back.shape[1:] == frames.shape[1:] and back.shape[0] >= 2


def test_caption_violation_marker():
    images = np.zeros((2, 40, 64, 3), np.uint8)
    out = caption_frames(images, [["no red door", "step 1"], ["x"]], [False, True])
    assert out.shape[0] == 2 and out.shape[1] > 40 and out.shape[2] == 64
    assert (out[1, 0, 0] == VIOLATION_RGB).all() and (out[0, 0, 0] == 0).all()
    strip = out[:, 40:].astype(int)
    reddish = (strip[..., 0] > 150) & (strip[..., 1] < 100) & (strip[..., 2] < 100)
    assert reddish[1].any() and not reddish[0].any()  # the red word VIOLATION
    assert (strip[0] < 128).any()  # dark caption text drawn


def test_examples_run(tmp_path, monkeypatch, capsys):
    """examples/render_gif.py and examples/gym_loop.py run (in-process: compiles are shared)."""
    monkeypatch.chdir(tmp_path)
    for script in ("render_gif.py", "gym_loop.py"):
        runpy.run_path(str(ROOT / "examples" / script), run_name="__main__")
    assert (tmp_path / "two_rooms.gif").stat().st_size > 0
    assert "episodes ended" in capsys.readouterr().out


def test_mp4_written(tmp_path):
    pytest.importorskip("imageio_ffmpeg")
    iio = pytest.importorskip("imageio.v3")
    from jaxgrid.video import save_video

    frames = np.random.default_rng(0).integers(0, 255, (3, 33, 47, 3), dtype=np.uint8)  # odd sizes
    path = save_video(frames, tmp_path / "ep.mp4", fps=2)
    assert iio.improps(path).shape[-3:] == (34, 48, 3)
