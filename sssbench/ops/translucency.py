"""Translucency: light transmitted through thin parts (004 §3.2; 001 §5.2).

The transmittance of a sum-of-Gaussians profile through a slab of thickness ``s`` is

    T(s) = Σ_i w_i exp(−s² / v_i)                      (004 eq. 3.10; 001 eq. 16)

with the profile's weights ``w_i`` (per channel) and variances ``v_i`` (mm²). Two forms:

``form="jimenez2012"`` (default): the 2012 SSSS transmittance shader (004 Fig. 3.11):
``s = thickness · 8.25 (1 − translucency) / width`` and the result is
``T(s) · clamp(0.3 + n·(−l), 0, 1)``: the light reaching the back face, wrapped by 0.3 so that
transmission fades out only once the light is clearly in front.

``form="deon"``: d'Eon's per-Gaussian weights ``w_i e^{−d²/v_i}`` (001 eq. 16) at the physical
thickness ``d = m cos θ`` (001 §5.2: the shadow-map distance ``m`` corrected by the angle
between the light and the surface normal, applied in full because the light-facing surface is
assumed to face opposite the visible one, ``N_A = −N_C``, as on a slab), times the Lambert
irradiance of that light-facing surface, ``max(0, n·(−l))``. In screen space we have no
convolved irradiance of the light-facing surface, so every Gaussian sees the same point light
(d'Eon looks up the irradiance texture convolved by ``G(v_i)``; the later blur of the diffuse
buffer re-introduces the spread).

Both return *irradiance*: the pipeline adds it to ``diffuse`` before the blur, so that the
transmitted light scatters with its neighbours (004 §3.2).
"""

from __future__ import annotations

import torch
from torch import nn

from sssbench._checks import check_choice, check_magnitude, check_scalar
from sssbench.gbuffer import GBuffer
from sssbench.ops._repr import options_repr
from sssbench.ops._stencil import active_pixels, apply_on_active
from sssbench.ops.timing import timed_pass
from sssbench.profiles.sum_of_gaussians import SumOfGaussians

__all__ = ["Translucency", "translucency", "transmittance", "TRANSLUCENCY_FORMS", "back_light"]

TRANSLUCENCY_FORMS = ("jimenez2012", "deon")
#: 004 Fig. 3.11: ``scale = 8.25 * (1.0 - translucency) / sss_width``
_SHADER_SCALE = 8.25
#: 004 Fig. 3.11: ``clamp(0.3 + dot(light_vector, -world_normal), 0.0, 1.0)``
_WRAP = 0.3


def _as_profile(profile: str | SumOfGaussians) -> SumOfGaussians:
    if isinstance(profile, str):
        return SumOfGaussians.from_table(profile)
    if not isinstance(profile, SumOfGaussians):
        raise TypeError(
            f"profile must be a SumOfGaussians or a table name, got {type(profile).__name__}"
        )
    return profile


def transmittance(s: torch.Tensor, profile: str | SumOfGaussians) -> torch.Tensor:
    """``T(s) = Σ_i w_i exp(−s²/v_i)`` (004 eq. 3.10) per channel.

    Args:
        s: distance through the material in mm (the 2012 form passes its scaled distance),
            any shape ``(...)``, >= 0.
        profile: a :class:`SumOfGaussians` or a table name (``"skin_deon6"`` gives the
            shader's constants of 004 Fig. 3.11).

    Returns:
        ``(..., 3)``.

    Example:
        >>> transmittance(torch.zeros(1, dtype=torch.float64), "skin_deon6").tolist()
        [[1.0, 1.0, 1.0]]
    """
    prof = _as_profile(profile)
    v = prof.variances.to(s)
    w = prof.weights.to(s)
    return torch.exp(-(s[..., None] ** 2) / v) @ w  # 004 eq. 3.10


def _check_options(
    form: str, translucency: float, width: float, intensity: float, apply_albedo: bool
) -> tuple[float, float, float]:
    """Validated ``(translucency, width, intensity)`` of :func:`translucency`."""
    check_choice("form", form, TRANSLUCENCY_FORMS)
    if not isinstance(apply_albedo, bool):
        raise TypeError(f"apply_albedo must be a bool, got {type(apply_albedo).__name__}")
    return (
        check_scalar("translucency", translucency, 0.0, 1.0, high_inclusive=False),
        check_magnitude("width", width, "length"),
        check_magnitude("intensity", intensity, "factor", zero=True),
    )


def _required(gbuffer: GBuffer) -> None:
    if not isinstance(gbuffer, GBuffer):
        raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
    for name in ("thickness", "normal", "light_dir"):
        if getattr(gbuffer, name) is None:
            raise ValueError(
                f"translucency needs gbuffer.{name} "
                f"({'(B, 3)' if name == 'light_dir' else '(B, C, H, W)'}), got None"
            )


def back_light(gbuffer: GBuffer) -> torch.Tensor:
    """``n·(−l)`` per pixel, ``(B, 1, H, W)``: > 0 where the light is behind the surface.

    Needs ``normal`` and ``light_dir``.
    """
    if gbuffer.normal is None or gbuffer.light_dir is None:
        missing = "normal" if gbuffer.normal is None else "light_dir"
        raise ValueError(f"back_light needs gbuffer.{missing}, got None")
    light = gbuffer.light_dir.to(gbuffer.dtype)[:, :, None, None]
    return -(gbuffer.normal * light).sum(1, keepdim=True)


def translucency(
    gbuffer: GBuffer,
    profile: str | SumOfGaussians,
    translucency: float = 0.0,
    width: float = _SHADER_SCALE,
    *,
    form: str = "jimenez2012",
    intensity: float = 1.0,
    apply_albedo: bool = True,
) -> torch.Tensor:
    """Irradiance transmitted through the object from a back light (004 §3.2).

    Computed only where ``mask > 0`` (zero elsewhere).

    Args:
        gbuffer: needs ``thickness`` (mm toward the light), ``normal`` (view space, +z toward
            the camera) and ``light_dir`` (toward the light); uses ``mask`` (stencil) and
            ``albedo``.
        profile: the sum of Gaussians whose ``w_i, v_i`` define ``T`` (004 Table 3.1:
            ``"skin_deon6"``).
        translucency: in [0, 1) (2012 form): 0 = physically thick, toward 1 = more
            translucent (the scaled distance shrinks to 0).
        width: mm, > 0 (2012 form): the SSS width of the 2012 shader. The scaled distance is
            ``s = thickness · 8.25 (1 − translucency) / width`` (004 Fig. 3.11); the default
            ``width = 8.25`` with ``translucency = 0`` gives ``s = thickness`` in mm.
        form: ``"jimenez2012"`` or ``"deon"`` (module docstring). ``"deon"`` ignores
            ``translucency`` and ``width``.
        intensity: radiance scale of the (directional) light, >= 0.
        apply_albedo: multiply by ``albedo`` when present, as 004 §3.2 does ("multiplied by
            the diffuse emission"). :class:`~sssbench.ops.pipeline.Pipeline` passes ``False``:
            its texturing stage applies albedo to diffuse and transmitted light together.

    Returns:
        ``(B, 3, H, W)`` transmitted irradiance, >= 0.

    Shape:
        - output: ``(B, 3, H, W)``

    Example:
        >>> from data_synth import make_scene
        >>> g = make_scene("backlit_ear", (16, 16), dtype=torch.float64)
        >>> t = translucency(g, "skin_deon6")
        >>> t.shape, bool(t.max() > 0)
        (torch.Size([1, 3, 16, 16]), True)
    """
    translucency, width, intensity = _check_options(
        form, translucency, width, intensity, apply_albedo
    )
    _required(gbuffer)
    prof = _as_profile(profile)

    albedo = gbuffer.albedo if apply_albedo else None
    inputs = [gbuffer.thickness, back_light(gbuffer)]
    if albedo is not None:
        inputs.append(albedo)
    scale = _SHADER_SCALE * (1.0 - translucency) / width  # 004 Fig. 3.11

    def shade(thick: torch.Tensor, nl: torch.Tensor, *alb: torch.Tensor) -> torch.Tensor:
        if form == "jimenez2012":
            t = transmittance(thick[:, 0] * scale, prof)  # 004 eq. 3.10 at the scaled s
            t = t * (_WRAP + nl).clamp(0.0, 1.0)  # 004 Fig. 3.11
        else:
            d = thick[:, 0] * nl[:, 0].abs().clamp_max(1.0)  # 001 §5.2: d = m cos θ
            t = transmittance(d, prof) * nl.clamp_min(0.0)  # 001 eq. 16, Lambert at A
        t = intensity * t
        return t * alb[0] if alb else t

    out = torch.zeros_like(gbuffer.diffuse)
    active = active_pixels(gbuffer.mask, gbuffer.depth.numel())
    return apply_on_active(shade, out, inputs, active)


class Translucency(nn.Module):
    """Module twin of :func:`translucency`.

    Args:
        profile: the sum of Gaussians defining ``T(s)`` (004 eq. 3.10).
        translucency: in [0, 1) (2012 form).
        width: mm, > 0 (2012 form).
        form: ``"jimenez2012"`` (004 Fig. 3.11) or ``"deon"`` (001 eq. 16).
        intensity: light scale, >= 0.
        apply_albedo: multiply by ``albedo`` when present.

    Shape:
        - forward(gbuffer): ``(B, 3, H, W)``.
        - forward(gbuffer, add_to): ``add_to + transmitted``, inactive pixels untouched.

    Example:
        >>> from data_synth import make_scene
        >>> g = make_scene("backlit_ear", (16, 16), dtype=torch.float64)
        >>> Translucency("skin_deon6", 0.5, 8.0)(g).shape
        torch.Size([1, 3, 16, 16])
    """

    extra_repr = options_repr

    needs = ("thickness", "normal", "mask")

    def __init__(
        self,
        profile: str | SumOfGaussians,
        translucency: float = 0.0,
        width: float = _SHADER_SCALE,
        *,
        form: str = "jimenez2012",
        intensity: float = 1.0,
        apply_albedo: bool = True,
    ) -> None:
        super().__init__()
        self.translucency, self.width, self.intensity = _check_options(
            form, translucency, width, intensity, apply_albedo
        )
        self.profile = _as_profile(profile)
        self.form = form
        self.apply_albedo = apply_albedo

    def forward(self, gbuffer: GBuffer, add_to: torch.Tensor | None = None) -> torch.Tensor:
        _required(gbuffer)
        n = gbuffer.depth.numel() if gbuffer.mask is None else int((gbuffer.mask > 0).sum())
        with timed_pass("translucency", 1, n):
            t = translucency(
                gbuffer,
                self.profile,
                self.translucency,
                self.width,
                form=self.form,
                intensity=self.intensity,
                apply_albedo=self.apply_albedo,
            )
            return t if add_to is None else add_to + t
