"""The MLflow mirror against a real local MLflow store (SQLite in tmp_path): a sweep of three
fake runs is logged under a parent and read back with MlflowClient.search_runs."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from sssbench.store.mlflow_mirror import (
    MAX_KEY_LENGTH,
    MAX_PARAM_VALUE_LENGTH,
    MlflowMirror,
    flatten_params,
    numeric_metrics,
    require_mlflow,
)

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def mlflow():
    os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
    return pytest.importorskip("mlflow")


@pytest.fixture(scope="module")
def store_dir(tmp_path_factory):
    """One SQLite store for the module (creating its tables takes seconds)."""
    return tmp_path_factory.mktemp("mlflow_store")


# ----------------------------------------------------------------------------- without mlflow
def test_importing_sssbench_does_not_import_mlflow():
    code = (
        "import sys, sssbench, sssbench.app, sssbench.io, sssbench.store.mlflow_mirror\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'mlflow'))"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[]"


def test_missing_mlflow_says_what_to_install(monkeypatch, tmp_path):
    for name in [m for m in sys.modules if m.split(".")[0] == "mlflow"]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "mlflow", None)  # import mlflow -> ImportError
    with pytest.raises(ImportError, match=r'pip install "sssbench\[mlflow\]"'):
        MlflowMirror(directory=tmp_path)
    with pytest.raises(ImportError, match=r'pip install "sssbench\[mlflow\]"'):
        require_mlflow()


def test_require_mlflow_passes_when_installed(mlflow):
    require_mlflow()


def test_needs_a_uri_or_directory():
    with pytest.raises(ValueError, match="tracking_uri or directory"):
        MlflowMirror()


def test_flatten_params():
    point = {
        "scene": "head",
        "scene_params": {"z": 500, "light": {"dir": [0, 0, 1]}},
        "method_params": {},
        "samples": None,
        "dtype": "float32",
        "force": True,
        "seed": 0,
    }
    assert flatten_params(point) == {
        "scene": "head",
        "scene_params.z": "500",
        "scene_params.light.dir": "[0, 0, 1]",
        "method_params": "{}",
        "samples": "null",
        "dtype": "float32",
        "force": "true",
        "seed": "0",
    }


def test_params_keys_and_values_fit_mlflow_limits():
    long_a, long_b = "a" * 300, "a" * 299 + "b"
    flat = flatten_params({long_a: 1, long_b: 2, "bad key!?": "x" * 7000})
    keys = sorted(flat)
    assert all(len(k) <= MAX_KEY_LENGTH for k in keys) and len(keys) == 3
    assert keys[-1] == "bad key__"  # the two long keys stay distinct (3 keys)
    value = flat["bad key__"]
    assert len(value) == MAX_PARAM_VALUE_LENGTH and value.endswith("...")
    assert value[:-3] == "x" * (MAX_PARAM_VALUE_LENGTH - 3)


def test_numeric_metrics_keep_only_real_numbers():
    got = numeric_metrics(
        {"rmse": 0.5, "samples_per_pixel": 14, "hit": True, "name": "x", "times": [1.0]}
    )
    assert got == {"rmse": 0.5, "samples_per_pixel": 14.0}


def test_limits_match_mlflow(mlflow):
    from mlflow.utils import validation

    assert MAX_KEY_LENGTH <= validation.MAX_ENTITY_KEY_LENGTH
    assert MAX_PARAM_VALUE_LENGTH <= validation.MAX_PARAM_VAL_LENGTH


# ----------------------------------------------------------------------------- a real store
def fake_run(run_dir: Path, i: int) -> tuple[dict, dict, list[Path]]:
    run_dir.mkdir(parents=True)
    point = {
        "scene": "head",
        "scene_params": {"z": 400 + 100 * i},
        "method": "preintegrated",
        "method_params": {},
        "samples": 7 + 2 * i,
        "resolution": [64, 48],
        "dtype": "float32",
        "sampling": None,
    }
    metrics = {"rmse": 0.01 * (i + 1), "psnr": 30.0 + i, "time_ms": 1.5 * i, "hit": False}
    (run_dir / "metrics.json").write_text(json.dumps(metrics))
    (run_dir / "result.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes([i]) * 10)
    return point, metrics, [run_dir / "metrics.json", run_dir / "result.png"]


def test_sweep_of_three_runs_reads_back(mlflow, store_dir, tmp_path, monkeypatch):
    from mlflow.tracking import MlflowClient

    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)  # nothing may be written to the working directory
    sweep_dir = tmp_path / "multirun"
    mirror = MlflowMirror(directory=store_dir, experiment="sweep-test")
    parent = mirror.start_sweep(sweep_dir, "my sweep")

    # the jobs of a sweep run in other processes: a fresh mirror finds the parent
    job_mirror = MlflowMirror(directory=store_dir, experiment="sweep-test")
    assert job_mirror.find_sweep(sweep_dir) == parent
    logged = {}
    for i, status in enumerate(["ok", "ok", "failed"]):
        point, metrics, artifacts = fake_run(sweep_dir / str(i), i)
        run_id = job_mirror.log_run(
            point, metrics, artifacts, status, config_hash=f"hash{i}", tags={"error": None}
        )
        logged[run_id] = (point, metrics, status, i)
    mirror.end_sweep({"ok": 2, "failed": 1})

    client = MlflowClient(tracking_uri=f"sqlite:///{store_dir / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("sweep-test")
    assert experiment.artifact_location == (store_dir / "mlflow_artifacts").as_uri()
    children = client.search_runs(
        [experiment.experiment_id], filter_string=f"tags.mlflow.parentRunId = '{parent}'"
    )
    assert sorted(r.info.run_id for r in children) == sorted(logged)
    for run in children:
        point, metrics, status, i = logged[run.info.run_id]
        assert run.data.params == {
            "scene": "head",
            "scene_params.z": str(400 + 100 * i),
            "method": "preintegrated",
            "method_params": "{}",
            "samples": str(7 + 2 * i),
            "resolution": "[64, 48]",
            "dtype": "float32",
            "sampling": "null",
        }
        assert run.data.metrics == {
            "rmse": metrics["rmse"],
            "psnr": metrics["psnr"],
            "time_ms": metrics["time_ms"],
        }
        assert run.data.tags["status"] == status
        assert run.data.tags["config_hash"] == f"hash{i}"
        assert run.data.tags["error"] == "null"
        assert run.info.status == {"ok": "FINISHED", "failed": "FAILED"}[status]
        names = sorted(a.path for a in client.list_artifacts(run.info.run_id))
        assert names == ["metrics.json", "result.png"]
        local = client.download_artifacts(run.info.run_id, "result.png", str(tmp_path))
        assert Path(local).read_bytes() == (sweep_dir / str(i) / "result.png").read_bytes()
    parent_run = client.get_run(parent)
    assert parent_run.info.status == "FAILED"  # one run failed
    assert parent_run.info.run_name == "my sweep"
    assert parent_run.data.metrics == {"runs_ok": 2.0, "runs_failed": 1.0}
    assert list(cwd.iterdir()) == []


def test_non_finite_metrics_and_single_runs(mlflow, store_dir, tmp_path):
    mirror = MlflowMirror(directory=store_dir, experiment="single")
    point, _, artifacts = fake_run(tmp_path / "run", 0)
    run_id = mirror.log_run(point, {"psnr": math.inf, "flip": math.nan}, artifacts, "timeout")
    run = mirror.client.get_run(run_id)
    assert run.info.status == "KILLED" and "mlflow.parentRunId" not in run.data.tags
    assert math.isnan(run.data.metrics["flip"])
    # MLflow's SQL store keeps +inf as the largest float64
    assert run.data.metrics["psnr"] == sys.float_info.max


def test_bad_calls_create_no_run(mlflow, store_dir, tmp_path):
    mirror = MlflowMirror(directory=store_dir, experiment="bad")
    point, metrics, artifacts = fake_run(tmp_path / "run", 0)
    with pytest.raises(FileNotFoundError, match="missing.png"):
        mirror.log_run(point, metrics, [*artifacts, tmp_path / "missing.png"], "ok")
    with pytest.raises(ValueError, match="status must be one of"):
        mirror.log_run(point, metrics, artifacts, "skipped")
    assert mirror.client.search_runs([mirror.experiment_id]) == []
    with pytest.raises(RuntimeError, match="no sweep started"):
        mirror.end_sweep()


def test_deleted_experiment_is_a_clear_error(mlflow, store_dir):
    mirror = MlflowMirror(directory=store_dir, experiment="gone")
    mirror.client.delete_experiment(mirror.experiment_id)
    with pytest.raises(ValueError, match="'gone' is deleted"):
        MlflowMirror(directory=store_dir, experiment="gone")
