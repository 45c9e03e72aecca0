"""Claims on points (sssbench/store/claims.py): one job runs a point at a time, a job that finds
the point claimed waits for it and skips it when the other job stored it, a dead holder's claim
is taken over; and two processes executing the same point at once run it once."""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import sqlite3
import subprocess
import sys
import threading
import time
import types

import pytest
from specs import small_spec

from sssbench.run import runner
from sssbench.store import claims as claims_mod
from sssbench.store.claims import PointClaims
from sssbench.store.tracking import RunRecord, RunStore, config_hash, utc_now

H = "a" * 16


def _ok_row(store: RunStore, cfg: dict) -> None:
    store.record(RunRecord(config=cfg, status="ok", metrics={"rmse": 0.1}))


def _insert_claim(store: RunStore, host: str, pid: int, expires: float) -> None:
    PointClaims(store, 60.0).holder(H)  # creates the table
    with sqlite3.connect(store.path) as conn:
        conn.execute(
            "INSERT INTO claims VALUES (?, 'other', ?, ?, ?, ?)", (H, host, pid, utc_now(), expires)
        )


def test_a_claim_excludes_others_until_released(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    a, b = PointClaims(store, 60.0), PointClaims(store, 60.0)
    assert a.claim(H) == "mine"
    assert a.claim(H) == "mine"  # its own claim again
    assert b.claim(H) == "busy"
    assert b.holder(H) == a.owner
    b.release(H)  # not b's: nothing happens
    assert b.claim(H) == "busy"
    a.release(H)
    assert a.holder(H) is None
    assert b.claim(H) == "mine"


def test_a_stored_point_answers_done_and_since_filters_older_rows(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    cfg = {"scene": "sphere"}
    h = config_hash(cfg)
    before = utc_now()
    _ok_row(store, cfg)
    after = utc_now()
    c = PointClaims(store, 60.0)
    assert c.claim(h) == "done"  # any ok row
    assert c.claim(h, since=before) == "done"  # stored after `before`
    assert c.claim(h, since=after) == "mine"  # a forced run: the older row does not count
    failed = {"scene": "cube"}
    store.record(RunRecord(config=failed, status="failed"))
    assert c.claim(config_hash(failed)) == "mine"  # a failed row is not done


def test_a_dead_holder_on_this_host_is_taken_over(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], check=True,
                          capture_output=True, text=True)  # fmt: skip
    dead = int(proc.stdout)  # a pid that has exited
    _insert_claim(store, claims_mod.socket.gethostname(), dead, time.time() + 3600)
    assert PointClaims(store, 60.0).claim(H) == "mine"


def test_a_live_holder_on_this_host_keeps_its_claim(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    _insert_claim(store, claims_mod.socket.gethostname(), os.getppid(), time.time() + 3600)
    assert PointClaims(store, 60.0).claim(H) == "busy"


@pytest.mark.parametrize("expires_in, answer", [(3600.0, "busy"), (-1.0, "mine")])
def test_a_holder_on_another_host_is_live_until_its_lease_ends(tmp_path, expires_in, answer):
    store = RunStore(tmp_path / "s.sqlite")
    _insert_claim(store, "another-host.invalid", 1, time.time() + expires_in)
    assert PointClaims(store, 60.0).claim(H) == answer


def test_a_long_wait_says_so_every_wait_log_s(tmp_path, monkeypatch, caplog):
    """A job waiting on a holder on another host logs when it starts and every WAIT_LOG_S after
    (on a fake clock: 0.25 s polls, a line per second), naming the holder and its lease end, and
    claims the point once the holder is gone."""
    store = RunStore(tmp_path / "s.sqlite")
    _insert_claim(store, "another-host.invalid", 1, time.time() + 3600)
    clock = {"now": 0.0, "sleeps": 0}

    def sleep(s: float) -> None:
        clock["now"] += s
        clock["sleeps"] += 1
        if clock["sleeps"] == 13:  # 3.25 s: the holder finishes without storing the point
            with sqlite3.connect(store.path) as conn:
                conn.execute("DELETE FROM claims WHERE config_hash = ?", (H,))

    fake = types.SimpleNamespace(
        time=time.time, strftime=time.strftime, localtime=time.localtime,
        monotonic=lambda: clock["now"], sleep=sleep,
    )  # fmt: skip
    monkeypatch.setattr(claims_mod, "time", fake)
    monkeypatch.setattr(claims_mod, "POLL_S", 0.25)
    monkeypatch.setattr(claims_mod, "WAIT_LOG_S", 1.0)
    with caplog.at_level(logging.INFO, logger=claims_mod.log.name):
        assert PointClaims(store, 60.0).wait(H, label="the point") == "mine"
    lines = [r.getMessage() for r in caplog.records if "waiting for the point" in r.getMessage()]
    assert len(lines) == 4, lines  # the start, then after 1, 2 and 3 s
    assert lines[0].startswith("waiting for the point: the same point is being run by other")
    for line, waited in zip(lines[1:], (1, 2, 3), strict=True):
        assert line.startswith(f"still waiting for the point after {waited} s: held by other")
    assert all("another-host.invalid" in line and "lapses at" in line for line in lines)


def test_bad_arguments_are_named(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    with pytest.raises(ValueError, match="lease_s"):
        PointClaims(store, 0.0)
    with pytest.raises(ValueError, match="read-only"):
        PointClaims(RunStore(store.path, readonly=True), 60.0)


@pytest.mark.parametrize("stored", [True, False])
def test_execute_waits_for_the_job_running_its_point(tmp_path, monkeypatch, stored):
    monkeypatch.setattr(claims_mod, "POLL_S", 0.02)
    spec = small_spec(tmp_path)
    store = RunStore(spec.store)
    h = config_hash(spec.point())
    holder = PointClaims(store, 60.0)
    assert holder.claim(h) == "mine"
    out: list = []
    t = threading.Thread(target=lambda: out.append(runner.execute(spec, tmp_path / "run")))
    t.start()
    time.sleep(0.3)
    assert t.is_alive() and not out  # waiting, not running: nothing stored yet
    assert not store.is_done(h)
    if stored:  # the other job stores the point ok
        _ok_row(store, spec.point())
    holder.release(h)
    t.join(60)
    assert not t.is_alive()
    assert out[0].status == ("skipped" if stored else "ok")
    assert len(store.runs(status="ok")) == 1
    assert holder.holder(h) is None  # the runner released its own claim


def _execute(spec, run_dir, barrier, q) -> None:
    barrier.wait(timeout=60)
    q.put(runner.execute(spec, run_dir).status)


def test_two_processes_run_one_point_once(tmp_path):
    spec = small_spec(tmp_path, repeats=3, resolution=(48, 48))
    runner.prepare(spec)  # the reference cached: both start on the run itself
    ctx = mp.get_context("spawn")  # not fork: torch's threads are running in this process
    barrier, q = ctx.Barrier(2), ctx.Queue()
    procs = [
        ctx.Process(target=_execute, args=(spec, tmp_path / f"run{i}", barrier, q))
        for i in range(2)
    ]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
    assert [p.exitcode for p in procs] == [0, 0]
    assert sorted(q.get(timeout=5) for _ in procs) == ["ok", "skipped"]
    rows = RunStore(spec.store).runs()
    assert [r["status"] for r in rows] == ["ok"]
