"""Provenance records and the log of a stage (dpsi.provenance.recorded)."""

import json

import pytest

from dpsi.provenance import provenance_path, recorded


def test_failing_stage_writes_its_error_to_the_log_and_leaves_no_provenance(tmp_path):
    output, log = tmp_path / "fused.npy", tmp_path / "fuse.log"
    provenance_path(output).write_text("{}")  # left by an earlier run whose output Snakemake deleted
    with pytest.raises(ValueError, match="view_3.ply: truncated"):
        with recorded([output], [], {}, log) as logger:
            logger.info("reading views")
            raise ValueError("view_3.ply: truncated")
    text = log.read_text()
    assert "reading views" in text and "FAILED: view_3.ply: truncated" in text
    assert "Traceback (most recent call last)" in text and "raise ValueError" in text
    assert not provenance_path(output).exists()


def test_successful_stage_replaces_the_provenance(tmp_path):
    output, source = tmp_path / "table.csv", tmp_path / "input.txt"
    source.write_text("x")
    provenance_path(output).write_text(json.dumps({"params": {"density": 1}}))
    with recorded([output], [source], {"density": 2}, tmp_path / "table.log"):
        output.write_text("a,b\n")
    record = json.loads(provenance_path(output).read_text())
    assert record["params"] == {"density": 2} and str(source) in record["inputs"]
    assert "FAILED" not in (tmp_path / "table.log").read_text()
