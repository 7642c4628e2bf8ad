"""``agents.runner.run`` never resumes from records it cannot verify: each checkpoint's
records (``metrics.jsonl``) are digested in ``checkpoints.json``. An edited record makes
the run redo the chunks after the newest checkpoint whose records still match (the result
equals the undamaged run's, bit for bit), or refuse by name when none matches; digests
written without records' (an older run directory) never verify records. A checkpoint that
cannot be saved stops the run with a ``CheckpointError`` naming the kept one.

The runs use a configuration of their own: ``tests/agents/test_runner.py`` counts the
compilations of its first run of ``TINY``.
"""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import orbax.checkpoint as ocp
import pytest
from helpers.agents_cases import SEEDS, TINY, leaves

from agents import checkpoint
from agents.checkpoint import CheckpointError, ResumeError
from agents.runner import load_agents, run

CONFIG = dataclasses.replace(TINY, ent_coef=0.013)  # two chunks, checkpointed after each


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """An undamaged finished run: its directory and result."""
    out = tmp_path_factory.mktemp("finished")
    return out, run(CONFIG, seeds=SEEDS, out_dir=out, progress=False)


@pytest.fixture
def copy(finished, tmp_path):
    """A copy of the finished run's directory, to damage."""
    return shutil.copytree(finished[0], tmp_path / "run")


def edit(out, chunk: int) -> None:
    """Change two numbers of seed 0's record of ``chunk``, keeping the line valid JSON."""
    path = out / "metrics.jsonl"
    records = [json.loads(line) for line in path.read_text().splitlines()]
    (r,) = [r for r in records if r["seed"] == 0 and r["chunk"] == chunk]
    r["eval/success_rate"] += 0.25
    r["loss"] *= 2
    path.write_text("".join(json.dumps(r) + "\n" for r in records))


def assert_same_run(result, reference) -> None:
    assert result["complete"]
    assert result["records"] == reference["records"]
    for a, b in zip(leaves(result["runner"]), leaves(reference["runner"]), strict=True):
        np.testing.assert_array_equal(a, b)


def test_each_checkpoint_records_the_digest_of_its_records(finished):
    out, result = finished
    digests = json.loads((out / "checkpoints.json").read_text())
    assert sorted(digests) == ["1", "2"]
    for step, entry in digests.items():
        held = [r for r in result["records"] if r["chunk"] < int(step)]
        assert len(held) == len(SEEDS) * int(step)
        assert entry["records"] == checkpoint.records_sha256(held)
        assert set(entry["files"]) and all(len(v) == 64 for v in entry["files"].values())


def test_an_edited_record_of_the_last_chunk_is_redone_from_the_checkpoint_before(
    finished, copy, capsys
):
    _, reference = finished
    edit(copy, chunk=1)
    resumed = run(CONFIG, seeds=SEEDS, out_dir=copy, progress=False)
    err = capsys.readouterr().err
    assert f"{copy / 'checkpoints' / '2'}: {copy / 'metrics.jsonl'}: the records" in err
    assert "deleted, resuming from an older one" in err
    assert_same_run(resumed, reference)
    assert (copy / "metrics.jsonl").read_text() == (finished[0] / "metrics.jsonl").read_text()


def test_an_edited_record_that_every_checkpoint_holds_is_refused_by_name(finished, copy):
    _, reference = finished
    edit(copy, chunk=0)
    with pytest.raises(ResumeError, match="metrics.jsonl") as e:
        run(CONFIG, seeds=SEEDS, out_dir=copy, progress=False)
    assert "resume=False" in str(e.value)
    assert_same_run(run(CONFIG, seeds=SEEDS, out_dir=copy, progress=False, resume=False),
                    reference)  # fmt: skip


def test_digests_without_records_verify_files_but_never_records(finished, copy):
    """``checkpoints.json`` as written before records were digested ({step: {file: sha}}):
    the agents still load (their files verify), but no resume uses the unverified log."""
    _, reference = finished
    path = copy / "checkpoints.json"
    path.write_text(json.dumps({k: v["files"] for k, v in json.loads(path.read_text()).items()}))
    agents = load_agents(copy)
    assert agents["chunks"] == CONFIG.num_chunks
    for a, b in zip(leaves(agents["params"]), leaves(reference["params"]), strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ResumeError, match="no digest of its records"):
        run(CONFIG, seeds=SEEDS, out_dir=copy, progress=False)


def test_a_checkpoint_that_cannot_be_saved_stops_the_run_by_name(finished, tmp_path,
                                                                 monkeypatch):  # fmt: skip
    _, reference = finished
    out = tmp_path / "run"
    run(CONFIG, seeds=SEEDS, out_dir=out, progress=False, max_chunks=1)
    # orbax raises while writing checkpoint 2 (a leaf it cannot write)
    monkeypatch.setattr(checkpoint, "save_args",
                        lambda state: ocp.args.StandardSave({"x": object()}))  # fmt: skip
    with pytest.raises(CheckpointError) as e:
        run(CONFIG, seeds=SEEDS, out_dir=out, progress=False)
    assert isinstance(e.value, OSError)
    assert f"checkpoint 2 could not be saved in {out / 'checkpoints'}" in str(e.value)
    assert f"the last good checkpoint (chunk 1) is kept in {out / 'checkpoints'}" in str(e.value)
    monkeypatch.undo()
    assert_same_run(run(CONFIG, seeds=SEEDS, out_dir=out, progress=False), reference)
