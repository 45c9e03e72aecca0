"""The exact reference: the surface integral of 000 eq. 1 over the visible pixels (DESIGN §4).

Every pixel gathers every neighbour within the profile's support, weighted by the integral of
the radial profile over the neighbour's world-space footprint at the true 3D distance between
the two surface points. This is the quantity every screen-space method approximates; on a flat
fronto-parallel plane it is exactly a 2D convolution with the per-cell kernel.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from sssbench._checks import check_scalar
from sssbench.gbuffer import GBuffer, pixel_size_mm
from sssbench.ops.timing import timed_pass
from sssbench.profiles.base import Profile

__all__ = ["ReferenceSSS", "reference_sss", "reference_radius_px"]

#: default energy tolerance of the support radius (see :func:`reference_sss`)
DEFAULT_TOL = 1e-6


def _padded_positions(
    depth: torch.Tensor, fov_y: float, pad: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """View-space x, y, z (mm) of a replicate-padded depth map at its *unclamped* grid cells.

    Neighbours beyond the border keep the border's depth (clamp, as the screen-space passes
    do) but sit at their own grid position, i.e. the surface is extended, not folded back.
    Same pixel-centre convention as :func:`sssbench.gbuffer.view_positions`.
    """
    _, _, h, w = depth.shape
    zp = torch.nn.functional.pad(depth, (pad, pad, pad, pad), mode="replicate")
    t = math.tan(fov_y / 2.0)
    cols = torch.arange(-pad, w + pad, dtype=depth.dtype, device=depth.device)
    rows = torch.arange(-pad, h + pad, dtype=depth.dtype, device=depth.device)
    u = (cols + 0.5 - w / 2) / (h / 2)
    v = (h / 2 - rows - 0.5) / (h / 2)
    x = u.view(1, 1, 1, -1) * zp * t
    y = v.view(1, 1, -1, 1) * zp * t
    return x, y, zp


def reference_radius_px(gbuffer: GBuffer, profile: Profile, tol: float = DEFAULT_TOL) -> int:
    """Half-size in pixels of the gather window: the profile's support radius (mm) over the
    smallest pixel footprint among active pixels, capped by the image size."""
    radius_mm = profile.radius(tol)
    mask = gbuffer.mask_or_ones()
    depth = gbuffer.depth[mask > 0] if bool((mask > 0).any()) else gbuffer.depth
    _, h, w = gbuffer.shape
    pmin = float(pixel_size_mm(depth.min(), gbuffer.fov_y, h))
    return int(min(math.ceil(radius_mm / pmin) + 1, max(h, w)))


def reference_sss(
    gbuffer: GBuffer,
    profile: Profile,
    *,
    tol: float = DEFAULT_TOL,
    radius_px: int | None = None,
) -> torch.Tensor:
    """Exact screen-space subsurface scattering of ``gbuffer.diffuse`` with ``profile``.

    ``M_i = Σ_j m_j E_j ∫_{cell_j} R(|p − p_i|) dA / ‖R‖₁`` (000 eq. 1, discretised by cells):
    ``p_i`` are the view-space pixel centres (:func:`~sssbench.gbuffer.view_positions`), a
    neighbour's cell is its square footprint ``pixel_size_mm(z_j)`` wide in the lateral plane
    at depth offset ``Δz = z_j − z_i``, and the profile is integrated over that cell in closed
    form where the profile provides it (:meth:`Profile.cell_integral`): a Gaussian narrower
    than a pixel keeps its full weight. Choices (documented here because the spec leaves them
    open):

    - Normalisation: divided by ``profile.total()`` per channel, like every normalised
      screen-space kernel, so a constant image on a plane comes out unchanged (the albedo /
      total reflectance is applied by texturing, not by the blur).
    - Support: the neighbours within ``profile.radius(tol)`` mm — the larger of "below
      ``tol`` × peak" and "less than ``tol`` of the energy outside" — gathered over the
      square window of that half-size, so the neglected energy is below ``tol``.
    - Borders: clamp-to-edge like the screen-space passes: a neighbour beyond the image has
      the border pixel's colour and depth at its own (extended) grid position.
    - Stencil: only neighbours with ``mask > 0`` (the SSS surface) contribute, weighted by
      their mask; pixels with mask 0 are copied through; a fractional mask lerps between the
      input and the scattered value (strength).
    - Tilted surfaces: the footprint is the lateral pixel square and Δz enters through the
      true 3D distance; the extra area of a tilted cell (1/cos θ) is not added, matching what
      a depth buffer can tell about the surface.

    Args:
        gbuffer: needs ``diffuse``, ``depth``, ``fov_y``; uses ``mask`` if present.
        profile: the radial profile (mm).
        tol: energy / peak tolerance of the support radius, in (0, 1).
        radius_px: override the window half-size in pixels.

    Returns:
        ``(B, 3, H, W)`` in the G-buffer's dtype (computed in float64).
    """
    if not isinstance(gbuffer, GBuffer):
        raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
    if not isinstance(profile, Profile):
        raise TypeError(f"profile must be a sssbench Profile, got {type(profile).__name__}")
    check_scalar("tol", tol, 0.0, 1.0, low_inclusive=False, high_inclusive=False)
    total = profile.total()
    if bool((total <= 0).any()):
        raise ValueError(f"profile total must be > 0 in every channel, got {total.tolist()}")
    k = reference_radius_px(gbuffer, profile, tol) if radius_px is None else int(radius_px)
    if k < 0:
        raise ValueError(f"radius_px must be >= 0, got {radius_px}")

    g = gbuffer.to(torch.float64)
    b, h, w = g.shape
    mask = g.mask_or_ones()
    pad = (k, k, k, k)
    xp, yp, zp = _padded_positions(g.depth, g.fov_y, k)
    src = torch.nn.functional.pad(g.diffuse * mask, pad, mode="replicate")
    src_mask = torch.nn.functional.pad(mask, pad, mode="replicate") > 0
    half = 0.5 * pixel_size_mm(zp, g.fov_y, h)
    xc, yc, zc = (t[..., k : k + h, k : k + w] for t in (xp, yp, zp))

    active = mask > 0
    n_active = int(active.sum())
    acc = torch.zeros(b, h, w, 3, dtype=torch.float64)
    radius_mm = profile.radius(tol)
    with timed_pass("reference", (2 * k + 1) ** 2, n_active):
        for dv in range(-k, k + 1):
            for du in range(-k, k + 1):
                sl = (..., slice(k + dv, k + dv + h), slice(k + du, k + du + w))
                dx = xp[sl] - xc
                dy = yp[sl] - yc
                # skip offsets whose nearest cell edge is beyond the support everywhere
                near = torch.sqrt(
                    (dx.abs() - half[sl]).clamp_min(0) ** 2
                    + (dy.abs() - half[sl]).clamp_min(0) ** 2
                )
                if float(near.min()) > radius_mm:
                    continue
                wgt = profile.cell_integral(dx, dy, zp[sl] - zc, half[sl], half[sl])  # (B,1,H,W,3)
                contrib = wgt[:, 0] * src[sl].permute(0, 2, 3, 1)
                acc += torch.where(src_mask[sl][:, 0, ..., None], contrib, 0.0)
    scattered = (acc / total).permute(0, 3, 1, 2)
    out = g.diffuse + mask * (scattered - g.diffuse)
    out = torch.where(active, out, g.diffuse)
    return out.to(gbuffer.dtype)


class ReferenceSSS(nn.Module):
    """Module twin of :func:`reference_sss`.

    Args:
        profile: the radial diffusion profile.
        tol: support tolerance (see :func:`reference_sss`).

    Shape:
        - forward(gbuffer): ``(B, 3, H, W)``.
    """

    #: G-buffer fields the operator reads (besides diffuse, depth, fov_y)
    needs = ("mask",)

    def __init__(self, profile: Profile, tol: float = DEFAULT_TOL) -> None:
        super().__init__()
        if not isinstance(profile, Profile):
            raise TypeError(f"profile must be a sssbench Profile, got {type(profile).__name__}")
        self.profile = profile
        self.tol = check_scalar("tol", tol, 0.0, 1.0, low_inclusive=False, high_inclusive=False)

    def forward(self, gbuffer: GBuffer) -> torch.Tensor:
        return reference_sss(gbuffer, self.profile, tol=self.tol)
