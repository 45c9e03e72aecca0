"""Report tables and plots from a run store."""

from __future__ import annotations

import json
import math

import pandas as pd
import pytest

from sssbench import report
from sssbench.store.tracking import PassStats, RunRecord, RunStore, config_hash


def _fill(store: RunStore) -> list[dict]:
    cfgs = []
    for scene in ("sphere", "step_edge"):
        for method, err, t in (
            ("preintegrated", 0.05, 2.0),
            ("sum_of_gaussians", 0.02, 6.0),
            ("reference", 0.0, 50.0),
            ("slow_bad", 0.1, 60.0),
        ):
            cfg = {
                "scene": scene,
                "method": method,
                "profile": "skin_jg10",
                "sampling": "importance",
                "samples": 7,
            }
            passes = [
                PassStats(f"{method}.x", 7, 64, t / 2, t / 2, t / 2, 1),
                PassStats(f"{method}.y", 7, 64, t / 2, t / 2, t / 2, 1),
            ]
            metrics = {
                "rmse": err,
                "rel_rms": err,
                "psnr": math.inf if err == 0 else 30.0,
                "ssim": 0.9,
                "delta_e": 1.0,
                "flip": 0.01,
            }
            store.record(
                RunRecord(config=cfg, status="ok", metrics=metrics, passes=passes, time_ms=t)
            )
            cfgs.append(cfg)
    bad = {
        "scene": "sphere",
        "method": "broken",
        "profile": "skin_jg10",
        "sampling": "importance",
        "samples": 7,
    }
    store.record(RunRecord(config=bad, status="failed", error="ValueError: boom"))
    cfgs.append(bad)
    return cfgs


def test_pareto_front():
    assert report.pareto_front([1, 2, 3, 4], [4, 1, 2, 0.5]) == [0, 1, 3]
    assert report.pareto_front([1, 1], [2, 1]) == [1]
    assert report.pareto_front([1, float("nan")], [1, 0]) == [0]


def test_report_from_store(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    _fill(store)
    rep = report.write_report(tmp_path / "s.sqlite", tmp_path / "out")
    for p in (rep.summary_csv, rep.summary_md, rep.error_vs_time, rep.pass_times):
        assert p is not None and p.is_file() and p.stat().st_size > 0
    table = pd.read_csv(rep.summary_csv)
    assert len(table) == 9
    stored = {(r["scene"], r["method"]): r for r in store.runs(latest=True)}
    for row in table.itertuples():
        s = stored[(row.scene, row.method)]
        assert row.status == s["status"]
        for m in ("rmse", "rel_rms", "ssim", "delta_e", "flip", "time_ms"):
            if s[m] is None:
                assert pd.isna(getattr(row, m))
            else:
                assert getattr(row, m) == pytest.approx(s[m])
    md = rep.summary_md.read_text()
    assert "## sphere" in md and "## step_edge" in md and "ValueError: boom" in md
    assert "∞" in md


def test_report_from_sweep_dir_only_its_points(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    cfgs = _fill(store)
    sweep = tmp_path / "sweep"
    for i, cfg in enumerate(cfgs[:3]):
        (sweep / str(i)).mkdir(parents=True)
        (sweep / str(i) / "point.json").write_text(
            json.dumps({"config_hash": config_hash(cfg), "store": str(store.path)})
        )
    rep = report.write_report(sweep)
    assert rep.out_dir == sweep.resolve() / "report"
    assert len(rep.table) == 3


def test_forced_rerun_supersedes(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    cfg = {"scene": "sphere", "method": "m", "profile": "p", "sampling": "uniform", "samples": 3}
    store.record(RunRecord(config=cfg, status="ok", metrics={"rel_rms": 0.5}, time_ms=1.0))
    store.record(RunRecord(config=cfg, status="ok", metrics={"rel_rms": 0.25}, time_ms=1.0))
    rep = report.write_report(store.path, tmp_path / "out")
    assert rep.table["rel_rms"].tolist() == [0.25]


def test_main_cli(tmp_path, capsys):
    store = RunStore(tmp_path / "s.sqlite")
    _fill(store)
    assert report.main([str(store.path), "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "preintegrated" in out and "summary.md" in out and "error_vs_time.png" in out
    assert report.main([str(tmp_path / "missing.sqlite")]) == 2
    assert "sssbench-report:" in capsys.readouterr().err
