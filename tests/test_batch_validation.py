"""Hydra's check of a sweep's batch composes one job per signature (sssbench/app.py,
``_validate_one_per_signature``): every group choice whole, every other override by its key."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from sssbench import app


def test_signature_keeps_group_choices_and_reduces_values_to_keys():
    job = [
        "+experiment=paper_benchmark",
        "scene=sphere",
        "++scene.params.pixel_mm=0.3",
        "method=disk",
        "samples=13",
        "hydra/launcher=joblib",
        "~texturing",
    ]
    assert app.job_signature(job) == (
        "+experiment=paper_benchmark",
        "scene=sphere",
        "++scene.params.pixel_mm",
        "method=disk",
        "samples",
        "hydra/launcher=joblib",
        "~texturing",
    )


class _Loader:
    """A config loader that records the jobs it is asked to compose."""

    def __init__(self) -> None:
        self.jobs: list[list[str]] = []

    def load_sweep_config(self, master_config, sweep_overrides):
        self.jobs.append(list(sweep_overrides))


@pytest.fixture
def validate():
    from hydra.plugins.sweeper import Sweeper

    app._install_batch_validation()
    app._install_batch_validation()  # idempotent: Hydra's own check is kept once
    assert len(app._HYDRA_VALIDATE) == 1
    assert app._HYDRA_VALIDATE[0] is not app._validate_one_per_signature
    assert Sweeper.validate_batch_is_legal is app._validate_one_per_signature
    yield Sweeper.validate_batch_is_legal


def test_the_paper_batch_composes_one_job_per_scene_and_method(validate):
    batch = app.preset_grid("paper_benchmark")
    pairs = {
        (next(o for o in job if o.startswith("scene=")), next(o for o in job if "method=" in o))
        for job in batch
    }
    assert len(batch) == 288 and len(pairs) == 6 * 8  # the preset's grid: 6 scenes × 8 methods
    loader = _Loader()
    sweeper = SimpleNamespace(hydra_context=SimpleNamespace(config_loader=loader), config={})
    validate(sweeper, batch)
    assert len(loader.jobs) == len(pairs)
    composed = {(j[1], j[3]) for j in loader.jobs}  # every scene and method, each once
    assert composed == pairs
    assert all(j in batch for j in loader.jobs)  # jobs of the batch, unchanged


def test_a_key_of_its_own_is_composed(validate):
    # a job whose overrides name a key no other job names is its own signature
    batch = [["method=disk", "samples=7"], ["method=disk", "samples=13"], ["method=disk", "x=1"]]
    loader = _Loader()
    validate(SimpleNamespace(hydra_context=SimpleNamespace(config_loader=loader), config={}), batch)
    assert loader.jobs == [batch[0], batch[2]]


@pytest.fixture
def composed_state():
    saved = app._STATE.get("composed")
    yield app._STATE
    app._STATE["composed"] = saved


def test_the_main_jobs_grid_composes_once_after_check_values(validate, composed_state):
    # the README's main job: 24 jobs, each its own scene and method, so 24 signatures; every
    # one was composed by check_values, so Hydra's check composes one of them
    argv = ["-m", "+experiment=benchmark"]
    assert app.check_values(argv) is None
    batch = app.preset_grid("benchmark")
    assert len(batch) == 24 and len({app.job_signature(j) for j in batch}) == 24
    composed_state["composed"] = app.composed_jobs(argv)
    assert {frozenset(j) for j in batch} <= composed_state["composed"]
    loader = _Loader()
    validate(SimpleNamespace(hydra_context=SimpleNamespace(config_loader=loader), config={}), batch)
    assert loader.jobs == [batch[0]]


def test_jobs_check_values_did_not_compose_keep_their_signatures(validate, composed_state):
    argv = ["-m", "method=disk,artist", "samples=7"]
    assert app.check_values(argv) is None
    composed_state["composed"] = app.composed_jobs(argv)
    assert composed_state["composed"] == {
        frozenset({"method=disk", "samples=7"}),
        frozenset({"method=artist", "samples=7"}),
    }
    batch = [
        ["method=disk", "samples=7"],
        ["method=artist", "samples=7"],
        ["method=disk", "samples=13"],  # not in the grid check_values read
        ["method=artist", "samples=13"],
    ]
    loader = _Loader()
    validate(SimpleNamespace(hydra_context=SimpleNamespace(config_loader=loader), config={}), batch)
    assert loader.jobs == [batch[0], batch[2], batch[3]]


def test_a_prefixed_value_is_left_to_hydra(composed_state):
    # check_values reads +samples=7 (OmegaConf adds or sets it) but Hydra refuses to append a
    # key the config has: such a job is not counted as composed
    argv = ["-m", "method=disk", "+samples=7"]
    assert app.check_values(argv) is None
    assert app.composed_jobs(argv) == frozenset()
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.errors import ConfigCompositionException

    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(app.CONF_DIR), version_base="1.3"):
        with pytest.raises(ConfigCompositionException):
            compose(config_name="config", overrides=["store=x", "method=disk", "+samples=7"])
    GlobalHydra.instance().clear()


def test_inspecting_reads_no_grid():
    assert app.composed_jobs(["--help", "method=disk"]) == frozenset()
