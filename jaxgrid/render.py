"""Pictures of states in MiniGrid's look (RGB) and as text (ANSI / ASCII map).

:func:`render` draws a :class:`~jaxgrid.types.State` the way minigrid 3.2.0's
``env.get_frame()`` does: one ``tile_size`` x ``tile_size`` tile per cell with grey grid lines,
walls, floor, doors (open, closed, locked) in their colours, keys, balls, boxes, goal, lava, the
agent's red triangle pointing in its direction, and the cells the agent can see lightened.

It is pure ``jax.numpy`` and fixed-shape, so ``jax.jit(render, static_argnames=...)`` compiles
once and ``jax.vmap`` renders a batch. Every cell's tile is *gathered* from a precomputed
atlas (one tile per distinct ``(object, colour, state)`` drawing, plain and highlighted, and the
same with the agent on top per direction), drawn once per tile size in numpy with MiniGrid's own
recipe: the shapes of ``minigrid.core.world_object`` filled on a 3x supersampled tile, then
averaged down. The result equals minigrid's ``get_frame`` pixel for pixel on the levels the tests
convert. The visible cells come from :mod:`jaxgrid.observation` (the occlusion the observation
uses).

:func:`render_ansi` writes the grid as text in :mod:`jaxgrid.ascii`'s two-characters-per-cell
legend with the agent as an arrow (``>>``, ``VV``, ``<<``, ``^^``, as MiniGrid's
``pprint_grid``), so the text of a state whose agent stands on an empty cell parses back with
:func:`jaxgrid.ascii.from_ascii`.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrid.ascii import COLOUR_LETTERS
from jaxgrid.constants import (
    BALL,
    BOX,
    CLOSED,
    DOOR,
    FLOOR,
    GOAL,
    KEY,
    LAVA,
    LOCKED,
    OPEN,
    WALL,
)
from jaxgrid.observation import see_behind, view_cells, view_offsets, visibility_mask
from jaxgrid.types import State

__all__ = ["COLORS", "render", "render_ansi", "render_view", "tile_atlas", "view_mask"]

#: RGB of each colour index, ``minigrid.core.constants.COLORS`` (red 0, green 1, ... grey 5).
COLORS = np.array(
    [[255, 0, 0], [0, 255, 0], [0, 0, 255], [112, 39, 195], [255, 255, 0], [100, 100, 100]],
    dtype=np.float64,
)
#: Supersampling factor of MiniGrid's ``Grid.render_tile`` (tiles are drawn 3x and averaged).
SUBDIVS = 3
GRID_LINE = (100, 100, 100)
AGENT_RGB = (255, 0, 0)
LAVA_RGB = (255, 128, 0)
HIGHLIGHT_ALPHA = 0.30  # minigrid.utils.rendering.highlight_img: towards white by 30 %

NUM_OBJECTS, NUM_COLOURS, NUM_STATES = 11, 6, 3
NUM_CODES = NUM_OBJECTS * NUM_COLOURS * NUM_STATES


# ---------------------------------------------------------------------------------------------
# Shapes, as in minigrid.utils.rendering, vectorised over the sub-pixel centres of one tile
# ---------------------------------------------------------------------------------------------


def _centres(size: int) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y)`` planes of pixel centres in ``[0, 1]`` for a ``size``-pixel tile, indexed
    ``[y, x]`` like the image (MiniGrid's ``fill_coords``)."""
    c = (np.arange(size) + 0.5) / size
    y, x = np.meshgrid(c, c, indexing="ij")
    return x, y


def _rect(x, y, xmin, xmax, ymin, ymax):
    return (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)


def _circle(x, y, cx, cy, r):
    return (x - cx) * (x - cx) + (y - cy) * (y - cy) <= r * r


def _line(x, y, x0, y0, x1, y1, r):
    p0 = np.array([x0, y0], np.float32).astype(np.float64)
    p1 = np.array([x1, y1], np.float32).astype(np.float64)
    d = p1 - p0
    dist = np.linalg.norm(d)
    d = d / dist
    a = np.clip((x - p0[0]) * d[0] + (y - p0[1]) * d[1], 0, dist)
    px, py = p0[0] + a * d[0], p0[1] + a * d[1]
    return np.hypot(x - px, y - py) <= r


def _triangle(x, y, a, b, c):
    a, b, c = (np.array(p, np.float32).astype(np.float64) for p in (a, b, c))
    v0, v1 = c - a, b - a
    v2x, v2y = x - a[0], y - a[1]
    dot00, dot01, dot11 = v0 @ v0, v0 @ v1, v1 @ v1
    dot02 = v0[0] * v2x + v0[1] * v2y
    dot12 = v1[0] * v2x + v1[1] * v2y
    inv = 1 / (dot00 * dot11 - dot01 * dot01)
    u = (dot11 * dot02 - dot01 * dot12) * inv
    v = (dot00 * dot12 - dot01 * dot02) * inv
    return (u >= 0) & (v >= 0) & (u + v < 1)


def _agent_mask(x, y, direction: int):
    """MiniGrid's agent triangle, rotated by ``direction`` quarter turns about the centre."""
    theta = 0.5 * math.pi * direction
    xr, yr = x - 0.5, y - 0.5
    x2 = 0.5 + xr * math.cos(-theta) - yr * math.sin(-theta)
    y2 = 0.5 + yr * math.cos(-theta) + xr * math.sin(-theta)
    return _triangle(x2, y2, (0.12, 0.19), (0.87, 0.50), (0.12, 0.81))


def _paint(img, mask, colour) -> None:
    # MiniGrid assigns float colours into a uint8 image: numpy truncates.
    img[mask] = np.asarray(colour, np.float64).astype(np.uint8)


def _draw_object(img, x, y, kind: int, colour: int, state: int) -> None:
    """``WorldObj.render`` of minigrid 3.2.0 for one encoded object (nothing for empty/unseen)."""
    c = COLORS[colour]
    if kind in (WALL, GOAL):
        _paint(img, _rect(x, y, 0, 1, 0, 1), c)
    elif kind == FLOOR:
        _paint(img, _rect(x, y, 0.031, 1, 0.031, 1), c / 2)
    elif kind == LAVA:
        _paint(img, _rect(x, y, 0, 1, 0, 1), LAVA_RGB)
        for i in range(3):
            lo, hi = 0.3 + 0.2 * i, 0.4 + 0.2 * i
            for x0, y0, x1, y1 in (
                (0.1, lo, 0.3, hi),
                (0.3, hi, 0.5, lo),
                (0.5, lo, 0.7, hi),
                (0.7, hi, 0.9, lo),
            ):
                _paint(img, _line(x, y, x0, y0, x1, y1, 0.03), (0, 0, 0))
    elif kind == DOOR:
        if state == OPEN:
            _paint(img, _rect(x, y, 0.88, 1.00, 0.00, 1.00), c)
            _paint(img, _rect(x, y, 0.92, 0.96, 0.04, 0.96), (0, 0, 0))
        elif state == LOCKED:
            _paint(img, _rect(x, y, 0, 1, 0, 1), c)
            _paint(img, _rect(x, y, 0.06, 0.94, 0.06, 0.94), 0.45 * c)
            _paint(img, _rect(x, y, 0.52, 0.75, 0.50, 0.56), c)  # key slot
        else:
            _paint(img, _rect(x, y, 0, 1, 0, 1), c)
            _paint(img, _rect(x, y, 0.04, 0.96, 0.04, 0.96), (0, 0, 0))
            _paint(img, _rect(x, y, 0.08, 0.92, 0.08, 0.92), c)
            _paint(img, _rect(x, y, 0.12, 0.88, 0.12, 0.88), (0, 0, 0))
            _paint(img, _circle(x, y, 0.75, 0.50, 0.08), c)  # handle
    elif kind == KEY:
        _paint(img, _rect(x, y, 0.50, 0.63, 0.31, 0.88), c)
        _paint(img, _rect(x, y, 0.38, 0.50, 0.59, 0.66), c)
        _paint(img, _rect(x, y, 0.38, 0.50, 0.81, 0.88), c)
        _paint(img, _circle(x, y, 0.56, 0.28, 0.190), c)
        _paint(img, _circle(x, y, 0.56, 0.28, 0.064), (0, 0, 0))
    elif kind == BALL:
        _paint(img, _circle(x, y, 0.5, 0.5, 0.31), c)
    elif kind == BOX:
        _paint(img, _rect(x, y, 0.12, 0.88, 0.12, 0.88), c)
        _paint(img, _rect(x, y, 0.18, 0.82, 0.18, 0.82), (0, 0, 0))
        _paint(img, _rect(x, y, 0.16, 0.84, 0.47, 0.53), c)


def _highlight(img: np.ndarray) -> np.ndarray:
    """``highlight_img``: 30 % towards white, truncated to uint8."""
    blend = img + HIGHLIGHT_ALPHA * (np.array((255, 255, 255), np.uint8) - img)
    return blend.clip(0, 255).astype(np.uint8)


def _downsample(img: np.ndarray, size: int) -> np.ndarray:
    """Mean over ``SUBDIVS x SUBDIVS`` blocks, truncated to uint8 as MiniGrid's assignment."""
    return img.reshape(size, SUBDIVS, size, SUBDIVS, 3).mean(axis=(1, 3)).astype(np.uint8)


def _unique_key(kind: int, colour: int, state: int) -> tuple[int, int, int]:
    """The drawing a code shares: only doors differ by state; empty, unseen and the (never
    stored) agent code draw nothing."""
    if kind in (0, 1, 10):
        return (1, 0, 0)
    return (kind, colour, state if kind == DOOR else 0)


@functools.cache
def tile_atlas(tile_size: int = 32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every distinct tile MiniGrid draws, at one tile size (computed once, cached).

    Returns:
        ``index``: int32 ``(NUM_CODES,)``, the tile of cell code ``(o * 6 + c) * 3 + s`` for an
        encoded cell ``(o, c, s)``.
        ``tiles``: uint8 ``(2, T, ts, ts, 3)``; ``tiles[h, index[code]]`` equals minigrid's
        ``Grid.render_tile(obj, highlight=bool(h), tile_size=ts)`` as ``get_frame`` stores it
        (uint8). Empty and unseen cells show only the grid lines (MiniGrid's ``None`` cell).
        ``agent``: uint8 ``(2, 4, T, ts, ts, 3)``: the same tiles with the agent's triangle
        drawn over them, per direction (0 right, 1 down, 2 left, 3 up).
    """
    if not isinstance(tile_size, int) or isinstance(tile_size, bool) or tile_size < 1:
        raise ValueError(f"tile_size must be a positive int, got {tile_size!r}")
    big = tile_size * SUBDIVS
    x, y = _centres(big)
    base = np.zeros((big, big, 3), np.uint8)
    _paint(base, _rect(x, y, 0, 0.031, 0, 1), GRID_LINE)  # left edge
    _paint(base, _rect(x, y, 0, 1, 0, 0.031), GRID_LINE)  # top edge
    agent_masks = [_agent_mask(x, y, d) for d in range(4)]
    keys = sorted(
        {
            _unique_key(o, c, s)
            for o in range(NUM_OBJECTS)
            for c in range(NUM_COLOURS)
            for s in range(NUM_STATES)
        }
    )
    slot = {k: i for i, k in enumerate(keys)}
    index = np.array(
        [
            slot[_unique_key(o, c, s)]
            for o in range(NUM_OBJECTS)
            for c in range(NUM_COLOURS)
            for s in range(NUM_STATES)
        ],
        np.int32,
    )
    tiles = np.zeros((2, len(keys), tile_size, tile_size, 3), np.uint8)
    agent = np.zeros((2, 4, len(keys), tile_size, tile_size, 3), np.uint8)
    for t, key in enumerate(keys):
        img = base.copy()
        _draw_object(img, x, y, *key)
        tiles[0, t] = _downsample(img, tile_size)
        tiles[1, t] = _downsample(_highlight(img), tile_size)
        for d, mask in enumerate(agent_masks):
            with_agent = img.copy()
            _paint(with_agent, mask, AGENT_RGB)
            agent[0, d, t] = _downsample(with_agent, tile_size)
            agent[1, d, t] = _downsample(_highlight(with_agent), tile_size)
    return index, tiles, agent


# ---------------------------------------------------------------------------------------------
# The renderer
# ---------------------------------------------------------------------------------------------


def view_mask(state: State, view_size: int, see_through_walls: bool) -> jax.Array:
    """bool ``(W, H)``: the world cells the agent sees (MiniGrid's ``get_full_render`` mask).

    Each world cell is mapped to its cell in the agent's ``view_size`` view (an inverse of
    :func:`jaxgrid.observation.view_offsets`, by gather), whose visibility comes from
    :func:`jaxgrid.observation.visibility_mask` unless ``see_through_walls``.
    """
    grid = state.grid
    width, height = grid.shape[:2]
    v = view_size
    if see_through_walls:
        visible = jnp.ones((v, v), bool)
    else:
        visible = visibility_mask(see_behind(view_cells(grid, state.agent_pos, state.agent_dir, v)))
    offsets = jnp.asarray(view_offsets(v))[state.agent_dir]  # (V, V, 2): view (i, j) -> offset
    # The offset is linear in (i, j): offset = i * di + j * dj + origin.
    origin = offsets[0, 0]
    di = offsets[1, 0] - origin
    dj = offsets[0, 1] - origin
    xs, ys = np.meshgrid(np.arange(width), np.arange(height), indexing="ij")
    rx = jnp.asarray(xs) - state.agent_pos[0] - origin[0]
    ry = jnp.asarray(ys) - state.agent_pos[1] - origin[1]
    # di and dj are orthogonal unit vectors, so the inverse is a projection.
    i = rx * di[0] + ry * di[1]
    j = rx * dj[0] + ry * dj[1]
    inside = (i >= 0) & (i < v) & (j >= 0) & (j < v)
    return inside & visible[jnp.clip(i, 0, v - 1), jnp.clip(j, 0, v - 1)]


def render(
    state: State,
    env=None,
    *,
    tile_size: int = 32,
    highlight: bool = True,
) -> jax.Array:
    """RGB image of ``state`` in MiniGrid's look: uint8 ``(H * tile_size, W * tile_size, 3)``.

    The image is indexed ``[row, column]`` (``y`` down, ``x`` right), like
    ``minigrid_env.get_frame()``. ``env`` supplies the view size and ``see_through_walls`` for
    the highlight of the agent's view; with ``env=None`` (or ``highlight=False``) nothing is
    highlighted. ``env``, ``tile_size`` and ``highlight`` are static under ``jit``::

        img = jax.jit(render, static_argnums=1, static_argnames="tile_size")(state, env)
        imgs = jax.vmap(lambda s: render(s, env))(states)   # a batch: (B, H*ts, W*ts, 3)
    """
    view = None if env is None else (int(env.view_size), bool(env.see_through_walls))
    return render_view(state, view, tile_size, highlight)


def render_view(
    state: State,
    view: tuple[int, bool] | None,
    tile_size: int = 32,
    highlight: bool = True,
) -> jax.Array:
    """:func:`render` with the view given as ``(view_size, see_through_walls)`` or ``None``.

    Handy as a jit static argument: it depends on two numbers rather than a whole env.
    """
    index, tiles, agent = tile_atlas(tile_size)
    num_tiles = tiles.shape[1]
    grid = state.grid.astype(jnp.int32)
    width, height = grid.shape[:2]
    code = (grid[..., 0] * NUM_COLOURS + grid[..., 1]) * NUM_STATES + grid[..., 2]
    tile = jnp.asarray(index)[jnp.clip(code, 0, NUM_CODES - 1)].T  # (H, W): image rows first
    if highlight and view is not None:
        lit = view_mask(state, *view).T.astype(jnp.int32)
    else:
        lit = jnp.zeros((height, width), jnp.int32)
    flat = jnp.asarray(tiles.reshape(2 * num_tiles, tile_size, tile_size, 3))
    img = flat[lit * num_tiles + tile]  # (H, W, ts, ts, 3): one gather for the whole grid
    # The agent's cell: its tile with the triangle, gathered once and selected in.
    ax = jnp.clip(state.agent_pos[0], 0, width - 1)
    ay = jnp.clip(state.agent_pos[1], 0, height - 1)
    direction = jnp.clip(state.agent_dir, 0, 3)
    flat_agent = jnp.asarray(agent.reshape(2 * 4 * num_tiles, tile_size, tile_size, 3))
    agent_tile = flat_agent[(lit[ay, ax] * 4 + direction) * num_tiles + tile[ay, ax]]
    xs, ys = np.meshgrid(np.arange(width), np.arange(height), indexing="xy")  # (H, W)
    here = (jnp.asarray(xs) == state.agent_pos[0]) & (jnp.asarray(ys) == state.agent_pos[1])
    img = jnp.where(here[..., None, None, None], agent_tile, img)
    return img.transpose(0, 2, 1, 3, 4).reshape(height * tile_size, width * tile_size, 3)


# ---------------------------------------------------------------------------------------------
# Text
# ---------------------------------------------------------------------------------------------

_LETTER = {i: k for k, i in COLOUR_LETTERS.items()}  # colour index -> letter (grey is E)
_OBJECT_CHAR = {WALL: "W", FLOOR: "F", KEY: "K", BALL: "A", BOX: "B", GOAL: "G", LAVA: "V"}
_DOOR_CHAR = {OPEN: "_", CLOSED: "D", LOCKED: "L"}
_AGENT_STR = (">>", "VV", "<<", "^^")
_ANSI = {0: "31", 1: "32", 2: "34", 3: "35", 4: "33", 5: "90"}  # terminal colour per index


def _cell_text(kind: int, colour: int, state: int) -> str:
    if kind == WALL and colour == COLOUR_LETTERS["E"]:
        return "##"
    if kind == DOOR:
        return _DOOR_CHAR.get(state, "D") + _LETTER.get(colour, "?")
    if kind in _OBJECT_CHAR:
        return _OBJECT_CHAR[kind] + _LETTER.get(colour, "?")
    if kind == 0:
        return "??"  # unseen: never in a world grid
    return ".."


def render_ansi(state: State, *, color: bool = False) -> str:
    """Text picture of ``state``, one line per grid row, two characters per cell.

    Uses :mod:`jaxgrid.ascii`'s legend (``##`` wall, ``..`` empty, ``G.``-style object + colour
    letter, ``D``/``L``/``_`` closed/locked/open doors) and draws the agent as an arrow
    (``>>`` ``VV`` ``<<`` ``^^``) like MiniGrid's ``pprint_grid``; the arrow hides the cell it
    stands on. ``color=True`` adds ANSI terminal colours. Takes one (unbatched) state; runs on
    the host (not jittable).
    """
    grid = np.asarray(state.grid)
    if grid.ndim != 3:
        raise ValueError(f"render_ansi takes one state; got a grid of shape {grid.shape}")
    ax, ay = (int(v) for v in np.asarray(state.agent_pos))
    direction = int(np.asarray(state.agent_dir)) % 4
    lines = []
    for y in range(grid.shape[1]):
        row = []
        for x in range(grid.shape[0]):
            kind, colour, st = (int(v) for v in grid[x, y])
            if (x, y) == (ax, ay):
                text, code = _AGENT_STR[direction], "1;31"
            else:
                text = _cell_text(kind, colour, st)
                code = _ANSI.get(colour) if kind not in (0, 1) else None
                if kind == LAVA:
                    code = "33"
            row.append(f"\x1b[{code}m{text}\x1b[0m" if color and code else text)
        lines.append("".join(row))
    return "\n".join(lines)
