"""``python -m experiments.two_rooms_lava --quick``: outputs exist and follow the schema.

In a file of its own so that ``pytest -n 2 --dist loadfile`` runs it beside the TwoRooms runs.
"""

import pytest
from helpers.experiment_runs import check_outputs, quick

from experiments import two_rooms_lava


@pytest.mark.slow
def test_two_rooms_lava_quick(tmp_path):
    quick(two_rooms_lava, tmp_path, "--modes", "checker,none")
    results = check_outputs(tmp_path, "two_rooms_lava", modes=("checker", "none"))
    assert results["checker"]["trained_on"] == "TwoRoomsLava-v0"
