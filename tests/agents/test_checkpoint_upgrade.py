"""A run directory saved by earlier code, in an older state layout, resumes and goes on as
that code went on.

``tests/fixtures/run_dirs/two_rooms_before/`` holds the first of two chunks of a TwoRooms run
with its checkpoint, saved before the paper scenarios' constraint and monitor moved into
``ConstrainedExtras`` (made by ``tests/fixtures/run_dirs/make_two_rooms_before.py``);
``two_rooms_before_continued.jsonl`` holds both chunks' records of that code's
uninterrupted run. Today's code reads the checkpoint through the scenario's
``upgrade_extras`` and must log the second chunk as the old code did: the same counts,
and floats equal to float32 rounding (XLA:CPU's last bits depend on the processor).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from agents import checkpoint, run_record
from agents.runner import run

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "run_dirs"
BEFORE = FIXTURES / "two_rooms_before"


def _records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


@pytest.fixture
def old_run(tmp_path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(BEFORE, out)
    return out


def test_a_checkpoint_of_the_older_layout_resumes_as_the_old_code_went_on(old_run, capfd):
    info = run_record.read_run_info(old_run)
    config = run_record.saved_config(info)
    assert checkpoint.resume_point(checkpoint.make_manager(old_run / "checkpoints"), old_run,
                                   [(s,) for s in info["seeds"]], lambda r: (r["seed"],)
                                   )[0] == 1  # fmt: skip
    run(config, seeds=info["seeds"], out_dir=old_run, progress=False)
    assert "older layout" in capfd.readouterr().err
    got = _records(old_run / "metrics.jsonl")
    want = _records(FIXTURES / "two_rooms_before_continued.jsonl")
    assert [(r["seed"], r["chunk"]) for r in got] == [(r["seed"], r["chunk"]) for r in want]
    assert want[-1]["train/episodes"] > 0 and want[0]["train/violations"] > 0
    for g, w in zip(got, want, strict=True):
        for name, value in w.items():  # the old records' fields (today's log has more)
            if isinstance(value, float):
                np.testing.assert_allclose(g[name], value, rtol=1e-5, atol=1e-7, err_msg=name)
            else:
                assert g[name] == value, name


def test_a_damaged_older_checkpoint_is_refused_by_name(old_run):
    """An older layout that the upgrade cannot place (a constraint of no row of the table)
    is a ResumeError naming the checkpoint, not a silent fresh start."""
    info = run_record.read_run_info(old_run)
    config = run_record.saved_config(info)
    other = dataclasses.replace(config, env_kwargs={"split": "heldout"})
    run_record.write_run_info(old_run, other, info["seeds"])
    with pytest.raises(checkpoint.ResumeError, match="older layout"):
        run(other, seeds=info["seeds"], out_dir=old_run, progress=False)
