"""``experiments.provenance``: the digest names the sources, and ``code.json`` records every
code that wrote into a run directory."""

from __future__ import annotations

import shutil

from experiments import provenance
from jaxgrid.io import read_json


def test_digest_is_stable_and_changes_with_any_source(tmp_path, monkeypatch):
    first = provenance.code_identity()
    assert provenance.code_identity()["sha256"] == first["sha256"]
    assert first["versions"]["jax"]
    for package in provenance.PACKAGES:  # a copy of the sources gives the same digest
        shutil.copytree(provenance.ROOT / package, tmp_path / package,
                        ignore=shutil.ignore_patterns("__pycache__"))  # fmt: skip
    monkeypatch.setattr(provenance, "ROOT", tmp_path)
    assert provenance.code_identity()["sha256"] == first["sha256"]
    path = tmp_path / "agents" / "config.py"
    path.write_text(path.read_text() + "\n# one more line\n")
    assert provenance.code_identity()["sha256"] != first["sha256"]


def test_record_appends_a_new_code_once_and_warns(tmp_path, monkeypatch, capsys):
    entries = provenance.record(tmp_path)
    assert len(entries) == 1 and entries[0]["first_used"]
    assert provenance.record(tmp_path) == entries  # the same code: nothing added
    assert capsys.readouterr().err == ""
    other = {**entries[0], "sha256": "f" * 64}
    other.pop("first_used")
    monkeypatch.setattr(provenance, "code_identity", lambda: other)
    both = provenance.record(tmp_path)
    assert [e["sha256"] for e in both] == [entries[0]["sha256"], "f" * 64]
    assert read_json(tmp_path / "code.json") == both
    err = capsys.readouterr().err
    assert "made by other code" in err and str(tmp_path / "code.json") in err


def test_other_library_versions_count_as_other_code(tmp_path, monkeypatch):
    first = provenance.record(tmp_path)[0]
    other = {**first, "versions": {**first["versions"], "jax": "0.0.1"}}
    other.pop("first_used")
    monkeypatch.setattr(provenance, "code_identity", lambda: other)
    assert len(provenance.record(tmp_path)) == 2
