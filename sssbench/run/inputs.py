"""A run's inputs: its profile, pipelines and G-buffer (a synthetic scene built once per
process, :mod:`sssbench.run.runmemo`), the exact reference from the cache, the region the
metrics cover, the do-nothing baseline scored once per scene, and the check that the method
left its G-buffer untouched."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from sssbench.ops import ReferenceSSS
from sssbench.run import registry, runmemo
from sssbench.run.spec import RunSpec, mc_options
from sssbench.store.refcache import cached_reference, reference_key

__all__ = [
    "Built",
    "baseline",
    "build",
    "check_requested",
    "check_spec",
    "check_stages",
    "scene_label",
    "check_untouched",
    "error_scale",
    "metric_mask",
    "pipelines",
    "reference_image",
    "reference_stages",
    "run_pixel_mm",
    "scene_gbuffer",
    "scene_key",
    "stage_pipeline",
    "without_specular",
]


@dataclass
class Built:
    """What a run is made of: its profile, its pipeline and the reference's, the G-buffer
    fields both need, and the G-buffer (B, C, H, W fields, mm)."""

    profile: Any
    pipeline: Any
    ref_pipeline: Any
    fields: tuple[str, ...]
    gbuffer: Any


def build(spec: RunSpec) -> Built:
    """Build the run's profile, pipelines and G-buffer (the fields both pipelines need), and
    check that every stage the run asks for can run on the scene (:func:`check_requested`)."""
    profile = registry.build_profile(spec.profile, spec.profile_kind, **spec.profile_params)
    pipeline, ref_pipeline = pipelines(spec, profile)
    fields = tuple(sorted(set(pipeline.needs) | set(ref_pipeline.needs)))
    gbuffer = scene_gbuffer(spec, fields)
    check_requested(spec, pipeline, gbuffer)
    return Built(profile, pipeline, ref_pipeline, fields, gbuffer)


def check_spec(spec: RunSpec, memo: dict[str, Any] | None = None) -> None:
    """Check every value of ``spec`` a run reads, as the run reads it, building no image — what
    the app runs for every job of a sweep before the first run (issue 28): the profile, the
    method, the exact reference and the stages are constructed by the registry functions
    :func:`build` uses (cheap: no image), the scene's parameters are checked by its own builder
    stopped before its first image (:func:`sssbench.run.registry.check_scene`) and the Monte
    Carlo options by the Monte Carlo reference's own check. One set of rules: the pre-check and
    the run cannot disagree on a value.

    Args:
        spec: the run.
        memo: a dict shared by the checks of one grid: each part (scene, profile, method, …)
            is checked once per distinct set of the values it reads.

    Raises:
        ValueError: one line naming the config key (``scene.params``, ``profile.params``,
            ``method.params``, ``reference_params``, a stage's ``params``), whose it is, and
            the error of the constructor that refused it.
    """
    memo = {} if memo is None else memo

    def part(key: str, where: str, reads: Any, make: Any) -> Any:
        index = json.dumps([key, reads], sort_keys=True, default=str)
        if index not in memo:
            try:
                memo[index] = make()
            except (ValueError, TypeError) as exc:
                message = " ".join(str(exc).split())
                raise ValueError(
                    f"{key} {'with' if '=on' in key else 'of'} {where}: {message}"
                ) from exc
        return memo[index]

    scene = (spec.scene, spec.scene_params, spec.resolution, spec.seed, spec.dtype)
    part(
        "scene.params",
        f"scene {scene_label(spec)}",
        scene,
        lambda: registry.check_scene(
            spec.scene, spec.resolution, seed=spec.seed, dtype=spec.dtype, params=spec.scene_params
        ),
    )
    kind = (spec.profile, spec.profile_kind, spec.profile_params)
    profile = part(
        "profile.params",
        f"profile {spec.profile}",
        kind,
        lambda: registry.build_profile(spec.profile, spec.profile_kind, **spec.profile_params),
    )
    options = (spec.method, spec.method_params, spec.samples, spec.sampling, spec.seed)
    method = part(
        "method.params / samples / sampling",
        f"method {spec.method}",
        [kind, options],
        lambda: registry.method_from_spec(spec, profile),
    )
    part(
        "reference_params",
        f"the exact reference of profile {spec.profile}",
        [kind, spec.reference_params],
        lambda: ReferenceSSS(profile, **spec.reference_params),
    )
    for stage, params in spec.stages.items():
        if params is not None:
            part(
                f"{stage}=on ({stage}.params)",
                f"method {spec.method}",
                [kind, options, stage, params],
                lambda stage=stage, params=params: registry.build_pipeline(
                    method, profile, {stage: params}, auto=False
                ),
            )
    part(
        "stages",
        f"method {spec.method}",
        [kind, options, spec.stages],
        lambda: stage_pipeline(spec, method, profile),
    )
    if spec.reference == "mc":
        from sssbench.mc.options import check_options

        mc = mc_options(spec)
        part("reference_params (mc_*)", "the Monte Carlo reference", mc,
             lambda: check_options(**mc))  # fmt: skip


def stage_pipeline(spec: RunSpec, method: Any, profile: Any, *, for_reference: bool = False) -> Any:
    """The pipeline of ``method`` with the run's stages. A stage a run switches on was asked
    for (every stage is off by default), so the pipeline's automatic plan — which leaves out a
    stage it judges negligible on the scene — is off: the requested stage runs, or the run
    fails naming why (:func:`check_requested`); only defaults are ever planned away."""
    return registry.build_pipeline(
        method, profile, spec.stages, for_reference=for_reference, auto=False
    )


def scene_label(spec: RunSpec) -> str:
    """The run's scene as a message names it: its name and its parameters (``face
    (pixel_mm=0.3)``: the ``face_portrait`` option), a file scene by its path."""
    params = {k: v for k, v in spec.scene_params.items() if k != "sha256"}
    if not params:
        return spec.scene
    return f"{spec.scene} ({', '.join(f'{k}={v}' for k, v in sorted(params.items()))})"


def check_requested(spec: RunSpec, pipeline: Any, gbuffer: Any) -> None:
    """Raise ``ValueError`` naming the stage and the reason when a stage the run switches on
    cannot run on its scene (a G-buffer field the scene does not have, no back light, an
    empty mask): such a run would otherwise be stored ``ok`` with the stage silently left out."""
    requested = {k for k, v in spec.stages.items() if v is not None}
    for entry in pipeline.plan(gbuffer):
        if entry.stage in requested and not entry.runs:
            raise ValueError(
                f"{entry.stage}=on cannot run on scene {scene_label(spec)}: {entry.reason} "
                f"(leave {entry.stage} off for this scene, or choose a scene that has it)"
            )


def check_stages(spec: RunSpec) -> list[str]:
    """What the app checks before the first run of a job that switches a stage on (issue 28):
    the run's own inputs are built (:func:`build`: the profile, the pipelines, the scene's
    G-buffer, kept in :mod:`sssbench.run.runmemo` for the run that follows) and

    - a stage that **cannot run** on the scene — a G-buffer field it needs is missing, no
      masked pixel is back-lit (translucency's cosine term is zero everywhere, so it would add
      exactly nothing), the mask is empty, or the method does not take the stage's input —
      raises ``ValueError`` (``TypeError`` for the method) naming the stage and why
      (:func:`check_requested`);
    - a stage that would **add exactly nothing** (translucency through a thickness whose
      transmittance is 0 in float64: the image would be bit for bit the one without it,
      :meth:`~sssbench.ops.Pipeline.inert`) raises ``ValueError`` the same way: a row stored
      as ``translucency=on`` would claim a stage that did not take part;
    - a stage that runs but that the automatic plan would leave out as **negligible** (too
      thick to transmit: at most 0.1 % of the back light; no silhouette; widths changed by at
      most 2 %) is returned as one note per stage. It is not refused: ``on`` means "run this
      stage" (docs/architecture.md §5) — the thresholds are judgements, the stage still changes
      the image a little and its cost is a real measurement — so the run goes ahead as asked and
      the app prints the note before the first run.

    Returns:
        one line per requested stage judged negligible on the scene (empty for none).
    """
    if not any(v is not None for v in spec.stages.values()):
        return []
    built = build(spec)
    requested = {k for k, v in spec.stages.items() if v is not None}
    for stage, reason in built.pipeline.inert(built.gbuffer).items():
        if stage in requested:
            raise ValueError(
                f"{stage}=on cannot change the image on scene {scene_label(spec)}: {reason} "
                f"(leave {stage} off for this scene, or choose a scene where it can)"
            )
    return [
        f"{stage}=on on scene {scene_label(spec)}: runs as asked, though the automatic plan would "
        f"leave it out ({reason.removeprefix('auto: ')})"
        for stage, reason in built.pipeline.negligible(built.gbuffer).items()
        if stage in requested
    ]


def reference_image(
    spec: RunSpec, gbuffer: Any, profile: Any, pipeline: Any, cache_dir: Path | None
) -> tuple[torch.Tensor, bool, float]:
    """The reference image (``pipeline``: the run's reference pipeline), from the cache."""
    key = scene_key(
        spec, profile, reference_params=spec.reference_params, stages=reference_stages(spec)
    )
    image, hit, ms = cached_reference(
        key, lambda: pipeline.run(gbuffer).image, cache_dir, shape=tuple(gbuffer.diffuse.shape)
    )
    return image.to(gbuffer.dtype), hit, ms


def scene_key(spec: RunSpec, profile: Any, **extra: Any) -> dict[str, Any]:
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


def scene_gbuffer(spec: RunSpec, fields: tuple[str, ...]) -> Any:
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


def baseline(
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
            method = registry.build_method("identity", profile)
            identity = stage_pipeline(spec, method, profile, for_reference=True).run(gbuffer).image
        identity = identity.clone()  # a normal tensor (deep-copyable outside inference mode)
        flip_mean, flip_local = verdict.visibility_stats(reference, identity, mask)
        return identity, rel_rms(identity, reference, mask), flip_mean, flip_local

    if spec.scene == registry.FILE_SCENE:
        return compute()
    key = scene_key(
        spec, profile, reference_params=spec.reference_params, stages=reference_stages(spec)
    ) | {"reference": spec.reference, "baseline_stages": spec.stages}
    return runmemo.remembered("baseline", key, compute)


def reference_stages(spec: RunSpec) -> dict[str, Any]:
    return {k: v for k, v in spec.stages.items() if v is not None and registry.STAGES[k][1]}


def metric_mask(gbuffer: Any, dtype: torch.dtype) -> torch.Tensor | None:
    if gbuffer.mask is None:
        return None
    support = (gbuffer.mask > 0).to(dtype)
    if bool(support.reshape(support.shape[0], -1).sum(1).gt(0).all()):
        return support
    return None


def pipelines(spec: RunSpec, profile: Any) -> tuple[Any, Any]:
    """The run's pipeline (its method and stages) and its reference's pipeline."""
    method = registry.method_from_spec(spec, profile)
    pipeline = stage_pipeline(spec, method, profile)
    reference = ReferenceSSS(profile, **spec.reference_params)
    ref_pipeline = stage_pipeline(spec, reference, profile, for_reference=True)
    return pipeline, ref_pipeline


def error_scale(result: torch.Tensor, reference: torch.Tensor) -> float:
    """The run's largest |error| relative to the reference peak (the preview's scale)."""
    err = (result[:1] - reference[:1]).abs().mean(1)
    peak = float(reference[:1].max()) or 1.0
    return float(err.max()) / peak


def run_pixel_mm(gbuffer: Any) -> float:
    """Footprint of a pixel (mm) at the median depth of the SSS region (mask > 0, or all)."""
    from sssbench.gbuffer import pixel_size_mm

    depth = gbuffer.depth[:1]
    if gbuffer.mask is not None and bool((gbuffer.mask[:1] > 0).any()):
        depth = depth[gbuffer.mask[:1] > 0]
    z = float(depth.double().median())
    return float(pixel_size_mm(torch.tensor(z), gbuffer.fov_y, gbuffer.shape[1]))


def without_specular(image: torch.Tensor, gbuffer: Any) -> torch.Tensor:
    """``image`` before the specular the pipeline adds after scattering (on the stencil)."""
    if gbuffer.specular is None:
        return image
    active = (gbuffer.mask_or_ones() > 0).to(image.dtype)
    return image - gbuffer.specular.to(image.dtype) * active
