"""benchmarks.family_throughput and the masked auto-reset adapter it measures."""

from __future__ import annotations

import sys

import pytest

from benchmarks import env_throughput as ET
from benchmarks import family_throughput


def test_family_throughput_says_navix_is_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "navix", None)  # absent, even where it is installed
    with pytest.raises(ImportError, match="needs navix"):
        family_throughput.main(["--num-envs", "4"])


@pytest.mark.slow
def test_masked_auto_reset_plays_the_same_episodes():
    a, b = (
        ET.measure(lib, 8, 32, repeats=1, env_id="MiniGrid-LavaGapS5-v0")
        for lib in ("jaxgrid", "jaxgrid-masked")
    )
    assert a["episodes_finished"] > 0
    assert (a["episodes_finished"], a["reward_sum"]) == (b["episodes_finished"], b["reward_sum"])
    assert b["lib"] == "jaxgrid-masked" and "BatchedAutoReset" in b["notes"]["auto_reset"]
