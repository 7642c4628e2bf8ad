"""Levels from ASCII maps.

A map is a multi-line string, **two characters per cell** (the same idea as MiniGrid's
``MiniGridEnv.pprint_grid``): the first character names the object, the second its colour.

=========  ==========================================================================
cell       meaning
=========  ==========================================================================
``..``     empty (two spaces also work, except at the end of a line)
``##``     grey wall (``W`` + colour for a coloured wall, e.g. ``WR``)
``F.``     floor (blue by default; ``F`` + colour for another)
``G.``     goal (green)               ``V.``  lava (red)
``D`` c    closed door of colour c    ``L`` c locked door     ``_`` c  open door
``K`` c    key of colour c            ``A`` c ball            ``B`` c  box (empty)
``>>``     agent facing right; ``VV`` (or ``vv``) down, ``<<`` left, ``^^`` up; it stands on an
           empty cell. Exactly one agent.
=========  ==========================================================================

Colour letters: ``R`` red, ``G`` green, ``B`` blue, ``P`` purple, ``Y`` yellow, ``E`` grey
(MiniGrid prints grey as ``G`` too; we need them apart). For walls, floor, goal and lava a
second character of ``.`` or space means the object's default colour.

Example::

    level = from_ascii('''
        ##########
        ##>>..##G.
        ##..KYLY..
        ##########
    ''')
"""

from __future__ import annotations

import textwrap

import numpy as np

from jaxgrid.constants import (
    BALL,
    BLUE,
    BOX,
    CLOSED,
    DOOR,
    EMPTY_CELL,
    FLOOR,
    GOAL,
    GREEN,
    GREY,
    KEY,
    LAVA,
    LOCKED,
    OPEN,
    RED,
    WALL,
)
from jaxgrid.levels.fixed import FixedLevel

COLOUR_LETTERS = {"R": 0, "G": 1, "B": 2, "P": 3, "Y": 4, "E": 5}
# object letter -> (type, state, default colour or None when a colour is required)
_OBJECTS = {
    "W": (WALL, 0, GREY),
    "F": (FLOOR, 0, BLUE),
    "G": (GOAL, 0, GREEN),
    "V": (LAVA, 0, RED),
    "D": (DOOR, CLOSED, None),
    "L": (DOOR, LOCKED, None),
    "_": (DOOR, OPEN, None),
    "K": (KEY, 0, None),
    "A": (BALL, 0, None),
    "B": (BOX, 0, None),
}
_AGENT = {">>": 0, "VV": 1, "vv": 1, "<<": 2, "^^": 3}
_EMPTY = {"..", "  "}


def parse_ascii(text: str) -> tuple[np.ndarray, tuple[int, int], int]:
    """Parse a map into ``(grid uint8 (W, H, 3), agent_pos, agent_dir)``.

    Raises ``ValueError`` naming the line and column of the first problem.
    """
    if not isinstance(text, str):
        raise TypeError(f"an ASCII map must be a str, got {type(text).__name__}")
    lines = textwrap.dedent(text).split("\n")
    while lines and not lines[0].strip():
        lines.pop(0)
    while lines and not lines[-1].strip():
        lines.pop()
    lines = [line.rstrip("\r") for line in lines]
    if not lines:
        raise ValueError("ASCII map is empty")
    width2 = len(lines[0].rstrip())
    if width2 % 2:
        raise ValueError(f"line 1 has {width2} characters; cells take two characters each")
    width, height = width2 // 2, len(lines)
    grid = np.broadcast_to(EMPTY_CELL, (width, height, 3)).copy()
    agents = []
    for y, line in enumerate(lines):
        body = line[:width2] if len(line.rstrip()) <= width2 else line  # trailing blanks only
        if len(body) != width2:
            raise ValueError(
                f"line {y + 1} has {len(body)} characters but line 1 has {width2}: "
                "rows must all be the same width"
            )
        for x in range(width):
            tok = body[2 * x : 2 * x + 2]
            where = f"line {y + 1}, column {2 * x + 1} (cell x={x}, y={y})"
            if tok in _EMPTY:
                continue
            if tok == "##":
                grid[x, y] = (WALL, GREY, 0)
            elif tok in _AGENT:
                agents.append(((x, y), _AGENT[tok], where))
            elif tok[0] in _OBJECTS:
                kind, state, default = _OBJECTS[tok[0]]
                if tok[1] in COLOUR_LETTERS:
                    colour = COLOUR_LETTERS[tok[1]]
                elif tok[1] in ". " and default is not None:
                    colour = default
                else:
                    need = "a colour letter" if default is None else "a colour letter, '.' or ' '"
                    raise ValueError(
                        f"unknown colour {tok[1]!r} in cell {tok!r} at {where}: expected {need} "
                        f"({', '.join(f'{k}' for k in COLOUR_LETTERS)})"
                    )
                grid[x, y] = (kind, colour, state)
            else:
                raise ValueError(
                    f"unknown symbol {tok!r} at {where}; see jaxgrid.ascii for the legend"
                )
    if not agents:
        raise ValueError("ASCII map has no agent: put one of >>, VV, <<, ^^ on an empty cell")
    if len(agents) > 1:
        raise ValueError(f"ASCII map has {len(agents)} agents; the second is at {agents[1][2]}")
    ((pos, direction, _),) = agents
    return grid, pos, direction


def from_ascii(
    text: str,
    *,
    view_size: int = 7,
    see_through_walls: bool = False,
    max_steps: int | None = None,
    carrying: tuple[int, int, int] | None = None,
) -> FixedLevel:
    """A :class:`FixedLevel` from a map (see the module docstring for the legend).

    ``max_steps`` defaults to ``4 * width * height``; ``carrying`` is an encoded object
    ``(type, colour, state)`` the agent starts with (e.g. ``(KEY, RED, 0)``).
    """
    grid, pos, direction = parse_ascii(text)
    width, height = grid.shape[:2]
    return FixedLevel(
        width=width,
        height=height,
        max_steps=max_steps if max_steps is not None else 4 * width * height,
        view_size=view_size,
        see_through_walls=see_through_walls,
        layout=grid.tobytes(),
        agent_start=pos,
        agent_dir=direction,
        carrying=tuple(int(c) for c in carrying) if carrying is not None else (1, 0, 0),
    )
