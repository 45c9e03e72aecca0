"""A sweep's runs in parallel processes (sssbench.run.parallel) with each run's timed section
alone (sssbench.run.settings.timing_slot / exclusive_timing): the lock's exclusion is checked
with a second open file description standing for another worker, and the runs store the same
numbers as runs executed one by one."""

from __future__ import annotations

import fcntl
import json
import os
import threading
import time

import pytest
from specs import budget_grid, budget_spec

from sssbench.run import runmemo, runner
from sssbench.run.parallel import run_parallel
from sssbench.run.settings import checkpoint, exclusive_timing, timing_slot


def _try_lock(path, kind: int) -> bool:
    """Whether another process (another open file description) could take ``kind`` now."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, kind | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False
    finally:
        os.close(fd)


def test_timed_section_excludes_every_other_worker(tmp_path):
    lock = tmp_path / "timing.lock"
    with timing_slot(lock):
        # outside the timed section: others may work (shared) but not time (exclusive)
        assert _try_lock(lock, fcntl.LOCK_SH)
        assert not _try_lock(lock, fcntl.LOCK_EX)
        with exclusive_timing():
            # while timing: no other worker may work at all
            assert not _try_lock(lock, fcntl.LOCK_SH)
        assert _try_lock(lock, fcntl.LOCK_SH)
    assert _try_lock(lock, fcntl.LOCK_EX)  # the slot is released


def test_exclusive_timing_outside_a_slot_is_a_no_op(tmp_path):
    with exclusive_timing():
        checkpoint()
    with timing_slot(tmp_path / "l"), pytest.raises(RuntimeError, match="nested"):
        with timing_slot(tmp_path / "l"):
            pass


def _eventually(condition, seconds: float = 20.0) -> bool:
    """Whether ``condition()`` holds within ``seconds`` (polled; a deadline, not a speed)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.01)
    return False


def _gate(lock) -> int:
    return os.open(str(lock) + ".gate", os.O_RDWR | os.O_CREAT, 0o600)


def test_a_worker_waiting_to_time_stops_the_others_at_their_next_checkpoint(tmp_path):
    lock = tmp_path / "timing.lock"
    gate = _gate(lock)
    try:
        with timing_slot(lock):
            checkpoint()  # no worker waits: straight through, still at shared work
            assert not _try_lock(lock, fcntl.LOCK_EX)
            fcntl.flock(gate, fcntl.LOCK_EX)  # another worker now waits to time
            passed = threading.Event()
            worker = threading.Thread(target=lambda: (checkpoint(), passed.set()))
            worker.start()
            # at the checkpoint this worker lets the slot go, so the other one can time …
            assert _eventually(lambda: _try_lock(lock, fcntl.LOCK_EX))
            # … and it does not resume while the other one waits or times
            assert not passed.is_set() and worker.is_alive()
            fcntl.flock(gate, fcntl.LOCK_UN)
            worker.join(20)
            assert passed.is_set()
            assert not _try_lock(lock, fcntl.LOCK_EX)  # back at shared work
    finally:
        os.close(gate)


def test_a_worker_waiting_to_time_holds_back_new_shared_work(tmp_path):
    """Writer preference: while a worker waits for the others' current stretch of work to
    end, none of them starts a new one (else two workers that score all the time would keep a
    timed run waiting forever)."""
    lock = tmp_path / "timing.lock"
    other = os.open(lock, os.O_RDWR | os.O_CREAT, 0o600)
    fcntl.flock(other, fcntl.LOCK_SH)  # another worker is at shared work
    timed = threading.Event()

    def timer() -> None:
        with timing_slot(lock), exclusive_timing():
            timed.set()

    worker = threading.Thread(target=timer)
    worker.start()
    try:
        # the timer waits (the other worker still works) and closes the gate meanwhile
        assert _eventually(lambda: not _try_lock(str(lock) + ".gate", fcntl.LOCK_SH))
        assert not timed.is_set()
        fcntl.flock(other, fcntl.LOCK_UN)  # the other worker reaches a checkpoint
        worker.join(20)
        assert timed.is_set()
        assert _try_lock(str(lock) + ".gate", fcntl.LOCK_SH)  # the gate is open again
    finally:
        os.close(other)


def test_work_while_waiting_runs_beside_others_work_never_beside_a_timed_section(tmp_path):
    """exclusive_timing(while_waiting): the untimed calls run after the gate is closed (no
    new shared work starts), under the shared lock (never while another worker times: it
    holds the exclusive lock), beside the others' current work; then the section times
    alone."""
    lock = tmp_path / "timing.lock"
    other, other_gate = os.open(lock, os.O_RDWR | os.O_CREAT, 0o600), _gate(lock)
    seen: dict[str, bool] = {}
    go, waited, timed = threading.Event(), threading.Event(), threading.Event()

    def while_waiting() -> None:
        seen["gate closed"] = not _try_lock(str(lock) + ".gate", fcntl.LOCK_SH)
        seen["others may work"] = _try_lock(lock, fcntl.LOCK_SH)
        seen["nobody may time"] = not _try_lock(lock, fcntl.LOCK_EX)
        waited.set()

    def timer() -> None:
        with timing_slot(lock):
            go.wait(20)
            with exclusive_timing(while_waiting):
                seen["alone"] = not _try_lock(lock, fcntl.LOCK_SH)
                timed.set()

    def take(kind: int) -> bool:
        try:
            fcntl.flock(other, kind | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            return False

    worker = threading.Thread(target=timer)
    try:
        worker.start()
        assert _eventually(lambda: not _try_lock(lock, fcntl.LOCK_EX))  # in its slot
        fcntl.flock(other_gate, fcntl.LOCK_EX)  # the other worker waits to time …
        go.set()  # … and this one wants to time too: it lets its shared lock go
        assert _eventually(lambda: take(fcntl.LOCK_EX))  # the other one times
        fcntl.flock(other_gate, fcntl.LOCK_UN)
        assert _eventually(lambda: not _try_lock(str(lock) + ".gate", fcntl.LOCK_SH))
        time.sleep(0.2)
        assert not waited.is_set()  # not beside the other worker's timed section
        fcntl.flock(other, fcntl.LOCK_SH)  # its section ends: back at shared work
        assert _eventually(waited.is_set)
        time.sleep(0.2)
        assert not timed.is_set()  # the other worker has not reached a checkpoint
        fcntl.flock(other, fcntl.LOCK_UN)  # it does
        worker.join(20)
        assert timed.is_set()
        assert seen == dict.fromkeys(
            ("gate closed", "others may work", "nobody may time", "alone"), True
        )
    finally:
        go.set()
        os.close(other)
        os.close(other_gate)
        worker.join(20)


def test_work_while_waiting_runs_outside_a_slot_too():
    calls = []
    with exclusive_timing(lambda: calls.append(1)):
        calls.append(2)
    assert calls == [1, 2]


def _grid(tmp_path, name: str):
    return budget_grid(tmp_path, name, "cache", (("preintegrated", 5), ("identity", None)))


_TIME_KEYS = {"time_ms", "pass_times", "wall_s", "reference_ms", "versions", "reference_cache_hit"}


def test_parallel_runs_store_what_serial_runs_store(tmp_path):
    runmemo.clear()
    serial = _grid(tmp_path, "serial")
    for k, spec in enumerate(serial):
        assert runner.execute(spec, tmp_path / "serial" / f"{k}").status == "ok"
    out = run_parallel(_grid(tmp_path, "parallel"), tmp_path / "parallel", 2, progress=False)
    assert [status for _, status in out] == ["ok"] * len(serial)
    for k in range(len(serial)):
        a = json.loads((tmp_path / "serial" / f"{k}" / "metrics.json").read_text())
        b = json.loads((tmp_path / "parallel" / f"{k}" / "metrics.json").read_text())
        assert a.keys() == b.keys()
        for key in a.keys() - _TIME_KEYS:
            assert a[key] == b[key] or (a[key] != a[key] and b[key] != b[key]), key


def test_a_joblib_sweeps_runs_hold_the_timing_lock(tmp_path):
    """``sssbench -m ... hydra/launcher=joblib``: each job's run holds the sweep's timing lock
    (its timed section alone); the basic launcher (one run at a time) and a single run don't."""
    pytest.importorskip("hydra_plugins.hydra_joblib_launcher")
    from hydra import compose, initialize_config_dir

    from sssbench import app

    with initialize_config_dir(config_dir=str(app.CONF_DIR), version_base="1.3"):
        cfg = compose(
            config_name="config", overrides=["hydra/launcher=joblib"], return_hydra_config=True
        )
    lock = tmp_path / ".timing.lock"
    with app._timing_slot(str(cfg.hydra.launcher._target_), tmp_path):
        assert lock.is_file() and _try_lock(lock, fcntl.LOCK_SH)
        assert not _try_lock(lock, fcntl.LOCK_EX)
    basic = "hydra._internal.core_plugins.basic_launcher.BasicLauncher"
    with app._timing_slot(basic, tmp_path / "b"), app._timing_slot("", None):
        assert not (tmp_path / "b" / ".timing.lock").exists()


def test_a_failing_run_is_stored_failed_and_its_group_goes_on(tmp_path):
    """A run that raises (here: 0 taps, refused by the method) is stored ``failed`` in its
    worker, which leaves the timing slot as it found it: the runs after it in its scene group,
    and the other group's, still run and are stored ok."""
    specs = [
        budget_spec(tmp_path, "step_edge", "preintegrated", 0, "s", "cache"),
        budget_spec(tmp_path, "step_edge", "preintegrated", 5, "s", "cache"),
        budget_spec(tmp_path, "sphere", "identity", None, "s", "cache"),
    ]
    out = run_parallel(specs, tmp_path / "runs", 2, progress=False)
    assert [status for _, status in out] == ["failed", "ok", "ok"]
    error = (tmp_path / "runs" / "0" / "error.txt").read_text()
    assert "samples" in error
