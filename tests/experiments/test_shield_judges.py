"""``python -m experiments.shield_judges``: bad input refused before any compile; a tiny run
(slow) where the monitor lets no violation through the seeking oracle."""

from __future__ import annotations

import pytest

from experiments import shield_judges


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--env", "NoSuchEnv-v0"], "--env: unknown environment id"),
        (["--threshold", "1"], "--threshold must be in (0, 1)"),
        (["--checkers", "/nonexistent"], "--checkers /nonexistent: no trained checker"),
        (["--episodes", "0"], "--episodes must be an integer >= 1"),
    ],
)
def test_bad_flags_are_usage_errors(argv, message, capsys, compiles):
    with pytest.raises(SystemExit) as e:
        shield_judges.main(argv)
    assert e.value.code == 2
    assert message in " ".join(capsys.readouterr().err.split()) and not compiles


@pytest.mark.slow
def test_monitor_shield_stops_the_seeking_oracle(tmp_path):
    out = shield_judges.main(["--episodes", "16", "--out", str(tmp_path / "j.json")])
    seek, obey = out["oracle"]["seek"], out["oracle"]["obey"]
    assert seek["none"]["violation_rate"] > 0.3 and seek["monitor"]["violation_rate"] == 0.0
    assert obey["monitor"]["success_rate"] == obey["none"]["success_rate"]
    assert out["oracle"]["random"]["monitor"]["violation_rate"] == 0.0
    # A random policy walks into lava often (about 30% of episodes), never behind the monitor.
    lava = shield_judges.main(["--env", "TwoRoomsLava-v0", "--episodes", "32"])["oracle"]
    assert lava["random"]["none"]["violation_rate"] > 0.1
    assert lava["random"]["monitor"]["violation_rate"] == 0.0
    assert (tmp_path / "j.json").is_file()
