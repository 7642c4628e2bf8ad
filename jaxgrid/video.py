"""Episodes as captioned frames, GIFs and MP4s.

>>> import jax, jaxgrid
>>> from jaxgrid.video import record_episodes
>>> env = jaxgrid.make("TwoRooms-v0")
>>> policy = lambda obs, state, key: jax.random.randint(key, (), 0, 3)   # left/right/forward
>>> record_episodes(env, policy, jax.random.PRNGKey(0), 2, "two_rooms.gif")  # doctest: +SKIP

Every frame is :func:`jaxgrid.render.render` of a state with a caption strip below it: the
episode's constraint (scenarios; :func:`jaxgrid.language.detokenize` of the observation's
tokens), the step count, the step's reward, and, on a step with ``info["violation"]``, a red
border and the word VIOLATION. Captions use Pillow's built-in default font (Pillow comes with
imageio), so no font files need to be installed. imageio and Pillow are imported only inside
the functions that need them.
"""

from __future__ import annotations

import functools
import os
import tempfile
import warnings
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrid import language
from jaxgrid.io import atomic_write
from jaxgrid.render import render_view
from jaxgrid.types import State, TimeStep

__all__ = ["caption_frames", "record_episodes", "render_episode", "save_gif", "save_video"]

CAPTION_BG = (255, 255, 255)
CAPTION_FG = (0, 0, 0)
VIOLATION_RGB = (220, 0, 0)


def _base_env(env):
    """The innermost environment (unwraps ``AutoReset`` and similar ``.env`` wrappers)."""
    while hasattr(type(env), "__dataclass_fields__") and "env" in env.__dataclass_fields__:
        env = env.env
    return env


def _stack(items):
    """A time-stacked pytree from a stacked pytree or a sequence of pytrees."""
    if isinstance(items, (list, tuple)):
        return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *items)
    return items


@functools.partial(jax.jit, static_argnums=(1, 2, 3))
def _render_batch(states: State, view, tile_size: int, highlight: bool) -> jax.Array:
    return jax.vmap(lambda s: render_view(s, view, tile_size, highlight))(states)


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)  # FreeType build of Pillow >= 10.1
    except (TypeError, OSError, ImportError):
        return ImageFont.load_default()  # Pillow's bitmap font


def caption_frames(
    images: np.ndarray,
    lines: Sequence[Sequence[str]],
    violations: Sequence[bool] | None = None,
    *,
    font_size: int | None = None,
) -> np.ndarray:
    """Put caption lines under each image: uint8 ``(T, H + strip, W, 3)``.

    ``lines[t]`` are the text lines of frame ``t`` (wrapped to the image width). Frames with
    ``violations[t]`` get a red border and a red "VIOLATION" line. The caption strip has the
    same height on every frame (the tallest caption), so frames stack into one video.
    """
    from PIL import Image, ImageDraw

    images = np.asarray(images, np.uint8)
    num, height, width = images.shape[:3]
    violations = [False] * num if violations is None else [bool(v) for v in violations]
    size = font_size or max(10, min(16, width // 24))
    font = _font(size)
    measure = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    line_h = size + 4
    pad = 4

    def wrap(text: str) -> list[str]:
        out, cur = [], ""
        for word in text.split():
            trial = f"{cur} {word}".strip()
            if cur and measure.textlength(trial, font=font) > width - 2 * pad:
                out.append(cur)
                cur = word
            else:
                cur = trial
        return out + ([cur] if cur else [])

    wrapped = []
    for t in range(num):
        rows = [row for text in lines[t] for row in wrap(text)]
        if violations[t]:
            rows.append("VIOLATION")
        wrapped.append(rows)
    strip = pad * 2 + line_h * max(1, max((len(r) for r in wrapped), default=1))
    border = max(2, width // 64)
    out = np.empty((num, height + strip, width, 3), np.uint8)
    for t in range(num):
        canvas = Image.new("RGB", (width, height + strip), CAPTION_BG)
        frame = images[t].copy()
        if violations[t]:
            frame[:border], frame[-border:] = VIOLATION_RGB, VIOLATION_RGB
            frame[:, :border], frame[:, -border:] = VIOLATION_RGB, VIOLATION_RGB
        canvas.paste(Image.fromarray(frame), (0, 0))
        draw = ImageDraw.Draw(canvas)
        for k, row in enumerate(wrapped[t]):
            colour = VIOLATION_RGB if row == "VIOLATION" and violations[t] else CAPTION_FG
            draw.text((pad, height + pad + k * line_h), row, fill=colour, font=font)
        out[t] = np.asarray(canvas)
    return out


def render_episode(
    env,
    states: State | Sequence[State],
    timesteps: TimeStep | Sequence[TimeStep],
    *,
    tile_size: int = 32,
    highlight: bool = True,
    captions: bool = True,
    font_size: int | None = None,
) -> np.ndarray:
    """Frames of an episode: uint8 ``(T, H', W', 3)``, one per ``(state, timestep)`` pair.

    ``states`` and ``timesteps`` are time-stacked pytrees (e.g. the outputs of a ``lax.scan``,
    with the reset first) or lists of single ones. Frame ``t`` renders ``states[t]`` (the agent's
    view highlighted when ``highlight``) and, when ``captions``, writes under it the constraint
    text (scenarios), ``step``, the reward of ``timesteps[t]``, "done" when the episode ended
    there, and marks ``info["violation"]`` steps with a red border and "VIOLATION". Rendering
    runs as one jitted, vmapped call over the whole episode.
    """
    states, timesteps = _stack(states), _stack(timesteps)
    base = _base_env(env)
    view = (int(base.view_size), bool(base.see_through_walls))
    images = np.asarray(_render_batch(states, view, int(tile_size), bool(highlight)))
    if not captions:
        return images
    num = images.shape[0]
    obs, info = timesteps.observation, timesteps.info
    steps = np.asarray(states.step_count).reshape(num)
    rewards = np.asarray(timesteps.reward, np.float64).reshape(num)
    done = (np.asarray(timesteps.terminated) | np.asarray(timesteps.truncated)).reshape(num)
    tokens = np.asarray(obs["constraint"]) if "constraint" in obs else None
    violations = np.asarray(info["violation"]).reshape(num) if "violation" in info else None
    lines = []
    for t in range(num):
        rows = []
        if tokens is not None:
            rows.append(language.detokenize(tokens[t]))
        status = f"step {int(steps[t])}   reward {rewards[t]:.2f}"
        rows.append(status + ("   done" if done[t] else ""))
        lines.append(rows)
    return caption_frames(images, lines, violations, font_size=font_size)


def save_gif(frames, path: str | os.PathLike, fps: float = 5.0, loop: int = 0) -> str:
    """Write uint8 frames ``(T, H, W, 3)`` as an animated GIF, atomically; returns the path.

    ``loop=0`` repeats forever. Uses imageio's Pillow plugin.
    """
    import imageio.v3 as iio

    frames = np.asarray(frames, np.uint8)
    if frames.ndim != 4 or frames.shape[-1] != 3 or len(frames) == 0:
        raise ValueError(f"frames must be uint8 (T, H, W, 3) with T >= 1, got {frames.shape}")
    path = os.fspath(path)
    data = iio.imwrite("<bytes>", frames, extension=".gif", duration=1000.0 / fps, loop=loop)
    atomic_write(path, data)
    return path


def save_video(frames, path: str | os.PathLike, fps: float = 5.0) -> str:
    """Write uint8 frames ``(T, H, W, 3)`` as an H.264 MP4, atomically; returns the path.

    Needs the ``imageio-ffmpeg`` package (``pip install imageio-ffmpeg``). Frames are padded
    with white to even height and width, which H.264 requires. ffmpeg writes to a scratch
    directory, and the finished file is moved into place with :func:`jaxgrid.io.atomic_write`.
    """
    import imageio.v2 as iio2

    frames = np.asarray(frames, np.uint8)
    if frames.ndim != 4 or frames.shape[-1] != 3 or len(frames) == 0:
        raise ValueError(f"frames must be uint8 (T, H, W, 3) with T >= 1, got {frames.shape}")
    h, w = frames.shape[1:3]
    frames = np.pad(frames, ((0, 0), (0, h % 2), (0, w % 2), (0, 0)), constant_values=255)
    path = os.fspath(path)
    try:
        with warnings.catch_warnings(), tempfile.TemporaryDirectory() as scratch:
            # imageio-ffmpeg starts ffmpeg with subprocess (fork + exec at once), which is safe;
            # JAX's generic "os.fork() was called" warning does not apply.
            warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called")
            tmp = os.path.join(scratch, "video.mp4")
            iio2.mimwrite(tmp, list(frames), fps=fps, macro_block_size=2, format="FFMPEG")
            with open(tmp, "rb") as f:
                atomic_write(path, f.read())
    except (ImportError, ValueError, RuntimeError) as e:
        raise RuntimeError(
            f"could not write {path!r} with imageio's ffmpeg plugin ({e}); "
            "install it with `pip install imageio-ffmpeg`, or use save_gif"
        ) from e
    return path


@functools.partial(jax.jit, static_argnums=0)
def _reset(env, key):
    return env.reset(key)


@functools.partial(jax.jit, static_argnums=0)
def _step(env, state, action):
    return env.step(state, action)


def record_episodes(
    env,
    policy_fn: Callable,
    key: jax.Array,
    num_episodes: int,
    path: str | os.PathLike,
    *,
    fps: float = 5.0,
    tile_size: int = 32,
    hold_last: int = 3,
    max_steps: int | None = None,
) -> np.ndarray:
    """Run ``num_episodes`` episodes of one environment and write them to one GIF (or MP4).

    ``policy_fn(observation, state, key) -> action`` picks each action (it may be jitted or
    plain Python). Episodes run on the raw environment (an ``AutoReset`` wrapper is unwrapped)
    until terminated or truncated, or ``max_steps`` steps; each episode's last frame is shown
    ``hold_last`` extra times. ``path`` ending in ``.mp4`` writes a video
    (:func:`save_video`), anything else a GIF (:func:`save_gif`). Returns the frames.
    """
    env = _base_env(env)
    episodes = []
    for _ in range(num_episodes):
        key, reset_key = jax.random.split(key)
        state, ts = _reset(env, reset_key)
        states, timesteps = [state], [ts]
        limit = env.max_steps if max_steps is None else max_steps
        for _ in range(limit):
            key, act_key = jax.random.split(key)
            action = jnp.asarray(policy_fn(ts.observation, state, act_key), jnp.int32)
            state, ts = _step(env, state, action)
            states.append(state)
            timesteps.append(ts)
            if bool(ts.terminated | ts.truncated):
                break
        frames = render_episode(env, states, timesteps, tile_size=tile_size)
        episodes.append(np.concatenate([frames] + [frames[-1:]] * hold_last))
    width = max(f.shape[2] for f in episodes)
    height = max(f.shape[1] for f in episodes)
    frames = np.concatenate(
        [
            np.pad(
                f,
                ((0, 0), (0, height - f.shape[1]), (0, width - f.shape[2]), (0, 0)),
                constant_values=255,
            )
            for f in episodes
        ]
    )
    if os.fspath(path).lower().endswith(".mp4"):
        save_video(frames, path, fps=fps)
    else:
        save_gif(frames, path, fps=fps)
    return frames
