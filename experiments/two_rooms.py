"""TwoRooms (the paper's 2Rooms).

Run ``python -m experiments.two_rooms [--quick | --paper] [--out DIR]``.

See :mod:`experiments.pipeline` for the phases, the outputs and the presets
(``preset(SCENARIO, name)``), and ``--help`` for the flags.
"""

from checker.cli import run_main
from experiments.pipeline import main, scenario

SCENARIO = scenario("two_rooms", "TwoRooms-v0")

if __name__ == "__main__":
    run_main(lambda: main(SCENARIO), "python -m experiments.two_rooms")
