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
