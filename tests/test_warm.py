"""Warming a sweep's caches in parallel (sssbench.run.warm): the runs that follow find every
entry they read already cached, and store the same numbers as runs that computed them."""

from __future__ import annotations

import dataclasses
import json

import pytest
from specs import budget_grid, budget_spec

from sssbench.run import runmemo, runner
from sssbench.run.spec import RunSpec
from sssbench.run.warm import group_by_scene, tasks, warm


def _spec(tmp_path, scene: str, method: str, samples: int | None, cache: str) -> RunSpec:
    return budget_spec(tmp_path, scene, method, samples, cache, cache)


def _grid(tmp_path, cache: str) -> list[RunSpec]:
    return budget_grid(tmp_path, cache, cache)


def test_grouped_by_scene(tmp_path):
    groups = group_by_scene(_grid(tmp_path, "c"))
    assert [[s.scene for s in g] for g in groups] == [["step_edge"] * 3, ["sphere"] * 3]


def test_tasks_queue_the_bilinear_references_first(tmp_path):
    # two tasks per scene: its bilinear reference (the larger half) and its box reference with
    # the converged limits; every bilinear task before every box task
    queue = tasks(_grid(tmp_path, "c"))
    assert [(part, g[0].scene) for part, g in queue] == [
        ("bilinear", "step_edge"),
        ("bilinear", "sphere"),
        ("reference", "step_edge"),
        ("reference", "sphere"),
    ]
    # a group without a budgeted run (the baseline alone) has no bilinear task
    alone = [s for s in _grid(tmp_path, "c") if s.method == "identity"]
    assert [part for part, _ in tasks(alone)] == ["reference", "reference"]


@pytest.mark.parametrize("workers", [1, 2])
def test_runs_after_warming_compute_nothing_and_store_the_same(tmp_path, workers):
    runmemo.clear()
    warmed = _grid(tmp_path, "warm")
    warm(warmed, workers, progress=False)
    entries = sorted(p.name for p in (tmp_path / "warm").iterdir())
    # a reference per scene, a converged limit per (scene, method), and each scene's bilinear
    # reference (the budget's reconstruction part, measured on curved scenes too since #27)
    assert len(entries) == 2 + 2 + 2
    cold = _grid(tmp_path, "cold")
    for k, (a, b) in enumerate(zip(warmed, cold, strict=True)):
        runmemo.clear()
        for spec, name in ((a, "warm"), (b, "cold")):
            assert runner.execute(spec, tmp_path / f"{name}{k}").status == "ok"
        ma = json.loads((tmp_path / f"warm{k}" / "metrics.json").read_text())
        mb = json.loads((tmp_path / f"cold{k}" / "metrics.json").read_text())
        assert ma["reference_cache_hit"] and not (k % 3 == 0 and mb["reference_cache_hit"])
        for key in ("rel_rms", "rel_rms_identity", "err_taps", "err_model", "err_screen"):
            if key in mb:
                assert ma[key] == pytest.approx(mb[key], rel=1e-12, nan_ok=True), key
    assert sorted(p.name for p in (tmp_path / "warm").iterdir()) == entries


def test_a_failing_preparation_is_reported_not_raised(tmp_path, capsys):
    bad = dataclasses.replace(_spec(tmp_path, "step_edge", "preintegrated", 5, "c"), samples=-3)
    warm([bad], 1)
    assert "warm failed (the run will retry)" in capsys.readouterr().out
