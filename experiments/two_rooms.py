"""TwoRooms (the paper's 2Rooms).

Run ``python -m experiments.two_rooms [--quick | --paper] [--out DIR]``: the row
``EXPERIMENTS["two_rooms"]`` of :mod:`experiments.presets`, run by
:func:`experiments.pipeline.main` (phases, outputs, presets); ``--help`` lists the flags.
"""

from checker.cli import run_main
from experiments.pipeline import main
from experiments.presets import EXPERIMENTS

SCENARIO = EXPERIMENTS["two_rooms"]

if __name__ == "__main__":
    run_main(lambda: main(SCENARIO), "python -m experiments.two_rooms")
