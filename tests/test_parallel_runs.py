"""A sweep's runs in parallel processes (sssbench.run.parallel) with each run's timed section
alone (sssbench.run.settings.timing_slot / exclusive_timing): the lock's exclusion is checked
with a second open file description standing for another worker, and the runs store the same
numbers as runs executed one by one."""

from __future__ import annotations

import fcntl
import json
import os

import pytest
from specs import budget_grid

from sssbench.run import runmemo, runner
from sssbench.run.parallel import run_parallel
from sssbench.run.settings import exclusive_timing, timing_slot


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
        pass
    with timing_slot(tmp_path / "l"), pytest.raises(RuntimeError, match="nested"):
        with timing_slot(tmp_path / "l"):
            pass


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
