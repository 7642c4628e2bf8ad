"""benchmarks.hazard_checks on a tiny HazardRooms."""

from __future__ import annotations

import pytest

from benchmarks import hazard_checks
from jaxgrid import language
from jaxgrid.hazard import HazardRooms


@pytest.mark.slow
def test_oracle_figures_cover_every_type_and_obey():
    env = HazardRooms(width=9, height=9, max_steps=60)
    figures = hazard_checks.oracle_figures(env, episodes=5, batch=64)
    assert list(figures) == list(language.CONSTRAINT_TYPES)
    for f in figures.values():
        assert f["episodes"] >= 5
        assert f["success_pct"] == 100.0 and f["violated_pct"] == 0.0
        assert 0.0 <= f["unconstrained_violated_pct"] <= 100.0
    kinds = figures["sequential"]["by_kind"]
    assert set(kinds) <= set(hazard_checks.KINDS) and {k.split()[0] for k in kinds} == {
        "after",
        "before",
    }
    assert sum(k["episodes"] for k in kinds.values()) == figures["sequential"]["episodes"]


def test_bad_episode_count_is_refused():
    with pytest.raises(SystemExit):
        hazard_checks.main(["--episodes", "0"])
