"""``--checker DIR`` is compared with the run on every setting that changes what its alarms
mean, refused by name before anything is written or compiled, and the refused ``--out``
stays usable."""

from __future__ import annotations

import dataclasses

import jax
import pytest

from checker.model import CheckerConfig, TrainedChecker, init_params
from checker.store import save
from experiments import checker_phases, phases, pipeline, two_rooms
from experiments.pipeline import preset


@pytest.fixture(scope="module")
def window_checker(tmp_path_factory):
    """An untrained TwoRooms window checker saved with lookahead 1 and window 5."""
    config = CheckerConfig()
    directory = tmp_path_factory.mktemp("checker")
    save(TrainedChecker(init_params(config, jax.random.PRNGKey(0)), config, lookahead=1,
                        env_id="TwoRooms-v0"), directory)  # fmt: skip
    return directory


def _cfg(checker, out, **checker_train):
    cfg = preset(two_rooms.SCENARIO, "quick")
    return dataclasses.replace(cfg, checker=str(checker), out=str(out), checker_train=(
        dataclasses.replace(cfg.checker_train, **checker_train)))  # fmt: skip


def test_a_checker_of_the_run_settings_is_accepted(window_checker, tmp_path):
    assert checker_phases.load_reused(_cfg(window_checker, tmp_path)).lookahead == 1


@pytest.mark.parametrize("setting, value, flag", [("lookahead", 0, "--lookahead"),
                                                  ("window", 3, "--window")])  # fmt: skip
def test_another_label_timing_or_window_is_refused_by_name(window_checker, tmp_path, setting,
                                                           value, flag):  # fmt: skip
    cfg = _cfg(window_checker, tmp_path, **{setting: value})
    with pytest.raises(ValueError, match=f"trained with {setting} .*asks for {flag} {value}"):
        checker_phases.load_reused(cfg)


def test_a_refused_checker_leaves_out_reusable(window_checker, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["--quick", "--no-progress", "--checker", str(window_checker), "--out", str(out)]
    with pytest.raises(SystemExit) as e:
        pipeline.main(two_rooms.SCENARIO, [*argv, "--lookahead", "0"])
    assert e.value.code == 2
    assert "trained with lookahead 1" in capsys.readouterr().err
    # nothing recorded: the same --out takes the corrected flags without "another
    # configuration"
    assert not (out / "config.json").exists() and not (out / ".lock").exists()
    fixed = pipeline.parse_args(argv, two_rooms.SCENARIO)
    checker_phases.load_reused(fixed)
    phases.prepare_out(fixed)
    assert (out / "config.json").exists()
