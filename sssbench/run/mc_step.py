"""A run's errors against Monte Carlo light transport (``reference=mc``; docs/mc.md)."""

from __future__ import annotations

from typing import Any

import torch

from sssbench.run.inputs import without_specular
from sssbench.run.spec import RunSpec, mc_options

__all__ = ["mc_metrics", "mc_verdicts", "TOL"]

#: differences of relative RMS errors at or below this are "no difference" however small their
#: noise (a 4e-9 difference is no finding; experiments/mc_gap.py uses the same)
TOL = 1e-4


def mc_metrics(
    spec: RunSpec,
    gbuffer: Any,
    result: torch.Tensor,
    reference: torch.Tensor,
    identity: torch.Tensor,
) -> dict[str, Any]:
    """Errors against Monte Carlo light transport (``reference=mc``; docs/mc.md).

    Quantity compared: the *diffuse* SSS result, i.e. the pipeline's image without the
    specular it adds after scattering (:func:`without_specular`), against the MC exitance
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

    options = mc_options(spec)
    material = options["material"]
    mc = scene_mc(spec.scene, gbuffer, spec.scene_params, **options)
    batches = mc.batches
    if spec.stages.get("texturing") is not None and gbuffer.albedo is not None:
        batches = batches * gbuffer.albedo[:1].double()
    region = mc.mask & (gbuffer.mask_or_ones()[0, 0] > 0)
    out: dict[str, Any] = {}
    for name, image in (("rel_rms_mc", result), ("reference_vs_mc", reference)):
        value, se = noise_corrected_rel_rms(without_specular(image, gbuffer)[:1], batches, region)
        out[name], out[f"{name}_se"] = value, se
    out["identity_vs_mc"], out["identity_vs_mc_se"] = noise_corrected_rel_rms(
        without_specular(identity, gbuffer)[:1], batches, region
    )
    out |= {"mc_photons": mc.photons, "mc_seconds": mc.seconds, "mc_material": str(material)}
    out["mc_verdicts"] = mc_verdicts(
        {"run": result, "reference": reference, "identity": identity},
        gbuffer,
        batches,
        region,
        mc.photons,
    )
    return out


def mc_verdicts(
    images: dict[str, torch.Tensor],
    gbuffer: Any,
    batches: torch.Tensor,
    region: torch.Tensor,
    photons: int,
) -> dict[str, str]:
    """The run against doing nothing and against the exact profile reference, each judged
    against Monte Carlo by the one significance rule (:func:`sssbench.mc.significance.compare`:
    resolved beyond ``K_SIGMA`` paired jackknife standard errors over the same MC batches,
    below :data:`TOL` "no difference", else "not resolved at N photons"). The verdict reads
    "run is <verdict> than ..." (closer: smaller error against the MC).

    Args:
        images: ``run``, ``reference`` and ``identity`` images ``(B, 3, H, W)``.
        batches: ``(K, 3, H, W)`` independent MC batch images (K >= 3).
        region: ``(H, W)`` pixels scored.
        photons: the MC's photon count, named in an unresolved verdict.

    Returns:
        ``{"run_vs_identity": verdict, "run_vs_reference": verdict}``.
    """
    from sssbench.mc.significance import compare, scene_errors

    diffuse = {k: without_specular(v, gbuffer)[:1] for k, v in images.items()}
    _, diff = scene_errors(diffuse, batches, region)
    return {
        f"run_vs_{other}": compare(*diff("run", other), photons=photons, tol=TOL).verdict
        for other in ("identity", "reference")
    }
