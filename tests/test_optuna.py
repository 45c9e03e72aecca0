"""The Optuna preset in its quick form: ``sssbench -m +experiment=optuna_quick`` stores its
trials like any sweep, returns (rel_rms, time_ms) to the sweeper, and the report's Optuna front
is the non-dominated set of the trials (brute force, and Optuna's own ``best_trials``), drawn
beside a grid sweep's front in the same panel."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from sssbench.app import OBJECTIVES, preset_hydra
from sssbench.report import load_runs, run_sweeper, search_fronts, summary_table, write_report

REPO = Path(__file__).resolve().parents[1]
#: optuna 2.x's database models (unused here: the study is in memory) on SQLAlchemy 2
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning:optuna.storages._rdb.models")


def _sssbench(args: list[str], cwd: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO), "MPLBACKEND": "Agg"}
    return subprocess.Popen(
        [sys.executable, "-m", "sssbench", "-m", *args],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def _dominates(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return a[0] <= b[0] and a[1] <= b[1] and a != b


def _non_dominated(points: list[tuple[float, float]]) -> set[tuple[float, float]]:
    """Brute force, O(n²): the points no other point dominates."""
    return {p for p in points if not any(_dominates(q, p) for q in points)}


@pytest.fixture(scope="module")
def searched(tmp_path_factory):
    """One quick Optuna search and, at the same time, a grid sweep of the same scene (tap
    placement ``power``, which the quick search never proposes) into one store."""
    tmp = tmp_path_factory.mktemp("optuna")
    common = [
        f"store={tmp / 'runs.sqlite'}",
        f"reference_cache={tmp / 'refs'}",
        "~hydra.callbacks.report",  # the test writes the report itself, once
    ]
    search = _sssbench(
        ["+experiment=optuna_quick", *common, f"hydra.sweep.dir={tmp / 'search'}"], tmp
    )
    grid_args = [
        "scene=step_edge",
        "++scene.params.pixel_mm=0.1",
        "resolution=24",
        "repeats=1",
        "previews=false",
        "budget=false",
        "sampling=power",
        "samples=3,7",
        f"hydra.sweep.dir={tmp / 'grid'}",
    ]
    grid = _sssbench([*grid_args, *common], tmp)
    outputs = [p.communicate(timeout=300)[0] for p in (search, grid)]
    for p, out in zip((search, grid), outputs, strict=True):
        assert p.returncode == 0, out[-3000:]
    return tmp, outputs[0]


def _trial_dirs(tmp: Path) -> list[Path]:
    return sorted(p.parent for p in (tmp / "search").rglob("point.json"))


def test_trials_are_stored_runs(searched):
    tmp, log = searched
    preset = yaml.safe_load((REPO / "sssbench/conf/experiment/optuna_quick.yaml").read_text())
    n_trials = preset["hydra"]["sweeper"]["n_trials"]
    trials = _trial_dirs(tmp)
    assert len(trials) == n_trials
    statuses = [json.loads((d / "point.json").read_text())["status"] for d in trials]
    assert set(statuses) <= {"ok", "skipped"} and "ok" in statuses
    assert all(run_sweeper(str(d)) == "optuna" for d in trials)
    runs, _ = load_runs(tmp / "runs.sqlite")
    stored = {r.run_dir for r in runs.itertuples()}
    ran = {str(d.resolve()) for d, s in zip(trials, statuses, strict=True) if s == "ok"}
    assert ran <= stored  # every trial that ran is a stored run of its own
    assert f"{n_trials}/{n_trials}]" in log  # the progress line counts trials, not a grid


def test_optuna_front_is_the_non_dominated_set_of_the_trials(searched):
    tmp, _ = searched
    runs, _ = load_runs(tmp / "runs.sqlite")
    table = summary_table(runs)
    assert table["scene"].nunique() == 1 and table["resolution"].nunique() == 1
    fronts = search_fronts(table)
    assert set(fronts) == {"grid", "optuna"}
    trials = table[table["run_dir"].map(run_sweeper) == "optuna"]
    points = [(float(r.time_ms), float(r.rel_rms)) for r in trials.itertuples()]
    front = [(float(r.time_ms), float(r.rel_rms)) for r in fronts["optuna"].itertuples()]
    assert len(front) == len(set(front))  # each front point once
    assert set(front) == _non_dominated(points)
    assert front == sorted(front)  # fastest first
    # Optuna's own Pareto set (its best_trials, from the values the app returned)
    results = yaml.safe_load((tmp / "search" / "optimization_results.yaml").read_text())
    assert results["name"] == "optuna" and OBJECTIVES == ("rel_rms", "time_ms")
    optuna_front = {(v[1], v[0]) for v in (s["values"] for s in results["solutions"])}
    assert optuna_front == set(front)
    # the grid's front is over the grid's runs only: the basic sweeper's jobs
    assert {run_sweeper(d) for d in fronts["grid"]["run_dir"]} == {"basic"}
    grid = table[table["run_dir"].map(run_sweeper) == "basic"]
    grid_points = [(float(r.time_ms), float(r.rel_rms)) for r in grid.itertuples()]
    got = {(float(r.time_ms), float(r.rel_rms)) for r in fronts["grid"].itertuples()}
    assert got == _non_dominated(grid_points)


def test_report_draws_both_fronts(searched, monkeypatch):
    tmp, _ = searched
    drawn = []
    import matplotlib.axes

    step = matplotlib.axes.Axes.step

    def spy(self, x, y, *args, **kwargs):
        drawn.append((kwargs.get("color"), list(x)))
        return step(self, x, y, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "step", spy)
    report = write_report(tmp / "runs.sqlite", tmp / "report")
    assert report.error_vs_time is not None and report.error_vs_time.is_file()
    fronts = search_fronts(report.table)
    colours = [c for c, _ in drawn]
    assert colours.count("k") == 1 and colours.count("tab:red") == 1
    red = next(x for c, x in drawn if c == "tab:red")
    assert len(red) == len(fronts["optuna"])


@pytest.mark.parametrize("preset", ["optuna", "optuna_quick"])
def test_preset_search_space_reaches_the_methods_options(preset):
    """Every value of the preset's search space, as the override text the Optuna sweeper
    writes for it, composes into a run of the method with that option; the quoted 'null'
    (Hydra's choice() cannot hold null) arrives as None."""
    from hydra_plugins.hydra_optuna_sweeper._impl import create_params_from_overrides
    from optuna.distributions import CategoricalDistribution

    from sssbench.app import compose_spec

    hydra = preset_hydra(preset)
    assert "OptunaSweeper" in hydra.sweeper._target_
    assert list(hydra.sweeper.direction) == ["minimize"] * len(OBJECTIVES)
    params = [f"{k}={v}" for k, v in hydra.sweeper.params.items()]
    space, fixed = create_params_from_overrides(params)
    assert not fixed and set(space) == {
        "samples",
        "sampling",
        "method.params.follow_surface",
        "method.params.rotation",
    }
    for key, dist in space.items():
        assert isinstance(dist, CategoricalDistribution)
        for choice in dist.choices:
            spec = compose_spec(f"+experiment={preset}", f"{key}={choice}")
            got = {
                "samples": spec.samples,
                "sampling": spec.sampling,
                "method.params.follow_surface": spec.method_params.get("follow_surface"),
                "method.params.rotation": spec.method_params.get("rotation"),
            }[key]
            assert got == (None if choice == "null" else choice)
    assert "null" in space["method.params.rotation"].choices


def test_full_preset_lands_in_the_benchmarks_portrait_panel():
    """The report draws the search's front beside the grid's when both share a ranking
    group (scene, scale, resolution, profile, stages): the preset's are the default
    benchmark's face_portrait point's."""
    from sssbench.app import compose_spec

    search = compose_spec("+experiment=optuna")
    grid = compose_spec("+experiment=benchmark", "scene=face_portrait")
    for key in ("scene", "scene_params", "resolution", "profile", "stages", "repeats", "budget"):
        assert getattr(search, key) == getattr(grid, key), key
    assert "face_portrait" in preset_hydra("benchmark").sweeper.params.scene
