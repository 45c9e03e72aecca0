"""SVD rank-N separable SSS (000 §3 eq. 2): ``2N`` passes, one horizontal + vertical pair per
singular term, summed."""

from __future__ import annotations

import torch

from sssbench._checks import check_int, check_magnitude, check_method_options
from sssbench.gbuffer import GBuffer
from sssbench.kernels.low_rank import LowRankKernel, low_rank
from sssbench.kernels.matrix import MAX_MATRIX_SIZE, kernel_matrix
from sssbench.ops.functional import functional
from sssbench.ops.gather import separable_pass
from sssbench.ops.method import SeparableMethod
from sssbench.profiles.base import Profile

__all__ = ["LowRankSSS", "low_rank_sss"]


class LowRankSSS(SeparableMethod):
    """Rank-N SVD approximation of the discretised kernel (000 §3, eq. 2), 2N passes.

    The profile is integrated over an ``n × n`` grid of cells covering ``[-extent, extent]²``
    (:func:`~sssbench.kernels.kernel_matrix`), the matrix is normalised to sum 1 per channel
    (the kernel "normalised to one", 000 §4: like every other method here, a constant image
    stays constant at full rank), and factored by the SVD (:func:`~sssbench.kernels.low_rank`;
    Eckart–Young: the best rank-N approximation in the Frobenius norm). Term ``i`` is applied
    as a horizontal pass with ``a_i`` (the right singular vector) and a vertical pass with the
    left one, and the terms are summed: ``Σ_i ((E * a_i) * a'_i)`` (000 eq. 2). The taps sit
    at the cell centres (mm), ``n`` per pass; the weights are cell masses and may be negative.

    A truncated rank does not sum to one: the result carries the rank-N kernel's own sum
    (000 §3: "a rather large energy loss"), shown by :attr:`kernel_sum`. The methods are
    compared as the paper does, without renormalising.

    Stencil: pixels with mask 0 are copied through. A term's horizontal pass leaves them at
    ``E · Σ a_i`` (what the pass computes on a constant neighbourhood) rather than ``E``, so
    the vertical pass of every term sees a consistently scaled neighbour and the sum over
    terms stays normalised next to masked-out pixels.

    Args:
        profile: radial diffusion profile (mm).
        rank: number of separable terms N, in [1, n].
        n: cells per side, i.e. taps per pass; odd (a cell on the centre), else
            ``ValueError``: with an even n the peak is split between the two cells beside
            the centre, moved half a cell out, and the error grows with the taps.
        extent: half-width of the discretised square in mm; default ``profile.radius()``.
        follow_surface: ``"lerp"`` (default), ``"gaussian"`` or ``None`` (see
            :func:`separable_pass`). 000 §3 analyses the SVD terms as kernels; for rendering,
            000 §7 uses the screen-space pass of [JSG09], whose shader follows the surface with
            the depth lerp (002 appendix ``SSSS_FOLLOW_SURFACE``, 004 §3.1.2 Fig. 3.6): the
            default. Measured on ``head_closeup`` (skin_jg10, rank 3, 31 cells, 128²): ``None``
            0.040 rel RMS, worse than the unblurred input's 0.037; the lerp 0.012.
        surface_scale: mm; default the profile's widest length scale.
        rotation: stochastic rotation radius fraction (000 §6), or ``None``.
        seed: rotation seed (one :class:`Rotation` for every pass).

    Shape:
        - forward(gbuffer): ``(B, 3, H, W)``.

    Example:
        >>> from sssbench.profiles import SumOfGaussians
        >>> op = LowRankSSS(SumOfGaussians.from_table("skin_deon6"), 3, n=21, extent=6.0)
        >>> g = GBuffer(torch.ones(1, 3, 8, 8), torch.full((1, 1, 8, 8), 100.0), 0.4)
        >>> op(g).shape, op.kernel.rank
        (torch.Size([1, 3, 8, 8]), 3)
    """

    needs = ("mask",)
    no_sample_weight = (
        "renormalises each pass by its summed weights, which needs one non-negative normalised "
        "kernel; the SVD terms of LowRankSSS carry negative weights and are summed, so use "
        "another method for halo reduction"
    )

    def __init__(
        self,
        profile: Profile,
        rank: int = 3,
        n: int = 31,
        extent: float | None = None,
        follow_surface: str | None = "lerp",
        surface_scale: float | None = None,
        rotation: float | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__()
        if not isinstance(profile, Profile):
            raise TypeError(f"profile must be a sssbench Profile, got {type(profile).__name__}")
        check_method_options(surface_scale, seed)
        if extent is not None:
            extent = check_magnitude("extent", extent, "length")
        n = check_int("n", n, 1, MAX_MATRIX_SIZE)
        if n % 2 == 0:
            # 000 §3 discretises the kernel on cells; with an even n no cell sits on the
            # centre, the profile's peak is split between the two cells beside it and moved
            # half a cell out: light_dot at 0.3 mm/px (skin_deon6, rank 3) scores rel RMS
            # 0.50 at n = 10 against 0.13 at n = 9 and 0.12 at n = 11
            raise ValueError(
                f"n (cells per side, taps per pass) must be odd so that a cell sits on the "
                f"kernel's centre, got {n}; use {n - 1} or {n + 1}"
            )
        rank = check_int("rank", rank, 1, n)
        self.set_options(
            follow_surface, surface_scale, rotation, seed, default_scale=profile.length_scales()[1]
        )
        extent = check_magnitude("extent", profile.radius() if extent is None else extent, "length")
        m = kernel_matrix(profile, extent, n)
        m = m / m.sum((1, 2), keepdim=True)  # 000 §4: normalised to one
        self.profile = profile
        self.matrix = m
        self.kernel: LowRankKernel = low_rank(m, rank, extent=extent)  # 000 §3 SVD
        self.rank = rank
        self.n = n
        self.extent = extent

    @property
    def kernel_sum(self) -> torch.Tensor:
        """``(3,)`` sum of the rank-N kernel (1 at full rank)."""
        return sum(h.sum() * v.sum() for h, v in self.kernel.terms)

    def scatter(self, gbuffer: GBuffer, options: dict[str, object]) -> torch.Tensor:
        image = gbuffer.diffuse
        active = gbuffer.mask_or_ones() > 0
        dtype = gbuffer.dtype
        out = torch.zeros_like(image)
        for i, (h, v) in enumerate(self.kernel.terms):  # 000 eq. 2: Σ (E * a_i) * a_i
            tmp = separable_pass(image, h, "x", gbuffer, name=f"low_rank{i}.x", **options)
            h_sum = h.sum().to(dtype=dtype, device=image.device).view(1, 3, 1, 1)
            tmp = torch.where(active, tmp, image * h_sum)
            name = f"low_rank{i}.y"
            out = out + separable_pass(tmp, v, "y", gbuffer, name=name, inplace=True, **options)
        return torch.where(active, out, image)


#: the functional twin: every argument of :class:`LowRankSSS`, kernels reused
low_rank_sss = functional(LowRankSSS, "low_rank_sss")
