"""The run store holds at most one ``ok`` row per point (config hash), also with concurrent
sweeps writing one store and for stores written before the constraint existed."""

from __future__ import annotations

import multiprocessing as mp
import sqlite3

import pytest

from sssbench.store.tracking import PassStats, RunRecord, RunStore, config_hash

POINTS = 12


def _cfg(i: int) -> dict:
    return {"scene": "sphere", "method": "m", "profile": "p", "sampling": "uniform", "samples": i}


def _ok(i: int, rmse: float = 0.1) -> RunRecord:
    passes = [PassStats("m.x", 3, 10, 1.0, 1.0, 1.0, 1), PassStats("m.y", 3, 10, 1.0, 1.0, 1.0, 1)]
    return RunRecord(config=_cfg(i), status="ok", metrics={"rmse": rmse}, passes=passes, time_ms=2)


def _ok_rows(path) -> dict[str, int]:
    with sqlite3.connect(path) as conn:
        rows = conn.execute(
            "SELECT config_hash, COUNT(*) FROM runs WHERE status = 'ok' GROUP BY config_hash"
        ).fetchall()
    return dict(rows)


def test_database_refuses_a_second_ok_row(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    store.record(_ok(1))
    with sqlite3.connect(store.path) as conn:  # bypassing record(): the schema itself refuses
        with pytest.raises(sqlite3.IntegrityError, match="UNIQUE"):
            conn.execute(
                "INSERT INTO runs (config_hash, config_json, status, started_at, finished_at) "
                "VALUES (?, '{}', 'ok', 'a', 'b')",
                (config_hash(_cfg(1)),),
            )
        # failed / timed-out rows of the same point are history, never refused
        conn.execute(
            "INSERT INTO runs (config_hash, config_json, status, started_at, finished_at) "
            "VALUES (?, '{}', 'failed', 'a', 'b')",
            (config_hash(_cfg(1)),),
        )


def test_forced_rerun_replaces_the_ok_row_and_its_passes(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    first = store.record(_ok(1, rmse=0.5))
    second = store.record(_ok(1, rmse=0.25))
    rows = store.runs()
    assert [r["id"] for r in rows] == [second] and rows[0]["rmse"] == 0.25
    assert {p["run_id"] for p in store.passes()} == {second} and first != second


def _sweep(path: str, order: list[int], barrier, errors) -> None:
    """One sweep: each point it does not find done is run and recorded, as the app does. The
    barrier holds both sweeps between the check and the write, the race of two sweeps that
    start a point at the same time (both see it not done, both record it)."""
    try:
        store = RunStore(path, timeout_s=5.0)
        for i in order:
            todo = not store.is_done(config_hash(_cfg(i)))
            barrier.wait(timeout=60)
            if todo:
                store.record(_ok(i))
    except BaseException as exc:  # reported to the parent: the test asserts none
        errors.put(f"{type(exc).__name__}: {exc}")
        raise


def test_two_concurrent_sweeps_leave_one_ok_row_per_point(tmp_path):
    path = str(tmp_path / "s.sqlite")
    RunStore(path)
    ctx = mp.get_context("fork")
    barrier, errors = ctx.Barrier(2), ctx.Queue()
    order = list(range(POINTS))
    procs = [ctx.Process(target=_sweep, args=(path, order, barrier, errors)) for _ in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
    assert [p.exitcode for p in procs] == [0, 0], errors.get(timeout=1)
    assert _ok_rows(path) == {config_hash(_cfg(i)): 1 for i in range(POINTS)}
    # nothing lost: every stored ok run has both of its passes, no orphan pass rows
    store = RunStore(path)
    ok_ids = {r["id"] for r in store.runs(status="ok")}
    assert sorted(p["run_id"] for p in store.passes()) == sorted(list(ok_ids) * 2)


def test_migration_keeps_the_latest_of_duplicate_ok_rows(tmp_path):
    path = tmp_path / "old.sqlite"
    RunStore(path)
    with sqlite3.connect(path) as conn:  # a store written before the constraint existed
        names = [r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='index'")]
        for name in names:
            if not name.startswith("sqlite_"):
                conn.execute(f"DROP INDEX {name}")
    h = config_hash(_cfg(3))
    with sqlite3.connect(path) as conn:  # duplicates, as the old code could write them
        conn.execute("PRAGMA foreign_keys = ON")
        ids = []
        for rmse in (0.3, 0.2, 0.1):
            cur = conn.execute(
                "INSERT INTO runs (config_hash, config_json, status, rmse, passes, started_at, "
                "finished_at) VALUES (?, '{}', 'ok', ?, 1, 'a', 'b')",
                (h, rmse),
            )
            ids.append(cur.lastrowid)
            conn.execute(
                "INSERT INTO passes (run_id, idx, name) VALUES (?, 0, 'm.x')", (cur.lastrowid,)
            )
        conn.execute(
            "INSERT INTO runs (config_hash, config_json, status, started_at, finished_at) "
            "VALUES (?, '{}', 'failed', 'a', 'b')",
            (h,),
        )
    store = RunStore(path)  # migrates
    rows = store.runs()
    assert [(r["status"], r["rmse"]) for r in rows if r["status"] == "ok"] == [("ok", 0.1)]
    assert [r["id"] for r in rows if r["status"] == "ok"] == [ids[-1]]
    assert len([r for r in rows if r["status"] == "failed"]) == 1
    assert [p["run_id"] for p in store.passes()] == [ids[-1]]
    assert _ok_rows(path) == {h: 1}
