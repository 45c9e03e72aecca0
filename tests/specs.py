"""A small run for tests of the runner: a 24² float64 scene, one untimed repeat, no budget,
no previews, its store and reference cache in the test's directory."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sssbench.run.spec import RunSpec


def small_spec(tmp_path: Path, **overrides: Any) -> RunSpec:
    """A :class:`RunSpec` of ``step_edge`` with ``skin_jg10`` (``overrides`` replace fields)."""
    fields: dict[str, Any] = dict(
        scene="step_edge",
        method="identity",
        profile="skin_jg10",
        sampling=None,
        samples=None,
        resolution=(24, 24),
        repeats=1,
        warmup=0,
        budget=False,
        previews=False,
        dtype="float64",
        store=tmp_path / "s.sqlite",
        reference_cache=tmp_path / "cache",
    )
    return RunSpec(**(fields | overrides))


#: (method, samples) of :func:`budget_grid`: two tap counts of one kernel and the baseline
BUDGET_METHODS = (("preintegrated", 5), ("preintegrated", 7), ("identity", None))


def budget_spec(
    tmp_path: Path, scene: str, method: str, samples: int | None, store: str, cache: str
) -> RunSpec:
    """A 20² run with its error budget (importance-sampled taps for ``preintegrated``), its
    store ``<tmp_path>/<store>.sqlite`` and reference cache ``<tmp_path>/<cache>``."""
    return small_spec(
        tmp_path,
        scene=scene,
        method=method,
        sampling="importance" if method == "preintegrated" else None,
        samples=samples,
        resolution=(20, 20),
        budget=True,
        store=tmp_path / f"{store}.sqlite",
        reference_cache=tmp_path / cache,
    )


def budget_grid(
    tmp_path: Path, store: str, cache: str, methods: tuple = BUDGET_METHODS
) -> list[RunSpec]:
    """:func:`budget_spec` for ``step_edge`` and ``sphere`` × ``methods``: two scene groups."""
    return [
        budget_spec(tmp_path, scene, method, samples, store, cache)
        for scene in ("step_edge", "sphere")
        for method, samples in methods
    ]
