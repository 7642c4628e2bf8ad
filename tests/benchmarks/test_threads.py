"""benchmarks.threads: bad flags fail at once; a short run (slow: two compiles at the
experiments' sizes) reports identical parameters both ways."""

import pytest

from benchmarks import threads


@pytest.mark.parametrize(
    ("argv", "message"),
    [(["--rounds", "0"], "--rounds must be >= 1"), (["--seeds", "0"], "--seeds must be >= 1"),
     (["--modes", "none", "none"], "at least two different modes"),
     (["--modes", "none", "nope"], "invalid choice")],
)  # fmt: skip
def test_bad_flags_are_usage_errors(capsys, argv, message):
    with pytest.raises(SystemExit) as e:
        threads.main(argv)
    assert e.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.slow
def test_short_run_is_identical_both_ways():
    line = threads.main(["--seeds", "1", "--updates", "1", "--rounds", "1"])
    assert line["identical"] is True and line["speedup"] > 0
    assert len(line["sequential_s"]) == len(line["threads_s"]) == 1
