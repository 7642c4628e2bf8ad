"""TwoRooms-Lava (the paper's 2Rooms-Lava).

Run ``python -m experiments.two_rooms_lava [--quick | --paper] [--out DIR]``.

See :mod:`experiments.pipeline` for the phases, the outputs and ``--help`` for the flags.
"""

from experiments.pipeline import ExperimentConfig, main

DEFAULTS = ExperimentConfig(
    experiment="two_rooms_lava", env_id="TwoRoomsLava-v0", checker_env_id="TwoRoomsLava-v0"
)

if __name__ == "__main__":
    main(DEFAULTS)
