"""A run's error budget step: the cached inputs (the method converged in taps, the
bilinear-reconstruction reference) and the budget's parts (docs/error_budget.md)."""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import Any

import torch

from sssbench.run import registry, runmemo
from sssbench.run.inputs import reference_stages, scene_key, without_specular
from sssbench.run.settings import checkpoint
from sssbench.run.spec import RunSpec
from sssbench.store.refcache import cached_reference

__all__ = [
    "BUDGET_START",
    "BUDGET_MAX",
    "LADDER_DTYPE",
    "BudgetInputs",
    "bilinear_reference",
    "budget_inputs",
    "budget_limit",
    "budget_metrics",
    "budget_truth",
    "has_budget",
    "runs_float64",
]

#: the tap ladder of the converged method in a run's budget: 17, 33, 65, 129, 257 taps
#: (independent of the run's own count, so one cached limit serves a whole samples sweep)
BUDGET_START, BUDGET_MAX = 17, 257
#: the dtype the ladder's passes run in (their outputs and differences are taken in float64).
#: A choice (issue 30: the ladder was about a tenth of a cold paper benchmark's CPU time, and
#: the native loop runs twice the float32 pixels per vector): the ladder stops at a change of
#: 1e-4 rel RMS (``CONVERGED_TOL``), and float32 moves the converged image by far less —
#: measured against the float64 ladder on the 512² benchmark scenes: at most 1.9e-6 rel RMS
#: (``light_dot`` at 0.1 mm/px, whose RMS is small against its peak), 5e-8–3e-7 elsewhere,
#: the same stopping tap count everywhere, at 0.4–0.7× the CPU time (tested on a small scene
#: against the float64 ladder in tests/test_budget_ladder.py)
LADDER_DTYPE = torch.float32


@dataclass
class BudgetInputs:
    """What a run's error budget reads from the reference cache, and how it builds the
    method at a tap count."""

    build: Any  # samples -> the run's method at that tap count
    g64: Any  # the G-buffer in float64
    limit: tuple[torch.Tensor, int, float]  # converged image, its taps, its last change
    bilinear: torch.Tensor | None  # the bilinear-reconstruction reference


def has_budget(spec: RunSpec) -> bool:
    """Whether a run of ``spec`` has an error budget (see :func:`budget_inputs`)."""
    return not (
        spec.method in ("reference", "identity")
        or not registry.METHODS[spec.method].deterministic
        or not registry.method_takes(spec.method, "samples")
        or reference_stages(spec)
        or spec.samples is None
    )


def runs_float64(spec: RunSpec) -> bool:
    """Whether a run of ``spec`` runs float64 passes: a float64 run, or one with an error
    budget, whose method runs once on the float64 G-buffer
    (:func:`sssbench.score.budget.error_budget`): the native loops of both dtypes are then
    built side by side (:func:`sssbench.ops.native.want_float64`)."""
    return spec.dtype == "float64" or bool(spec.budget and has_budget(spec))


def _limit_sampling(spec: RunSpec) -> str | None:
    # fitted taps (sampling="optimised") exist for the run's own tap count only; the converged
    # limit is reached by the method's own placement rule at many taps (the pre-integrated
    # kernel's importance sampling, the sum of Gaussians' uniform taps, the 2012 builder's)
    return (
        registry.default_option(spec.method, "sampling")
        if spec.sampling == "optimised"
        else spec.sampling
    )


def _builder(spec: RunSpec, profile: Any) -> Any:
    limit_sampling = _limit_sampling(spec)

    def build(samples: int) -> Any:
        sampling = spec.sampling if samples == spec.samples else limit_sampling
        return registry.method_from_spec(spec, profile, samples=samples, sampling=sampling)

    return build


def budget_limit(
    spec: RunSpec, profile: Any, gbuffer: Any, reference: torch.Tensor
) -> tuple[torch.Tensor, int, float]:
    """The run's method converged in taps (:func:`sssbench.score.budget.converged` from
    :data:`BUDGET_START` to :data:`BUDGET_MAX` taps, the passes in :data:`LADDER_DTYPE`, the
    image and its changes in float64): ``(image, taps, last change)``, from the reference
    cache (computed and stored on a miss). Independent of the run's tap count: one entry
    serves a whole samples sweep."""
    from sssbench.score import budget

    key = scene_key(spec, profile)
    scale = float(reference.double().pow(2).mean().sqrt()) or 1.0
    limit_sampling = _limit_sampling(spec)
    limit_key = {
        **key,
        "budget_limit": [spec.method, spec.method_params, limit_sampling, BUDGET_START, BUDGET_MAX],
        # a new key for the float32 ladder: entries of the float64 one are not reused
        "ladder_dtype": str(LADDER_DTYPE),
    }
    build = _builder(spec, profile)

    def compute_limit() -> torch.Tensor:  # the ladder's G-buffer on a miss only
        image, n, change = budget.converged(
            build, BUDGET_START, gbuffer.to(LADDER_DTYPE), max_samples=BUDGET_MAX, scale=scale
        )
        return torch.cat([image.reshape(-1), torch.tensor([float(n), change], dtype=image.dtype)])

    packed, _, _ = cached_reference(limit_key, compute_limit, spec.reference_cache)
    packed = packed.double()
    return packed[:-2].reshape(gbuffer.diffuse.shape), int(packed[-2]), float(packed[-1])


def bilinear_reference(spec: RunSpec, profile: Any, gbuffer: Any) -> torch.Tensor | None:
    """The run's reference with the bilinear reconstruction (the budget's ``err_recon``), from
    the reference cache (computed and stored on a miss); ``None`` where the reference has no
    reconstruction option. Independent of the method: one entry per scene."""
    from sssbench.ops import ReferenceSSS

    if "reconstruction" not in inspect.signature(ReferenceSSS.__init__).parameters:
        return None
    params = {**spec.reference_params, "reconstruction": "bilinear"}
    if params.get("method") == "gather":  # the cell gather is box-only: same integral
        params.pop("method")
    bil_key = {**scene_key(spec, profile), "reference_params": params}
    bil, _, _ = cached_reference(
        bil_key,
        lambda: ReferenceSSS(profile, **params)(gbuffer),
        spec.reference_cache,
        shape=tuple(gbuffer.diffuse.shape),
    )
    return bil


def budget_inputs(
    spec: RunSpec, profile: Any, gbuffer: Any, reference: torch.Tensor
) -> BudgetInputs | None:
    """The budget's cached inputs (computed and stored on a miss), or ``None`` when the run
    has no budget (:func:`has_budget`): the reference and the baseline, stochastic estimators
    (their error is bias plus noise, not taps), methods without a tap count, and runs where a
    stage changes the light (the budget's flat-plane model has no stages).

    The method converged in taps (:func:`budget_limit`) and the bilinear-reconstruction
    reference (:func:`bilinear_reference`) do not depend on the run's tap count: one cached
    entry serves a whole samples sweep. ``err_recon`` is computed on every scene the exact
    reference runs on (the bilinear reference's FFT path on planes, its closed-form near field
    elsewhere, about twice the box reference's time; docs/error_budget.md)."""
    if not has_budget(spec):
        return None
    limit = budget_limit(spec, profile, gbuffer, reference)
    bil = bilinear_reference(spec, profile, gbuffer)
    return BudgetInputs(_builder(spec, profile), gbuffer.to(torch.float64), limit, bil)


def budget_truth(spec: RunSpec, profile: Any, g64: Any) -> torch.Tensor:
    """:func:`sssbench.score.budget.budget_truth` of the run's scene (float64 G-buffer
    ``g64``), computed once per process and scene (:mod:`sssbench.run.runmemo`, keyed by the
    scene's cache key and the G-buffer's fields): it does not depend on the method."""
    from dataclasses import fields

    from sssbench.score import budget

    def compute() -> torch.Tensor:
        return budget.budget_truth(g64, profile)

    if spec.scene == registry.FILE_SCENE:
        return compute()
    names = sorted(f.name for f in fields(g64) if isinstance(getattr(g64, f.name), torch.Tensor))
    key = scene_key(spec, profile) | {"fields": names}
    return runmemo.remembered("budget_truth", key, compute)


def budget_metrics(
    spec: RunSpec,
    profile: Any,
    gbuffer: Any,
    reference: torch.Tensor,
) -> dict[str, float]:
    """The run's error budget (:func:`sssbench.score.budget.error_budget`, docs/error_budget.md);
    empty where :func:`budget_inputs` says the run has none."""
    from sssbench.score import budget

    inputs = budget_inputs(spec, profile, gbuffer, reference)
    if inputs is None:
        return {}
    checkpoint()  # a process waiting to time goes first (settings.timing_slot)
    # the budget splits the SSS stage's error: the reference without the specular the
    # pipeline adds after scattering (on the stencil), as the method alone computes it
    sss_reference = without_specular(reference, gbuffer)
    result = budget.error_budget(
        inputs.build,
        spec.samples,
        inputs.g64,
        profile,
        reference=sss_reference,
        reference_bilinear=inputs.bilinear,
        limit=inputs.limit,
        recon=inputs.bilinear is not None,
        truth=budget_truth(spec, profile, inputs.g64),
    ).as_dict()
    keys = [k for k in result if k.startswith(("err_", "contribution_"))] + ["taps_residual"]
    return {k: float(result[k]) for k in keys if k != "err_total"} | {
        "converged_samples": int(result["converged_samples"])
    }
