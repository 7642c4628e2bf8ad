"""HazardRooms: constraints that count, wait for a trigger or keep a distance.

Run ``python -m experiments.hazard_rooms [--quick | --paper] [--out DIR]``: the row
``EXPERIMENTS["hazard_rooms"]`` of :mod:`experiments.presets` (a memory checker,
:mod:`checker.memory_model`, and a recurrent policy, so that both can count; its other changes and
their reasons are in the row), by :func:`experiments.pipeline.main`; ``--help`` lists the flags.
"""

from checker.cli import run_main
from experiments.pipeline import main
from experiments.presets import EXPERIMENTS, HAZARD_SENTENCES

SCENARIO = EXPERIMENTS["hazard_rooms"]
SENTENCES = HAZARD_SENTENCES  # the agents' episodes draw one of these

if __name__ == "__main__":
    run_main(lambda: main(SCENARIO), "python -m experiments.hazard_rooms")
