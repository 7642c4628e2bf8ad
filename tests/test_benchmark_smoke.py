"""Smoke test of the env-throughput benchmark harness at tiny sizes (N=2, T=8)."""

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
