"""``python -m benchmarks.checker_cost``: flags checked before compiling, a tiny timing."""

from __future__ import annotations

import jax
import pytest
from helpers.cli_help import help_entries, squeezed

import jaxgrid
from benchmarks import checker_cost
from checker.model import CheckerConfig, new_checker


def test_flags(capsys, compiles):
    with pytest.raises(SystemExit) as exc:
        checker_cost.main(["--envs", "8", "0"])
    assert exc.value.code == 2 and "--envs: every count must be >= 1" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        checker_cost.main(["--help"])
    assert exc.value.code == 0
    entries = help_entries(capsys.readouterr().out)
    assert {"--env", "--envs", "--steps", "--repeats", "--checker"} <= set(entries)
    assert "(default:2561024 4096)".replace(" ", "") in squeezed(entries["--envs"])
    assert not compiles


@pytest.mark.slow
def test_tiny_measurement():
    env = jaxgrid.make("TwoRooms-v0")
    config = CheckerConfig(window=3, gru_dim=8, word_dim=4, state_dim=8, mlp_dim=8)
    trained = new_checker(config, jax.random.PRNGKey(0))
    row = checker_cost.measure(env, trained, num_envs=4, steps=4, repeats=2)
    assert row["num_envs"] == 4 and row["steps"] == 4
    for name in ("env_only", "env_plus_checker"):
        assert row[f"{name}_compile_s"] > 0 and row[f"{name}_s"] > 0
    assert row["slowdown"] == pytest.approx(row["env_plus_checker_s"] / row["env_only_s"])
