"""ThreeRooms-Key with the TwoRooms checker (the paper's generalisation experiment).

Run ``python -m experiments.three_rooms_key [--quick | --paper] [--out DIR]``.

See :mod:`experiments.pipeline` for the phases, the outputs and ``--help`` for the flags.
"""

from experiments.pipeline import ExperimentConfig, main

DEFAULTS = ExperimentConfig(
    experiment="three_rooms_key", env_id="ThreeRoomsKey-v0", checker_env_id="TwoRooms-v0"
)

if __name__ == "__main__":
    main(DEFAULTS)
