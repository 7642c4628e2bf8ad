"""benchmarks.hazard_checks and benchmarks.family_throughput on tiny inputs."""

from __future__ import annotations

import importlib.util

import pytest

from benchmarks import family_throughput, hazard_checks
from jaxgrid import hazard_language as HL
from jaxgrid.hazard import HazardRooms


def test_oracle_figures_cover_every_type_and_obey():
    env = HazardRooms(width=9, height=9, max_steps=60)
    figures = hazard_checks.oracle_figures(env, episodes=5, batch=64)
    assert list(figures) == list(HL.CONSTRAINT_TYPES)
    for f in figures.values():
        assert f["episodes"] >= 5
        assert f["success_pct"] == 100.0 and f["violated_pct"] == 0.0
        assert 0.0 <= f["unconstrained_violated_pct"] <= 100.0


def test_bad_episode_count_is_refused():
    with pytest.raises(SystemExit):
        hazard_checks.main(["--episodes", "0"])


@pytest.mark.skipif(importlib.util.find_spec("navix") is not None, reason="navix is installed")
def test_family_throughput_says_navix_is_missing(capsys):
    with pytest.raises(SystemExit):
        family_throughput.main(["--num-envs", "4"])
    assert "navix" in capsys.readouterr().err
