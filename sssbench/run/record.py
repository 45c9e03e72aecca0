"""A run's record: ``point.json`` while it runs, ``metrics.json`` and ``passes.csv`` when it
ends, one row in the run store, the optional MLflow mirror, and the log line."""

from __future__ import annotations

import csv
import logging
import os
from pathlib import Path
from typing import Any

from sssbench import _json
from sssbench.run.spec import RunSpec
from sssbench.store.tracking import PassStats, RunRecord, RunStore, utc_now

log = logging.getLogger("sssbench")

__all__ = [
    "INFO_KEYS",
    "log_outcome",
    "mirror",
    "run_label",
    "store_run",
    "write_json",
    "write_outputs",
]

#: the payload's keys copied into the store's ``info`` of a run
INFO_KEYS = (
    "threads",
    "backend",
    "versions",
    "plan",
    "skipped_stages",
    "reference_cache_hit",
    "metric_region",
    "visible",
    "error_visible",
    "error_scale",
    "mc_verdicts",
    "renderer",
    "gl_version",
    "timing_note",
    "time_source",
    "gl_disk_geometry",
)


def write_json(path: Path, payload: dict[str, Any]) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(_json.dumps(payload, indent=2, default=str))
    os.replace(tmp, path)


def run_label(spec: RunSpec) -> str:
    """``scene/method/profile/sampling/samples`` (``-`` for what does not apply)."""
    return "/".join(
        str(v) if v is not None else "-"
        for v in (spec.scene, spec.method, spec.profile, spec.sampling, spec.samples)
    )


def write_outputs(
    run_dir: Path, payload: dict[str, Any], stats: list[PassStats], extra: dict[str, Any]
) -> None:
    """``metrics.json`` (the payload and ``extra``: status, hash, wall time) and ``passes.csv``
    (one row per pass) into the run directory; nothing when the run measured nothing."""
    if not payload:
        return
    write_json(run_dir / "metrics.json", {**payload, **extra})
    with open(run_dir / "passes.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["name", "samples", "pixels", "ms_median", "ms_min", "ms_max", "repeats"])
        for p in stats:
            w.writerow([p.name, p.samples, p.pixels, p.ms_median, p.ms_min, p.ms_max, p.repeats])


def store_run(
    store: RunStore,
    *,
    point: dict[str, Any],
    status: str,
    message: str,
    metrics: dict[str, Any],
    payload: dict[str, Any],
    stats: list[PassStats],
    wall: float,
    run_dir: Path,
    sweep_dir: str | Path | None,
    started: str,
) -> None:
    """One row in the run store for the run (its point, status, metrics, passes, info)."""
    store.record(
        RunRecord(
            config=point,
            status=status,
            metrics=metrics,
            passes=stats,
            time_ms=payload.get("time_ms"),
            error=message or None,
            info={k: payload[k] for k in INFO_KEYS if k in payload} | {"wall_s": wall},
            run_dir=str(run_dir.resolve()),
            sweep_dir=str(Path(sweep_dir).resolve()) if sweep_dir else None,
            started_at=started,
            finished_at=utc_now(),
        )
    )


def log_outcome(
    label: str, status: str, message: str, payload: dict[str, Any], n_passes: int, wall: float
) -> None:
    """The run's one log line: its figures when ok, its status and message otherwise."""
    if status == "ok":
        log.info(
            "ok %s: %d passes, %.2f ms, rel_rms %.4g, skill %+.2f, flip %.4f (%.1f s)%s",
            label,
            n_passes,
            payload["time_ms"],
            payload["rel_rms"],
            payload["skill"],
            payload["flip"],
            wall,
            ("" if payload["visible"] else " [SSS not visible at this scale]")
            + (" [visibly wrong]" if payload.get("error_visible") else ""),
        )
    else:
        log.error("%s %s: %s (%.1f s)", status, label, message, wall)


def mirror(
    spec: RunSpec,
    point: dict[str, Any],
    metrics: dict[str, Any],
    payload: dict[str, Any],
    run_dir: Path,
    status: str,
    h: str,
    sweep_dir: str | Path | None,
) -> None:
    """Mirror the run into MLflow (:mod:`sssbench.store.mlflow_mirror`) under its sweep's parent
    run. The store stays the source of truth: a failure here is logged, never raised."""
    try:
        from sssbench.store.mlflow_mirror import MlflowMirror

        mirror = MlflowMirror(spec.mlflow_uri, directory=spec.store.parent)
        parent = mirror.find_sweep(sweep_dir) if sweep_dir else None
        names = ["metrics.json", "passes.csv", "error.txt", *payload.get("previews", [])]
        mirror.log_run(
            point,
            {**metrics, "time_ms": payload.get("time_ms")},
            [run_dir / n for n in names if (run_dir / n).is_file()],
            status,
            parent=parent,
            config_hash=h,
            run_name=run_label(spec),
        )
    except Exception as exc:
        log.error("MLflow mirror failed for %s: %s: %s", run_label(spec), type(exc).__name__, exc)
