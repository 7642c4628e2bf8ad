"""Level generators: MiniGrid's classic levels and fixed layouts (ASCII maps, converted envs)."""

from jaxgrid.levels.classic import DoorKey, Empty, LavaGap
from jaxgrid.levels.fixed import FixedLevel

__all__ = ["DoorKey", "Empty", "FixedLevel", "LavaGap"]
