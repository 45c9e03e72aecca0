"""Error budget of a screen-space SSS method: where its error comes from (docs/error_budget.md).

For a method at ``N`` taps on a G-buffer with exact reference ``R`` (box reconstruction,
:class:`~sssbench.ops.ReferenceSSS`), the error image ``M_N − R`` is split into four images
that add up to it exactly:

- **taps**: ``M_N − M_∞``, the method against itself converged in taps (:func:`converged`);
- **model**: ``K − T``, the method's own continuous 2D kernel (:func:`method_kernel`) against
  the true profile, both applied to the scene's irradiance on a flat fronto-parallel plane at
  the scene's footprint (one pixel size, :func:`footprint_mm`) with exact cell integrals and
  the reference's stencil convention (:func:`flat_convolution`);
- **recon**: ``R_bilinear − R``, the reference under the gather's reconstruction convention
  (the passes read the image with linear interpolation; the reference integrates
  piecewise-constant pixel cells) — ``NaN`` (and folded into screen) when
  :class:`~sssbench.ops.ReferenceSSS` has no ``reconstruction`` keyword;
- **screen**: the rest, ``(M_∞ − R_bilinear) − (K − T)``: what the screen-space pass adds on
  this G-buffer beyond its kernel shape on a plane (depth steps, follow-surface, curvature,
  mask borders read by the gather, level of detail).

Each part is reported as its rel RMS (``‖part‖ / ‖R‖`` over the mask, the denominator of
:func:`sssbench.score.metrics.rel_rms`) and as its *contribution* ``⟨part, M_N − R⟩ / (‖R‖ ‖M_N −
R‖)``: the contributions add up exactly to the total rel RMS (a part that cancels another
has a negative contribution). The norms add up only in quadrature when the parts are
orthogonal; the budget reports ``quadrature = √Σ norm²`` next to the total to show how close.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from sssbench._checks import check_int, check_scalar
from sssbench._memo import by_content
from sssbench.gbuffer import GBuffer, pixel_size_mm
from sssbench.kernels.artist import ArtistParams, _per_channel
from sssbench.kernels.jimenez2012 import _WIDTHS_PER_UNIT, _base_profile
from sssbench.kernels.matrix import MAX_MATRIX_SIZE, kernel_matrix
from sssbench.kernels.sampling import MAX_SAMPLES, gaussian_mixture_interval
from sssbench.profiles.base import Profile

__all__ = [
    "Term",
    "ContinuousKernel",
    "method_kernel",
    "profile_kernel",
    "footprint_mm",
    "flat_convolution",
    "converged",
    "Budget",
    "budget_truth",
    "error_budget",
    "CONVERGED_TOL",
]

#: interval function ``(a, b) -> (K, 3)``: the mass of a 1D kernel factor over ``[a, b]`` (mm)
Interval = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
#: taps are converged when doubling them changes the output by less than this (rel RMS)
CONVERGED_TOL = 1e-4
#: a Gaussian of this σ (mm) stands for a delta (the unblurred first Gaussian, 003 §7.3.3)
_DELTA_SIGMA = 1e-12
#: tap range of the 2012 kernel builder above 20 samples, kernel units (002 appendix)
_JIMENEZ2012_RANGE = 3.0
#: support of Gaussian kernels in σ (mass outside < 6e-7)
_GAUSS_SUPPORT = 5.0


@dataclass(frozen=True)
class Term:
    """One separable term ``fx(x) fy(y)`` of a 2D kernel, given by the masses of its factors
    over intervals (per channel)."""

    fx: Interval
    fy: Interval


@dataclass(frozen=True)
class ContinuousKernel:
    """A method's continuous 2D kernel ``Σ_i fx_i(x) fy_i(y)`` (mm), per channel.

    Attributes:
        terms: the separable terms.
        radius_mm: half-width of a square outside which the kernel is negligible.
        cells_fn: optional exact cell integrator (for a radial profile, its own
            ``cell_integral``) used instead of the terms.
    """

    terms: tuple[Term, ...]
    radius_mm: float
    cells_fn: Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor] | None = None

    def cells(self, pixel_mm: float, k: int) -> torch.Tensor:
        """Masses of the kernel over the ``(2k+1)²`` pixel cells around the origin.

        Returns:
            ``(3, 2k+1, 2k+1)`` float64, rows along y (top = +y), columns along x.
        """
        offs = torch.arange(-k, k + 1, dtype=torch.float64) * pixel_mm
        h = pixel_mm / 2.0
        if self.cells_fn is not None:
            dy, dx = torch.meshgrid(-offs, offs, indexing="ij")
            half = torch.full_like(dx, h)
            return self.cells_fn(dx, dy, half).permute(2, 0, 1)
        out = torch.zeros(3, 2 * k + 1, 2 * k + 1, dtype=torch.float64)
        for t in self.terms:
            ix = t.fx(offs - h, offs + h)  # (n, 3)
            iy = t.fy(-offs - h, -offs + h)
            out += iy.T[:, :, None] * ix.T[:, None, :]
        return out


# ------------------------------------------------------------------- continuous kernels
def _gaussians(sigmas: torch.Tensor, masses: torch.Tensor) -> Interval:
    """Interval masses of ``Σ_j m_j N(0, σ_j²)`` (``(J, 3)`` each; σ floored to a delta)."""
    s = sigmas.double().clamp_min(_DELTA_SIGMA)
    m = masses.double()
    return lambda a, b: gaussian_mixture_interval(a, b, s, m)


def _separable(f: Interval, radius_mm: float) -> ContinuousKernel:
    return ContinuousKernel((Term(f, f),), float(radius_mm))


def profile_kernel(profile: Profile) -> ContinuousKernel:
    """The true kernel ``R(r) / ‖R‖₁`` with the profile's own exact cell integral (the
    reference's per-cell weights, 000 eq. 1)."""
    total = profile.total()

    def cells(dx, dy, half):
        return profile.cell_integral(dx, dy, torch.zeros_like(dx), half, half) / total

    return ContinuousKernel((), profile.radius(1e-6), cells)


def _preintegrated_kernel(method) -> ContinuousKernel:
    # 000 eq. 5: A_p(x, y) = a_p(x) a_p(y) / ‖R‖₁ with ∫ a_p = ‖R‖₁ per axis
    p = method.profile
    total = p.total()
    return _separable(lambda a, b: p.preintegrated_interval(a, b) / total, p.radius(1e-6))


def _artist_kernel(method) -> ContinuousKernel:
    # 000 eq. 6, normalised to one: w N(σ_n) + (1 − w) N(σ_f) per axis
    params: ArtistParams = method.params
    sig, mass = params._sigmas_masses()
    return _separable(_gaussians(sig, mass), _GAUSS_SUPPORT * float(sig.max()))


def _jimenez2012_kernel(method) -> ContinuousKernel:
    """002 eq. 1 per axis: ``(1 − t) δ(x) + t p(x / (0.001 + f)) / ‖·‖``, ``p`` the red radial
    profile without its narrowest Gaussian, in mm: kernel units × 2/3 × width
    (:func:`~sssbench.kernels.jimenez2012`). ``p`` is restricted to the range the 2012 kernel
    builder places its taps in when they converge (±3 kernel units, more than 20 samples) and
    renormalised there, as the builder normalises its weights: that is the continuous kernel
    its taps converge to (the ±2 range of <= 20 samples then shows as taps error)."""
    t = _per_channel("strength", method.strength, 0.0, 1.0)
    f = _per_channel("falloff", method.falloff, 0.0, None)
    var, wr = _base_profile(method.base_profile)
    unit = _WIDTHS_PER_UNIT * method.width  # mm per kernel unit
    stretch = 0.001 + f  # 002 eq. 1
    sig = stretch[None, :] * torch.sqrt(var)[:, None] * unit  # (J, 3) mm
    # ∫ exp(−r²/2v)/(2πv) along a line = 1/√(2πv): the 1D mass of each radial Gaussian
    mass = wr[:, None] * stretch[None, :] / torch.sqrt(2 * math.pi * var)[:, None]
    p = _gaussians(sig, mass)
    lim = torch.tensor([_JIMENEZ2012_RANGE * unit], dtype=torch.float64)
    inside = p(-lim, lim)  # (1, 3)

    def f(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        delta = ((a < 0) & (b >= 0)).double()[:, None]  # (1 − t) δ(x)
        clipped = p(a.clamp(-lim, lim), b.clamp(-lim, lim)) / inside
        return t * clipped + (1.0 - t) * delta

    return _separable(f, float(lim))


def _sum_of_gaussians_kernel(method) -> ContinuousKernel:
    """003 §7.3.3: ``Σ_i w_i G_i / Σ_i w_i`` with 2D Gaussians (separable each), the first a
    delta when the method uses the unblurred image, widths times the stretch's ssslevel
    (on a fronto-parallel plane the derivative term of 003 §7.3.1 is 0)."""
    prof = method.profile
    order = torch.argsort(prof.variances)
    var = prof.variances[order].double()
    w = prof.weights[order].double()
    w = w / w.sum(0, keepdim=True)
    level = 1.0 if method.stretch is None else float(method.stretch.ssslevel)
    sig = torch.sqrt(var) * level
    if method.unblurred_first:
        sig = sig.clone()
        sig[0] = 0.0
    return _gaussian_sum(sig, w)


def _fused_sum_of_gaussians_kernel(method) -> ContinuousKernel:
    """003 §7.3 applied directly (000 §3 eq. 2): ``Σ_s c_s g_s(x) g_s(y)``, ``c_s = w_s / Σ w``,
    the profile's own Gaussians (no stretch, none unblurred): the profile itself, so its
    model part is 0 and the taps carry its error."""
    prof = method.profile
    order = torch.argsort(prof.variances)
    w = prof.weights[order].double()
    return _gaussian_sum(torch.sqrt(prof.variances[order].double()), w / w.sum(0, keepdim=True))


def _gaussian_sum(sig: torch.Tensor, w: torch.Tensor) -> ContinuousKernel:
    """``Σ_i w_i G_i`` with 2D Gaussians of σ ``sig (N,)`` (mm) and weights ``w (N, 3)``, one
    separable term each (``√w_i`` per axis)."""
    terms = []
    for i in range(sig.numel()):
        root = torch.sqrt(w[i : i + 1])  # (1, 3): √w_i on each axis
        f = _gaussians(sig[i : i + 1, None].expand(1, 3), root)
        terms.append(Term(f, f))
    return ContinuousKernel(tuple(terms), _GAUSS_SUPPORT * float(sig.max()))


def _piecewise(edges: np.ndarray, masses: torch.Tensor) -> Interval:
    """Interval masses of a density constant on each cell ``[edges[j], edges[j+1]]``."""
    cum = torch.cat([torch.zeros(1, 3, dtype=torch.float64), masses.cumsum(0)]).numpy()

    def f(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        def cdf(x):
            xs = x.numpy()
            return np.stack([np.interp(xs, edges, cum[:, c]) for c in range(3)], -1)

        return torch.from_numpy(cdf(b) - cdf(a))

    return f


def _low_rank_kernel(method, cell_mm: float | None = None) -> ContinuousKernel:
    """000 §3 eq. 2: the rank-N truncation of the SVD of the continuous kernel on the
    method's square ``[−extent, extent]²``, normalised to one before truncation (as the
    method). The continuum is approximated by a fine grid of cells of ``cell_mm`` (default a
    quarter of the method's cell), each SVD factor a density constant per fine cell."""
    extent = float(method.extent)
    fine = 2.0 * extent / method.n / 4.0 if cell_mm is None else cell_mm
    n = min(MAX_MATRIX_SIZE, int(math.ceil(2.0 * extent / fine)) | 1)
    m = kernel_matrix(method.profile, extent, n)
    m = m / m.sum((1, 2), keepdim=True)  # 000 §4: normalised to one
    u, s, vh = torch.linalg.svd(m)  # 000 §3
    edges = np.linspace(-extent, extent, n + 1)
    terms = []
    for i in range(method.rank):
        root = torch.sqrt(s[:, i])  # (3,)
        h = (vh[:, i, :] * root[:, None]).T  # (n, 3) along x
        v = (u[:, :, i] * root[:, None]).T.flip(0)  # (n, 3) along y: matrix rows run −y → +y
        terms.append(Term(_piecewise(edges, h), _piecewise(edges, v)))
    return ContinuousKernel(tuple(terms), extent * math.sqrt(2.0))


def method_kernel(method: nn.Module) -> ContinuousKernel:
    """The continuous 2D kernel a method approximates with its taps (see the module doc).

    Supported: :class:`~sssbench.ops.PreintegratedSSS` (``a_p(x) a_p(y)``, 000 eq. 5),
    :class:`~sssbench.ops.SumOfGaussiansSSS` (its Gaussians),
    :class:`~sssbench.ops.FusedSumOfGaussiansSSS` (the same, applied directly),
    :class:`~sssbench.ops.LowRankSSS`
    (rank-N SVD), :class:`~sssbench.ops.ArtistSSS` (000 eq. 6),
    :class:`~sssbench.ops.Jimenez2012SSS` (002 eq. 1), :class:`~sssbench.ops.IdentitySSS`
    (a delta), :class:`~sssbench.ops.ReferenceSSS` (its profile).
    """
    from sssbench import ops

    table = {
        ops.PreintegratedSSS: _preintegrated_kernel,
        ops.SumOfGaussiansSSS: _sum_of_gaussians_kernel,
        ops.FusedSumOfGaussiansSSS: _fused_sum_of_gaussians_kernel,
        ops.LowRankSSS: _low_rank_kernel,
        ops.ArtistSSS: _artist_kernel,
        ops.Jimenez2012SSS: _jimenez2012_kernel,
        ops.IdentitySSS: lambda m: _separable(_gaussians(torch.zeros(1, 3), torch.ones(1, 3)), 0.0),
        ops.ReferenceSSS: lambda m: profile_kernel(m.profile),
    }
    for cls, fn in table.items():
        if isinstance(method, cls):
            return fn(method)
    raise TypeError(
        f"method must be one of {[c.__name__ for c in table]}, got {type(method).__name__}"
    )


# ------------------------------------------------------------------- flat-plane convolution
def footprint_mm(gbuffer: GBuffer) -> float:
    """The scene's pixel footprint (mm): ``pixel_size_mm`` at the median depth of the masked
    pixels (the flat plane the model part is measured on). A choice: on a fronto-parallel
    plane every pixel has this size; on a curved scene the median is the typical one."""
    mask = gbuffer.mask_or_ones()
    z = gbuffer.depth[mask > 0] if bool((mask > 0).any()) else gbuffer.depth
    _, h, _ = gbuffer.shape
    return float(pixel_size_mm(z.double().median(), gbuffer.fov_y, h))


def flat_convolution(
    gbuffer: GBuffer, kernel: ContinuousKernel, pixel_mm: float, radius_mm: float | None = None
) -> torch.Tensor:
    """``gbuffer.diffuse`` scattered with ``kernel`` on a flat plane of ``pixel_mm`` pixels.

    The reference's convention (:func:`~sssbench.ops.reference.reference_sss`): only
    neighbours with ``mask > 0`` contribute and the result is divided by the weight gathered,
    borders clamp to the edge, the mask lerps (strength) and pixels with mask 0 are copied.
    A kernel whose cells do not sum to one (a truncated SVD) keeps its sum ``S``: the result
    is ``S · Σ s E w / Σ s w``. FFT per channel, float64.

    Args:
        gbuffer: B = 1; ``diffuse`` and ``mask`` are used (depth is not: the plane is flat).
        kernel: the 2D kernel.
        pixel_mm: pixel size (mm).
        radius_mm: support; default ``kernel.radius_mm``.

    Returns:
        ``(1, 3, H, W)`` float64.
    """
    b, h, w = gbuffer.shape
    if b != 1:
        raise ValueError(f"gbuffer must hold one image (B = 1), got B = {b}")
    pixel_mm = check_scalar("pixel_mm", pixel_mm, 0.0, low_inclusive=False)
    radius = kernel.radius_mm if radius_mm is None else radius_mm
    k = int(min(math.ceil(radius / pixel_mm) + 1, max(h, w)))
    ker = kernel.cells(pixel_mm, k)  # (3, n, n)
    e = gbuffer.diffuse.double()
    m = gbuffer.mask_or_ones().double()
    # memoised on the contents it reads (the kernel's cells, the light, the mask) and torch's
    # threads (the FFT's bits may depend on them): a method whose continuous kernel does not
    # depend on its tap count has the same model image at 7 and 13 taps (the benchmark's
    # samples sweep), bit for bit
    tag = ("flat_convolution", k, torch.get_num_threads())
    return by_content((ker, e, m), tag, lambda: _flat(ker, e, m, k))


def _flat(ker: torch.Tensor, e: torch.Tensor, m: torch.Tensor, k: int) -> torch.Tensor:
    """:func:`flat_convolution` of ``e`` ``(1, 3, H, W)`` with the cells ``ker``
    ``(3, 2k+1, 2k+1)`` over the mask ``m`` ``(1, 1, H, W)``, all float64.

    The FFT runs on the grid ``(P, Q)`` = :func:`_fast_shape` of ``(H+2k, W+2k)``: the next
    5-smooth sizes (912 = 2^4·3·19 costs about twice 960 = 2^6·3·5). The source (``e·s``
    and ``s``, ``s`` the mask's support) fills the whole grid, replicate-padded by
    ``p = (P-H) // 2 >= k`` rows above and ``P-H-p >= k`` below (columns alike), so it
    depends on the grid, not on ``k``. Why the kept outputs are the linear convolution,
    whatever the grid: the FFTs' product is the circular convolution over ``(P, Q)``, whose
    output ``n`` sums ``kf[t] src[(n - t) mod P]`` over the taps ``t = 0..2k`` (``kf`` the
    flipped cells); row ``i`` of the image is kept from ``n = i + p + k``, which reads
    ``n - t`` in ``[i + p - k, i + p + k]``, inside ``[0, P-1]`` for every ``i < H``: no
    wrap, and every row read is the image's row ``i + u - k`` clamped to the edge
    (``u = 2k - t``). The grid changes only the rounding (the FFT sums in another order):
    against the previous ``(H+2k, W+2k)`` grid on the paper benchmark's 512² scenes, every
    scene, scale and kernel, ``max |Δ| / max |out|`` <= 3.4e-15 and the largest per-pixel
    relative difference 5.8e-14 (``docs/numerics.md``); ``tests/score/test_flat_fft.py``
    compares it with a direct convolution to 1e-13.

    The source's spectrum (its 6 channels: more than half of the FFTs' work) is memoised on
    ``e``, ``m`` and the grid (:func:`sssbench._memo.by_content`): the runs of a scene share
    it whenever their kernels' radii fall on the same grid (the truth's kernel and most
    methods' do)."""
    _, _, h, w = e.shape
    total = ker.sum((1, 2))
    shape = _fast_shape(h + 2 * k, w + 2 * k)
    top, left = (shape[0] - h) // 2, (shape[1] - w) // 2

    def source_spectrum() -> torch.Tensor:
        s = (m > 0).double()
        src = torch.cat([e * s, s.expand(-1, 3, -1, -1)], 1)
        pads = (left, shape[1] - w - left, top, shape[0] - h - top)
        src = torch.nn.functional.pad(src, pads, mode="replicate")[0]  # (6, P, Q)
        return torch.fft.rfft2(src)

    tag = ("flat_source_spectrum", shape, torch.get_num_threads())
    src_spec = by_content((e, m), tag, source_spectrum)
    # the 2D transforms as their two 1D stages, each over what it needs (the same transforms,
    # summed in another order: equal to rounding): the kernel's rows along the rows first,
    # only its 2k+1 rows that are not zero padding, then along the columns; the inverse
    # along the columns, then along the rows only for the h rows kept (measured on 512² at
    # k = 30, 150, 512: 0.66–0.68× the time of rfft2 / irfft2 over the whole grid, issue 30)
    kf = torch.fft.rfft(ker.flip(-2, -1), n=shape[1], dim=-1)  # (3, 2k+1, Q/2+1)
    spec = torch.fft.fft(kf, n=shape[0], dim=-2)  # (3, P, Q/2+1)
    prod = src_spec.view(2, *spec.shape) * spec  # numerator and denominator sources
    # output (i, j) of the image sits at (i + top + k, j + left + k)
    rows, cols = slice(top + k, top + k + h), slice(left + k, left + k + w)
    res = torch.fft.irfft(torch.fft.ifft(prod, dim=-2)[..., rows, :], n=shape[1], dim=-1)
    num, den = res[0, :, :, cols], res[1, :, :, cols]
    scattered = total.view(3, 1, 1) * num / den.clamp_min(torch.finfo(torch.float64).tiny)
    out = e + m * (scattered[None] - e)
    return torch.where(m > 0, out, e)


def _fast_shape(hp: int, wp: int) -> tuple[int, int]:
    """The FFT grid of :func:`_flat` for a padded source ``(hp, wp)``: each side the smallest
    5-smooth size (2^a 3^b 5^c) at least as large (``scipy.fft.next_fast_len``, real)."""
    from scipy.fft import next_fast_len

    return next_fast_len(hp, real=True), next_fast_len(wp, real=True)


# ------------------------------------------------------------------- taps
def converged(
    build: Callable[[int], nn.Module],
    samples: int,
    gbuffer: GBuffer,
    *,
    tol: float = CONVERGED_TOL,
    max_samples: int = MAX_SAMPLES,
    scale: float | None = None,
) -> tuple[torch.Tensor, int, float]:
    """The method converged in taps: ``N_j = 2^j (N − 1) + 1`` taps (odd, nested centres)
    for ``j = 1, 2, …`` until two successive outputs differ by less than ``tol`` (rel RMS over
    the mask, denominator ``scale`` or the output's RMS) or ``N_j`` would exceed
    ``max_samples``.

    The methods converge slowly in taps (importance-sampled pre-integrated taps roughly as
    ``1/N``: 0.00037 rel RMS between 385 and 769 taps on ``light_dot``), so the cap can stop
    the doubling first; the last change is returned as an estimate of what is left.

    Returns:
        (the last output ``(B, 3, H, W)`` float64, its tap count, the rel RMS change of the
        last doubling — below ``tol`` when converged, ``NaN`` if no doubling fitted).
    """
    samples = check_int("samples", samples, 1)
    mask = gbuffer.mask_or_ones().double()
    with torch.no_grad():
        prev = build(samples)(gbuffer).double()
        denom = scale if scale is not None else _rms(prev, mask)
        n, change = samples, math.nan
        while True:
            nxt = 2 * (n - 1) + 1 if n > 1 else 3
            if nxt > max_samples:
                return prev, n, change
            out = build(nxt)(gbuffer).double()
            change = _rms(out - prev, mask) / denom
            prev, n = out, nxt
            if change < tol:
                return prev, n, change


def _rms(x: torch.Tensor, mask: torch.Tensor) -> float:
    """RMS over pixels and channels, the mask as weights (as
    :func:`sssbench.score.metrics.rmse`)."""
    wsum = float(mask.sum()) * x.shape[1]
    return math.sqrt(float((x * x * mask).sum()) / wsum)


def _dot(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor) -> float:
    return float((a * b * mask).sum()) / (float(mask.sum()) * a.shape[1])


# ------------------------------------------------------------------- the budget
@dataclass(frozen=True)
class Budget:
    """The error budget of one method on one G-buffer (all rel RMS over the mask, relative
    to the box reference's RMS).

    Attributes:
        total: rel RMS of ``M_N − R``.
        taps, model, recon, screen: rel RMS of each part (see the module doc); ``recon`` is
            NaN when the reference has no ``reconstruction`` keyword (then it is in screen).
        contributions: ``{part: ⟨part, M_N − R⟩ / (‖R‖ ‖M_N − R‖)}``; sums to ``total``.
        quadrature: ``√(taps² + model² + recon² + screen²)`` (NaN parts left out).
        samples, converged_samples: the tap counts of ``M_N`` and ``M_∞``.
        taps_residual: rel RMS change of the last tap doubling (below ``CONVERGED_TOL`` when
            ``M_∞`` converged; otherwise about the taps error left in ``screen``).
        pixel_mm: the footprint of the flat plane.
    """

    total: float
    taps: float
    model: float
    recon: float
    screen: float
    contributions: dict[str, float]
    quadrature: float
    samples: int
    converged_samples: int
    taps_residual: float
    pixel_mm: float

    def as_dict(self) -> dict[str, float]:
        d = {
            "err_total": self.total,
            "err_taps": self.taps,
            "err_model": self.model,
            "err_recon": self.recon,
            "err_screen": self.screen,
            "quadrature": self.quadrature,
            "samples": self.samples,
            "converged_samples": self.converged_samples,
            "taps_residual": self.taps_residual,
            "pixel_mm": self.pixel_mm,
        }
        d.update({f"contribution_{k}": v for k, v in self.contributions.items()})
        return d


def reference_with(profile: Profile, reconstruction: str) -> nn.Module | None:
    """``ReferenceSSS(profile, reconstruction=...)``, or ``None`` when the keyword does not
    exist (before the bilinear convention is available)."""
    from sssbench.ops import ReferenceSSS

    if "reconstruction" not in inspect.signature(ReferenceSSS.__init__).parameters:
        return None
    return ReferenceSSS(profile, reconstruction=reconstruction)


def budget_truth(gbuffer: GBuffer, profile: Profile) -> torch.Tensor:
    """The model part's truth: ``gbuffer.diffuse`` scattered by the true kernel
    (:func:`profile_kernel`) on the flat plane of the scene's footprint (:func:`footprint_mm`),
    ``(1, 3, H, W)`` float64. The same for every method on the scene."""
    g = gbuffer.to(torch.float64)
    with torch.no_grad():
        return flat_convolution(g, profile_kernel(profile), footprint_mm(g))


def error_budget(
    build: Callable[[int], nn.Module],
    samples: int,
    gbuffer: GBuffer,
    profile: Profile,
    *,
    reference: torch.Tensor | None = None,
    reference_bilinear: torch.Tensor | None = None,
    tol: float = CONVERGED_TOL,
    limit: tuple[torch.Tensor, int, float] | None = None,
    recon: bool = True,
    truth: torch.Tensor | None = None,
) -> Budget:
    """Split a method's error on ``gbuffer`` into taps, model, reconstruction and screen.

    Args:
        build: ``build(n)`` returns the method configured with ``n`` taps per pass (for
            :class:`~sssbench.ops.LowRankSSS`, ``n`` cells); every other option fixed.
        samples: the tap count ``N`` under study.
        gbuffer: B = 1.
        profile: the true profile (the reference's).
        reference: ``ReferenceSSS(profile)(gbuffer)`` (box), computed if ``None``.
        reference_bilinear: the same with ``reconstruction="bilinear"``, computed if
            ``None`` and available.
        tol: convergence tolerance of :func:`converged`.
        limit: the method converged in taps, as :func:`converged` returns it, when the caller
            has it already (the runner caches it: it does not depend on ``samples``).
        recon: split off the reconstruction convention; ``False`` leaves ``recon`` NaN (its
            image stays in screen) without computing the bilinear reference.
        truth: the true kernel on the flat plane, :func:`budget_truth` of ``gbuffer`` and
            ``profile``, when the caller has it (it does not depend on the method: the runner
            computes it once per scene), computed if ``None``.

    Returns:
        A :class:`Budget`.
    """
    from sssbench.ops import ReferenceSSS

    if gbuffer.shape[0] != 1:
        raise ValueError(f"gbuffer must hold one image (B = 1), got B = {gbuffer.shape[0]}")
    g = gbuffer.to(torch.float64)
    mask = g.mask_or_ones()
    with torch.no_grad():
        ref = (ReferenceSSS(profile)(g) if reference is None else reference).double()
        denom = _rms(ref, mask)
        if not denom > 0:
            raise ValueError("reference must be non-zero on the mask, got RMS = 0")
        method = build(samples)
        m_n = method(g).double()
        if limit is None:
            limit = converged(build, samples, g, tol=tol, scale=denom)
        m_inf, n_inf, residual = limit
        m_inf = m_inf.double()
        p = footprint_mm(g)
        if truth is None:
            truth = budget_truth(g, profile)
        model = flat_convolution(g, method_kernel(method), p)
        if reference_bilinear is None and recon:
            op = reference_with(profile, "bilinear")
            reference_bilinear = None if op is None else op(g)
    parts = {"taps": m_n - m_inf, "model": model - truth}
    if reference_bilinear is not None:
        r_bil = reference_bilinear.double()
        parts["recon"] = r_bil - ref
        parts["screen"] = (m_inf - r_bil) - parts["model"]
    else:
        parts["screen"] = (m_inf - ref) - parts["model"]
    err = m_n - ref
    total = _rms(err, mask) / denom
    norms = {k: _rms(v, mask) / denom for k, v in parts.items()}
    err_norm = _rms(err, mask)
    contrib = {
        k: (_dot(v, err, mask) / (denom * err_norm) if err_norm > 0 else 0.0)
        for k, v in parts.items()
    }
    return Budget(
        total=total,
        taps=norms["taps"],
        model=norms["model"],
        recon=norms.get("recon", math.nan),
        screen=norms["screen"],
        contributions=contrib,
        quadrature=math.sqrt(sum(v * v for v in norms.values())),
        samples=samples,
        converged_samples=n_inf,
        taps_residual=residual,
        pixel_mm=p,
    )
