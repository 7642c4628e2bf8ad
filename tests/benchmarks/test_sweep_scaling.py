"""benchmarks.sweep_scaling: bad flags fail at once; a tiny run (slow: two compiles)."""

import pytest

from benchmarks import sweep_scaling


@pytest.mark.parametrize(
    ("argv", "message"),
    [(["--agents", "0"], "--agents must be >= 1"), (["--updates", "0"], "--updates must be"),
     (["--mode", "nope"], "invalid choice")],
)  # fmt: skip
def test_bad_flags_are_usage_errors(capsys, argv, message):
    with pytest.raises(SystemExit) as e:
        sweep_scaling.main(argv)
    assert e.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.slow
def test_tiny_scaling_run():
    lines = sweep_scaling.main(["--agents", "1", "2", "--updates", "1", "--repeats", "1",
                                "--num-envs", "8"])  # fmt: skip
    assert [x["agents"] for x in lines] == [1, 2]
    assert lines[0]["total_vs_1_agents"] == 1.0 and lines[1]["sps_total"] > 0
    assert lines[1]["sps_per_agent"] == pytest.approx(lines[1]["sps_total"] / 2, rel=1e-3)
