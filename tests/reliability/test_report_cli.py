"""``sssbench-report`` on anything that is not a run store or a sweep directory: one line on
stderr naming the path and what was expected, a non-zero exit, and nothing written into a
file that is not a store."""

from __future__ import annotations

import json
import sqlite3

import pytest

from sssbench import report
from sssbench.store.tracking import RunRecord, RunStore


def _foreign_sqlite(path):
    with sqlite3.connect(path) as conn:
        conn.execute("CREATE TABLE x (a)")
    return path


def _tables(path) -> list[str]:
    with sqlite3.connect(path) as conn:
        return sorted(r[0] for r in conn.execute("SELECT name FROM sqlite_master"))


def _sweep_with(tmp_path, text: str):
    job = tmp_path / "sweep" / "0"
    job.mkdir(parents=True)
    (job / "point.json").write_text(text)
    return tmp_path / "sweep"


CASES = {
    "text_file": (
        lambda p: (p / "notes.txt").write_text("hello\n") and p / "notes.txt",
        "notes.txt",
    ),
    "binary_file": (
        lambda p: (p / "b.dat").write_bytes(bytes(range(256))) and p / "b.dat",
        "b.dat",
    ),
    "empty_file": (lambda p: (p / "e.sqlite").write_bytes(b"") == 0 and p / "e.sqlite", "e.sqlite"),
    "foreign_sqlite": (lambda p: _foreign_sqlite(p / "other.sqlite"), "other.sqlite"),
    "missing_path": (lambda p: p / "missing.sqlite", "missing.sqlite"),
    "malformed_point_json": (lambda p: _sweep_with(p, "{not json"), "point.json"),
    "point_json_not_a_point": (lambda p: _sweep_with(p, json.dumps({"a": 1})), "point.json"),
    "point_json_a_list": (lambda p: _sweep_with(p, "[1, 2]"), "point.json"),
    "empty_dir": (lambda p: (p / "d").mkdir() or p / "d", "d"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_not_a_store_is_one_line_and_non_zero(tmp_path, capsys, case):
    make, fragment = CASES[case]
    source = make(tmp_path)
    before = source.read_bytes() if source.is_file() else None
    code = report.main([str(source), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("sssbench-report: ") and fragment in lines[0]
    assert "expected" in lines[0]
    if before is not None:  # never turned into a store
        assert source.read_bytes() == before


def test_point_json_naming_a_non_store(tmp_path, capsys):
    other = _foreign_sqlite(tmp_path / "other.sqlite")
    sweep = _sweep_with(tmp_path, json.dumps({"config_hash": "abc", "store": str(other)}))
    assert report.main([str(sweep), "--out", str(tmp_path / "out")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "other.sqlite" in err[0] and "expected" in err[0]
    assert _tables(other) == ["x"]


def test_a_real_store_still_reports(tmp_path, capsys):
    store = RunStore(tmp_path / "s.sqlite")
    store.record(RunRecord(config={"scene": "s", "method": "m"}, status="failed", error="x"))
    assert report.main([str(store.path), "--out", str(tmp_path / "out")]) == 0
    assert capsys.readouterr().err == ""
