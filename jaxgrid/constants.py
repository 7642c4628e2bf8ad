"""MiniGrid's integer encodings, directions and actions (minigrid 3.2.0 values).

Every grid cell is a triple ``(object, colour, state)`` of uint8, exactly as
``minigrid.core.grid.Grid.encode`` writes it, so arrays can be compared with
MiniGrid's own output byte for byte.
"""

from __future__ import annotations

import numpy as np

# Object types (minigrid.core.constants.OBJECT_TO_IDX).
UNSEEN, EMPTY, WALL, FLOOR, DOOR, KEY, BALL, BOX, GOAL, LAVA, AGENT = range(11)
OBJECT_NAMES = (
    "unseen",
    "empty",
    "wall",
    "floor",
    "door",
    "key",
    "ball",
    "box",
    "goal",
    "lava",
    "agent",
)
OBJECT_TO_IDX = {name: i for i, name in enumerate(OBJECT_NAMES)}

# Colours (minigrid.core.constants.COLOR_TO_IDX).
RED, GREEN, BLUE, PURPLE, YELLOW, GREY = range(6)
COLOR_NAMES = ("red", "green", "blue", "purple", "yellow", "grey")
COLOR_TO_IDX = {name: i for i, name in enumerate(COLOR_NAMES)}

# Door states (minigrid.core.constants.STATE_TO_IDX).
OPEN, CLOSED, LOCKED = 0, 1, 2
STATE_NAMES = ("open", "closed", "locked")

# Actions (minigrid.core.actions.Actions).
LEFT, RIGHT, FORWARD, PICKUP, DROP, TOGGLE, DONE = range(7)
NUM_ACTIONS = 7
ACTION_NAMES = ("left", "right", "forward", "pickup", "drop", "toggle", "done")

# Direction d -> (dx, dy): 0 = +x (right), 1 = +y (down), 2 = -x (left), 3 = -y (up).
DIR_TO_VEC = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], dtype=np.int32)

# Frequently used cell triples.
EMPTY_CELL = np.array([EMPTY, 0, 0], dtype=np.uint8)
WALL_CELL = np.array([WALL, GREY, 0], dtype=np.uint8)
GOAL_CELL = np.array([GOAL, GREEN, 0], dtype=np.uint8)
LAVA_CELL = np.array([LAVA, RED, 0], dtype=np.uint8)
UNSEEN_CELL = np.array([UNSEEN, 0, 0], dtype=np.uint8)
