"""``run.json`` and the checkpoint digests as ``agents.checkpoint`` reads them, without
training: a resume matches the saved configuration (a field added since holds its declared
default), the saved configuration reads back as it was run, and a run counts as finished
where the digests list its last chunk.
"""

from __future__ import annotations

import dataclasses
import json

import pytest
from helpers.agents_cases import SEEDS, TINY

from agents import checkpoint, run_record
from agents.config import PPOConfig, check_sweep


def test_run_made_before_an_option_existed_resumes_while_it_is_off(tmp_path):
    """A ``run.json`` written before a config field existed describes the same run while
    the field holds its declared default (new options are added off by default)."""
    run_record.write_run_info(tmp_path, TINY, list(SEEDS))
    saved = json.loads((tmp_path / "run.json").read_text())
    del saved["config"]["penalty_gate"]
    (tmp_path / "run.json").write_text(json.dumps(saved))
    run_record.check_run_info(tmp_path, TINY, list(SEEDS))
    gated = dataclasses.replace(TINY, penalty_gate=0.5)
    with pytest.raises(ValueError, match="penalty_gate"):
        run_record.check_run_info(tmp_path, gated, list(SEEDS))
    del saved["config"]["num_envs"]  # TINY's is not PPOConfig's default: refused
    (tmp_path / "run.json").write_text(json.dumps(saved))
    assert TINY.num_envs != PPOConfig.num_envs
    with pytest.raises(ValueError, match="num_envs"):
        run_record.check_run_info(tmp_path, TINY, list(SEEDS))


def test_the_saved_configuration_reads_back_as_it_was_run(tmp_path):
    sweep = {"lr": [1e-4, 3e-4]}
    run_record.write_run_info(tmp_path, TINY, list(SEEDS), sweep=sweep)
    info = run_record.read_run_info(tmp_path)
    assert info == run_record.run_info(TINY, list(SEEDS), sweep=sweep)
    assert run_record.saved_config(info) == dataclasses.replace(TINY, seed=PPOConfig.seed)
    with pytest.raises(ValueError, match="no run.json"):
        run_record.read_run_info(tmp_path / "elsewhere")
    (tmp_path / "run.json").write_text("{")
    with pytest.raises(ValueError, match="damaged"):
        run_record.read_run_info(tmp_path)
    with pytest.raises(checkpoint.ResumeError, match="damaged"):
        run_record.check_run_info(tmp_path, TINY, list(SEEDS))


def test_a_run_is_finished_where_the_digests_list_its_last_chunk(tmp_path):
    assert TINY.num_chunks == 2
    assert not checkpoint.finished(tmp_path, TINY)  # no digests
    digests = tmp_path / checkpoint.DIGESTS
    digests.write_text(json.dumps({"1": {}}))
    assert not checkpoint.finished(tmp_path, TINY)
    digests.write_text(json.dumps({"1": {}, "2": {}}))
    assert checkpoint.finished(tmp_path, TINY)


def test_a_run_saved_under_a_renamed_setting_reads_under_its_new_name(tmp_path):
    """``run.json`` written when ``cost_limit`` was named ``cost_target`` (config and sweep):
    it resumes with the same value, refuses another, and reads back under the new name."""
    limited = dataclasses.replace(TINY, cost_limit=0.25)
    sweep = {"cost_limit": [0.1, 0.2]}
    run_record.write_run_info(tmp_path, limited, list(SEEDS), sweep=sweep)
    saved = json.loads((tmp_path / "run.json").read_text())
    saved["config"]["cost_target"] = saved["config"].pop("cost_limit")
    saved["sweep"] = {"cost_target": saved["sweep"]["cost_limit"]}
    (tmp_path / "run.json").write_text(json.dumps(saved))
    run_record.check_run_info(tmp_path, limited, list(SEEDS), sweep=sweep)
    with pytest.raises(ValueError, match="cost_limit"):
        run_record.check_run_info(tmp_path, TINY, list(SEEDS), sweep=sweep)
    info = run_record.read_run_info(tmp_path)
    assert info["sweep"] == sweep and "cost_target" not in info["config"]
    assert run_record.saved_config(info).cost_limit == 0.25
    assert check_sweep({"cost_target": (0.1, 0.2)}) == {"cost_limit": (0.1, 0.2)}
