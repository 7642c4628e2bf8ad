"""TwoRooms (the paper's 2Rooms).

Run ``python -m experiments.two_rooms [--quick | --paper] [--out DIR]``.

See :mod:`experiments.pipeline` for the phases, the outputs and ``--help`` for the flags.
"""

from experiments.pipeline import ExperimentConfig, main

DEFAULTS = ExperimentConfig(
    experiment="two_rooms", env_id="TwoRooms-v0", checker_env_id="TwoRooms-v0"
)

if __name__ == "__main__":
    main(DEFAULTS)
