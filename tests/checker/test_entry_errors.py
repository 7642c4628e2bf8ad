"""The commands ``python -m checker`` and ``python -m checker.memory``: a user's mistake is
one line naming the flag and exit status 2 before anything compiles; ``checker.memory --out``
is locked and refused unless new, empty or (with ``--overwrite``) a checker directory, as
``python -m checker``'s; Ctrl-C ends ``checker.memory`` with status 130, without a traceback.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time

import pytest
from helpers.cli_help import exit_code, fake_checker, help_entries, squeezed, stderr_text

from checker import __main__ as checker_main
from checker import memory as MC
from checker.store import CHECKER_FILES, check_vocab
from jaxgrid import rundir


def fake_checker_here(directory, **meta) -> str:
    return fake_checker(directory, env_id="TwoRooms-v0", **meta)


# ---------------------------------------------------------------------- python -m checker
@pytest.mark.parametrize(
    ("env", "instead"),
    [("HazardRooms-v0", "python -m checker --kind memory"),
     ("MiniGrid-DoorKey-8x8-v0", "MiniGrid-DoorKey-8x8-v0 has no constraint")],
)  # fmt: skip
def test_checker_refuses_an_env_without_the_scenarios_constraint(env, instead, tmp_path, capsys,
                                                                 compiles):  # fmt: skip
    out = tmp_path / "ck"
    assert exit_code(checker_main.main, ["--out", str(out), "--env", env]) == 2
    err = stderr_text(capsys)
    assert f"--env {env}: python -m checker needs one of the paper's scenarios" in err
    assert "ThreeRoomsKey-v0, TwoRooms-v0, TwoRoomsLava-v0" in err and instead in err
    assert not out.exists() and not compiles


@pytest.mark.parametrize(
    ("flags", "message"),
    [(["--samples", "inf"], "'inf' is not an integer"),
     (["--samples", "1e400"], "'1e400' is not an integer"),
     (["--seed", "1e20"], "'1e20' is out of range"),
     (["--num-envs", str(2**31)], "is out of range")],
)  # fmt: skip
def test_checker_refuses_integers_out_of_range(flags, message, tmp_path, capsys, compiles):
    out = tmp_path / "ck"
    assert exit_code(checker_main.main, ["--out", str(out), *flags]) == 2
    assert message in stderr_text(capsys)
    assert not out.exists() and not compiles


def test_checker_help_says_an_empty_out_is_accepted(capsys):
    assert exit_code(checker_main.main, ["--help"]) == 0
    text = help_entries(capsys.readouterr().out)["--out"]
    assert "new, empty, or (with --overwrite) an earlier checker's" in text, text


def test_a_checker_config_without_vocabulary_is_named_not_none():
    with pytest.raises(ValueError) as e:
        check_vocab({"config": {}}, "checker DIR")
    assert "checker DIR: its config.json records no constraint vocabulary" in str(e.value)
    assert "None" not in str(e.value)


# --------------------------------------------------------------- python -m checker.memory
def test_memory_help_lists_every_flag_with_its_default(capsys):
    assert exit_code(MC.main, ["--help"]) == 0
    entries = help_entries(capsys.readouterr().out)
    flags = {
        "--envs",
        "--steps",
        "--updates",
        "--batch-streams",
        "--guided",
        "--lookahead",
        "--seed",
        "--late",
        "--memory",
        "--actions",
        "--json",
        "--out",
        "--overwrite",
        "--kind",
    }
    assert flags <= set(entries), sorted(entries)
    missing = [f for f, text in entries.items() if f != "--help" and "(default:" not in text]
    assert not missing, missing
    assert "(default:512)" in squeezed(entries["--envs"])


@pytest.mark.parametrize(
    ("flags", "message"),
    [(["--seed", "1e20"], "'1e20' is out of range"),
     (["--envs", "inf"], "'inf' is not an integer"),
     (["--steps", "1e400"], "'1e400' is not an integer"),
     (["--updates", str(2**31)], "is out of range")],
)  # fmt: skip
def test_memory_refuses_integers_out_of_range(flags, message, tmp_path, capsys, compiles):
    out = tmp_path / "m"
    assert exit_code(MC.main, ["--out", str(out), *flags]) == 2
    assert message in stderr_text(capsys)
    assert not out.exists() and not compiles


def test_memory_refuses_a_checker_directory_unless_overwrite(tmp_path, monkeypatch, compiles):
    """A window checker's directory with its report: refused as it is; with --overwrite, its
    files are gone before any work, so no old report is left beside the new parameters."""
    out = tmp_path / "ck"
    fake_checker_here(out, lookahead=1)
    (out / "report.json").write_text("{}")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    monkeypatch.setattr(checker_main, "run_memory", lambda **kw: pytest.fail("work started"))
    with pytest.raises(ValueError, match="not empty.*--overwrite"):
        MC.main(["--out", str(out)])
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    (out / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="holds files no checker command writes.*notes.txt"):
        MC.main(["--out", str(out), "--overwrite"])
    assert (out / "notes.txt").read_text() == "mine" and (out / "report.json").exists()
    (out / "notes.txt").unlink()
    seen = {}

    def run(**kw):  # what a run finds in --out when it starts
        seen.update(files=sorted(os.listdir(out)), out=kw["out"])
        return {"train": {}, "heldout": {}}

    monkeypatch.setattr(checker_main, "run_memory", run)
    MC.main(["--out", str(out), "--overwrite"])
    assert seen == {"files": [rundir.LOCK_FILE], "out": str(out)}
    assert not out.joinpath(rundir.LOCK_FILE).exists() and not compiles
    assert set(CHECKER_FILES) >= {"params.msgpack", "config.json", "metrics.json", "report.json"}


def test_memory_checks_out_and_json_before_any_work(tmp_path, monkeypatch, capsys, compiles):
    monkeypatch.setattr(checker_main, "run_memory", lambda **kw: pytest.fail("work started"))
    a_file = tmp_path / "a-file"
    a_file.write_text("keep")
    with pytest.raises(ValueError, match="not writable"):
        MC.main(["--out", str(a_file / "sub")])
    for flags, message in (
        (["--out", str(a_file)], "--out"),
        (["--json", str(tmp_path)], "is a directory, not a file"),
        (["--json", str(a_file / "r.json")], "is a file, not a directory"),
    ):
        assert exit_code(MC.main, flags) == 2
        assert message in stderr_text(capsys)
    with rundir.lock(tmp_path / "held", "holder-under-test"):
        with pytest.raises(rundir.LockHeld, match="holder-under-test"):
            MC.main(["--out", str(tmp_path / "held")])
    assert a_file.read_text() == "keep" and not compiles


def test_ctrl_c_ends_checker_memory_at_once_without_a_traceback(tmp_path):
    """SIGINT while it collects and compiles: exit status 130 within 10 s, the lock released."""
    out = tmp_path / "m"
    argv = [sys.executable, "-m", "checker.memory", "--envs", "2", "--steps", "8",
            "--updates", "2", "--batch-streams", "1", "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lines: queue.Queue = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(line) for line in proc.stderr])
    reader.start()
    try:
        started = lines.get(timeout=120)  # its first line says the work has begun
        assert "python -m checker.memory: 2 streams x 8 frames" in started, started
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        t0 = time.monotonic()
        proc.wait(timeout=10)
        wall = time.monotonic() - t0
    finally:
        proc.kill()
        reader.join(timeout=10)
    err = "".join(lines.queue)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "interrupted" in err
    assert wall < 10 and not (out / rundir.LOCK_FILE).exists()
