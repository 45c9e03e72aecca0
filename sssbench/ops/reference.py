"""The exact reference: the surface integral of 000 eq. 1 over the visible pixels (DESIGN §4).

One module because the reference's cell integral, its tiling over threads and its cache
digest are one exact computation; the far field and the flat-plane path are already apart.

Every pixel gathers every neighbour within the profile's support, weighted by the integral of
the radial profile over the neighbour's world-space footprint at the true 3D distance between
the two surface points. This is the quantity every screen-space method approximates; on a flat
fronto-parallel plane it is exactly a 2D convolution with the per-cell kernel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from sssbench._checks import check_choice, check_int, check_scalar
from sssbench._console import bar as progress_bar
from sssbench.gbuffer import GBuffer, pixel_size_mm
from sssbench.ops import _reference_quad
from sssbench.ops._reference_far import Surface, gather, map_threads, with_border
from sssbench.ops._reference_flat import flat_kernel
from sssbench.ops._reference_near import HAT_OFFSETS, box_cell_sums, hat_cell_sums, node_sums
from sssbench.ops.timing import timed_pass
from sssbench.profiles.base import Profile, _gauss_legendre
from sssbench.profiles.sum_of_gaussians import (
    SumOfGaussians,
    cell_rules,
    flat_cell_mass,
    narrow_tilted_cell_mass,
)

__all__ = ["ReferenceSSS", "reference_sss", "reference_radius_px", "reference_code_digest"]

#: default energy tolerance of the support radius (see :func:`reference_sss`)
DEFAULT_TOL = 1e-6
#: steepest surface slope the reference trusts from a depth buffer (tan 85°)
MAX_SLOPE = math.tan(math.radians(85.0))
#: irradiance reconstructions (see :func:`reference_sss`)
RECONSTRUCTIONS = ("box", "bilinear")
#: methods of :func:`reference_sss`
METHODS = ("auto", "gather", "fft", "multipole")
#: a Gaussian at least this many (largest) pixel footprints wide (σ) is evaluated from block
#: moments by the multipole method; narrower ones cell by cell
WIDE_PIXELS = 1.5
#: the multipole method uses blocks whose patches fit in a ball of radius σ / FAR_RATIO
FAR_RATIO = 2.0


def reference_code_digest() -> str:
    """A digest of the source that computes references (this module and its private
    ``_reference_*`` modules, the native quadrature's C sources ``native/quad*`` and
    ``native/exp2_32.h``, every profile
    module, the camera) and of the numeric libraries whose rounding a reference carries
    (:func:`sssbench._digest.numeric_libraries`: torch, NumPy and NumPy's BLAS, which the far
    field's exp and products run in): caches of reference images add it to their key, so a
    changed reference is never served from a stale cache."""
    import hashlib
    from pathlib import Path

    import sssbench.gbuffer
    import sssbench.profiles

    here = Path(__file__)
    files = [here, *sorted(here.parent.glob("_reference_*.py"))]
    files += sorted((here.parent / "native").glob("quad*"))  # the near field's C sums
    files.append(here.parent / "native" / "exp2_32.h")  # and their exp's table
    files += sorted(Path(sssbench.profiles.__file__).parent.glob("*.py"))
    files.append(Path(sssbench.gbuffer.__file__))
    from sssbench._digest import numeric_libraries

    text = numeric_libraries() + "\n" + "".join(f.name + "\n" + f.read_text() for f in files)
    return hashlib.sha1(text.encode()).hexdigest()[:12]


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


def _minmod_slope(z: torch.Tensor, lateral: torch.Tensor, dim: int) -> torch.Tensor:
    """∂z/∂lateral along ``dim`` by the smaller of the two one-sided differences (0 where they
    disagree in sign), so a silhouette does not tilt the surface on either side of it."""
    dz = torch.diff(z, dim=dim)
    dl = torch.diff(lateral, dim=dim)
    fwd = dz / torch.where(dl == 0, torch.ones_like(dl), dl)
    pad_hi = [0, 0] * (z.ndim - 1 - dim) + [0, 1]
    pad_lo = [0, 0] * (z.ndim - 1 - dim) + [1, 0]
    a = torch.nn.functional.pad(fwd, pad_hi)  # forward difference at each cell
    b = torch.nn.functional.pad(fwd, pad_lo)  # backward difference
    slope = torch.where(a * b > 0, torch.sign(a) * torch.minimum(a.abs(), b.abs()), 0.0)
    return slope.clamp(-MAX_SLOPE, MAX_SLOPE)


def reference_radius_px(gbuffer: GBuffer, profile: Profile, tol: float = DEFAULT_TOL) -> int:
    """Half-size in pixels of the gather window: the profile's support radius (mm) over the
    smallest pixel footprint among active pixels, capped by the image size."""
    radius_mm = profile.radius(tol)
    mask = gbuffer.mask_or_ones()
    depth = gbuffer.depth[mask > 0] if bool((mask > 0).any()) else gbuffer.depth
    _, h, w = gbuffer.shape
    pmin = float(pixel_size_mm(depth.min(), gbuffer.fov_y, h))
    return int(min(math.ceil(radius_mm / pmin) + 1, max(h, w)))


def _flat_fft(
    g: GBuffer, profile: Profile, k: int, radius_mm: float, reconstruction: str
) -> tuple[torch.Tensor, torch.Tensor]:
    """``Σ_j s_j E_j w(i − j)`` and ``Σ_j s_j w(i − j)`` (``s`` = surface stencil) for a
    constant depth: FFT convolutions per channel (float64).

    The kernel is the gather's weight for each offset (:func:`flat_kernel`): on a plane every
    pixel sees its neighbour ``(du, dv)`` at ``(du·p, −dv·p, 0)`` mm. The bilinear
    reconstruction is linear in the values at the centres, so it is a convolution too: the
    stencil-weighted irradiance and the stencil are interpolated alike.
    """
    b, h, w = g.shape
    num = torch.empty(b, 3, h, w, dtype=torch.float64)
    den = torch.empty(b, 3, h, w, dtype=torch.float64)
    for i in range(b):
        z = g.depth[i].flatten()[0]
        pix = float(pixel_size_mm(z, g.fov_y, h))
        ker = flat_kernel(profile, pix, k, radius_mm, reconstruction)  # (3, n, n)
        stencil = (g.mask_or_ones()[i : i + 1] > 0).double()
        src = torch.cat([g.diffuse[i : i + 1] * stencil, stencil.expand(-1, 3, -1, -1)], 1)
        src = torch.nn.functional.pad(src, (k, k, k, k), mode="replicate")[0]  # (6, hp, wp)
        hp, wp = src.shape[-2:]
        kk = torch.zeros(3, hp, wp, dtype=torch.float64)
        kk[:, : 2 * k + 1, : 2 * k + 1] = ker
        kk = torch.roll(kk, (-k, -k), (1, 2)).repeat(2, 1, 1)
        res = torch.fft.irfft2(torch.fft.rfft2(src) * torch.fft.rfft2(kk), s=(hp, wp))
        num[i] = res[:3, k : k + h, k : k + w]
        den[i] = res[3:, k : k + h, k : k + w]
    return num, den


def _check_scale(g: GBuffer, profile: Profile) -> None:
    """Reject scenes whose pixel footprints and profile widths cannot be represented.

    Every weight is computed in a length unit of one pixel footprint (dimensionless
    ``area · R``), so the reference is the same at every scale as long as the squared ratios
    of the profile's widths to the footprints and the squared view positions are normal
    float64 numbers: footprints and depths in ``[1e-100, 1e100]`` mm and widths within
    ``1e100`` footprints.
    """
    _, h, _ = g.shape
    mask = g.mask_or_ones()
    depth = g.depth[mask > 0] if bool((mask > 0).any()) else g.depth.flatten()
    zlo, zhi = float(depth.min()), float(depth.max())
    plo, phi = (
        float(pixel_size_mm(torch.tensor(z, dtype=torch.float64), g.fov_y, h)) for z in (zlo, zhi)
    )
    lo, hi = profile.length_scales()
    ok = 1e-100 <= min(plo, zlo) and max(phi, zhi) <= 1e100
    ok = ok and hi / plo <= 1e100 and phi / lo <= 1e100
    if not ok:
        raise ValueError(
            "depth and fov_y must give pixel footprints and depths in [1e-100, 1e100] mm, "
            "within 1e100 of the profile's length scales; got depth in "
            f"[{zlo:g}, {zhi:g}] mm, footprint in [{plo:g}, {phi:g}] mm, profile scales "
            f"[{lo:g}, {hi:g}] mm"
        )


def reference_sss(
    gbuffer: GBuffer,
    profile: Profile,
    *,
    tol: float = DEFAULT_TOL,
    radius_px: int | None = None,
    method: str = "auto",
    reconstruction: str = "box",
    progress: bool | None = None,
    threads: int | None = None,
) -> torch.Tensor:
    """Exact screen-space subsurface scattering of ``gbuffer.diffuse`` with ``profile``.

    ``M_i = ∫_S E(p) R(|p − p_i|) dA / ∫_S R(|p − p_i|) dA`` (000 eq. 1): ``p_i`` are the
    view-space pixel centres (:func:`~sssbench.gbuffer.view_positions`), ``S`` the visible
    SSS surface as a union of one planar patch per pixel ("cell": the pixel's lateral square,
    ``pixel_size_mm(z_j)`` wide, centred on ``p_j``, tilted by the local depth slopes), and
    ``E`` the irradiance *reconstructed* on it from the pixel values (``reconstruction``):

    - ``"box"``: ``E`` is constant over each cell (the pixel's value): ``M_i = Σ_j s_j E_j
      w_ij / Σ_j s_j w_ij`` with ``w_ij = ∫_{cell_j} R(|p − p_i|) dA``;
    - ``"bilinear"``: ``E`` is the bilinear interpolation between the pixel centres (what a
      GPU's filtered texture fetch assumes), in each cell's own parameters: at ``p_n + s t_x
      + t t_y`` (``|s|, |t| ≤ h_n``) the values of the cell and its neighbours are weighted
      ``Λ(s/2h_n − a) Λ(t/2h_n − b)`` (``Λ`` the unit hat, ``(a, b)`` the neighbour's offset).
      Surface stencil and irradiance are interpolated alike: the numerator integrates the
      interpolated ``s E``, the denominator the interpolated ``s`` (so a constant irradiance
      stays constant). On a plane this is the convolution with ``R ⊗ (hat ⊗ hat)``.

    The profile is integrated exactly over the cells (closed forms, or the Taylor expansion
    below). Choices (documented here because the spec leaves them open):

    - Normalisation: divided by the weight actually gathered (the denominator above), per
      channel. Inside a surface this is ``‖R‖₁`` (so the kernel is normalised like every
      screen-space kernel; albedo / total reflectance is applied by texturing, not by the
      blur). Near a silhouette the neighbours behind the object are not in the G-buffer:
      dividing by ``‖R‖₁`` would darken every rim as if the hidden surface were unlit (by up to
      6% on ``sphere``, measured), so the hidden part is taken to carry the visible
      neighbourhood's weighted mean — a constant irradiance stays constant everywhere.
    - Support: the neighbours within ``profile.radius(tol)`` mm — the larger of "below
      ``tol`` × peak" and "less than ``tol`` of the energy outside" — gathered over the
      square window of that half-size, so the neglected energy is below ``tol``.
    - Borders: clamp-to-edge like the screen-space passes: a neighbour beyond the image has
      the border pixel's colour and depth at its own (extended) grid position.
    - Stencil: only neighbours with ``mask > 0`` (the SSS surface) contribute; pixels with
      mask 0 are copied through; a fractional mask lerps between the input and the scattered
      value (strength).
    - Tilted surfaces: each neighbour's cell is the planar patch over its lateral pixel
      square with the local depth slopes (minmod of the one-sided differences, so a
      silhouette does not tilt its neighbours; clamped at 85°), integrated with its area
      element at true 3D distances. Without the area element a sphere's interior loses
      energy as cos θ (10% at 25°, measured).

    Methods (all compute the same quantity):

    - ``"gather"`` (box only): every neighbour cell within the window, one closed form or
      Gauss–Legendre rule per cell (:meth:`Profile.cell_integral`; sums of Gaussians take a
      batched path with the same rules, see :func:`_gather_sog`). Cost ∝ window area.
    - ``"fft"``: constant depth only: every neighbour at the same offset has the same weight,
      so the sums are 2D convolutions (``torch.fft``) with the closed-form 1D factors of
      :mod:`sssbench.ops._reference_flat`, precise at any pixel / profile ratio.
    - ``"multipole"`` (sums of Gaussians): Gaussians narrower than ``WIDE_PIXELS`` times the largest
      footprint by the cell gather within their own (small) support, with nine hat-weighted cell
      integrals per neighbour cell for the bilinear reconstruction (the same closed forms,
      Gauss–Legendre per quadrant: :mod:`sssbench.ops._reference_near`, contracted with the
      neighbours block by block; about 2.0× the box reference's CPU time on the face and the
      sphere at 128², 0.3 mm/px, and 1.2–2.0× less than before issue 30 on the 512² face,
      head_cheek and sphere at 0.1 and 0.3 mm/px, measured); wider Gaussians from the
      moments of the reconstructed ``q dA`` (mass, dipole, quadrupole; exact for both
      reconstructions) of the coarsest pixel blocks whose patches fit in a ball of radius ``σ /
      FAR_RATIO``, by the second-order Taylor expansion of the Gaussian about the block centre;
      cells too large or steep for that are split into sub-patches that fit the same ball, with
      exact moments (:mod:`sssbench.ops._reference_far`). The expansion's error is third order in
      the block radius over σ where the irradiance or the surface jumps and exponentially small
      where they are smooth. Measured against a brute-force surface integral on a curved masked
      surface with a depth step and a shadow edge, kernel up to 37 px wide
      (tests/ops/test_reference_far.py): rel RMS 1.5e-5 (box) and 1.7e-5 (bilinear) at ``FAR_RATIO``
      2, 1.8e-6 / 3.7e-6 at 3, 2.9e-4 at 1; white-noise irradiance on a plane, one Gaussian, is the
      worst case measured: up to 1.5e-4 at 2. Support: every surface cell of the image extended by
      ``k`` pixels (clamp-to-edge) within ``σ_g √(2 ln(1 / tol_g))`` in 3D, ``tol_g`` = ``tol`` over
      the Gaussian's largest share of a channel's total (each Gaussian leaves out at most ``tol`` of
      any channel's energy). This equals the window of the other methods unless ``k`` is capped by
      the image size (a kernel wider than the image), where the other methods stop at ``±k`` pixels
      from each target.
    - ``"auto"``: fft for a constant depth, multipole for a sum of Gaussians with the
      library's cell integral, gather otherwise.

    Scale: all weights are computed as dimensionless ``area · R`` in a unit of one pixel
    footprint (and the 1D masses without CDF cancellation), so scaling the scene and the
    profile together does not change the result; depths and footprints outside
    ``[1e-100, 1e100]`` mm raise a ``ValueError`` (:func:`_check_scale`).

    Args:
        gbuffer: needs ``diffuse``, ``depth``, ``fov_y``; uses ``mask`` if present.
        profile: the radial profile (mm).
        tol: energy / peak tolerance of the support radius, in (0, 1).
        radius_px: override the window half-size in pixels, an integer in ``[0, max(H, W)]``
            (the automatic window is capped there too: beyond the image a window reaches only
            clamp-to-edge copies of the border, and its padding costs ``(H + 2k)(W + 2k)``
            cells, so an unbounded ``k`` could ask for any amount of memory).
        method: ``"auto"``, ``"gather"``, ``"fft"`` or ``"multipole"`` (see above).
        reconstruction: ``"box"`` or ``"bilinear"`` (see above).
        progress: show a progress bar (tqdm) on stderr — on a terminal only; ``None``: when
            the multipole evaluation has more than 500 000 target pixels × Gaussians (a few
            seconds).
        threads: Python threads of the gather and multipole methods (independent tiles of
            targets, each computed with one intra-op torch thread, so the result is the same
            for every ``threads``); ``None``: ``torch.get_num_threads()``.

    Returns:
        ``(B, 3, H, W)`` in the G-buffer's dtype (computed in float64).
    """
    if not isinstance(gbuffer, GBuffer):
        raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
    if not isinstance(profile, Profile):
        raise TypeError(f"profile must be a sssbench Profile, got {type(profile).__name__}")
    check_scalar("tol", tol, 0.0, 1.0, low_inclusive=False, high_inclusive=False)
    check_choice("method", method, METHODS)
    check_choice("reconstruction", reconstruction, RECONSTRUCTIONS)
    workers = torch.get_num_threads() if threads is None else threads
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"threads must be a positive int or None, got {threads!r}")
    total = profile.total()
    if bool((total <= 0).any()):
        raise ValueError(f"profile total must be > 0 in every channel, got {total.tolist()}")
    _check_scale(gbuffer, profile)
    if radius_px is None:
        k = reference_radius_px(gbuffer, profile, tol)
    else:  # bounded before anything is allocated: the padded image grows as (H + 2k)(W + 2k)
        k = check_int("radius_px", radius_px, 0, max(gbuffer.shape[1:]))

    g = gbuffer.to(torch.float64)
    b, h, w = g.shape
    mask = g.mask_or_ones()
    flat_depth = bool((g.depth.amax((1, 2, 3)) == g.depth.amin((1, 2, 3))).all())
    if method == "fft" and not flat_depth:
        raise ValueError("method='fft' needs a constant depth (a fronto-parallel plane)")
    if method == "auto":
        method = "fft" if flat_depth else "multipole" if _is_sum_of_gaussians(profile) else "gather"
    if method == "fft":
        n_active = int((mask > 0).sum())
        with timed_pass("reference", (2 * k + 1) ** 2, n_active):  # timed like the others
            num, den = _flat_fft(g, profile, k, profile.radius(tol), reconstruction)
        return _finish(g, mask, num, den).to(gbuffer.dtype)
    if method == "multipole" and not _is_sum_of_gaussians(profile):
        raise ValueError(
            "method='multipole' needs a SumOfGaussians profile with the library's cell "
            f"integral, got {type(profile).__name__}"
        )
    if method == "gather" and reconstruction != "box":
        raise ValueError(
            "method='gather' integrates piecewise-constant cells; use reconstruction='box' or "
            "method='multipole' / 'fft' for 'bilinear'"
        )
    active = torch.nonzero(mask.reshape(-1) > 0).squeeze(1)
    bi, rem = active // (h * w), active % (h * w)
    hp, wp = h + 2 * k, w + 2 * k
    centre = bi * hp * wp + (rem // w + k) * wp + (rem % w + k)  # flat index in the padding
    radius_mm = profile.radius(tol)
    with timed_pass("reference", (2 * k + 1) ** 2, int(active.numel())):
        if method == "multipole":
            acc, wsum = _multipole(g, profile, k, active, tol, reconstruction, progress, workers)
        elif _is_sum_of_gaussians(profile):
            table = _surface(g, k).table
            acc, wsum = _gather_sog(profile, table, centre, wp, k, radius_mm, workers=workers)
        else:
            acc, wsum = _gather_generic(profile, _surface(g, k).table, centre, wp, k, radius_mm)
    num = torch.zeros(b * h * w, 3, dtype=torch.float64).index_copy(0, active, acc)
    den = torch.ones(b * h * w, 3, dtype=torch.float64).index_copy(0, active, wsum)
    num = num.reshape(b, h, w, 3).permute(0, 3, 1, 2)
    den = den.reshape(b, h, w, 3).permute(0, 3, 1, 2)
    return _finish(g, mask, num, den).to(gbuffer.dtype)


@dataclass(frozen=True)
class _Padded:
    """The surface padded by ``k`` pixels: ``fields`` ``(B, 10, Hp, Wp)`` = x, y, z, half,
    slope_x, slope_y, stencil, irradiance·stencil (3); :attr:`table` the same channels-last
    (a copy, made when asked for)."""

    fields: torch.Tensor

    @property
    def table(self) -> torch.Tensor:
        """``(B·Hp·Wp, 10)``: one row of everything a neighbour contributes per cell."""
        return self.fields.permute(0, 2, 3, 1).reshape(-1, self.fields.shape[1])


def _surface(g: GBuffer, k: int) -> _Padded:
    """Cell geometry of the padded surface (see :func:`reference_sss`)."""
    b, h, _ = g.shape
    pad = (k, k, k, k)
    xp, yp, zp = _padded_positions(g.depth, g.fov_y, k)
    stencil = (g.mask_or_ones() > 0).double()
    src = torch.nn.functional.pad(g.diffuse * stencil, pad, mode="replicate")
    src_mask = torch.nn.functional.pad(stencil, pad, mode="replicate")
    # a neighbour off the surface gets a zero-size cell: no weight, and it does not drive the
    # quadrature order of the cells that matter
    half = 0.5 * pixel_size_mm(zp, g.fov_y, h) * src_mask
    slope_x = _minmod_slope(zp, xp, 3)
    slope_y = _minmod_slope(zp, yp, 2)
    return _Padded(torch.cat([xp, yp, zp, half, slope_x, slope_y, src_mask, src], 1))


def _multipole(
    g: GBuffer,
    profile: SumOfGaussians,
    k: int,
    active: torch.Tensor,
    tol: float,
    reconstruction: str,
    progress: bool | None,
    workers: int = 1,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Numerator and denominator ``(E, 3)`` of the active pixels by the ``"multipole"``
    method of :func:`reference_sss` on ``workers`` threads. The padded surface is built
    here and dropped once its scaled copy (with the one-pixel border the far field reads)
    exists; the far field then holds the pyramid's levels ≥ 1 and one Gaussian's sources at
    a time (3.2 GiB peak RSS on the 1080p face close-up with skin_deon6, measured)."""
    b, h, w = g.shape
    e = active.numel()
    acc = torch.zeros(e, 3, dtype=torch.float64)
    wsum = torch.zeros_like(acc)
    if e == 0:
        return acc, wsum
    mask = g.mask_or_ones()
    depth = g.depth[mask > 0]
    unit = float(pixel_size_mm(depth.min(), g.fov_y, h))  # the length unit: a footprint
    p_max = float(pixel_size_mm(depth.max(), g.fov_y, h)) / unit
    var = (profile.variances / unit**2).tolist()
    wts = profile.weights
    wide = [i for i, v in enumerate(var) if math.sqrt(v) >= WIDE_PIXELS * p_max]
    narrow = [i for i in range(len(var)) if i not in wide]
    groups = [(wide, FAR_RATIO)] if wide else []
    # a bar when the run takes more than a few seconds (measured on the face close-up,
    # skin_deon6: ~2e5 px·Gaussians per CPU second)
    show = e * len(var) > 500_000 if progress is None else progress
    # the bilinear near field reads every cell's 3×3 neighbours: one more ring of padding
    ring = 1 if reconstruction == "bilinear" else 0
    surf = _surface(g, k + ring)
    if narrow:
        sub = SumOfGaussians(profile.variances[narrow], wts[narrow])
        r_n = sub.radius(tol)
        k_n = min(k, math.ceil(r_n / unit) + 1)
        kr = k + ring
        hp, wp = h + 2 * kr, w + 2 * kr
        bi, rem = active // (h * w), active % (h * w)
        centre = bi * hp * wp + (rem // w + kr) * wp + (rem % w + kr)
        with progress_bar(show, desc="reference (cells)", unit="offset") as near_bar:
            acc, wsum = _gather_sog(
                sub,
                surf.table,
                centre,
                wp,
                k_n,
                r_n,
                progress=near_bar,
                workers=workers,
                reconstruction=reconstruction,
            )
    if ring:
        surf = _Padded(surf.fields[..., ring:-ring, ring:-ring])
    if not groups:
        return acc, wsum
    n_far = sum(len(ids) for ids, _ in groups)
    bar = progress_bar(show, total=e * n_far, desc="reference (moments)", unit="px·G")
    foot = 2 * math.tan(g.fov_y / 2) / h
    for i in range(b):
        f = surf.fields[i]
        parts = [f[0] / unit, f[1] / unit, f[2] / unit, f[3] / unit, f[4], f[5], *f[7:10], f[6]]
        u_max = float((torch.stack([f[0], f[1]]).abs() / f[2]).amax())
        s = Surface(with_border(parts), k, foot, u_max)
        del parts, f
        if i == b - 1:
            del surf  # the padded surface is not needed once its scaled copies exist
        sel = torch.nonzero(active // (h * w) == i).squeeze(1)
        rem = active[sel] % (h * w)
        rows, cols = rem // w + k, rem % w + k
        for ids, ratio in groups:
            v_g = [var[j] for j in ids]
            # each Gaussian's own share of the tolerance: it may leave out tol × the smallest
            # channel total of the profile
            share = [float((wts[j] / profile.total()).max()) for j in ids]
            tols = [min(0.5, tol / max(sh, tol)) for sh in share]
            per_gaussian = gather(
                s, rows, cols, v_g, tols, reconstruction, ratio, progress=bar, workers=workers
            )
            # elementwise, one Gaussian at a time (a matrix product's rounding may depend
            # on torch's thread count)
            for j, res in zip(ids, per_gaussian, strict=True):
                acc[sel] += res[:, :3] * wts[j]
                wsum[sel] += res[:, 3:] * wts[j]
    bar.close()
    return acc, wsum


def _gather_generic(
    profile: Profile, table: torch.Tensor, centre: torch.Tensor, wp: int, k: int, radius_mm: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """``Σ_j s_j E_j w_ij`` and ``Σ_j s_j w_ij`` per active centre, one neighbour offset at a
    time through :meth:`Profile.cell_integral` (any profile)."""
    xc, yc, zc = table[centre, 0], table[centre, 1], table[centre, 2]
    acc = torch.zeros(centre.numel(), 3, dtype=torch.float64)
    wsum = torch.zeros_like(acc)
    for dv in range(-k, k + 1):
        for du in range(-k, k + 1):
            nb = table[centre + dv * wp + du]
            dx, dy, hh = nb[:, 0] - xc, nb[:, 1] - yc, nb[:, 3]
            # skip offsets whose nearest cell edge is beyond the support everywhere
            near2 = (dx.abs() - hh).clamp_min(0) ** 2 + (dy.abs() - hh).clamp_min(0) ** 2
            on = nb[:, 6] > 0
            if not bool(on.any()) or float(near2[on].min()) > radius_mm**2:
                continue  # same rule as _flat_fft
            wgt = profile.cell_integral(dx, dy, nb[:, 2] - zc, hh, hh, nb[:, 4], nb[:, 5])
            wgt = wgt * nb[:, 6:7]
            acc += wgt * nb[:, 7:10]
            wsum += wgt
    return acc, wsum


#: offsets × centres gathered per batch by :func:`_gather_sog`
_BATCH_ELEMS = 1 << 18
#: centres per chunk of :func:`_gather_sog` (a chunk's batches stay in cache)
_CENTRES = 1 << 15
#: a Gauss–Legendre Gaussian is left out of an offset whose cells all lie where it is below
#: exp(-_SOG_SKIP) of its peak (see :func:`_gather_sog`; ``cell_integral`` uses 40)
_SOG_SKIP = 25.0


def _is_sum_of_gaussians(profile: Profile) -> bool:
    """A :class:`SumOfGaussians` whose cell integral is the library's (not overridden)."""
    return (
        isinstance(profile, SumOfGaussians)
        and type(profile).cell_integral is SumOfGaussians.cell_integral
    )


def _sog_gauss_legendre(
    dx: torch.Tensor,
    dy: torch.Tensor,
    dz: torch.Tensor,
    hh: torch.Tensor,
    sx: torch.Tensor,
    sy: torch.Tensor,
    v: list[float],
    n: list[int],
    weights: torch.Tensor,
) -> torch.Tensor:
    """``Σ_g weights_g ∫∫ G(v_g, |Δ + s t_x + t t_y|) dA`` over square planar patches of
    half-size ``hh`` by the n_g×n_g Gauss–Legendre rule of
    :meth:`SumOfGaussians.cell_integral`, several Gaussians at once; ``weights`` ``(G, 3)``
    -> ``(3, M)``.

    With ``s = hh·ξ_a``, ``t = hh·ξ_b``, ``t_x = (1, 0, slope_x)``, ``t_y = (0, 1, slope_y)``
    the squared distance of a node is a fixed polynomial of the node,
    ``|Δ|² + 2hξ_a Δ·t_x + 2hξ_b Δ·t_y + h²ξ_a²|t_x|² + h²ξ_b²|t_y|² + 2h²ξ_aξ_b t_x·t_y``,
    so the exponents of every node of every Gaussian (001 eq. 7) are one matrix product of a
    (nodes, 6) table with six per-cell features, and the node sums, weighted by quadrature
    and channel weights, a second one.
    The same nodes and weights as the per-Gaussian rule, summed in another order (rounding).
    """
    phi, wsum = [], []
    for vg, ng in zip(v, n, strict=True):
        x, w = _gauss_legendre(ng)
        xa, xb = np.repeat(x, ng), np.tile(x, ng)
        phi.append(np.stack([np.ones_like(xa), xa, xb, xa**2, xb**2, xa * xb], 1) * (-0.5 / vg))
        wsum.append(np.outer(w, w).ravel() / (2 * math.pi * vg))
    rows = sum(len(c) for c in wsum)
    reduce = np.zeros((len(v), rows))
    start = 0
    for g, c in enumerate(wsum):
        reduce[g, start : start + len(c)] = c
        start += len(c)
    a_mat = torch.from_numpy(np.concatenate(phi)).to(dx)
    r_mat = weights.to(dx).t() @ torch.from_numpy(reduce).to(dx)  # (3, nodes)
    return node_sums(a_mat, r_mat, dx, dy, dz, sx, sy, hh)


def _sog_cell_weights(
    profile: SumOfGaussians,
    rule: tuple[int | str | None, ...],
    dx: torch.Tensor,
    dy: torch.Tensor,
    dz: torch.Tensor,
    hh: torch.Tensor,
    sx: torch.Tensor,
    sy: torch.Tensor,
) -> torch.Tensor:
    """:meth:`SumOfGaussians.cell_integral` of flat cell tensors (M,) with the per-Gaussian
    ``rule`` of :func:`cell_rules`, channels first: ``(3, M)``."""
    v = profile.variances.to(dx)
    used = [i for i, r in enumerate(rule) if r is not None]
    terms: dict[int, torch.Tensor] = {}
    for i in used:
        if rule[i] == "flat":
            terms[i] = flat_cell_mass(dx, dy, dz, hh, hh, v[i])
        elif rule[i] == "narrow":
            terms[i] = narrow_tilted_cell_mass(dx, dy, dz, hh, hh, sx, sy, v[i])
    w = profile.weights.to(dx)
    out = None
    quad = [i for i in used if isinstance(rule[i], int)]
    if quad:
        order = [int(rule[i]) for i in quad]  # type: ignore[arg-type]
        var = [float(v[i]) for i in quad]
        out = _sog_gauss_legendre(dx, dy, dz, hh, sx, sy, var, order, w[quad])
    for i, term in terms.items():
        out = w[i][:, None] * term if out is None else out + w[i][:, None] * term
    assert out is not None
    return out


def _gather_sog(
    profile: SumOfGaussians,
    table: torch.Tensor,
    centre: torch.Tensor,
    wp: int,
    k: int,
    radius_mm: float,
    progress: object = None,
    workers: int = 1,
    reconstruction: str = "box",
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`_gather_generic` for a sum of Gaussians, many offsets per batch (``progress``:
    a tqdm bar, advanced by the offsets done; the chunks of centres run on ``workers`` threads,
    :func:`~sssbench.ops._reference_far.map_threads`).

    Centres are taken in chunks of ``_CENTRES`` (bands of rows, so a batch stays in cache),
    offsets nearest first in batches of ``_BATCH_ELEMS // centres``; each offset of a chunk
    keeps its own support test and its own :func:`cell_rules` (as if it were one
    :meth:`SumOfGaussians.cell_integral` call on the chunk's cells), and offsets with the same
    rule are integrated together. Equal to the offset loop to rounding (tested).

    Sums of Gaussians (with the library's cell integral) take a batched path: many offsets
    at a time, each with the rule :meth:`SumOfGaussians.cell_integral` picks for it alone
    (same nodes, same closed forms; the node exponents and sums as matrix products), equal
    to the offset loop to rounding (tested) but for one approximation: a Gaussian integrated
    by Gauss–Legendre is left out of an offset whose cells all lie more than ``√(50 v)``
    mm (lateral nearest distance) from the centre, instead of ``√(80 v)``. Every node of
    such a cell is at least that far in 3D, and a 2D Gaussian holds ``exp(−r²/2v)`` of its
    mass beyond ``r`` (from 001 eq. 7), so the weight left out is below
    ``2 A e^−25 ≈ 4.5e-10`` of the Gaussian's mass (``A ≤ √(1 + 2 tan² 85°) ≈ 16.2`` the
    largest area element, 2 for cells overlapping at depth steps) and the output moves by
    at most ``2 max E`` times that over the gathered fraction of ``‖R‖₁`` (measured: 2e-13
    on the 512² head). The narrow closed form keeps ``√(80 v)``: with slopes along both axes
    it is not bounded by the nearest distance (measured: 7.6e-2 of a Gaussian's mass on a
    silhouette cell 9σ away), so leaving it out earlier would change the result.

    ``reconstruction="bilinear"``: each neighbour cell contributes the nine hat-weighted
    integrals of :func:`~sssbench.ops._reference_near.hat_cell_weights` (same rules, a
    Gauss–Legendre rule per quadrant) times the values of its 3×3 neighbours, which
    ``table`` must hold (one ring of padding beyond the ``k`` the offsets reach); computed
    and contracted block by block by :func:`~sssbench.ops._reference_near.hat_cell_sums`
    (equal to contracting ``hat_cell_weights`` to rounding, tested)."""
    e = centre.numel()
    acc = torch.zeros(e, 3, dtype=torch.float64)
    wsum = torch.zeros_like(acc)
    if e == 0:
        return acc, wsum
    v = [float(x) for x in profile.variances.to(torch.float64)]
    offs = sorted((du * du + dv * dv, dv, du) for dv in range(-k, k + 1) for du in range(-k, k + 1))
    shift = torch.tensor([dv * wp + du for _, dv, du in offs], dtype=centre.dtype)
    # field-major (every gathered field contiguous), without the stencil column: a neighbour
    # is on the surface iff its cell has a size (depth > 0 is validated by GBuffer), and a
    # zero-size cell has weight exactly 0 in every rule
    cols = [0, 1, 2, 3, 4, 5, 7, 8, 9] if reconstruction == "box" else list(range(10))
    fields = table[:, cols].t().contiguous()
    hat = values = None
    if reconstruction == "bilinear":  # flat-index shifts of the 3×3 neighbours (row −b)
        hat = torch.tensor([a - b * wp for a, b in HAT_OFFSETS], dtype=centre.dtype)
        values = fields[6:10].t().contiguous()  # (N, 4): a neighbour's row is one gather
    elif fields.dtype == torch.float64 and _reference_quad.available():
        # the box rule through the native quadrature: rows (1, q) (the denominator is W)
        values = torch.cat([torch.ones_like(fields[6, :, None]), fields[6:9].t()], 1)
    if progress is not None:
        progress.reset(total=shift.numel() * math.ceil(e / _CENTRES))

    def chunk(i: int) -> int:
        part = slice(i, i + _CENTRES)
        acc[part], wsum[part] = _sog_chunk(
            profile, v, fields, centre[part], shift, radius_mm, hat, values
        )
        return shift.numel()

    for n in map_threads(chunk, range(0, e, _CENTRES), workers):
        if progress is not None:
            progress.update(n)
    return acc, wsum


def _sog_chunk(
    profile: SumOfGaussians,
    v: list[float],
    fields: torch.Tensor,
    centre: torch.Tensor,
    shift: torch.Tensor,
    radius_mm: float,
    hat: torch.Tensor | None = None,
    values: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`_gather_sog` of at most ``_CENTRES`` centres (``fields``: field-major
    neighbour table, ``shift``: flat offsets nearest first; ``hat``: the flat shifts of the
    nine bilinear neighbours, ``None`` for the box reconstruction, whose table has no
    stencil row; ``values``: the bilinear reconstruction's ``(N, 4)`` stencil and irradiance ·
    stencil per cell, see :func:`~sssbench.ops._reference_near.hat_cell_sums`; for the box
    reconstruction ``(N, 4)`` rows ``(1, irradiance · stencil)`` when its cells are summed by
    the native quadrature (:func:`~sssbench.ops._reference_near.box_cell_sums`), else
    ``None``)."""
    e = centre.numel()
    acc = torch.zeros(e, 3, dtype=torch.float64)
    wsum = torch.zeros_like(acc)
    xc, yc, zc = fields[0, centre], fields[1, centre], fields[2, centre]
    per = max(1, _BATCH_ELEMS // e)
    # the gather and the offsets from the centre in one native pass (the same values)
    fast = fields.dtype == torch.float64 and _reference_quad.available()
    centre = centre.contiguous()
    for a in range(0, shift.numel(), per):
        sh = shift[a : a + per]
        c = sh.numel()
        idx = (centre[None, :] + sh[:, None]).reshape(1, -1).expand(fields.shape[0], -1)
        if fast:
            nb = _reference_quad.offset_fields(fields, centre, sh.contiguous())
            dx, dy, dz = nb[0], nb[1], nb[2]
        else:
            nb = torch.gather(fields, 1, idx).view(-1, c, e)
            dx, dy, dz = nb[0] - xc, nb[1] - yc, nb[2] - zc
        hh, sx, sy = nb[3], nb[4], nb[5]
        with torch.no_grad():
            near2 = (dx.abs() - hh).clamp_min_(0).square_()
            near2 += (dy.abs() - hh).clamp_min_(0).square_()
            near2_min = near2.amin(1).tolist()
            # the support test of _gather_generic: the nearest on-surface cell of the offset
            near_on = near2.masked_fill_(hh <= 0, math.inf).amin(1).tolist()
            h_max = hh.amax(1).tolist()
            tilted = (torch.count_nonzero(sx, 1) + torch.count_nonzero(sy, 1)).tolist()
        groups: dict[tuple[int | str | None, ...], list[int]] = {}
        for j in range(c):
            if near_on[j] > radius_mm**2:
                continue  # no on-surface neighbour, or all beyond the support
            rule = cell_rules(v, near2_min[j], h_max[j], tilted[j] > 0, 2.0 * _SOG_SKIP)
            if any(r is not None for r in rule):
                groups.setdefault(rule, []).append(j)
        for rule, rows in groups.items():
            sub = [dx, dy, dz, hh, sx, sy, nb[6:9]]
            if len(rows) < c:
                sel = torch.tensor(rows)
                sub = [t.index_select(-2, sel) for t in sub]
            if hat is not None and values is not None:
                cells = idx[0].view(c, e)
                if len(rows) < c:
                    cells = cells.index_select(0, sel)
                geom = [t.reshape(-1) for t in sub[:6]]
                cells = cells.reshape(-1)
                # cells off the surface (zero size) have weight exactly 0 in every rule:
                # only the others are integrated, their sums put back among zeros
                on = torch.nonzero(geom[3] > 0).squeeze(1)
                if on.numel() == cells.numel():
                    part = hat_cell_sums(profile, rule, *geom, values, cells, hat)
                else:
                    part = geom[0].new_zeros(6, cells.numel())
                    if on.numel():
                        geom = [t.index_select(0, on) for t in geom]
                        got = hat_cell_sums(profile, rule, *geom, values, cells[on], hat)
                        part.index_copy_(1, on, got)
                part = part.view(6, -1, e).sum(1)
                acc += part[:3].t()
                wsum += part[3:].t()
                continue
            if values is not None:  # the box rule, native (box_cell_sums)
                cells = idx[0].view(c, e)
                if len(rows) < c:
                    cells = cells.index_select(0, sel)
                geom = torch.stack([t.reshape(-1) for t in sub[:6]])
                part = box_cell_sums(profile, rule, geom, values, cells.reshape(-1))
                part = part.view(6, -1, e).sum(1)
                acc += part[:3].t()
                wsum += part[3:].t()
                continue
            wgt = _sog_cell_weights(profile, rule, *(t.reshape(-1) for t in sub[:6]))
            wgt = wgt.view(3, -1, e)
            acc += (wgt * sub[6]).sum(1).t()
            wsum += wgt.sum(1).t()
    return acc, wsum


def _finish(g: GBuffer, mask: torch.Tensor, num: torch.Tensor, den: torch.Tensor) -> torch.Tensor:
    """Normalise by the gathered weight, apply strength, copy masked-out pixels through."""
    scattered = num / den.clamp_min(torch.finfo(torch.float64).tiny)
    out = g.diffuse + mask * (scattered - g.diffuse)
    return torch.where(mask > 0, out, g.diffuse)


class ReferenceSSS(nn.Module):
    """Module twin of :func:`reference_sss`.

    Args:
        profile: the radial diffusion profile.
        tol: support tolerance (see :func:`reference_sss`).
        method: ``"auto"``, ``"gather"``, ``"fft"`` or ``"multipole"``.
        reconstruction: ``"box"`` (piecewise-constant pixel cells, the default) or
            ``"bilinear"`` (bilinear interpolation between pixel centres).

    Shape:
        - forward(gbuffer): ``(B, 3, H, W)``.
    """

    #: G-buffer fields the operator reads (besides diffuse, depth, fov_y)
    needs = ("mask",)

    def __init__(
        self,
        profile: Profile,
        tol: float = DEFAULT_TOL,
        method: str = "auto",
        reconstruction: str = "box",
    ) -> None:
        super().__init__()
        check_choice("method", method, METHODS)
        check_choice("reconstruction", reconstruction, RECONSTRUCTIONS)
        self.method = method
        self.reconstruction = reconstruction
        if not isinstance(profile, Profile):
            raise TypeError(f"profile must be a sssbench Profile, got {type(profile).__name__}")
        self.profile = profile
        self.tol = check_scalar("tol", tol, 0.0, 1.0, low_inclusive=False, high_inclusive=False)

    def forward(self, gbuffer: GBuffer) -> torch.Tensor:
        return reference_sss(
            gbuffer,
            self.profile,
            tol=self.tol,
            method=self.method,
            reconstruction=self.reconstruction,
        )
