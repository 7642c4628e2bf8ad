"""ThreeRooms-Key with the TwoRooms checker (the paper's generalisation experiment).

Run ``python -m experiments.three_rooms_key [--quick | --paper] [--out DIR]``.

See :mod:`experiments.pipeline` for the phases, the outputs and the presets
(``preset(SCENARIO, name)``), and ``--help`` for the flags.
"""

from checker.cli import run_main
from experiments.pipeline import main, scenario

SCENARIO = scenario("three_rooms_key", "ThreeRoomsKey-v0", "TwoRooms-v0")

if __name__ == "__main__":
    run_main(lambda: main(SCENARIO), "python -m experiments.three_rooms_key")
