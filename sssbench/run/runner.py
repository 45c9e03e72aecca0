"""Run one point: build, time, compare, record (DESIGN §6).

:func:`execute` is the one run function of the project: the Hydra app calls it for every job
of a sweep, and the experiments call it for their grids. It

1. skips the point if the run store already holds it with status ``ok`` (unless ``force``);
2. builds the scene with the fields the pipeline needs, runs the pipeline ``warmup`` times
   untimed and ``repeats`` times timed (per pass: median / min / max; run time = sum of the
   pass medians);
3. loads the exact reference from the cache (:mod:`sssbench.store.refcache`) or computes it;
4. computes the metrics (:mod:`sssbench.score.metrics`) over the SSS region (mask > 0), the
   do-nothing baseline's errors on the same scene and the run's skill against it
   (:mod:`sssbench.score.verdict`), and the error budget (:mod:`sssbench.score.budget`) — or, for a
   stochastic method, its error split into bias and noise over ``seeds`` method seeds
   (:func:`bias_noise`);
5. writes ``metrics.json``, ``passes.csv``, ``point.json`` and previews into the run directory
   and records the run in the store.

A run that raises is stored ``failed`` (with its message; the traceback goes to
``error.txt``), one over ``timeout_s`` is stored ``timeout``; :func:`execute` never raises
for a failure of the run itself. Process-wide torch settings it changes (threads, the gather
backend) are restored when it returns.
"""

from __future__ import annotations

import contextlib
import csv
import inspect
import json
import logging
import os
import platform
import signal
import statistics
import threading
import time
import traceback
from collections.abc import Iterator
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import torch

from sssbench.run import registry, runmemo
from sssbench.run.spec import RunSpec
from sssbench.score.metrics import METRICS
from sssbench.store.refcache import cached_reference, reference_key
from sssbench.store.tracking import PassStats, RunRecord, RunStore, config_hash, utc_now

log = logging.getLogger("sssbench")

__all__ = [
    "RunOutcome",
    "RunTimeout",
    "bias_noise",
    "execute",
    "is_stochastic",
    "measure",
    "pass_stats",
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
    "visibility_local",
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
)


def pass_stats(runs: list[list[Any]]) -> list[PassStats]:
    """Per-pass median / min / max over repeats (passes matched by position and name)."""
    if not runs:
        return []
    n = len(runs[0])
    for r in runs[1:]:
        if [p.name for p in r] != [p.name for p in runs[0]]:
            raise RuntimeError(
                "the pipeline ran different passes in different repeats: "
                f"{[p.name for p in runs[0]]} vs {[p.name for p in r]}"
            )
    out = []
    for i in range(n):
        ms = [r[i].ms for r in runs]
        first = runs[0][i]
        out.append(
            PassStats(
                first.name,
                first.samples,
                first.pixels,
                statistics.median(ms),
                min(ms),
                max(ms),
                len(ms),
            )
        )
    return out


class RunTimeout(Exception):
    """The run exceeded ``timeout_s``."""


@contextlib.contextmanager
def time_limit(seconds: float | None) -> Iterator[None]:
    """Raise :class:`RunTimeout` after ``seconds`` of wall time (SIGALRM in the main thread;
    elsewhere the limit is checked when the block ends)."""
    if not seconds or seconds <= 0:
        yield
        return
    start = time.monotonic()
    use_signal = (
        hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()
    )
    if use_signal:

        def handler(signum: int, frame: Any) -> None:
            raise RunTimeout(f"run exceeded timeout_s={seconds:g} s")

        previous = signal.signal(signal.SIGALRM, handler)
        signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        if use_signal:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
    if time.monotonic() - start > seconds:
        raise RunTimeout(f"run exceeded timeout_s={seconds:g} s")


@contextlib.contextmanager
def torch_settings(threads: int | None, backend: str) -> Iterator[None]:
    """Set torch's intra-op threads and the gather backend for a block; restore both."""
    from sssbench.ops import backend as use_backend

    before_threads = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(int(threads))
    try:
        with use_backend(backend):
            yield
    finally:
        torch.set_num_threads(before_threads)


def backend_used(backend: str) -> str:
    """The tap-loop backend a run really used: ``native`` falls back to ``torch`` without a C
    compiler (see :mod:`sssbench.ops.native`)."""
    from sssbench.ops import native

    return "torch" if backend == "native" and native.library() is None else backend


def versions() -> dict[str, str]:
    """Python and package versions of the run."""
    out = {"python": platform.python_version()}
    for pkg in (
        "sssbench",
        "torch",
        "kornia",
        "numpy",
        "scikit-image",
        "hydra-core",
        "flip-evaluator",
        "pandas",
        "openexr",
        "mlflow",
    ):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


# ----------------------------------------------------------------------------- one run
@dataclass
class RunOutcome:
    """What :func:`execute` returns: the status and the stored metrics."""

    status: str  # ok, failed, timeout, skipped
    config_hash: str
    message: str = ""
    metrics: dict[str, Any] = field(default_factory=dict)


def _reference(
    spec: RunSpec, gbuffer: Any, profile: Any, pipeline: Any, cache_dir: Path | None
) -> tuple[torch.Tensor, bool, float]:
    """The reference image (``pipeline``: the run's reference pipeline), from the cache."""
    key = _scene_key(
        spec, profile, reference_params=spec.reference_params, stages=_reference_stages(spec)
    )
    image, hit, ms = cached_reference(
        key, lambda: pipeline.run(gbuffer).image, cache_dir, shape=tuple(gbuffer.diffuse.shape)
    )
    return image.to(gbuffer.dtype), hit, ms


def _scene_key(spec: RunSpec, profile: Any, **extra: Any) -> dict[str, Any]:
    """The cache key of an image computed from the run's scene and profile (plus ``extra``)."""
    return reference_key(
        scene=spec.scene,
        scene_params=spec.scene_params,
        profile=profile,
        resolution=spec.resolution,
        seed=spec.seed,
        dtype=spec.dtype,
        **extra,
    )


def _scene(spec: RunSpec, fields: tuple[str, ...]) -> Any:
    """The run's G-buffer; a synthetic scene is built once per process for all the runs on
    it (:mod:`sssbench.run.runmemo`), a user's file is read every time."""

    def build() -> Any:
        return registry.build_scene(
            spec.scene,
            spec.resolution,
            seed=spec.seed,
            fields=fields,
            dtype=spec.dtype,
            params=spec.scene_params,
        )

    if spec.scene == registry.FILE_SCENE:
        return build()
    key = {
        "scene": spec.scene,
        "params": spec.scene_params,
        "resolution": list(spec.resolution),
        "seed": spec.seed,
        "fields": list(fields),
        "dtype": spec.dtype,
    }
    return runmemo.remembered("scene", key, build)


def check_untouched(gbuffer: Any, pristine: Any, method: str) -> None:
    """Raise if the method's run changed its G-buffer (compared bit for bit with
    ``pristine``, the same scene as built): the reference, the baseline and the budget are
    computed from that G-buffer, and would silently score a different scene."""
    from dataclasses import fields as dc_fields

    from sssbench._memo import same_bits  # bit for bit: NaN == NaN, -0.0 != 0.0

    changed = [
        f.name
        for f in dc_fields(gbuffer)
        if isinstance(getattr(gbuffer, f.name), torch.Tensor)
        and not same_bits(getattr(pristine, f.name), getattr(gbuffer, f.name))
    ]
    if changed:
        raise RuntimeError(
            f"method {method!r} wrote into its G-buffer ({', '.join(changed)} changed): a "
            "method must return a new image and leave its input as it was (the reference, "
            "the baseline and the error budget are computed from that input)"
        )


def _baseline(
    spec: RunSpec,
    gbuffer: Any,
    profile: Any,
    reference: torch.Tensor,
    mask: torch.Tensor | None,
) -> tuple[torch.Tensor, float, float, float]:
    """The do-nothing baseline on the run's scene (the SSS stage left out, the other stages
    as the reference runs them): ``(image, rel RMS, mean FLIP, local FLIP)`` against the
    reference. The same for every method of a sweep on the scene, so computed once per
    process (:mod:`sssbench.run.runmemo`, keyed by the reference's cache key and the stages)."""
    from sssbench.score import verdict
    from sssbench.score.metrics import rel_rms

    def compute() -> tuple[torch.Tensor, float, float, float]:
        with torch.inference_mode():
            identity = (
                registry.build_pipeline(
                    registry.build_method("identity", profile),
                    profile,
                    spec.stages,
                    for_reference=True,
                )
                .run(gbuffer)
                .image
            )
        identity = identity.clone()  # a normal tensor (deep-copyable outside inference mode)
        flip_mean, flip_local = verdict.visibility_stats(reference, identity, mask)
        return identity, rel_rms(identity, reference, mask), flip_mean, flip_local

    if spec.scene == registry.FILE_SCENE:
        return compute()
    key = _scene_key(
        spec, profile, reference_params=spec.reference_params, stages=_reference_stages(spec)
    ) | {"reference": spec.reference, "baseline_stages": spec.stages}
    return runmemo.remembered("baseline", key, compute)


def _reference_stages(spec: RunSpec) -> dict[str, Any]:
    return {k: v for k, v in spec.stages.items() if v is not None and registry.STAGES[k][1]}


def _mask(gbuffer: Any, dtype: torch.dtype) -> torch.Tensor | None:
    if gbuffer.mask is None:
        return None
    support = (gbuffer.mask > 0).to(dtype)
    if bool(support.reshape(support.shape[0], -1).sum(1).gt(0).all()):
        return support
    return None


def prepare(spec: RunSpec) -> None:
    """Compute and cache what a run of ``spec`` reads from the reference cache — the
    reference, and with ``spec.budget`` the converged limit and the bilinear reference of
    its error budget — without timing anything. A sweep can warm its caches in parallel
    processes, then time its runs one at a time (``experiments/benchmark.py``); a run that
    finds nothing cached computes the same entries itself."""
    with torch_settings(spec.threads, spec.backend), torch.inference_mode():
        profile = registry.build_profile(spec.profile, spec.profile_kind, **spec.profile_params)
        pipeline, ref_pipeline = _pipelines(spec, profile)
        gbuffer = _scene(spec, tuple(sorted(set(pipeline.needs) | set(ref_pipeline.needs))))
        reference, _, _ = _reference(spec, gbuffer, profile, ref_pipeline, spec.reference_cache)
        if spec.budget:
            _budget_inputs(spec, profile, gbuffer, reference)


def _pipelines(spec: RunSpec, profile: Any) -> tuple[Any, Any]:
    """The run's pipeline (its method and stages) and its reference's pipeline."""
    from sssbench.ops import ReferenceSSS

    method = registry.method_from_spec(spec, profile)
    pipeline = registry.build_pipeline(method, profile, spec.stages)
    ref_pipeline = registry.build_pipeline(
        ReferenceSSS(profile, **spec.reference_params), profile, spec.stages, for_reference=True
    )
    return pipeline, ref_pipeline


def measure(spec: RunSpec, run_dir: Path) -> tuple[dict[str, Any], list[PassStats]]:
    """Build, time, compare; return the ``metrics.json`` payload and the pass statistics."""
    from sssbench.score import verdict
    from sssbench.score.metrics import compute_all

    with torch_settings(spec.threads, spec.backend):
        profile = registry.build_profile(spec.profile, spec.profile_kind, **spec.profile_params)
        pipeline, ref_pipeline = _pipelines(spec, profile)
        method = pipeline.method
        fields = tuple(sorted(set(pipeline.needs) | set(ref_pipeline.needs)))
        gbuffer = _scene(spec, fields)
        is_reference = spec.method == "reference"
        warmup, repeats = (0, 1) if is_reference else (spec.warmup, spec.repeats)
        if is_reference and (spec.warmup, spec.repeats) != (0, 1):
            log.info("method=reference is timed once (warmup 0, repeats 1)")
        cache_dir = spec.reference_cache
        with torch.inference_mode():
            for _ in range(warmup):
                pipeline.run(gbuffer)
            records = []
            for _ in range(repeats):
                out = pipeline.run(gbuffer)
                records.append(out.records)
            result = out.image
        check_untouched(gbuffer, _scene(spec, fields), spec.method)
        with torch.inference_mode():
            reference, hit, ref_ms = _reference(spec, gbuffer, profile, ref_pipeline, cache_dir)
        mask = _mask(gbuffer, result.dtype)
        identity, base_rel, base_flip, base_flip_local = _baseline(
            spec, gbuffer, profile, reference, mask
        )
        stats = pass_stats(records)
        values = compute_all(result, reference, mask)
        budget = _budget(spec, profile, gbuffer, reference) if spec.budget else {}
        mc = {}
        if spec.reference == "mc":
            mc = _mc_metrics(spec, gbuffer, result, reference, identity)
        with torch.inference_mode():
            split = _seed_split(spec, method, profile, gbuffer, result, reference, mask)
        if split:  # a stochastic method: its rel RMS is the mean over the seeds
            values["rel_rms"] = split.pop("rel_rms")
    time_ms = float(sum(p.ms_median for p in stats))
    payload: dict[str, Any] = {
        "scene": spec.scene,
        "method": spec.method,
        "profile": spec.profile,
        "sampling": spec.sampling,
        "samples": spec.samples,
        "stages": {k: v for k, v in spec.stages.items() if v is not None},
        "passes": len(stats),
        "time_ms": time_ms,
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
        **values,
        "rel_rms_identity": base_rel,
        "flip_identity": base_flip,
        "skill": verdict.skill(values["rel_rms"], base_rel),
        "skill_flip": verdict.skill(values["flip"], base_flip),
        "visibility": base_flip,
        "visibility_local": base_flip_local,
        "visible": verdict.is_visible(base_flip, base_flip_local),
        **budget,
        **mc,
        **split,
        "pixel_mm": _pixel_mm(gbuffer),
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
        "backend": backend_used(spec.backend),
        "reference_cache_hit": hit,
        "reference_ms": ref_ms,
        "versions": versions(),
    }
    if spec.previews:
        from sssbench.io import write_image_exr
        from sssbench.score.previews import preview_strip

        payload["previews"] = preview_strip(
            run_dir, result, reference, title=f"{spec.scene} · {spec.method}"
        )
        for name, image in (("result", result), ("reference", reference)):
            write_image_exr(run_dir / f"{name}.exr", image[:1], allow_rounding=True)
            payload["previews"].append(f"{name}.exr")
        payload["error_scale"] = _error_scale(result, reference)
    return payload, stats


def is_stochastic(method_name: str, method: Any) -> bool:
    """Whether a method's result depends on its seed: registered ``deterministic=False`` (the
    disk) or a separable method with stochastic rotation on (``rotation`` not ``None``)."""
    entry = registry.METHODS[method_name]
    return not entry.deterministic or getattr(method, "rotation", None) is not None


def bias_noise(
    images: list[torch.Tensor], reference: torch.Tensor, mask: torch.Tensor | None = None
) -> dict[str, float]:
    """A stochastic method's error over ``K = len(images)`` seeds, split into bias and noise.

    All relative to the reference's RMS over the mask (as :func:`sssbench.score.metrics.rel_rms`),
    per image of the batch, then averaged over it:

    - ``rel_rms``: the mean over seeds of each seed's rel RMS error;
    - ``noise_rel_rms``: the RMS over pixels and channels of the standard deviation across
      seeds (unbiased, ``K − 1``), i.e. one frame's noise;
    - ``bias_rel_rms``: the rel RMS error of the seed mean, whose square still holds
      ``noise² / K`` of averaged noise, removed: ``√max(err(mean)² − noise² / K, 0)``
      (unbiased for ``bias²``; clamped at 0 when the noise hides the bias).

    For a large image each seed's squared error is ``≈ bias² + noise²``.

    Args:
        images: ``K >= 2`` results ``(B, 3, H, W)`` of the same method with different seeds.
        reference: ``(B, 3, H, W)``.
        mask: ``(B, 1, H, W)`` region (> 0) or ``None`` for all pixels.

    Returns:
        ``{"rel_rms", "bias_rel_rms", "noise_rel_rms", "seeds"}``.
    """
    from sssbench.score.metrics import rel_rms

    if len(images) < 2:
        raise ValueError(f"images must hold >= 2 seeds' results, got {len(images)}")
    k = len(images)
    stack = torch.stack([im.double() for im in images])  # (K, B, C, H, W)
    ref = reference.double()
    m = None if mask is None else (mask > 0).double()

    def mean_px(v: torch.Tensor) -> torch.Tensor:  # (B, C, H, W) -> (B,), over the mask
        if m is None:
            return v.flatten(1).mean(1)
        return (v * m).flatten(1).sum(1) / (m.flatten(1).sum(1) * v.shape[1])

    ref_rms = mean_px(ref**2).sqrt()
    noise = mean_px(stack.var(0)).sqrt() / ref_rms
    err_mean = mean_px((stack.mean(0) - ref) ** 2).sqrt() / ref_rms
    bias = (err_mean**2 - noise**2 / k).clamp_min(0.0).sqrt()
    per_seed = [rel_rms(im, ref, None if m is None else m) for im in stack]
    return {
        "rel_rms": sum(per_seed) / k,
        "bias_rel_rms": float(bias.mean()),
        "noise_rel_rms": float(noise.mean()),
        "seeds": k,
    }


def _seed_split(
    spec: RunSpec,
    method: Any,
    profile: Any,
    gbuffer: Any,
    first: torch.Tensor,
    reference: torch.Tensor,
    mask: torch.Tensor | None,
) -> dict[str, float]:
    """:func:`bias_noise` of a stochastic method over ``spec.seeds`` seeds: ``first`` (the
    timed result, the run's seed ``s``) and ``s + 1 … s + K − 1`` (``s`` = the method's own
    ``seed`` option if given, else the run's seed; the scene keeps the run's seed). Empty for
    deterministic methods and ``seeds == 1``."""
    seeds = spec.seeds
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise ValueError(f"seeds must be an integer >= 1, got {seeds!r}")
    if seeds == 1 or not is_stochastic(spec.method, method):
        return {}
    base = int(spec.method_params.get("seed", spec.seed))
    images = [first]
    for k in range(1, seeds):
        params = dict(spec.method_params)
        if "seed" in params:
            params["seed"] = base + k
        other = registry.method_from_spec(spec, profile, seed=base + k, params=params)
        images.append(registry.build_pipeline(other, profile, spec.stages).run(gbuffer).image)
    return bias_noise(images, reference, mask)


def _error_scale(result: torch.Tensor, reference: torch.Tensor) -> float:
    """The run's largest |error| relative to the reference peak (the preview's scale)."""
    err = (result[:1] - reference[:1]).abs().mean(1)
    peak = float(reference[:1].max()) or 1.0
    return float(err.max()) / peak


def _pixel_mm(gbuffer: Any) -> float:
    """Footprint of a pixel (mm) at the median depth of the SSS region (mask > 0, or all)."""
    from sssbench.gbuffer import pixel_size_mm

    depth = gbuffer.depth[:1]
    if gbuffer.mask is not None and bool((gbuffer.mask[:1] > 0).any()):
        depth = depth[gbuffer.mask[:1] > 0]
    z = float(depth.double().median())
    return float(pixel_size_mm(torch.tensor(z), gbuffer.fov_y, gbuffer.shape[1]))


#: the tap ladder of the converged method in a run's budget: 17, 33, 65, 129, 257 taps
#: (independent of the run's own count, so one cached limit serves a whole samples sweep)
BUDGET_START, BUDGET_MAX = 17, 257


@dataclass
class _BudgetInputs:
    """What a run's error budget reads from the reference cache, and how it builds the
    method at a tap count."""

    build: Any  # samples -> the run's method at that tap count
    g64: Any  # the G-buffer in float64
    limit: tuple[torch.Tensor, int, float]  # converged image, its taps, its last change
    bilinear: torch.Tensor | None  # the bilinear-reconstruction reference (flat scenes)


def _budget_inputs(
    spec: RunSpec, profile: Any, gbuffer: Any, reference: torch.Tensor
) -> _BudgetInputs | None:
    """The budget's cached inputs (computed and stored on a miss), or ``None`` when the run
    has no budget: the reference and the baseline, stochastic estimators (their error is
    bias plus noise, not taps), methods without a tap count, and runs where a stage changes
    the light (the budget's flat-plane model has no stages).

    The method converged in taps and the bilinear-reconstruction reference do not depend on
    the run's tap count: one cached entry serves a whole samples sweep. ``err_recon`` is
    computed on fronto-parallel planes only (the bilinear reference's FFT path); on curved
    surfaces the bilinear reference costs minutes per image, so ``err_recon`` is NaN there
    and the convention's share stays inside ``err_screen`` (docs/error_budget.md)."""
    from sssbench.ops import ReferenceSSS
    from sssbench.score import budget

    if (
        spec.method in ("reference", "identity")
        or not registry.METHODS[spec.method].deterministic
        or not registry.method_takes(spec.method, "samples")
        or _reference_stages(spec)
        or spec.samples is None
    ):
        return None

    # fitted taps (sampling="optimised") exist for the run's own tap count only; the converged
    # limit is reached by the method's own placement rule at many taps (the pre-integrated
    # kernel's importance sampling, the sum of Gaussians' uniform taps, the 2012 builder's)
    limit_sampling = (
        registry.default_option(spec.method, "sampling")
        if spec.sampling == "optimised"
        else spec.sampling
    )

    def build(samples: int) -> Any:
        sampling = spec.sampling if samples == spec.samples else limit_sampling
        return registry.method_from_spec(spec, profile, samples=samples, sampling=sampling)

    key = _scene_key(spec, profile)
    g64 = gbuffer.to(torch.float64)
    scale = float(reference.double().pow(2).mean().sqrt()) or 1.0
    limit_key = {
        **key,
        "budget_limit": [spec.method, spec.method_params, limit_sampling, BUDGET_START, BUDGET_MAX],
    }

    def compute_limit() -> torch.Tensor:
        image, n, change = budget.converged(
            build, BUDGET_START, g64, max_samples=BUDGET_MAX, scale=scale
        )
        return torch.cat([image.reshape(-1), torch.tensor([float(n), change], dtype=image.dtype)])

    packed, _, _ = cached_reference(limit_key, compute_limit, spec.reference_cache)
    packed = packed.double()
    limit = (packed[:-2].reshape(g64.diffuse.shape), int(packed[-2]), float(packed[-1]))
    bil = None
    flat = bool(gbuffer.depth.min() == gbuffer.depth.max())
    if flat and "reconstruction" in inspect.signature(ReferenceSSS.__init__).parameters:
        bil_key = {
            **key,
            "reference_params": {**spec.reference_params, "reconstruction": "bilinear"},
        }
        bil, _, _ = cached_reference(
            bil_key,
            lambda: ReferenceSSS(
                profile, **{**spec.reference_params, "reconstruction": "bilinear"}
            )(gbuffer),
            spec.reference_cache,
            shape=tuple(gbuffer.diffuse.shape),
        )
    return _BudgetInputs(build, g64, limit, bil)


def _budget(
    spec: RunSpec,
    profile: Any,
    gbuffer: Any,
    reference: torch.Tensor,
) -> dict[str, float]:
    """The run's error budget (:func:`sssbench.score.budget.error_budget`, docs/error_budget.md);
    empty where :func:`_budget_inputs` says the run has none."""
    from sssbench.score import budget

    inputs = _budget_inputs(spec, profile, gbuffer, reference)
    if inputs is None:
        return {}
    # the budget splits the SSS stage's error: the reference without the specular the
    # pipeline adds after scattering (on the stencil), as the method alone computes it
    sss_reference = _without_specular(reference, gbuffer)
    result = budget.error_budget(
        inputs.build,
        spec.samples,
        inputs.g64,
        profile,
        reference=sss_reference,
        reference_bilinear=inputs.bilinear,
        limit=inputs.limit,
        recon=inputs.bilinear is not None,
    ).as_dict()
    keys = [k for k in result if k.startswith(("err_", "contribution_"))] + ["taps_residual"]
    return {k: float(result[k]) for k in keys if k != "err_total"} | {
        "converged_samples": int(result["converged_samples"])
    }


def _without_specular(image: torch.Tensor, gbuffer: Any) -> torch.Tensor:
    """``image`` before the specular the pipeline adds after scattering (on the stencil)."""
    if gbuffer.specular is None:
        return image
    active = (gbuffer.mask_or_ones() > 0).to(image.dtype)
    return image - gbuffer.specular.to(image.dtype) * active


def _mc_metrics(
    spec: RunSpec,
    gbuffer: Any,
    result: torch.Tensor,
    reference: torch.Tensor,
    identity: torch.Tensor,
) -> dict[str, Any]:
    """Errors against Monte Carlo light transport (``reference=mc``; docs/mc.md).

    Quantity compared: the *diffuse* SSS result, i.e. the pipeline's image without the
    specular it adds after scattering (:func:`_without_specular`), against the MC exitance
    normalised by the material's diffuse albedo ``ρ = (1 − F(0)) R_d``
    (:mod:`sssbench.mc.scene`): with texturing off (the default) the pipeline blurs the
    irradiance with a profile normalised to 1, which on a uniformly, normally lit plane gives
    back the irradiance, as ``M/ρ`` does. With a texturing stage the pipeline multiplies by
    the G-buffer's albedo (``pre``, ``post`` and ``sqrt`` agree for the uniform albedo of the
    MC scenes), so the MC image is multiplied by it too. Translucency needs nothing: the MC
    carries the light through thin parts physically, with or without the stage.

    The material is the measured one of the run's profile table
    (:data:`sssbench.mc.scene.PROFILE_MATERIALS`) unless ``reference_params.mc_material``
    names another. Errors are relative RMS over the stencil where the MC has a value, with
    the MC noise subtracted (:func:`sssbench.mc.scene.noise_corrected_rel_rms`), each with
    its jackknife standard error."""
    from sssbench.mc.scene import noise_corrected_rel_rms, scene_mc

    opts = spec.mc_params
    material = opts.get("mc_material", spec.profile)
    mc = scene_mc(
        spec.scene,
        gbuffer,
        spec.scene_params,
        material,
        photons=opts.get("mc_photons"),
        batches=opts.get("mc_batches", 8),
        seed=opts.get("mc_seed", spec.seed),
        workers=opts.get("mc_workers"),
    )
    batches = mc.batches
    if spec.stages.get("texturing") is not None and gbuffer.albedo is not None:
        batches = batches * gbuffer.albedo[:1].double()
    region = mc.mask & (gbuffer.mask_or_ones()[0, 0] > 0)
    out: dict[str, Any] = {}
    for name, image in (("rel_rms_mc", result), ("reference_vs_mc", reference)):
        value, se = noise_corrected_rel_rms(_without_specular(image, gbuffer)[:1], batches, region)
        out[name], out[f"{name}_se"] = value, se
    out["identity_vs_mc"] = noise_corrected_rel_rms(
        _without_specular(identity, gbuffer)[:1], batches, region
    )[0]
    out |= {"mc_photons": mc.photons, "mc_seconds": mc.seconds, "mc_material": str(material)}
    return out


def _write_json(path: Path, payload: dict[str, Any]) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2, default=str))
    os.replace(tmp, path)


def run_label(spec: RunSpec) -> str:
    """``scene/method/profile/sampling/samples`` (``-`` for what does not apply)."""
    return "/".join(
        str(v) if v is not None else "-"
        for v in (spec.scene, spec.method, spec.profile, spec.sampling, spec.samples)
    )


def execute(spec: RunSpec, run_dir: str | Path, sweep_dir: str | Path | None = None) -> RunOutcome:
    """Run one point and record it; never raises for a failure of the run itself."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    store = RunStore(spec.store, journal_mode=spec.store_journal)
    point = spec.point()
    h = config_hash(point)
    label = run_label(spec)
    point_file = run_dir / "point.json"
    info = {"config_hash": h, "store": str(store.path), "config": point, "status": "running"}
    _write_json(point_file, info)
    if not spec.force and store.is_done(h):
        log.info("skip %s: already stored ok in %s (force=true re-runs)", label, store.path)
        _write_json(point_file, {**info, "status": "skipped"})
        return RunOutcome("skipped", h)
    started = utc_now()
    t0 = time.perf_counter()
    status, message, payload, stats = "ok", "", {}, []
    try:
        with time_limit(spec.timeout_s):
            payload, stats = measure(spec, run_dir)
    except RunTimeout as exc:
        status, message = "timeout", str(exc)
    except Exception as exc:
        status, message = "failed", f"{type(exc).__name__}: {exc}"
        (run_dir / "error.txt").write_text(traceback.format_exc())
    wall = time.perf_counter() - t0
    metrics = {k: payload[k] for k in METRIC_KEYS if k in payload}
    if payload:
        _write_json(
            run_dir / "metrics.json",
            {**payload, "status": status, "config_hash": h, "wall_s": wall},
        )
        with open(run_dir / "passes.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["name", "samples", "pixels", "ms_median", "ms_min", "ms_max", "repeats"])
            for p in stats:
                w.writerow(
                    [p.name, p.samples, p.pixels, p.ms_median, p.ms_min, p.ms_max, p.repeats]
                )
    record = RunRecord(
        config=point,
        status=status,
        metrics=metrics,
        passes=stats,
        time_ms=payload.get("time_ms"),
        error=message or None,
        info={
            k: payload[k]
            for k in (
                "threads",
                "backend",
                "versions",
                "plan",
                "skipped_stages",
                "reference_cache_hit",
                "metric_region",
                "visible",
                "error_scale",
            )
            if k in payload
        }
        | {"wall_s": wall},
        run_dir=str(run_dir.resolve()),
        sweep_dir=str(Path(sweep_dir).resolve()) if sweep_dir else None,
        started_at=started,
        finished_at=utc_now(),
    )
    store.record(record)
    _write_json(point_file, {**info, "status": status, "error": message or None})
    if spec.mlflow:
        _mirror(spec, point, metrics, payload, run_dir, status, h, sweep_dir)
    if status == "ok":
        log.info(
            "ok %s: %d passes, %.2f ms, rel_rms %.4g, skill %+.2f, flip %.4f (%.1f s)%s",
            label,
            len(stats),
            payload["time_ms"],
            payload["rel_rms"],
            payload["skill"],
            payload["flip"],
            wall,
            "" if payload["visible"] else " [SSS not visible at this scale]",
        )
    else:
        log.error("%s %s: %s (%.1f s)", status, label, message, wall)
    return RunOutcome(status, h, message, metrics)


def _mirror(
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
