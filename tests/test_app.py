"""The Hydra app: config composition (compose API), single runs and sweeps (subprocess).

Subprocess runs use tiny resolutions on the sphere scene (its reference is cheap) and put every
output, the store and the reference cache under ``tmp_path``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

import data_synth
from sssbench import app, report
from sssbench.run import registry, runner
from sssbench.store.tracking import RunStore, config_hash

REPO = Path(__file__).resolve().parents[1]
TINY = ["scene=sphere", "resolution=[24,24]", "repeats=1", "warmup=0", "previews=true"]
METRIC_FIELDS = {
    "scene",
    "method",
    "profile",
    "sampling",
    "samples",
    "passes",
    "time_ms",
    "pass_times",
    "rmse",
    "rel_rms",
    "psnr",
    "ssim",
    "delta_e",
    "flip",
    "threads",
    "versions",
}


def _env() -> dict[str, str]:
    env = dict(os.environ)
    # the repo first on the path, whatever the state of the editable install
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["HYDRA_FULL_ERROR"] = "0"
    return env


def _sssbench(tmp_path: Path, *args: str, multirun: bool = False, timeout: float = 240):
    out = [
        "hydra.run.dir=" + str(tmp_path / "run"),
        "hydra.sweep.dir=" + str(tmp_path / "sweep"),
        "store=" + str(tmp_path / "store.sqlite"),
        "reference_cache=" + str(tmp_path / "reference_cache"),
    ]
    cmd = [sys.executable, "-m", "sssbench", *(["-m"] if multirun else []), *args, *out]
    return subprocess.run(
        cmd, cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=timeout
    )


def _compose(*overrides: str, hydra: bool = False):
    with initialize_config_dir(config_dir=str(app.CONF_DIR), version_base="1.3"):
        return compose(
            config_name="config",
            overrides=["store=/tmp/x.sqlite", *overrides],
            return_hydra_config=hydra,
        )


# ----------------------------------------------------------------------------- compose API
def test_conf_dir_found_from_package():
    assert app.CONF_DIR == REPO / "sssbench" / "conf" and (app.CONF_DIR / "config.yaml").is_file()


@pytest.mark.parametrize(
    "group",
    ["method", "scene", "profile", "sampling", "translucency", "curvature", "halo", "texturing"],
)
def test_every_group_option_composes(group):
    for path in sorted((app.CONF_DIR / group).glob("*.yaml")):
        cfg = _compose(f"{group}={path.stem}")
        assert cfg[group]["name"]
        if group == "method" and registry.METHODS[cfg.method.name].cls not in dir(
            __import__("sssbench.ops", fromlist=["x"])
        ):
            continue  # YAML present before its operator: skip building the spec
        if group == "scene" and path.stem == "file":  # needs scene.path: tested below
            with pytest.raises(ValueError, match="scene=file needs scene.path"):
                app.spec_from_cfg(cfg)
            continue
        if group == "scene" and path.stem in data_synth.RETIRED_SCENES:  # refused, named
            with pytest.raises(ValueError, match="is retired"):
                app.spec_from_cfg(cfg)
            continue
        spec = app.spec_from_cfg(cfg)
        assert spec.store == Path("/tmp/x.sqlite")


def test_spec_defaults_and_identity():
    spec = app.spec_from_cfg(_compose())
    assert (spec.method, spec.scene, spec.samples, spec.sampling) == (
        "preintegrated",
        "sphere",
        7,
        "importance",
    )
    assert spec.resolution == (128, 128)
    # method=reference takes no taps: samples / sampling drop out of the point identity
    ref = app.spec_from_cfg(_compose("method=reference", "samples=13"))
    assert ref.samples is None and ref.sampling is None
    assert "store" not in spec.point() and "force" not in spec.point()


def test_spec_rejects_bad_values():
    with pytest.raises(ValueError, match="resolution must be"):
        app.spec_from_cfg(_compose("resolution=[1,2,3]"))
    with pytest.raises(ValueError, match="dtype must be float32 or float64"):
        app.spec_from_cfg(_compose("dtype=float16"))
    with pytest.raises(ValueError, match="repeats must be"):
        app.spec_from_cfg(_compose("repeats=0"))
    with pytest.raises(ValueError, match="backend must be one of"):
        app.spec_from_cfg(_compose("backend=gpu"))


def test_backend_is_part_of_the_point_and_defaults_to_native():
    spec = app.spec_from_cfg(_compose())
    assert spec.backend == "native" and spec.point()["backend"] == "native"
    torch_spec = app.spec_from_cfg(_compose("backend=torch"))
    assert config_hash(torch_spec.point()) != config_hash(spec.point())


def test_benchmark_preset_sets_the_grid():
    cfg = _compose("+experiment=benchmark", hydra=True)
    params = cfg.hydra.sweeper.params
    assert params.scene == "step_edge,light_dot,face_portrait" and params.method.startswith("glob(")
    assert cfg.hydra.callbacks.report._target_ == "sssbench.report.ReportCallback"


def test_pass_stats_median_min_max():
    from sssbench.ops.timing import PassRecord

    runs = [[PassRecord("a", 3, 10, ms), PassRecord("b", 3, 10, 2 * ms)] for ms in (1.0, 3.0, 2.0)]
    stats = runner.pass_stats(runs)
    assert [(s.name, s.ms_median, s.ms_min, s.ms_max, s.repeats) for s in stats] == [
        ("a", 2.0, 1.0, 3.0, 3),
        ("b", 4.0, 2.0, 6.0, 3),
    ]


def test_time_limit_raises():
    with pytest.raises(runner.RunTimeout, match="timeout_s=0.1"):
        with runner.time_limit(0.1):
            time.sleep(2)
    with runner.time_limit(None):
        pass


def test_execute_records_timeout_in_process(tmp_path):
    spec = app.spec_from_cfg(
        _compose(*TINY, f"store={tmp_path / 's.sqlite'}", "timeout_s=0.001", "previews=false")
    )
    outcome = runner.execute(spec, tmp_path / "run")
    assert outcome.status == "timeout"
    (row,) = RunStore(tmp_path / "s.sqlite").runs()
    assert row["status"] == "timeout" and "timeout_s" in row["error"]


# ----------------------------------------------------------------------------- subprocess
def test_single_run_writes_everything(tmp_path):
    proc = _sssbench(tmp_path, *TINY)
    assert proc.returncode == 0, proc.stderr
    run = tmp_path / "run"
    metrics = json.loads((run / "metrics.json").read_text())
    assert METRIC_FIELDS <= set(metrics)
    assert metrics["status"] == "ok" and metrics["passes"] == len(metrics["pass_times"]) >= 2
    assert metrics["time_ms"] == pytest.approx(sum(p["ms_median"] for p in metrics["pass_times"]))
    for p in metrics["pass_times"]:
        assert p["ms_min"] <= p["ms_median"] <= p["ms_max"]
    assert 0 <= metrics["rel_rms"] < 1 and 0 <= metrics["flip"] <= 1
    for name in ("passes.csv", "result.png", "reference.png", "error.png", "point.json"):
        assert (run / name).is_file(), name
    (row,) = RunStore(tmp_path / "store.sqlite").runs()
    assert row["status"] == "ok" and row["rmse"] == pytest.approx(metrics["rmse"])
    assert list((tmp_path / "reference_cache").glob("reference_*.pt"))
    # same point again: skipped (store unchanged), the reference comes from the cache
    proc = _sssbench(tmp_path, *TINY, "force=true")
    assert proc.returncode == 0, proc.stderr
    assert json.loads((run / "metrics.json").read_text())["reference_cache_hit"] is True
    assert f"output in {run}" in proc.stdout
    # the forced re-run supersedes: one ok row per point (tracking.py's unique index)
    (rerun,) = RunStore(tmp_path / "store.sqlite").runs()
    assert rerun["status"] == "ok" and rerun["id"] > row["id"]


def test_bad_override_is_one_line(tmp_path):
    proc = _sssbench(tmp_path, "method=nope")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "unknown method 'nope'" in lines[0] and "preintegrated" in lines[0]
    assert "Traceback" not in proc.stderr
    proc = _sssbench(tmp_path, "scene=sphere,nope", multirun=True)
    assert proc.returncode == 2 and "unknown scene 'nope'" in proc.stderr


JOBLIB_SWEEP = [
    *TINY,
    "method=preintegrated",
    "samples=3,5",
    "sampling=uniform,importance",
    "hydra/launcher=joblib",
    "hydra.launcher.n_jobs=2",
]


def test_joblib_sweep_resume_force_and_report(tmp_path):
    proc = _sssbench(tmp_path, *JOBLIB_SWEEP, multirun=True)
    assert proc.returncode == 0, proc.stderr
    store = RunStore(tmp_path / "store.sqlite")
    rows = store.runs()
    assert len(rows) == 4 and {r["status"] for r in rows} == {"ok"}
    assert {(r["samples"], r["sampling"]) for r in rows} == {
        (3, "uniform"),
        (5, "uniform"),
        (3, "importance"),
        (5, "importance"),
    }

    proc = _sssbench(tmp_path, *JOBLIB_SWEEP, multirun=True)  # resume: nothing to do
    assert proc.returncode == 0, proc.stderr
    assert len(store) == 4
    assert (proc.stdout + proc.stderr).count("already stored ok") == 4

    rep = report.write_report(tmp_path / "sweep")
    assert len(rep.table) == 4 and all(p.is_file() for p in rep.paths())
    by_id = {r["id"]: r for r in store.runs()}
    for row in rep.table.itertuples():
        stored = by_id[row.run_id]
        for m in ("rmse", "rel_rms", "psnr", "ssim", "delta_e", "flip", "time_ms"):
            assert getattr(row, m) == pytest.approx(stored[m])

    # force=true re-runs every point (basic launcher here: the skip logic is the app's, not
    # the launcher's, and this keeps the test short)
    proc = _sssbench(tmp_path, *JOBLIB_SWEEP[:-2], "force=true", multirun=True)
    assert proc.returncode == 0, proc.stderr
    # each forced re-run replaced its point's ok row (one ok row per point)
    assert len(store) == 4 and min(r["id"] for r in store.runs()) > max(by_id)


def test_failing_point_recorded_and_exit_status(tmp_path):
    # a value no run could take (samples=0, reference_params.tol=2, translucency=on on a
    # scene without thickness) is refused before the first run (exit 2, nothing stored:
    # test_first_hour.py, test_value_checks.py); a point that fails at run time — here the
    # halo scene turned so far (tilt=80) that its render leaves pixels empty, which only the
    # render finds — is stored failed and the other point must still succeed
    halo = ["scene=halo", *TINY[1:]]
    proc = _sssbench(tmp_path, *halo, "++scene.params.tilt=45,80", multirun=True)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    rows = {
        r["config"]["scene_params"]["tilt"]: r for r in RunStore(tmp_path / "store.sqlite").runs()
    }
    assert rows[45]["status"] == "ok"
    assert rows[80]["status"] == "failed" and "empty" in rows[80]["error"]
    assert "Traceback" not in proc.stderr
    (err,) = (tmp_path / "sweep").glob("*/error.txt")
    assert "Traceback" in err.read_text()


def test_submitit_local_sweep(tmp_path):
    proc = _sssbench(
        tmp_path,
        *TINY,
        "samples=3,5",
        "hydra/launcher=submitit_local",
        "hydra.launcher.timeout_min=5",
        multirun=True,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rows = RunStore(tmp_path / "store.sqlite").runs()
    assert sorted(r["samples"] for r in rows) == [3, 5]
    assert {r["status"] for r in rows} == {"ok"}


# ----------------------------------------------------------------------------- the point
def test_stages_are_part_of_the_point():
    off = app.spec_from_cfg(_compose("translucency=off"))
    on = app.spec_from_cfg(_compose("translucency=on"))
    assert off.stages["translucency"] is None and on.stages["translucency"]["form"] == "deon"
    assert config_hash(off.point()) != config_hash(on.point())
    assert on.point()["stages"] == {"translucency": on.stages["translucency"]}


def test_every_swept_option_is_used_or_refused():
    # low_rank's tap count is its n: a samples sweep gives distinct points
    a = app.spec_from_cfg(_compose("method=low_rank", "samples=15"), ("method", "samples"))
    b = app.spec_from_cfg(_compose("method=low_rank", "samples=31"), ("method", "samples"))
    assert config_hash(a.point()) != config_hash(b.point())
    # an option the method does not take, given explicitly, is not passed to the method and
    # never splits its point (issue 28: the baseline is one point per scene); it is recorded
    a, b = (
        app.spec_from_cfg(_compose("method=low_rank", f"sampling={s}"), ("sampling",))
        for s in ("uniform", "importance")
    )
    assert a.sampling is None and a.ignored == {"sampling": "uniform"}
    assert config_hash(a.point()) == config_hash(b.point())
    ref = app.spec_from_cfg(_compose("method=identity", "samples=13"), ("samples",))
    assert ref.samples is None and ref.ignored == {"samples": 13} and "ignored" not in ref.point()
    # and an unknown method option is refused when the method is built
    with pytest.raises(ValueError, match="has no option"):
        registry.build_method("preintegrated", None, params={"taps": 3})


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["sampels=3"], "did you mean samples"),
        (["method="], "empty value for method"),
        (["timeout_s=abc"], "timeout_s must be a float"),
        (["repeats=1.5"], "repeats must be an int"),
        (["method=preintegrate"], "did you mean preintegrated"),
        (["translucency=maybe"], "unknown translucency 'maybe'"),
    ],
)
def test_bad_overrides_named_in_one_line(argv, expected):
    assert expected in app.check_overrides(argv)


def test_good_overrides_pass():
    ok = ["samples=3,5", "method=glob(*)", "+experiment=benchmark", "scene.params.pixel_mm=0.3"]
    assert app.check_overrides(ok) is None


def test_version_is_sssbench(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "sssbench", "--version"],
        env=_env(),
        capture_output=True,
        text=True,
        timeout=60,
    )
    from importlib import metadata

    assert (
        proc.returncode == 0 and proc.stdout.strip() == f"sssbench {metadata.version('sssbench')}"
    )


def test_users_gbuffer_file_runs_and_writes_exr(tmp_path):
    import data_synth
    from sssbench.io import read_image_exr, write_gbuffer

    g = data_synth.make_scene("head_cheek", (20, 24))
    write_gbuffer(tmp_path / "frame.exr", g)
    proc = _sssbench(tmp_path, "scene=file", f"scene.path={tmp_path / 'frame.exr'}", "repeats=1")
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["status"] == "ok" and metrics["resolution"] == [20, 24]
    result = read_image_exr(tmp_path / "run" / "result.exr")
    assert result.shape == (1, 3, 20, 24)
    # the point names the file's content: a changed file is a different point
    (row,) = RunStore(tmp_path / "store.sqlite").runs()
    assert len(row["config"]["scene_params"]["sha256"]) == 16


def test_sweep_mirrored_into_mlflow_matches_the_store(tmp_path):
    mlflow = pytest.importorskip("mlflow")
    proc = _sssbench(
        tmp_path, *TINY, "samples=3,5", "tracking.mlflow=true", "previews=false", multirun=True
    )
    assert proc.returncode == 0, proc.stderr
    stored = {r["config_hash"]: r for r in RunStore(tmp_path / "store.sqlite").runs()}
    mlflow.set_tracking_uri(f"sqlite:///{tmp_path / 'mlflow.db'}")
    client = mlflow.tracking.MlflowClient()
    exp = client.get_experiment_by_name("sssbench")
    runs = client.search_runs([exp.experiment_id])
    children = [r for r in runs if "mlflow.parentRunId" in r.data.tags]
    parents = {r.info.run_id for r in runs} - {r.info.run_id for r in children}
    assert len(children) == len(stored) == 2 and len(parents) == 1
    for r in children:
        row = stored[r.data.tags["config_hash"]]
        assert r.data.tags["mlflow.parentRunId"] in parents
        assert r.data.metrics["rel_rms"] == pytest.approx(row["rel_rms"])
        assert r.data.params["samples"] == str(row["samples"])


# ----------------------------------------------------------------------------- the warm-up
@pytest.mark.parametrize(
    ("launcher", "warmed"),
    [("basic", True), ("joblib", True), ("submitit_local", False), ("submitit_slurm", False)],
)
def test_sweep_warmup_runs_under_the_local_launchers(tmp_path, monkeypatch, launcher, warmed):
    """A sweep whose jobs run on this machine (basic: one at a time; joblib: side by side) is
    warmed in ``warm_workers`` processes before its first run, one task per scene; a cluster
    launcher's sweep (its jobs run on other nodes) is not. The launcher's ``_target_`` is
    Hydra's own, composed from its config group."""
    pytest.importorskip(
        "hydra_plugins.hydra_submitit_launcher" if "submitit" in launcher else "hydra"
    )
    import sssbench.run.warm as warm_module

    calls = []
    monkeypatch.setattr(warm_module, "warm", lambda specs, workers, **kw: calls.append(
        (sorted({s.scene for s in specs}), len(specs), workers)) or 0.0)  # fmt: skip
    from omegaconf import open_dict

    # inside Hydra's initialised state, as the callback runs
    with initialize_config_dir(config_dir=str(app.CONF_DIR), version_base="1.3"):
        cfg = compose(
            config_name="config",
            overrides=[
                f"hydra/launcher={launcher}",
                "resolution=[128,128]",
                f"store={tmp_path / 'store.sqlite'}",
            ],
            return_hydra_config=True,
        )
        with open_dict(cfg):  # the sweep's own overrides, as Hydra records them
            cfg.hydra.overrides.task = [
                "scene=sphere,step_edge",
                "method=identity,preintegrated",
                "resolution=[128,128]",
            ]
        app._warm_sweep(cfg)
    assert app.warms_under(str(cfg.hydra.launcher._target_)) is warmed
    assert calls == ([(["sphere", "step_edge"], 4, 2)] if warmed else [])


def test_a_fixed_override_replaces_the_presets_axis_as_hydra_does():
    """Hydra's basic sweeper keys its axes by the override's key with its prefix: a command
    line ``method=identity`` replaces the preset's ``method`` axis (one value), while the
    preset's other axes stay. The warm-up and the ETA read the grid the same way; the
    experiments' ``preset_grid`` also matches ``++scene.params.pixel_mm`` by its bare key."""
    from omegaconf import open_dict

    with initialize_config_dir(config_dir=str(app.CONF_DIR), version_base="1.3"):
        cfg = compose(
            config_name="config",
            overrides=["+experiment=paper_benchmark_1080p", "store=/tmp/x.sqlite"],
            return_hydra_config=True,
        )
    with open_dict(cfg):
        cfg.hydra.overrides.task = ["+experiment=paper_benchmark_1080p", "method=identity",
                                    "scene=face"]  # fmt: skip
    jobs = app.sweep_jobs(cfg)
    # 2 scenes x 2 scales x 7 methods in the preset; method and scene fixed: the 2 scales
    assert len(jobs) == 2 and app._sweep_size(cfg) == 2
    assert all("method=identity" in j and "scene=face" in j for j in jobs)
    grid = app.preset_grid("paper_benchmark", "scene=face", "++scene.params.pixel_mm=0.3")
    n_methods = len(list((app.CONF_DIR / "method").glob("*.yaml"))) - 1  # not the reference
    assert len(grid) == n_methods * 2  # x samples 7,13
    assert all(j.count("++scene.params.pixel_mm=0.3") == 1 for j in grid)
