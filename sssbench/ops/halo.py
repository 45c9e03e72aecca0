"""Halo reduction and colour bilateral weights for the gather primitive (004 §3.3.1, §3.3.2).

Both are cross bilateral filters (004 eq. 3.11): the diffusion kernel is the spatial term and a
range term on a guide image multiplies each sample; :func:`~sssbench.ops.separable_pass`
renormalises by the summed weights. Each builder returns ``(guide, sample_weight)`` ready for
``separable_pass(..., guide=guide, sample_weight=sample_weight)``, so any method can use them.

``"bilateral"`` — halo reduction (004 §3.3.1, after Mikkelsen 2010). The auxiliary image of
004 eq. 3.12 is ``I(x(p)) cos³φ_i ‖x(p)‖² / cos φ_j`` with ``φ_i`` the angle between the view
axis and the ray to the surface point ``x(p)`` and ``φ_j`` the angle between the surface
normal and the direction to the observer: the surface area one pixel covers, large at
contours, where "continuous areas in screen space but not in the geometry" meet. 004 makes it
distance independent by taking ``x(p)`` "as if it was always resting on the projection
plane", i.e. ``‖x‖ = 1/cos φ_i``, which leaves ``I · cos φ_i / cos φ_j``. Choices (the thesis
leaves them open): ``I(x(p)) = 1`` (the guide is geometric, so lighting does not block
scattering), the guide is the **logarithm** ``log(cos φ_i / cos φ_j)`` so that the range
weight compares area *ratios* (a contour pixel with 10× the area is as different at any
distance and any base obliquity), ``cos φ_j`` is clamped to ``min_cos`` (back-facing and
exactly grazing normals), and the range term is the Gaussian
``exp(−(E_p − E_q)² / 2σ²)`` (004 eq. 3.11's ``G_σr``, spatial term = the kernel weight).

``"lab"`` — skin / non-skin separation (004 §3.3.2): the guide is the CIE Lab colour
(:func:`kornia.color.rgb_to_lab` of the sRGB-encoded linear colour) of ``albedo`` (or of the
diffuse image, normalised to its maximum, when there is no albedo or ``source="diffuse"``), and
the range term is ``exp(−ΔE² / 2σ²)`` on the Euclidean Lab distance ΔE (CIE76).

004 §3.3.1 notes that with the weights some pixels turn black and falls back to the original
colour; here the centre tap's range weight is always 1, so the renormalised sum never
vanishes (unless a kernel has no centre weight).
"""

from __future__ import annotations

from collections.abc import Callable

import kornia
import torch

from sssbench._checks import MAGNITUDES, check_choice, check_magnitude, check_scalar
from sssbench.gbuffer import GBuffer, view_positions

__all__ = [
    "HALO_KINDS",
    "DEFAULT_SIGMA",
    "halo_guide",
    "lab_guide",
    "range_weight",
    "halo_weight",
]

HALO_KINDS = ("bilateral", "lab")
#: default range σ: log-area units for ``bilateral`` (a sample whose pixel covers e^0.25 ≈ 1.28×
#: the centre's area gets weight e^{-1/2}); Lab units for ``lab`` (ΔE ≈ 10: clearly different)
DEFAULT_SIGMA = {"bilateral": 0.25, "lab": 10.0}

SampleWeight = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def halo_guide(gbuffer: GBuffer, *, min_cos: float = 0.02) -> torch.Tensor:
    """The distance-independent auxiliary image of 004 eq. 3.12, as ``log(cos φ_i / cos φ_j)``.

    Args:
        gbuffer: needs ``normal`` (view space, +z toward the camera), ``depth``, ``fov_y``.
        min_cos: floor of ``cos φ_j`` in [1e-6, 1] (grazing or back-facing normals).

    Returns:
        ``(B, 1, H, W)`` guide: 0 for a surface facing the camera on the view axis, growing as
        the surface turns away (``−log min_cos`` at most).

    Example:
        >>> g = GBuffer(torch.ones(1, 3, 4, 4), torch.full((1, 1, 4, 4), 100.0), 0.01,
        ...             normal=torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, 4, 4))
        >>> bool(halo_guide(g).abs().max() < 1e-4)
        True
    """
    if not isinstance(gbuffer, GBuffer):
        raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
    if gbuffer.normal is None:
        raise ValueError("halo reduction (bilateral) needs gbuffer.normal (B, 3, H, W), got None")
    min_cos = check_scalar("min_cos", min_cos, MAGNITUDES["factor"][0], 1.0)
    pos = view_positions(gbuffer.depth, gbuffer.fov_y)  # camera at the origin, looking at +z
    dist = pos.norm(dim=1, keepdim=True)
    cos_i = pos[:, 2:3] / dist  # angle between the view axis and the ray
    # normals live in the frame with +z toward the camera, where the point is (x, y, −depth):
    # the direction to the observer is (−x, −y, depth) / ‖x‖
    to_eye = torch.cat([-pos[:, :2], pos[:, 2:3]], 1) / dist
    cos_j = (gbuffer.normal * to_eye).sum(1, keepdim=True).clamp_min(min_cos)
    return torch.log(cos_i / cos_j)  # 004 eq. 3.12, x(p) on the projection plane, I = 1


def lab_guide(gbuffer: GBuffer, *, source: str = "albedo") -> torch.Tensor:
    """CIE Lab colour of the surface (004 §3.3.2), ``(B, 3, H, W)``.

    Args:
        gbuffer: supplies ``albedo`` (linear, [0, 1]) or ``diffuse``.
        source: ``"albedo"`` (falls back to ``"diffuse"`` when the G-buffer has no albedo) or
            ``"diffuse"`` (the irradiance, divided by its per-image maximum, clamped to [0, 1]).

    Returns:
        ``(B, 3, H, W)``: L in [0, 100], a and b roughly in [−128, 127].

    Example:
        >>> g = GBuffer(torch.ones(1, 3, 2, 2), torch.ones(1, 1, 2, 2), 0.5)
        >>> round(float(lab_guide(g)[0, 0, 0, 0]), 3)
        100.0
    """
    if not isinstance(gbuffer, GBuffer):
        raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
    check_choice("source", source, ("albedo", "diffuse"))
    if source == "albedo" and gbuffer.albedo is not None:
        rgb = gbuffer.albedo
    else:
        d = gbuffer.diffuse
        peak = d.amax(dim=(1, 2, 3), keepdim=True).clamp_min(torch.finfo(d.dtype).tiny)
        rgb = (d / peak).clamp(0.0, 1.0)
    # kornia's rgb_to_lab expects sRGB-encoded input and linearises it itself; on contiguous
    # memory, so the guide does not depend on the layout (channels-last rounds differently)
    rgb = rgb.contiguous()
    return kornia.color.rgb_to_lab(kornia.color.linear_rgb_to_rgb(rgb))


def range_weight(sigma: float) -> SampleWeight:
    """The range term ``exp(−‖g_p − g_q‖² / 2σ²)`` of 004 eq. 3.11 / 3.13.

    Args:
        sigma: range scale in guide units, > 0.

    Returns:
        ``f(centre_guide (N, G), sample_guide (N, G)) -> (N, 1)`` for
        :func:`~sssbench.ops.separable_pass`'s ``sample_weight``.

    Example:
        >>> f = range_weight(1.0)
        >>> f(torch.zeros(2, 1), torch.tensor([[0.0], [2.0]])).flatten().tolist()
        [1.0, 0.1353352814912796]
    """
    sigma = check_magnitude("sigma", sigma, "factor")
    inv = 1.0 / (2.0 * sigma * sigma)

    def weight(centre: torch.Tensor, sample: torch.Tensor) -> torch.Tensor:
        d2 = ((sample - centre) ** 2).sum(1, keepdim=True)
        return torch.exp(-d2 * inv)

    return weight


def halo_weight(
    gbuffer: GBuffer,
    kind: str = "bilateral",
    sigma: float | None = None,
    **options: object,
) -> tuple[torch.Tensor, SampleWeight]:
    """``(guide, sample_weight)`` for :func:`~sssbench.ops.separable_pass` (004 §3.3).

    Args:
        gbuffer: the G-buffer the passes run on.
        kind: ``"bilateral"`` (halo reduction, 004 §3.3.1, needs ``normal``) or ``"lab"``
            (skin / non-skin colour distance, 004 §3.3.2).
        sigma: range σ (default :data:`DEFAULT_SIGMA` of ``kind``).
        **options: ``min_cos`` (bilateral) or ``source`` (lab).

    Returns:
        ``(guide (B, G, H, W), sample_weight)``.

    Example:
        >>> g = GBuffer(torch.rand(1, 3, 8, 8), torch.full((1, 1, 8, 8), 100.0), 0.5)
        >>> guide, f = halo_weight(g, "lab")
        >>> guide.shape
        torch.Size([1, 3, 8, 8])
    """
    check_choice("kind", kind, HALO_KINDS)
    sigma = DEFAULT_SIGMA[kind] if sigma is None else sigma
    if kind == "bilateral":
        guide = halo_guide(gbuffer, **options)
    else:
        guide = lab_guide(gbuffer, **options)
    return guide, range_weight(sigma)
