"""The SQLite run store: rows, resumability, atomicity, parallel writers."""

from __future__ import annotations

import math
import multiprocessing as mp
import sqlite3
from types import SimpleNamespace

import pytest

from sssbench.store.tracking import PassStats, RunRecord, RunStore, config_hash, utc_now


def _run(i: int = 0, status: str = "ok", **kw) -> RunRecord:
    cfg = {
        "scene": "sphere",
        "method": "preintegrated",
        "profile": "skin_jg10",
        "sampling": "importance",
        "samples": 7 + i,
    }
    passes = [
        PassStats("preintegrated.x", 7, 100, 1.0, 0.9, 1.2, 3),
        PassStats("preintegrated.y", 7, 100, 2.0, 1.9, 2.2, 3),
    ]
    return RunRecord(
        config=cfg,
        status=status,
        metrics={"rmse": 0.1 * (i + 1), "psnr": math.inf},
        passes=passes,
        time_ms=3.0,
        **kw,
    )


def test_config_hash_ignores_key_order():
    assert config_hash({"a": 1, "b": [1, 2]}) == config_hash({"b": [1, 2], "a": 1})
    assert config_hash({"a": 1}) != config_hash({"a": 2})
    with pytest.raises(TypeError, match="config must be a dict"):
        config_hash([1])


def test_record_and_read_back(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    rid = store.record(_run(0, run_dir="/x", info={"threads": 2}))
    rows = store.runs()
    assert len(rows) == 1 and rows[0]["id"] == rid
    r = rows[0]
    assert r["status"] == "ok" and r["scene"] == "sphere" and r["samples"] == 7
    assert r["rmse"] == pytest.approx(0.1) and r["psnr"] == math.inf
    assert r["metrics"]["rmse"] == pytest.approx(0.1) and r["info"] == {"threads": 2}
    assert r["passes"] == 2 and r["time_ms"] == 3.0
    passes = store.passes([rid])
    assert [p["name"] for p in passes] == ["preintegrated.x", "preintegrated.y"]
    assert passes[1]["ms_median"] == 2.0 and passes[1]["repeats"] == 3
    with sqlite3.connect(tmp_path / "s.sqlite") as conn:
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_is_done_only_for_ok(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    store.record(_run(0, status="failed", error="boom"))
    h = config_hash(_run(0).config)
    assert not store.is_done(h)
    store.record(_run(0))
    assert store.is_done(h)
    assert not store.is_done(config_hash(_run(1).config))


def test_latest_per_config(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    store.record(_run(0, status="failed", error="boom"))
    store.record(_run(0))
    store.record(_run(1, status="timeout", error="time limit"))
    assert len(store.runs()) == 3
    latest = store.runs(latest=True)
    assert [r["status"] for r in latest] == ["ok", "timeout"]
    assert [r["status"] for r in store.runs(latest=True, status="ok")] == ["ok"]


def test_failures_since(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    store.record(_run(0, status="failed", error="old", sweep_dir="/sweep"))
    since = utc_now()
    store.record(_run(1, status="failed", error="new", sweep_dir="/sweep"))
    store.record(_run(2, status="failed", error="other", sweep_dir="/other"))
    store.record(_run(3, sweep_dir="/sweep"))
    assert [f["error"] for f in store.failures_since(since, "/sweep")] == ["new"]
    assert len(store.failures_since(since)) == 2


def test_bad_status_and_types(tmp_path):
    with pytest.raises(ValueError, match="status must be one of"):
        RunRecord(config={}, status="done")
    store = RunStore(tmp_path / "s.sqlite")
    with pytest.raises(TypeError, match="run must be a RunRecord"):
        store.record({"status": "ok"})
    with pytest.raises(ValueError, match="journal_mode"):
        RunStore(tmp_path / "t.sqlite", journal_mode="memory")


def test_failed_write_leaves_no_partial_row(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    bad = _run(0)
    # the second pass is broken: the run row is inserted, then writing the passes raises
    bad.passes = [bad.passes[0], SimpleNamespace(name="broken", samples=1, pixels=1)]
    with pytest.raises(AttributeError):
        store.record(bad)
    assert len(store) == 0 and store.passes() == []
    store.record(_run(0))
    assert len(store) == 1


def _writer(args):
    path, worker, n = args
    store = RunStore(path, timeout_s=5.0)
    for i in range(n):
        store.record(_run(worker * 1000 + i))
    return n


def test_parallel_writers(tmp_path):
    path = str(tmp_path / "s.sqlite")
    RunStore(path)
    with mp.get_context("fork").Pool(4) as pool:
        done = pool.map(_writer, [(path, w, 15) for w in range(4)])
    assert sum(done) == 60
    store = RunStore(path)
    assert len(store) == 60
    assert len(store.passes()) == 120
    assert len({r["config"]["samples"] for r in store.runs()}) == 60
