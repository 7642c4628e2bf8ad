"""benchmarks.env_throughput at tiny sizes (N=2, T=8): measurements, table, CLI."""

import json

import pytest

from benchmarks import env_throughput as bench


def _check(result: dict, lib: str) -> None:
    assert result["lib"] == lib
    assert result["num_envs"] == 2 and result["steps"] == 8
    assert len(result["times_s"]) == 2
    assert result["steps_per_s"] > 0 and result["steps_per_s_median"] > 0
    assert result["steps_per_s"] >= result["steps_per_s_median"]  # best is best
    assert result["compile_s"] is not None and result["compile_s"] > 0
    json.dumps(result)  # the report must be JSON-serialisable


def test_measure_jaxgrid_tiny():
    _check(bench.measure("jaxgrid", num_envs=2, steps=8, repeats=2), "jaxgrid")


@pytest.mark.slow  # each peer compiles for ~10 s on 2 cores; keeps the default run < 20 s
@pytest.mark.parametrize("lib", ["navix", "xminigrid"])
def test_measure_peer_tiny(lib):
    pytest.importorskip(lib)
    _check(bench.measure(lib, num_envs=2, steps=8, repeats=2), lib)


def test_table_and_ratio_with_skipped_lib():
    fake = [
        {"lib": "jaxgrid", "num_envs": 1, "steps_per_s": 300.0, "compile_s": 1.0},
        {"lib": "navix", "num_envs": 1, "steps_per_s": 100.0, "compile_s": 1.0},
        {"lib": "xminigrid", "num_envs": 1, "steps_per_s": 150.0, "compile_s": 1.0},
    ]
    assert bench.ratios(fake, [1]) == {1: {"vs": "xminigrid", "ratio": 2.0}}
    table = bench.format_table(
        fake, {"minigrid": "ImportError: x"}, [1], ["jaxgrid", "navix", "xminigrid", "minigrid"]
    )
    assert "skipped: ImportError: x" in table and "2.00x (vs xminigrid)" in table


def test_cli_writes_json_report(tmp_path, capsys):
    out = tmp_path / "runs" / "env.json"
    argv = ["--libs", "jaxgrid", "--num-envs", "2", "--steps", "8", "--repeats", "2",
            "--json", str(out)]  # fmt: skip
    report = bench.main(argv)
    assert json.loads(out.read_text()) == json.loads(json.dumps(report))
    (result,) = report["results"]
    _check(result, "jaxgrid")
    assert "jaxgrid" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, flag",
    [(["--repeats", "0"], "--repeats"), (["--steps", "0"], "--steps"),
     (["--num-envs", "4", "0"], "--num-envs"), (["--libs", "gym"], "--libs"),
     (["--python-steps", "-3"], "--python-steps")],
)  # fmt: skip
def test_cli_rejects_bad_flags(argv, flag, capsys):
    with pytest.raises(SystemExit) as exc:
        bench.main(argv)
    assert exc.value.code == 2
    assert flag in capsys.readouterr().err


def test_cli_help_shows_every_default(capsys):
    with pytest.raises(SystemExit):
        bench.main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    for shown in ("(default: [1, 256, 4096])", "(default: 3)", "(default: 3000)",
                  "(default: 0)", "(default: None)"):  # fmt: skip
        assert shown in text


def test_the_constrained_level_is_measured_against_the_unconstrained_one(tmp_path):
    argv = ["--libs", "jaxgrid", bench.CONSTRAINED_LIB, "--num-envs", "2", "--steps", "8",
            "--repeats", "2", "--json", str(tmp_path / "env.json")]  # fmt: skip
    report = bench.main(argv)
    ours, constrained = report["results"]
    _check(constrained, bench.CONSTRAINED_LIB)
    assert constrained["notes"]["constraint"] == bench.DEFAULT_CONSTRAINT
    ratio = ours["steps_per_s"] / constrained["steps_per_s"]
    assert report["constrained_step_time_ratio"] == {"2": ratio}
    assert report["config"]["constraint"] == bench.DEFAULT_CONSTRAINT


def test_cli_rejects_a_constraint_the_level_cannot_hold(capsys):
    with pytest.raises(SystemExit) as exc:
        bench.main(["--libs", bench.CONSTRAINED_LIB, "--constraint", "avoid lava"])
    assert exc.value.code == 2
    assert "never holds lava" in capsys.readouterr().err
