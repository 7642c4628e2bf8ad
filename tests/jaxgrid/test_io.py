"""jaxgrid.io: atomic writes, JSON and JSON-lines round trips, damaged-file errors."""

import os
import subprocess
import sys

import numpy as np
import pytest

from jaxgrid import io


def test_atomic_write_replaces_whole_file_and_leaves_no_temporaries(tmp_path):
    path = tmp_path / "sub" / "f.txt"
    assert io.atomic_write(path, "first\n") == path
    io.atomic_write(path, b"second")
    assert path.read_bytes() == b"second"
    assert sorted(os.listdir(path.parent)) == ["f.txt"]


def test_atomic_write_keeps_old_file_when_data_is_bad(tmp_path):
    path = tmp_path / "f.txt"
    io.atomic_write(path, "old")
    with pytest.raises(TypeError, match="f.txt"):
        io.atomic_write(path, 3)
    assert path.read_text() == "old"
    assert os.listdir(tmp_path) == ["f.txt"]


def test_atomic_write_respects_umask(tmp_path):
    old = os.umask(0o022)
    try:
        path = io.atomic_write(tmp_path / "f", "x")
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o644


def test_write_json_converts_numpy_and_jax_values(tmp_path):
    import jax.numpy as jnp

    obj = {
        "a": np.float32(0.5),
        "b": np.arange(3, dtype=np.int32),
        "c": jnp.array([[1.0, 2.0]]),
        "d": jnp.int32(7),
        "e": (np.bool_(True), None, "s"),
        "f": float("nan"),
        "g": tmp_path,
        3: [np.inf],
    }
    path = io.write_json(tmp_path / "x.json", obj)
    text = path.read_text()
    assert text.endswith("}\n") and text.startswith('{\n  "a"')
    back = io.read_json(path)
    assert back == {
        "a": 0.5,
        "b": [0, 1, 2],
        "c": [[1.0, 2.0]],
        "d": 7,
        "e": [True, None, "s"],
        "f": None,
        "g": str(tmp_path),
        "3": [None],
    }
    assert type(back["d"]) is int and type(back["e"][0]) is bool


def test_write_json_names_the_unconvertible_field(tmp_path):
    path = tmp_path / "x.json"
    with pytest.raises(TypeError, match=r"x\.json: value\.config\.fn: cannot write builtin"):
        io.write_json(path, {"config": {"fn": print}})
    assert not path.exists()


def test_read_json_names_a_truncated_file(tmp_path):
    path = io.write_json(tmp_path / "x.json", {"a": [1, 2, 3]})
    path.write_bytes(path.read_bytes()[:-6])
    with pytest.raises(ValueError, match="x.json: damaged or truncated JSON"):
        io.read_json(path)
    with pytest.raises(FileNotFoundError):
        io.read_json(tmp_path / "missing.json")


def test_jsonl_round_trip_and_append(tmp_path):
    path = tmp_path / "r.jsonl"
    io.write_jsonl(path, [{"chunk": 0, "v": np.float64(1.5)}, {"chunk": 1}])
    assert path.read_text() == '{"chunk": 0, "v": 1.5}\n{"chunk": 1}\n'
    io.append_jsonl(path, [{"chunk": 2}])
    assert io.read_jsonl(path) == [{"chunk": 0, "v": 1.5}, {"chunk": 1}, {"chunk": 2}]
    io.append_jsonl(tmp_path / "new" / "n.jsonl", [[1, 2]])
    assert io.read_jsonl(tmp_path / "new" / "n.jsonl") == [[1, 2]]


def test_read_jsonl_drops_torn_last_line_and_append_cuts_it_off(tmp_path):
    path = tmp_path / "r.jsonl"
    path.write_text('{"chunk": 0}\n{"chunk": 1}\n{"chu')
    assert io.read_jsonl(path) == [{"chunk": 0}, {"chunk": 1}]
    io.append_jsonl(path, [{"chunk": 2}])
    assert path.read_text() == '{"chunk": 0}\n{"chunk": 1}\n{"chunk": 2}\n'
    path.write_bytes(b'{"chunk": 0}\n{"a": "\xc3')  # torn inside a UTF-8 character
    assert io.read_jsonl(path) == [{"chunk": 0}]


def test_read_jsonl_keeps_a_complete_last_line_without_newline(tmp_path):
    path = tmp_path / "r.jsonl"
    path.write_text('{"chunk": 0}\n\n{"chunk": 1}')
    assert io.read_jsonl(path) == [{"chunk": 0}, {"chunk": 1}]


def test_read_jsonl_names_a_damaged_middle_line(tmp_path):
    path = tmp_path / "r.jsonl"
    path.write_text('{"chunk": 0}\n{"chu\n{"chunk": 2}\n')
    with pytest.raises(ValueError, match=r"r\.jsonl, line 2: damaged JSON record"):
        io.read_jsonl(path)
    path.write_text('{"chunk": 0}\n{"chu\n')  # ends in a newline: not torn, damaged
    with pytest.raises(ValueError, match="line 2"):
        io.read_jsonl(path)


def test_append_jsonl_converts_everything_before_writing(tmp_path):
    path = io.write_jsonl(tmp_path / "r.jsonl", [{"chunk": 0}])
    with pytest.raises(TypeError, match=r"r\.jsonl: appended record 1\.x: cannot write object"):
        io.append_jsonl(path, [{"chunk": 1}, {"x": object()}])
    assert io.read_jsonl(path) == [{"chunk": 0}]


def test_module_itself_does_not_import_jax():
    # Loaded on its own (jaxgrid/__init__ imports jax): the module needs only numpy.
    code = (
        "import importlib.util as u, pathlib, sys\n"
        "d = pathlib.Path(u.find_spec('jaxgrid').origin).parent\n"
        "spec = u.spec_from_file_location('io_alone', d / 'io.py')\n"
        "m = u.module_from_spec(spec); spec.loader.exec_module(m)\n"
        "print('jax' in sys.modules, m.to_jsonable({'a': (1,)}))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "{'a':", "[1]}"]


# ---------------------------------------------------------------- jaxgrid.rundir
def test_sha256_file_matches_the_bytes_and_changes_with_one_flipped_bit(tmp_path):
    from jaxgrid import rundir

    path = tmp_path / "p.bin"
    path.write_bytes(b"parameters" * 1000)
    digest = rundir.sha256_file(path)
    assert digest == rundir.sha256_bytes(b"parameters" * 1000)
    data = bytearray(path.read_bytes())
    data[5000] ^= 1
    path.write_bytes(bytes(data))
    assert rundir.sha256_file(path) != digest


def test_lock_is_exclusive_names_its_holder_and_is_released(tmp_path):
    import os
    import socket

    from jaxgrid import rundir

    with rundir.lock(tmp_path / "run", "first") as held:
        assert held.path.is_file()
        with pytest.raises(rundir.LockHeld) as e:
            rundir.lock(tmp_path / "run", "second")
        assert f"pid {os.getpid()} on {socket.gethostname()}" in str(e.value)
        assert "first" in str(e.value) and str(held.path) in str(e.value)
    assert not (tmp_path / "run" / rundir.LOCK_FILE).exists()
    with pytest.raises(KeyError):  # released on an exception too
        with rundir.lock(tmp_path / "run"):
            raise KeyError("boom")
    rundir.lock(tmp_path / "run").release()


def test_lock_of_a_dead_process_is_taken_over_with_a_message(tmp_path, capsys):
    import json
    import socket

    from jaxgrid import rundir

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    pid = int(dead.stdout)
    (tmp_path / rundir.LOCK_FILE).write_text(json.dumps({"pid": pid, "host": socket.gethostname()}))
    with rundir.lock(tmp_path):
        assert "no longer runs" in capsys.readouterr().err
    # Another host's lock is never taken over: its pid cannot be checked from here.
    (tmp_path / rundir.LOCK_FILE).write_text(json.dumps({"pid": pid, "host": "elsewhere"}))
    with pytest.raises(rundir.LockHeld, match="elsewhere"):
        rundir.lock(tmp_path)


def test_lock_refuses_a_file_as_directory(tmp_path):
    from jaxgrid import rundir

    (tmp_path / "f").write_text("x")
    with pytest.raises(ValueError, match="is a file"):
        rundir.lock(tmp_path / "f")


def test_lock_is_released_on_ctrl_c(tmp_path):
    from jaxgrid import rundir

    with pytest.raises(KeyboardInterrupt):
        with rundir.lock(tmp_path):
            raise KeyboardInterrupt
    assert not (tmp_path / rundir.LOCK_FILE).exists()


def test_check_free_refuses_a_held_lock_and_writes_nothing(tmp_path):
    from jaxgrid import rundir

    rundir.check_free(tmp_path / "missing")
    assert not (tmp_path / "missing").exists()
    with rundir.lock(tmp_path / "run", "holder"):
        with pytest.raises(rundir.LockHeld, match="holder"):
            rundir.check_free(tmp_path / "run")
    rundir.check_free(tmp_path / "run")


def test_out_flag_reads_both_spellings_the_last_one_winning():
    from jaxgrid import rundir

    assert rundir.out_flag(["--seed", "1"]) is None
    assert rundir.out_flag(["--out", "a", "--x"]) == "a"
    assert rundir.out_flag(["--out=a", "--out", "b"]) == "b"
    assert rundir.out_flag(["--out", "b", "--out=a"]) == "a"
    assert rundir.out_flag(["--out"]) is None  # argparse reports the missing value


def test_refuse_held_out_exits_2_naming_the_holder(tmp_path, capsys):
    from jaxgrid import rundir

    rundir.refuse_held_out(["--out", str(tmp_path / "run")])  # free: nothing happens
    with rundir.lock(tmp_path / "run", "holder-under-test"):
        with pytest.raises(SystemExit) as e:
            rundir.refuse_held_out([f"--out={tmp_path / 'run'}"])
    assert e.value.code == 2 and "holder-under-test" in capsys.readouterr().err


def test_holds_declared_default_reads_nested_fields_and_their_classes():
    import dataclasses

    @dataclasses.dataclass(frozen=True)
    class Inner:
        lr: float = 1e-3
        sizes: tuple = (16,)
        name: str = dataclasses.field(default_factory=lambda: "adam")

    @dataclasses.dataclass(frozen=True)
    class Outer:
        required: int
        inner: Inner = Inner(lr=5e-4)  # a preset: the class default is Inner's own

    cfg = Outer(required=3)
    assert io.holds_declared_default(cfg, "inner.sizes")
    assert io.holds_declared_default(cfg, "inner.name")
    assert not io.holds_declared_default(cfg, "inner.lr")  # 5e-4, not Inner's 1e-3
    assert not io.holds_declared_default(cfg, "required")  # no default declared
    assert not io.holds_declared_default(cfg, "inner.missing")
    assert not io.holds_declared_default(cfg, "nothing.lr")
    assert not io.holds_declared_default(Outer(3, Inner(sizes=[32])), "inner.sizes")
