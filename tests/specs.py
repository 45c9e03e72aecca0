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
