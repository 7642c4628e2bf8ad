"""ThreeRooms-Key with the TwoRooms checker (the paper's generalisation experiment).

Run ``python -m experiments.three_rooms_key [--quick | --paper] [--out DIR]``: the row
``EXPERIMENTS["three_rooms_key"]`` of :mod:`experiments.presets`, run by
:func:`experiments.pipeline.main` (phases, outputs, presets); ``--help`` lists the flags.
"""

from checker.cli import run_main
from experiments.pipeline import main
from experiments.presets import EXPERIMENTS

SCENARIO = EXPERIMENTS["three_rooms_key"]

if __name__ == "__main__":
    run_main(lambda: main(SCENARIO), "python -m experiments.three_rooms_key")
