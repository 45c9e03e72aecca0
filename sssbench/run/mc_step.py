"""A run's errors against Monte Carlo light transport (``reference=mc``; docs/mc.md)."""

from __future__ import annotations

from typing import Any

import torch

from sssbench.run.inputs import without_specular
from sssbench.run.spec import RunSpec

__all__ = ["mc_metrics"]


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
        value, se = noise_corrected_rel_rms(without_specular(image, gbuffer)[:1], batches, region)
        out[name], out[f"{name}_se"] = value, se
    out["identity_vs_mc"] = noise_corrected_rel_rms(
        without_specular(identity, gbuffer)[:1], batches, region
    )[0]
    out |= {"mc_photons": mc.photons, "mc_seconds": mc.seconds, "mc_material": str(material)}
    return out
