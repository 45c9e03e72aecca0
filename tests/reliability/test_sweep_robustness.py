"""Sweep robustness (issue 8): a run that raises, a run over ``timeout_s`` and a sweep killed
with SIGKILL mid-way. The app is driven as a subprocess (as in ``tests/test_app.py``) on tiny
sphere scenes; everything it writes stays under ``tmp_path``.
"""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

from sssbench.store.tracking import STATUSES, RunStore

REPO = Path(__file__).resolve().parents[2]
TINY = ["scene=sphere", "resolution=[16,16]", "warmup=0", "previews=false"]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["HYDRA_FULL_ERROR"] = "0"
    return env


def _cmd(tmp_path: Path, *args: str) -> list[str]:
    return [
        sys.executable,
        "-m",
        "sssbench",
        "-m",
        *args,
        "hydra.sweep.dir=" + str(tmp_path / "sweep"),
        "store=" + str(tmp_path / "store.sqlite"),
    ]


def _consistent(db: Path) -> list[sqlite3.Row]:
    """Integrity check, every run row complete (status valid, its passes all present)."""
    conn = sqlite3.connect(db)
    conn.row_factory = sqlite3.Row
    try:
        assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        assert conn.execute("PRAGMA foreign_key_check").fetchall() == []
        rows = conn.execute("SELECT * FROM runs ORDER BY id").fetchall()
        for r in rows:
            assert r["status"] in STATUSES
            stored = conn.execute("SELECT COUNT(*) FROM passes WHERE run_id = ?", (r["id"],))
            assert stored.fetchone()[0] == r["passes"], dict(r)
            if r["status"] == "ok":
                assert r["passes"] >= 1 and r["rmse"] is not None and r["time_ms"] is not None
        orphans = conn.execute(
            "SELECT COUNT(*) FROM passes WHERE run_id NOT IN (SELECT id FROM runs)"
        ).fetchone()[0]
        assert orphans == 0
        return rows
    finally:
        conn.close()


def test_raising_and_timed_out_runs_are_recorded_and_the_sweep_goes_on(tmp_path):
    # the halo scene turned by tilt=80 leaves pixels empty: a valid value that only the
    # render can find (the app's check before the first run accepts it: issue 28), so the scene
    # builder raises inside the run; timeout_s=0.001 times out the good point (tilt=45), which
    # the next job (timeout_s=600, same point: timeout_s is run control, not identity) then
    # runs, because only 'ok' rows count as done
    halo = ["scene=halo", *TINY[1:]]
    proc = subprocess.run(
        _cmd(tmp_path, *halo, "repeats=1", "samples=1,3", "++scene.params.tilt=80,45",
             "timeout_s=0.001,600"),  # fmt: skip
        cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr
    rows = _consistent(tmp_path / "store.sqlite")
    store = RunStore(tmp_path / "store.sqlite")
    by_point: dict[tuple, list[str]] = {}
    for r in store.runs():
        key = (r["samples"], r["config"]["scene_params"]["tilt"])
        by_point.setdefault(key, []).append((r["status"], r["error"] or ""))
    assert len(rows) == 8
    for samples in (1, 3):
        bad = by_point[(samples, 80)]
        # with timeout_s=0.001 the alarm may fire before the scene builder raises
        assert bad[0][0] in ("failed", "timeout") and bad[1][0] == "failed", bad
        assert all("empty" in e and "ValueError" in e for s, e in bad if s == "failed"), bad
        good = by_point[(samples, 45)]
        assert [s for s, _ in good] == ["timeout", "ok"], good
        assert "timeout_s=0.001" in good[0][1]
    n_failed = sum(r["status"] == "failed" for r in rows)
    errs = list((tmp_path / "sweep").glob("*/error.txt"))
    assert len(errs) == n_failed and all("Traceback" in p.read_text() for p in errs)


def test_sigkill_mid_sweep_leaves_a_consistent_store_and_resume_finishes(tmp_path):
    grid = [*TINY, "repeats=3", "samples=1,3,5,7"]
    db = tmp_path / "store.sqlite"
    proc = subprocess.Popen(
        _cmd(tmp_path, *grid), cwd=tmp_path, env=_env(), stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    done = 0
    try:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline and proc.poll() is None:
            if db.exists():
                try:
                    conn = sqlite3.connect(db, timeout=1)
                    done = conn.execute("SELECT COUNT(*) FROM runs WHERE status='ok'").fetchone()[0]
                    conn.close()
                except sqlite3.OperationalError:
                    done = 0  # schema not created yet
                if done >= 1:
                    break
            time.sleep(0.02)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)  # the process group this test started
        proc.wait(timeout=30)
    assert done >= 1, "no run was stored before the deadline"
    assert proc.returncode == -signal.SIGKILL, "the sweep finished before it could be killed"

    rows = _consistent(db)
    ok_before = {r["config_hash"] for r in rows if r["status"] == "ok"}
    assert 1 <= len(ok_before) < 4

    rerun = subprocess.run(
        _cmd(tmp_path, *grid), cwd=tmp_path, env=_env(), capture_output=True, text=True,
        timeout=240,
    )  # fmt: skip
    assert rerun.returncode == 0, rerun.stdout + rerun.stderr
    log = rerun.stdout + rerun.stderr
    assert log.count("already stored ok") == len(ok_before)
    rows = _consistent(db)
    ok = [r for r in rows if r["status"] == "ok"]
    assert sorted(r["samples"] for r in ok) == [1, 3, 5, 7]  # each point once: none redone
    assert {r["config_hash"] for r in ok} >= ok_before
