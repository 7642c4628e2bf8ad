"""``python -m experiments.two_rooms_lava --quick``: outputs exist and follow the schema.

In a file of its own so that ``pytest -n 2 --dist loadfile`` runs it beside the TwoRooms runs.
"""

from test_experiments import _check_outputs, _quick

from experiments import two_rooms_lava


def test_two_rooms_lava_quick(tmp_path):
    _quick(two_rooms_lava, tmp_path, "--modes", "checker,none")
    results = _check_outputs(tmp_path, "two_rooms_lava", modes=("checker", "none"))
    assert results["checker"]["trained_on"] == "TwoRoomsLava-v0"


def test_two_rooms_lava_preset_doubles_the_default_budget_only():
    """Lava's default preset trains longer; --quick and --paper, and TwoRooms, are unchanged."""
    import dataclasses

    from experiments import two_rooms
    from experiments.pipeline import PRESETS

    lava = two_rooms_lava.DEFAULTS.resolved()
    assert (lava.steps, lava.behaviour_steps) == (3_000_000, 600_000)
    assert two_rooms.DEFAULTS.resolved().steps == PRESETS["default"]["steps"]
    for flag in ("quick", "paper"):
        cfg = dataclasses.replace(two_rooms_lava.DEFAULTS, **{flag: True}).resolved()
        assert cfg.steps == PRESETS[flag]["steps"]
    assert dataclasses.replace(two_rooms_lava.DEFAULTS, steps=123_456).resolved().steps == 123_456
