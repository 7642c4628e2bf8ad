"""Level generators: MiniGrid's classic levels and fixed layouts (ASCII maps, converted envs)."""

from jaxgrid.levels.classic import DoorKey, Empty, LavaGap
from jaxgrid.levels.dynamic import DynamicObstacles
from jaxgrid.levels.fixed import FixedLevel
from jaxgrid.levels.keys import BlockedUnlockPickup, KeyCorridor, Unlock, UnlockPickup
from jaxgrid.levels.memory import Memory
from jaxgrid.levels.missions import Fetch, GoToDoor, GoToObject, PutNear
from jaxgrid.levels.navigation import Crossing, DistShift, FourRooms
from jaxgrid.levels.obstructed import ObstructedMaze1D, ObstructedMazeFull
from jaxgrid.levels.playground import Playground
from jaxgrid.levels.rooms import LockedRoom, MultiRoom, RedBlueDoors

__all__ = [
    "BlockedUnlockPickup",
    "Crossing",
    "DistShift",
    "DoorKey",
    "DynamicObstacles",
    "Empty",
    "Fetch",
    "FixedLevel",
    "FourRooms",
    "GoToDoor",
    "GoToObject",
    "KeyCorridor",
    "LavaGap",
    "LockedRoom",
    "Memory",
    "MultiRoom",
    "ObstructedMaze1D",
    "ObstructedMazeFull",
    "Playground",
    "PutNear",
    "RedBlueDoors",
    "Unlock",
    "UnlockPickup",
]
