"""Run one point: build, time, compare, record (DESIGN §6).

:func:`execute` is the one run function of the project: the Hydra app calls it for every job
of a sweep, and the experiments call it for their grids. It reads as its steps, each a
function in the module of its job:

1. **skip** the point if the run store already holds it with status ``ok`` (unless ``force``);
   else **claim** it (:mod:`sssbench.store.claims`): while another job of the sweep runs the
   same point, wait for it, and skip the point if that job stored it ``ok``;
2. **build** the profile, the pipelines and the scene with the fields they need
   (:func:`sssbench.run.inputs.build`);
3. **time** the pipeline: ``warmup`` untimed runs, ``repeats`` timed ones (per pass: median /
   min / max; run time = sum of the pass medians; :func:`sssbench.run.settings.time_runs`;
   the timed ones alone among a sweep's processes, the untimed ones while the others finish
   their current step: :func:`sssbench.run.settings.exclusive_timing`),
   then check that the method left its G-buffer as built (bit for bit against a pristine
   copy). From here to the record the G-buffer is sealed (:meth:`sssbench.gbuffer.GBuffer.sealed`):
   the memo trusts its stencils and masks in O(1) per call, and a write into it is an error
   (at the next lookup, at this check, or at the seal's end), never a stale value;
4. **reference**: the exact reference from the cache (:mod:`sssbench.store.refcache`) or
   computed;
5. **score**: the metrics (:mod:`sssbench.score.metrics`) over the SSS region (mask > 0), the
   do-nothing baseline's errors on the same scene and the run's skill against it
   (:mod:`sssbench.score.verdict`);
6. **budget or bias/noise**: the error budget (:mod:`sssbench.run.budget_step`) — or, for a
   stochastic method, its error split into bias and noise over ``seeds`` method seeds
   (:mod:`sssbench.run.stochastic`) — and errors against Monte Carlo with ``reference=mc``
   (:mod:`sssbench.run.mc_step`);
7. **record**: ``metrics.json``, ``passes.csv``, ``point.json`` and previews into the run
   directory, one row in the store (:mod:`sssbench.run.record`).

A run that raises is stored ``failed`` (with its message; the traceback goes to
``error.txt``), one over ``timeout_s`` is stored ``timeout``; :func:`execute` never raises
for a failure of the run itself. Process-wide torch settings it changes (threads, the gather
backend) are restored when it returns.
"""

from __future__ import annotations

import logging
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from sssbench._checks import check_choice
from sssbench.ops import native
from sssbench.run.budget_step import (
    bilinear_reference,
    budget_limit,
    budget_metrics,
    has_budget,
    runs_float64,
)
from sssbench.run.inputs import (
    Built,
    baseline,
    build,
    check_untouched,
    error_scale,
    metric_mask,
    reference_image,
    run_pixel_mm,
    scene_gbuffer,
)
from sssbench.run.mc_step import mc_metrics
from sssbench.run.record import (
    log_outcome,
    mirror,
    run_label,
    store_run,
    write_json,
    write_outputs,
)
from sssbench.run.settings import (
    RunTimeout,
    backend_used,
    checkpoint,
    exclusive_timing,
    gl_times,
    pass_stats,
    time_limit,
    time_runs,
    times_on_device,
    torch_settings,
    versions,
    warm_runs,
)
from sssbench.run.spec import RunSpec
from sssbench.run.stochastic import is_stochastic, seed_split
from sssbench.score import verdict
from sssbench.score.bias_noise import bias_noise
from sssbench.score.metrics import METRICS, compute_all, flip_map_over
from sssbench.store.claims import LEASE_MARGIN_S, LEASE_NO_LIMIT_S, PointClaims
from sssbench.store.tracking import PassStats, RunStore, config_hash, utc_now

log = logging.getLogger("sssbench")

__all__ = [
    "RunOutcome",
    "RunTimeout",
    "bias_noise",
    "check_untouched",
    "execute",
    "is_stochastic",
    "measure",
    "pass_stats",
    "prepare",
    "run_label",
    "time_limit",
    "versions",
    "METRIC_KEYS",
]

#: per-run numbers copied into the store's metrics: the image metrics
#: (:data:`sssbench.score.metrics.METRICS`), then these
METRIC_KEYS = (
    *METRICS,
    "rel_rms_identity",
    "flip_identity",
    "skill",
    "skill_flip",
    "visibility",
    "visibility_window",
    "error_flip_window",
    "err_model",
    "err_taps",
    "err_screen",
    "err_recon",
    "taps_residual",
    "converged_samples",
    "contribution_model",
    "contribution_taps",
    "contribution_screen",
    "contribution_recon",
    "bias_rel_rms",
    "noise_rel_rms",
    "seeds",
    "samples_per_pixel",
    "reference_ms",
    "pixel_mm",
    "rel_rms_mc",
    "rel_rms_mc_se",
    "reference_vs_mc",
    "reference_vs_mc_se",
    "identity_vs_mc",
    "identity_vs_mc_se",
)


@dataclass
class RunOutcome:
    """What :func:`execute` returns: the status and the stored metrics."""

    status: str  # ok, failed, timeout, skipped
    config_hash: str
    message: str = ""
    metrics: dict[str, Any] = field(default_factory=dict)


def execute(spec: RunSpec, run_dir: str | Path, sweep_dir: str | Path | None = None) -> RunOutcome:
    """Run one point and record it; never raises for a failure of the run itself."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    store = RunStore(spec.store, journal_mode=spec.store_journal)
    point, label = spec.point(), run_label(spec)
    h = config_hash(point)
    info = {"config_hash": h, "store": str(store.path), "config": point, "status": "running"}
    write_json(run_dir / "point.json", info)
    if not spec.force and store.is_done(h):  # 1. skip if stored
        log.info("skip %s: already stored ok in %s (force=true re-runs)", label, store.path)
        write_json(run_dir / "point.json", {**info, "status": "skipped"})
        return RunOutcome("skipped", h)
    claims = PointClaims(store, lease_s=claim_lease_s(spec))
    since = utc_now() if spec.force else ""  # forced: only a concurrent job's row counts
    if claims.wait(h, since, label) == "done":  # 1. another job stored it while we waited
        log.info("skip %s: stored ok by a concurrent job in %s", label, store.path)
        write_json(run_dir / "point.json", {**info, "status": "skipped"})
        return RunOutcome("skipped", h)
    try:
        started, t0 = utc_now(), time.perf_counter()
        status, message, payload, stats = _guarded_measure(spec, run_dir)  # 2.-6.
        wall = time.perf_counter() - t0
        metrics = {k: payload[k] for k in METRIC_KEYS if k in payload}
        write_outputs(run_dir, payload, stats, {"status": status, "config_hash": h, "wall_s": wall})
        store_run(store, point=point, status=status, message=message, metrics=metrics,  # 7.
                  payload=payload, stats=stats, wall=wall, run_dir=run_dir, sweep_dir=sweep_dir,
                  started=started)  # fmt: skip
    finally:
        claims.release(h)
    write_json(run_dir / "point.json", {**info, "status": status, "error": message or None})
    if spec.mlflow:
        mirror(spec, point, metrics, payload, run_dir, status, h, sweep_dir)
    log_outcome(label, status, message, payload, len(stats), wall)
    return RunOutcome(status, h, message, metrics)


def claim_lease_s(spec: RunSpec) -> float:
    """How long a claim on ``spec``'s point holds for a job on another host (s;
    :mod:`sssbench.store.claims`): the run's time limit plus a margin for building, scoring and
    recording, or a long default for a run without a limit."""
    if spec.timeout_s:
        return float(spec.timeout_s) + LEASE_MARGIN_S
    return LEASE_NO_LIMIT_S


def _guarded_measure(
    spec: RunSpec, run_dir: Path
) -> tuple[str, str, dict[str, Any], list[PassStats]]:
    """:func:`measure` under the run's time limit: ``(status, message, payload, stats)``; a
    failure is a status (its traceback into ``error.txt``), never an exception."""
    try:
        with time_limit(spec.timeout_s):
            payload, stats = measure(spec, run_dir)
        return "ok", "", payload, stats
    except RunTimeout as exc:
        return "timeout", str(exc), {}, []
    except Exception as exc:
        (run_dir / "error.txt").write_text(traceback.format_exc())
        return "failed", f"{type(exc).__name__}: {exc}", {}, []


#: what :func:`prepare` computes: everything, or one of the two halves a warm-up runs as
#: separate tasks (the box reference with the budget's converged limits; the bilinear reference)
PREPARE_PARTS = ("all", "reference", "bilinear")


def prepare(spec: RunSpec, part: str = "all") -> None:
    """Compute and cache what a run of ``spec`` reads from the reference cache — the
    reference, and with ``spec.budget`` the converged limit and the bilinear reference of
    its error budget — without timing anything. A sweep can warm its caches in parallel
    processes, then time its runs one at a time (``experiments/benchmark.py``); a run that
    finds nothing cached computes the same entries itself.

    ``part``: ``"all"``; ``"reference"`` (the reference and the converged limit, which is
    scaled by the reference's RMS); ``"bilinear"`` (the bilinear reference alone: it needs
    neither), so a warm-up can compute the two halves of a scene in two processes."""
    check_choice("part", part, PREPARE_PARTS)
    with torch_settings(spec.threads, spec.backend), torch.inference_mode():
        built = build(spec)
        budgeted = spec.budget and has_budget(spec)
        if part != "bilinear":
            reference, _, _ = reference_image(
                spec, built.gbuffer, built.profile, built.ref_pipeline, spec.reference_cache
            )
            if budgeted:
                budget_limit(spec, built.profile, built.gbuffer, reference)
        if budgeted and part != "reference":
            bilinear_reference(spec, built.profile, built.gbuffer)


def measure(spec: RunSpec, run_dir: Path) -> tuple[dict[str, Any], list[PassStats]]:
    """Build, time, compare; return the ``metrics.json`` payload and the pass statistics."""
    is_reference = spec.method == "reference"
    warmup, repeats = (0, 1) if is_reference else (spec.warmup, spec.repeats)
    if is_reference and (spec.warmup, spec.repeats) != (0, 1):
        log.info("method=reference is timed once (warmup 0, repeats 1)")
    if runs_float64(spec):  # a cold first run builds both dtypes' loops side by side
        native.want_float64()
    with torch_settings(spec.threads, spec.backend):
        built = build(spec)  # 2. build
        pristine = scene_gbuffer(spec, built.fields)  # the same scene, never handed out
        with built.gbuffer.sealed(pristine):  # memo lookups O(1); verified at the end
            return _measure_sealed(spec, run_dir, built, pristine, is_reference, warmup, repeats)


def _measure_sealed(
    spec: RunSpec,
    run_dir: Path,
    built: Built,
    pristine: Any,
    is_reference: bool,
    warmup: int,
    repeats: int,
) -> tuple[dict[str, Any], list[PassStats]]:
    """Steps 3.–6. of :func:`measure` on the run's sealed G-buffer (``pristine``: a separate
    copy of the scene as built)."""
    on_device = times_on_device(spec.backend, spec.method)  # GL: timed by the device
    cpu_runs = (0, 1) if on_device else (warmup, repeats)  # the image once, not timed twice

    def warm() -> None:  # the untimed calls, while the other processes finish their step
        warm_runs(built.pipeline, built.gbuffer, cpu_runs[0])

    # 3. time, alone among a sweep's processes (run.settings.timing_slot)
    with exclusive_timing(warm if cpu_runs[0] else None):
        t0 = time.perf_counter()
        out, stats = time_runs(built.pipeline, built.gbuffer, 0, cpu_runs[1])
        device = None
        if on_device:
            device = gl_times(spec.method, built.pipeline, built.gbuffer, warmup, repeats)
            stats = device[0] if device else stats
        wall_ms = (time.perf_counter() - t0) * 1e3
    if is_reference and not any(p.name == "reference" for p in stats):
        stats = _reference_pass(stats, wall_ms, built.gbuffer)
    result = out.image
    # from here on, untimed: a process of the sweep waiting to time goes first at each
    # checkpoint (settings.timing_slot), so the scoring overlaps the other processes' scoring
    check_untouched(built.gbuffer, pristine, spec.method)
    checkpoint()
    with torch.inference_mode():  # 4. reference
        reference, hit, ref_ms = reference_image(
            spec, built.gbuffer, built.profile, built.ref_pipeline, spec.reference_cache
        )
    mask = metric_mask(built.gbuffer, result.dtype)  # 5. score
    identity, *base = baseline(spec, built.gbuffer, built.profile, reference, mask)
    checkpoint()
    # one FLIP evaluation for the mean and the local, over the mask's box: both read only
    # the pixels with mask > 0 (the previews compute no FLIP)
    fmap = flip_map_over(result, reference, mask)
    checkpoint()
    values = compute_all(result, reference, mask, fmap=fmap)
    _, values["error_flip_window"], _ = verdict.error_visibility(result, reference, mask, fmap)
    checkpoint()
    extra = _budget_or_noise(spec, built, result, reference, identity, mask)  # 6.
    checkpoint()
    if "rel_rms" in extra:  # a stochastic method: its rel RMS is the mean over the seeds
        values["rel_rms"] = extra.pop("rel_rms")
    scores = _verdicts(values, *base) | extra
    payload = _payload(spec, built, out, stats, scores, warmup, repeats, mask)
    payload |= {"reference_cache_hit": hit, "reference_ms": ref_ms, "versions": versions()}
    if device:
        payload |= device[1]
    if spec.previews:
        payload |= _previews(spec, run_dir, result, reference)
    return payload, stats


def _reference_pass(stats: list[PassStats], wall_ms: float, gbuffer: Any) -> list[PassStats]:
    """``stats`` of a ``method=reference`` run (timed once) whose reference recorded no pass,
    with the reference as its first pass: the wall time of the run less the passes recorded
    around it (stages, specular), so the reference is reported at its cost, never as free."""
    ms = max(wall_ms - sum(p.ms_median for p in stats), 0.0)
    b, h, w = gbuffer.shape
    return [PassStats("reference", 0, b * h * w, ms, ms, ms, 1), *stats]


def _verdicts(
    values: dict[str, float], base_rel: float, base_flip: float, base_flip_local: float
) -> dict[str, Any]:
    """The image metrics with the baseline's errors on the same scene (``base_*``: its rel
    RMS, mean and local FLIP), the skill against it, whether SSS is visible at all and
    whether the run's own error is visible (its mean FLIP ``flip`` and local FLIP
    ``error_flip_window`` against the reference, by the same rule: ``error_visible``)."""
    return {
        **values,
        "rel_rms_identity": base_rel,
        "flip_identity": base_flip,
        "skill": verdict.skill(values["rel_rms"], base_rel),
        "skill_flip": verdict.skill(values["flip"], base_flip),
        "visibility": base_flip,
        "visibility_window": base_flip_local,
        "visible": verdict.is_visible(base_flip, base_flip_local),
        "error_visible": verdict.is_visible(values["flip"], values["error_flip_window"]),
    }


def _budget_or_noise(
    spec: RunSpec,
    built: Built,
    result: torch.Tensor,
    reference: torch.Tensor,
    identity: torch.Tensor,
    mask: torch.Tensor | None,
) -> dict[str, Any]:
    """The error budget (``spec.budget``), the errors against Monte Carlo (``reference=mc``)
    and, for a stochastic method, its bias and noise over seeds (its ``rel_rms`` then the
    mean over the seeds, replacing the timed seed's)."""
    out: dict[str, Any] = {}
    if spec.budget:
        out |= budget_metrics(spec, built.profile, built.gbuffer, reference)
        checkpoint()
    if spec.reference == "mc":
        out |= mc_metrics(spec, built.gbuffer, result, reference, identity)
        checkpoint()
    with torch.inference_mode():
        method = built.pipeline.method
        out |= seed_split(spec, method, built.profile, built.gbuffer, result, reference, mask)
    return out


def _payload(
    spec: RunSpec,
    built: Built,
    out: Any,
    stats: list[PassStats],
    scores: dict[str, Any],
    warmup: int,
    repeats: int,
    mask: torch.Tensor | None,
) -> dict[str, Any]:
    """The ``metrics.json`` payload: the point, the passes and their times, the scores."""
    return {
        "scene": spec.scene,
        "method": spec.method,
        "profile": spec.profile,
        "sampling": spec.sampling,
        "samples": spec.samples,
        "stages": {k: v for k, v in spec.stages.items() if v is not None},
        **({"ignored": spec.ignored} if spec.ignored else {}),
        "passes": len(stats),
        "time_ms": float(sum(p.ms_median for p in stats)),
        "pass_times": [
            {
                "name": p.name,
                "samples": p.samples,
                "pixels": p.pixels,
                "ms_median": p.ms_median,
                "ms_min": p.ms_min,
                "ms_max": p.ms_max,
            }
            for p in stats
        ],
        **scores,
        "pixel_mm": run_pixel_mm(built.gbuffer),
        "samples_per_pixel": int(sum(p.samples for p in stats)),
        "plan": [{"stage": e.stage, "runs": e.runs, "reason": e.reason} for e in out.plan],
        "skipped_stages": [list(s) for s in out.skipped],
        "metric_region": "mask>0" if mask is not None else "all",
        "resolution": list(spec.resolution),
        "seed": spec.seed,
        "dtype": spec.dtype,
        "repeats": repeats,
        "warmup": warmup,
        "threads": spec.threads if spec.threads is not None else torch.get_num_threads(),
        "backend": backend_used(spec.backend, spec.dtype),
    }


def _previews(
    spec: RunSpec, run_dir: Path, result: torch.Tensor, reference: torch.Tensor
) -> dict[str, Any]:
    """The preview strip and the result and reference as float EXR in the run directory."""
    from sssbench.io import write_image_exr
    from sssbench.score.previews import preview_strip

    files = preview_strip(run_dir, result, reference, title=f"{spec.scene} · {spec.method}")
    for name, image in (("result", result), ("reference", reference)):
        write_image_exr(run_dir / f"{name}.exr", image[:1], allow_rounding=True)
        files.append(f"{name}.exr")
    return {"previews": files, "error_scale": error_scale(result, reference)}
