"""Multipole evaluation of the exact reference for Gaussians wider than a pixel.

One module because the multipole expansion, its Taylor coefficients and its error bound are
one derivation; each part cites the others' equations.

The reference sums, for every target pixel ``i`` and every Gaussian ``g`` of a sum of
Gaussians (001 eq. 6–7), ``F_g(p_i) = ∫ q(p) G(v_g, |p − p_i|) dA`` over the visible surface,
``q`` the reconstructed irradiance (per channel) or the stencil. This module evaluates it from
the *moments* of ``q dA`` instead of cell by cell:

- Level 0: every surface cell (the planar patch of :func:`reference_sss`) is summarised by its
  mass ``M = ∫ q dA``, dipole ``D = ∫ q (p − c) dA`` and quadrupole ``Q = ∫ q (p − c)(p − c)ᵀ
  dA`` about its centre ``c``, in closed form for the box and the bilinear reconstruction.
- Level ℓ: 2×2 blocks of level ℓ−1 merged exactly (moments shifted to the area-weighted
  centroid of the block); each block carries the radius of a ball holding all its patches.
- Gaussian ``g`` is evaluated from the coarsest blocks whose ball radius is at most
  ``σ_g / ratio`` (a block is split into its children otherwise: a block across a depth
  step is never used), by the second-order Taylor expansion of the Gaussian about the block
  centre: ``M G + ∇G·D + ½ H:Q`` with ``∇G = −Δ G / v`` and ``H = (Δ Δᵀ / v² − I / v) G``,
  ``Δ = P − p_i``. The first neglected term is third order in ``radius / σ``; for a smooth
  ``q`` the sum is moreover a midpoint rule of a smooth integrand, whose error decays like
  ``exp(−2π² σ² / b²)`` (Poisson summation), so the error sits at discontinuities of ``q``
  (measured in the tests against a brute-force surface integral).
- Cells too large to expand for a Gaussian (steep or wide against σ) are split into
  sub-patches of radius ≤ ``σ / ratio`` whose moments are exact (:func:`cell_patches`), so
  they are expanded like the blocks. (Gauss–Legendre points on those cells, 12× as many
  sources on the 1080p face close-up with skin_deon6, took 44% of the time on a 960×540
  crop of it; measured. The error against the brute-force surface integral did not change
  in the tests: 4.8e-6 on the steep close-up, 1.5e-5 / 1.7e-5 on the curved surface.)
- Per Gaussian, the blocks of its cut and the sub-patches are listed once as sources, bucketed by
  squares of pixels (:func:`_sources`); per tile of targets (about a quarter of the Gaussian's reach
  wide, at least 16 pixels) the sources of the buckets under its window are dense: the exponents of
  all (target, source) pairs are one matrix product, the Taylor terms a second one (the polynomial
  in the target position is expanded about a tile origin, so both products are small matrices).
  Selecting the blocks per tile and Gaussian from the pyramid's levels instead was ~20× slower than
  the arithmetic on a 480×270 face close-up (skin_deon6, 0.07 mm per pixel; measured).

All lengths are divided by a unit ``L`` (a pixel footprint) first, so the weights
``area · G`` are dimensionless and the same at every scale of the scene.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from typing import Any, TypeVar

import numpy as np
import torch
from threadpoolctl import threadpool_limits

from sssbench._digest import numpy_exp_vectorised
from sssbench.profiles.base import _gauss_legendre

__all__ = [
    "Pyramid",
    "blas_product",
    "cell_moments",
    "exp_in_place",
    "far_field",
    "map_threads",
    "surface_pyramid",
]

_T = TypeVar("_T")
_R = TypeVar("_R")

#: per-channel moment layout: M, D (x, y, z), Q (xx, yy, zz, xy, xz, yz)
_NMOM = 10
#: quadrupole components (k, l) in the order of the layout
_QPAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
#: quadrature nodes per batch of :func:`cell_patches` in :func:`_sources` (bounds its memory)
_PATCH_NODES = 1 << 18


def _tangent_products(sx: torch.Tensor, sy: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """``t_x t_xᵀ``, ``t_y t_yᵀ`` and ``t_x t_yᵀ + t_y t_xᵀ`` of the patch tangents
    ``t_x = (1, 0, s_x)``, ``t_y = (0, 1, s_y)`` in the Q layout, each ``(6, ...)``."""
    one, zero = torch.ones_like(sx), torch.zeros_like(sx)
    txx = torch.stack([one, zero, sx * sx, zero, sx, zero])
    tyy = torch.stack([zero, one, sy * sy, zero, zero, sy])
    txy = torch.stack([zero, zero, 2 * sx * sy, one, sy, sx])
    return txx, tyy, txy


def _hat_moments(h: torch.Tensor, a: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``∫_{−h}^{h} w_a(s) s^k ds`` for k = 0, 1, 2: the weight of the neighbour at offset
    ``a ∈ {−1, 0, 1}`` (in pixels) of the bilinear interpolation across one cell of half-size
    ``h``: ``w_0 = 1 − |s|/2h``, ``w_{±1} = max(0, ±s/2h)``."""
    if a == 0:
        return 1.5 * h, torch.zeros_like(h), (5.0 / 12.0) * h**3
    return 0.25 * h, (a / 6.0) * h * h, 0.125 * h**3


def cell_moments(
    half: torch.Tensor,
    sx: torch.Tensor,
    sy: torch.Tensor,
    q_at: Callable[[int, int], torch.Tensor],
    reconstruction: str,
) -> torch.Tensor:
    """Moments of ``q dA`` over cell patches about their centres, ``(C, 10, *half.shape)``.

    Args:
        half: half-size of each cell's lateral square (0 off the surface), any shape ``S``.
        sx, sy: depth slopes of the patches, shape ``S``.
        q_at: ``q_at(a, b)`` the values ``(C, *S)`` at the centres of the cells' neighbours at
            column offset ``a`` and row offset ``−b`` (zero off the surface): ``"box"`` reads
            only ``q_at(0, 0)`` (``q`` constant over the cell), ``"bilinear"`` the 3×3
            neighbourhood (``q`` interpolated between the centres).
        reconstruction: ``"box"`` or ``"bilinear"``.

    The patch is ``c + s t_x + t t_y`` with ``|s|, |t| ≤ h``, area element
    ``A = √(1 + s_x² + s_y²)``, so ``∫ f dA = A ∫∫ f ds dt`` and every moment is a product of
    one-dimensional integrals (:func:`_hat_moments` for the bilinear weights).
    """
    area_el = torch.sqrt(1 + sx * sx + sy * sy)
    q0 = q_at(0, 0)
    out = q0.new_zeros(q0.shape[0], _NMOM, *half.shape)
    if reconstruction == "box":
        # Q = M h²/3 (t_x t_xᵀ + t_y t_yᵀ): xx, yy, zz, xy, xz, yz = 1, 1, s_x² + s_y², 0, s_x, s_y
        mass = torch.mul(q0, 4 * half * half * area_el, out=out[:, 0])
        hq = half * half / 3.0
        for j, f in ((0, hq), (1, hq), (2, hq * (sx * sx + sy * sy)), (4, hq * sx), (5, hq * sy)):
            torch.mul(mass, f, out=out[:, 4 + j])
        return out
    txx, tyy, txy = _tangent_products(sx, sy)
    # s runs along +x (columns), t along +y (rows upward): the t-neighbour b is row −b
    for a in (-1, 0, 1):
        i0a, i1a, i2a = _hat_moments(half, a)
        for b in (-1, 0, 1):
            i0b, i1b, i2b = _hat_moments(half, b)
            qn = q_at(a, b) * area_el
            out[:, 0] += qn * (i0a * i0b)
            out[:, 1] += qn * (i1a * i0b)  # D = A ∫∫ q (s t_x + t t_y)
            out[:, 2] += qn * (i0a * i1b)
            out[:, 3] += qn * (i1a * i0b * sx + i0a * i1b * sy)
            quad = i2a * i0b * txx + i0a * i2b * tyy + i1a * i1b * txy
            out[:, 4:] += qn[:, None] * quad[None]
    return out


def cell_radius(half: torch.Tensor, sx: torch.Tensor, sy: torch.Tensor) -> torch.Tensor:
    """Distance from a patch's centre to its farthest corner, ``h √(2 + (|s_x| + |s_y|)²)``."""
    return half * torch.sqrt(2 + (sx.abs() + sy.abs()) ** 2)


def cells_at(
    f: torch.Tensor, q: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor, reconstruction: str
) -> torch.Tensor:
    """:func:`cell_moments` of the cells at interior ``rows``, ``cols`` ``(N,)`` of the surface
    ``f`` ``(6, h, w)`` (x, y, z, half, slope_x, slope_y), ``q`` ``(C, h, w)`` with a
    one-pixel border: ``(N, C, 10)``."""
    r, c = rows + 1, cols + 1
    half, sx, sy = f[3:6, r, c]
    mom = cell_moments(half, sx, sy, lambda a, b: q[:, r - b, c + a], reconstruction)
    return mom.permute(2, 0, 1)


@dataclass
class Pyramid:
    """Block moments per level: ``pos[l]`` ``(3, H_l, W_l)`` expansion centres, ``mom[l]``
    ``(C, 10, H_l, W_l)`` moments about them for ``l ≥ 1``, ``area[l]`` ``(H_l, W_l)`` the
    stencil's area (the last channel's mass), ``rad[l]`` ``(H_l, W_l)`` bounding radii (0 for
    an empty block); level ``l`` blocks are ``2^l`` pixels wide. The cells' own moments
    (level 0, the largest array) are not kept: :meth:`moments` computes those asked for from
    the surface ``fields``, ``q`` (with a one-pixel border, as :func:`cells_at` takes it)."""

    pos: list[torch.Tensor]
    mom: list[torch.Tensor | None]
    area: list[torch.Tensor]
    rad: list[torch.Tensor]
    fields: torch.Tensor
    q: torch.Tensor
    reconstruction: str

    def moments(self, lev: int, flat: torch.Tensor) -> torch.Tensor:
        """Moments ``(N, C, 10)`` of the level-``lev`` blocks at flat indices ``flat``."""
        mom = self.mom[lev]
        if mom is None:
            w = self.area[0].shape[1]
            return cells_at(self.fields, self.q, flat // w, flat % w, self.reconstruction)
        return mom.flatten(2)[:, :, flat].permute(2, 0, 1)


def _merge(pos: torch.Tensor, mom: torch.Tensor, rad: torch.Tensor):
    """One level up: 2×2 children -> parent, moments shifted to the area centroid (the last
    channel of ``mom`` is the stencil's area) (parallel-axis theorem)."""
    c, _, h, w = mom.shape
    ch = mom.view(c, _NMOM, h // 2, 2, w // 2, 2)
    p = pos.view(3, h // 2, 2, w // 2, 2)
    r = rad.view(h // 2, 2, w // 2, 2)
    area = ch[-1, 0]
    mass = area.sum((1, 3))
    mean = p.mean((2, 4))  # centre of an empty block: the mean of the children
    cen = torch.where(
        mass > 0, (p * area).sum((2, 4)) / torch.where(mass > 0, mass, 1.0), mean
    )  # (3, h/2, w/2)
    delta = p - cen[:, :, None, :, None]  # (3, h/2, 2, w/2, 2)
    m = ch[:, 0]
    d = ch[:, 1:4]
    out = torch.empty(c, _NMOM, h // 2, w // 2, dtype=mom.dtype)
    out[:, 0] = m.sum((2, 4))
    out[:, 1:4] = (d + m[:, None] * delta[None]).sum((3, 5))
    for j, (k, l) in enumerate(_QPAIRS):
        t = ch[:, 4 + j] + d[:, k] * delta[l] + d[:, l] * delta[k] + m * delta[k] * delta[l]
        out[:, 4 + j] = t.sum((2, 4))
    dist = torch.sqrt((delta * delta).sum(0)) + r
    radius = torch.where(r > 0, dist, 0.0).amax((1, 3))
    return cen, out, radius


#: the 3×3 quadrupole from its 6 components (row-major)
_Q33 = [0, 3, 4, 3, 1, 5, 4, 5, 2]


def _sum3(t: torch.Tensor) -> torch.Tensor:
    """``t[..., 0] + t[..., 1] + t[..., 2]`` (left to right): what ``t.sum(-1)`` of a last
    axis of 3 computes, bit for bit (torch's reduction adds the three in order from the
    first; tests/ops/test_reference_far.py checks the two agree on every bit), without a
    reduction kernel's overhead on so short an axis (~10× the time at (1000, 4, 3), measured).
    One exception: three signed zeros summing to ``-0.0`` stay ``-0.0`` here, where the
    reduction, which starts from ``+0.0``, gives ``+0.0`` (the same value)."""
    return t[..., 0] + t[..., 1] + t[..., 2]


def _coefficients(p: torch.Tensor, mom: torch.Tensor, v: float) -> torch.Tensor:
    """Columns of the Taylor expansion for sources at ``p`` ``(S, 3)`` (relative to the tile
    origin) with moments ``mom`` ``(S, C, 10)``: ``(S, C · 10)`` such that the expansion at a
    target ``x`` is ``Σ_S G · [α + x·β + Σ_kl x_k x_l γ_kl]`` (see module docstring):
    ``β = D/v − QP/v²``, ``α = M − P·(D/v − QP/2v²) − tr Q / 2v`` (``= M − P·D/v + PᵀQP/2v²
    − tr Q/2v``), ``γ = Q / 2v²`` with the off-diagonal components twice (``x_k x_l`` appears
    once per pair).

    Every sum over the three axes is :func:`_sum3` (the same additions, in the same order, as
    ``sum(-1)``: the result is bitwise that of the reduction form, tested; 2.7× less CPU time
    than the reduction form at 1000 sources × 4 channels, the tiles' typical size on the 512²
    scenes, measured)."""
    s, c = mom.shape[:2]
    qv = mom[..., 4:]
    pl = [p[:, None, axis] for axis in range(3)]  # (S, 1) each
    # (QP)_k = Σ_l Q_kl P_l with Q_kl = qv[_Q33[3k + l]], added left to right (as _sum3)
    qp = mom.new_empty(s, c, 3)
    for k in range(3):
        a, b, d = (qv[..., _Q33[3 * k + axis]] * pl[axis] for axis in range(3))
        torch.add(a + b, d, out=qp[..., k])
    out = mom.new_empty(s, c, _NMOM)
    dv = mom[..., 1:4] / v
    qpv = qp / (v * v)
    torch.sub(dv, qpv, out=out[..., 1:4])
    half_step = torch.sub(dv, qpv, alpha=0.5)
    alpha = mom[..., 0] - _sum3(half_step * p[:, None])
    torch.sub(alpha, _sum3(qv[..., :3]), alpha=0.5 / v, out=out[..., 0])
    scale = torch.tensor([1.0, 1.0, 1.0, 2.0, 2.0, 2.0], dtype=mom.dtype) / (2 * v * v)
    torch.mul(qv, scale, out=out[..., 4:])
    return out.view(s, -1)


def _monomials(x: torch.Tensor) -> torch.Tensor:
    """``(T, 10)``: 1, x, y, z, x², y², z², xy, xz, yz."""
    one = torch.ones_like(x[:, :1])
    quad = torch.stack([x[:, k] * x[:, l] for k, l in _QPAIRS], 1)
    return torch.cat([one, x, quad], 1)


def exp_in_place(t: torch.Tensor) -> torch.Tensor:
    """``exp`` of every element of ``t``, written over it; returns ``t``.

    A contiguous float64 CPU tensor outside autograd (the reference's) goes, on a CPU where
    NumPy's float64 ``exp`` is vectorised (AVX-512:
    :func:`~sssbench._digest.numpy_exp_vectorised`), through NumPy's loop on the same memory (no
    copy); anything else through ``torch.exp_`` (NumPy's float32 ``exp`` is up to 2 ulp off: not
    used). Which one is a property of the machine (:func:`~sssbench._digest.far_exp`), fixed for
    the process, never of the timing. Why: the far field's ``(targets, sources)`` matrices are
    its largest elementwise work. On the 2-core AMD EPYC with AVX-512, NumPy's float64 ``exp``
    takes 0.77 ns per element against 1.85 ns for ``torch.exp_`` (one thread, 380 000 elements
    in [−40, 0]); on a 2-core AMD EPYC with AVX2 only (2026-12-04), where NumPy's loop is the C
    library's scalar ``exp``, 8.3 ns against torch's 3.5 ns: there ``torch.exp_``. Their error:
    at most 1 ulp from the correctly rounded result on 20 000 points of [−40, 0] (NumPy's mean
    0.045 ulp; torch's at most 1, mean 0.006), checked for both by
    tests/ops/test_reference_far.py against ``math.exp``. Elementwise and single-threaded (the
    reference's workers hold torch to one thread): the result does not depend on how the work is
    split into tiles or threads. Both release the GIL in the loop, so the reference's Python
    threads (:func:`map_threads`) still run side by side."""
    if (
        t.device.type == "cpu"
        and t.dtype == torch.float64
        and t.is_contiguous()
        and not t.requires_grad
        and numpy_exp_vectorised()
    ):
        a = t.numpy()
        np.exp(a, out=a)
        return t
    return torch.exp_(t)


#: how many :func:`map_threads` calls hold NumPy's BLAS to one thread at present, and the
#: limit they share (process-wide: the first one takes it, the last one restores the BLAS as
#: it was): :func:`blas_product` takes NumPy's product only while one does
_BLAS_HOLD: dict[str, Any] = {"count": 0, "limit": None}
_BLAS_HOLD_LOCK = threading.Lock()


def _hold_blas() -> None:
    """One more holder of NumPy's BLAS at one thread (see :data:`_BLAS_HOLD`)."""
    with _BLAS_HOLD_LOCK:
        if _BLAS_HOLD["count"] == 0:
            _BLAS_HOLD["limit"] = threadpool_limits(limits=1, user_api="blas")
        _BLAS_HOLD["count"] += 1


def _release_blas() -> None:
    """One holder fewer; the last one restores the BLAS's thread count."""
    with _BLAS_HOLD_LOCK:
        _BLAS_HOLD["count"] -= 1
        if _BLAS_HOLD["count"] == 0:
            _BLAS_HOLD["limit"].restore_original_limits()
            _BLAS_HOLD["limit"] = None


def blas_product(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a @ b`` for 2D tensors: while :func:`map_threads` holds NumPy's BLAS to one thread,
    float64 CPU tensors outside autograd through NumPy's BLAS (OpenBLAS in NumPy's wheels) on
    the same memory; anything else, or anywhere else, through ``torch``.

    Why (issue 30, "whole sweeps"): the far field's two products, ``(T, 5) · (5, S)`` (the
    exponents) and ``(T, S) · (S, 40)`` (the Taylor terms), were 14 % of a cold 512² paper
    benchmark's warm-up (py-spy, all processes); on this 2-core AMD EPYC (AVX-512) torch's
    MKL runs them at 24–28 GFLOP/s and OpenBLAS's SkylakeX kernels at 38–54 (one thread,
    the far field's shapes (256 × 584 … 1492) · (… × 40): 1.35–2.05× the speed; the
    exponents' product 1.2–1.4×). Another BLAS sums a dot product in another order: equal to
    rounding (tested against exactly summed dot products). Only at one thread: OpenBLAS's
    result at two threads differs in the last bits (tested), and the reference's must not
    depend on how many threads it had — the far field's products all run inside
    :func:`map_threads`' items."""
    if (
        _BLAS_HOLD["count"] > 0
        and a.device.type == "cpu"
        and b.device.type == "cpu"
        and a.dtype == torch.float64
        and b.dtype == torch.float64
        and not (a.requires_grad or b.requires_grad)
        and a.ndim == 2
        and b.ndim == 2
    ):
        return torch.from_numpy(np.matmul(a.numpy(), b.numpy()))
    return a @ b


def _gaussian_matrix(
    targets: torch.Tensor, sources: torch.Tensor, v: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Targets and sources relative to the targets' mean, and ``exp(−|p − x|²/2v)`` ``(T, S)``.

    The exponent is one product ``[x, 1, |x|²] · [p/v, −|p|²/2v, −1/2v]ᵀ`` (both relative to
    the origin, so the cancellation is of the window's size, not of the view distance; its
    rounding may leave an exponent of a few ulps above 0, harmless to ``exp``); the exp by
    :func:`exp_in_place` (measured on the 512² face at 0.3 mm/px, bilinear, one thread: the
    whole reference 9 % less CPU than with ``torch.exp_``, max |Δ| / max |out| = 2.9e-15).
    """
    origin = targets.mean(0)
    x = targets - origin
    p = sources - origin
    lhs = torch.cat([x, torch.ones_like(x[:, :1]), (x * x).sum(1, keepdim=True)], 1)
    rhs = torch.cat(
        [p / v, (-(p * p).sum(1) / (2 * v))[:, None], torch.full_like(p[:, :1], -0.5 / v)], 1
    )
    return x, p, exp_in_place(blas_product(lhs, rhs.t()))


def far_field(
    targets: torch.Tensor,
    sources: torch.Tensor,
    mom: torch.Tensor,
    v: float,
) -> torch.Tensor:
    """``Σ_S ∫ q G(v, |p − x|) dA`` by the second-order expansion, ``(T, C)``.

    Args:
        targets: ``(T, 3)`` target positions.
        sources: ``(S, 3)`` expansion centres.
        mom: ``(S, C, 10)`` moments about them.
        v: variance of the Gaussian (same length unit).
    """
    if sources.shape[0] == 0:
        return targets.new_zeros(targets.shape[0], mom.shape[1])
    x, p, g = _gaussian_matrix(targets, sources, v)
    cols = _coefficients(p, mom, v)  # (S, C·10)
    res = blas_product(g, cols).view(x.shape[0], mom.shape[1], _NMOM)
    return (res * _monomials(x)[:, None]).sum(-1) / (2 * math.pi * v)


@dataclass(frozen=True)
class Surface:
    """The padded surface of one image, in the scaled length unit.

    ``fields`` ``(6 + C, Hp + 2, Wp + 2)``: x, y, z, half, slope_x, slope_y (cell centre,
    half-size — 0 off the surface — and depth slopes), then ``q`` (irradiance channels times
    stencil, then the stencil), with a one-pixel replicated border (the neighbours of the
    bilinear reconstruction; :func:`with_border`); ``pad`` the padding in pixels, ``foot``
    the footprint of a pixel per unit depth (``2 tan(fov_y/2) / H``) and ``u_max`` the
    largest ``|x| / z`` of a target.
    """

    fields: torch.Tensor
    pad: int
    foot: float
    u_max: float

    @property
    def inner(self) -> torch.Tensor:
        """``(6 + C, Hp, Wp)``: the fields without the border (a view)."""
        return self.fields[:, 1:-1, 1:-1]


def with_border(parts: list[torch.Tensor]) -> torch.Tensor:
    """The ``(H, W)`` maps ``parts`` stacked ``(N, H + 2, W + 2)`` with a one-pixel border
    replicating the edge (``pad(..., mode="replicate")`` without a second copy)."""
    h, w = parts[0].shape
    out = parts[0].new_empty(len(parts), h + 2, w + 2)
    for i, t in enumerate(parts):
        out[i, 1:-1, 1:-1] = t
    out[:, 0, 1:-1] = out[:, 1, 1:-1]
    out[:, -1, 1:-1] = out[:, -2, 1:-1]
    out[:, :, 0] = out[:, :, 1]
    out[:, :, -1] = out[:, :, -2]
    return out


def map_threads(fn: Callable[[_T], _R], items: Iterable[_T], workers: int) -> Iterator[_R]:
    """``fn`` over ``items`` on ``workers`` Python threads, the results in the items' order.

    The work items of the reference (tiles of targets, chunks of centres) are many small
    tensor operations: torch's intra-op threads barely speed them up (measured: 2 threads
    doubled the CPU time for the same wall time), while independent items on separate
    Python threads do (torch releases the GIL inside its kernels). While the map runs, torch
    uses one intra-op thread (restored after), so every item is computed by the same
    sequence of single-threaded kernels whatever ``workers`` is: the result does not depend
    on the number of threads. ``fn`` must write only its own outputs (no shared
    accumulator). Autograd's modes are thread-local: the workers run ``fn`` under the
    caller's inference mode and grad mode (tensors made under ``torch.inference_mode()`` can
    only be written to under it). NumPy's BLAS (:func:`blas_product`) is held to one thread
    alike (``threadpoolctl``), restored after."""
    inference, grad = torch.is_inference_mode_enabled(), torch.is_grad_enabled()

    def in_callers_mode(item: _T) -> _R:
        with torch.inference_mode(inference), torch.set_grad_enabled(grad):
            return fn(item)

    # NumPy's BLAS (blas_product) at one thread too: the parallelism is the items'. Taken
    # first: threadpoolctl restores every thread pool it saw (torch's OpenMP's too) as it was
    _hold_blas()
    prev = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        if workers <= 1:
            yield from map(fn, items)
        else:
            pool = ThreadPoolExecutor(workers, thread_name_prefix="reference")
            try:
                yield from pool.map(in_callers_mode, items)
            finally:  # on an error or an interrupt, the items not started are dropped
                pool.shutdown(wait=True, cancel_futures=True)
    finally:
        _release_blas()
        torch.set_num_threads(prev)


def _pad_to(t: torch.Tensor, mult: int) -> torch.Tensor:
    """Zero-pad the last two dims up to multiples of ``mult``."""
    h, w = t.shape[-2:]
    return torch.nn.functional.pad(t, (0, (-w) % mult, 0, (-h) % mult))


def surface_pyramid(
    fields: torch.Tensor, q: torch.Tensor, reconstruction: str, levels: int, workers: int = 1
) -> Pyramid:
    """:func:`cell_moments` of the surface ``fields`` ``(6, Hp + 2, Wp + 2)``, ``q``
    ``(C, Hp + 2, Wp + 2)`` (one-pixel border) merged up to ``levels`` (the image zero-padded
    to multiples of ``2^levels``: cells of size 0, no moments).

    Built by bands of ``2^levels`` rows on ``workers`` threads (:func:`map_threads`): a
    band's cell moments are merged up and dropped, so level 0's moments (the largest array)
    never exist whole."""
    mult = 1 << levels
    hp, wp = fields.shape[1] - 2, fields.shape[2] - 2
    geo = fields[:, 1:-1, 1:-1]
    pos0 = _pad_to(geo[:3], mult)
    rad0 = _pad_to(cell_radius(geo[3], geo[4], geo[5]), mult)
    hm, wm = pos0.shape[1:]
    pos = [pos0] + [q.new_empty(3, hm >> lev, wm >> lev) for lev in range(1, levels + 1)]
    mom: list[torch.Tensor | None] = [None]
    mom += [q.new_empty(q.shape[0], _NMOM, hm >> lev, wm >> lev) for lev in range(1, levels + 1)]
    rad = [rad0] + [q.new_empty(hm >> lev, wm >> lev) for lev in range(1, levels + 1)]
    area = [q.new_zeros(hm, wm)]

    def band(r0: int) -> None:
        r1 = min(r0 + mult, hp)  # rows r0:r1 of the surface, zero-padded to mult rows
        g = fields[3:6, r0 + 1 : r1 + 1, 1 : wp + 1]

        def q_at(a: int, b: int) -> torch.Tensor:
            return q[:, r0 + 1 - b : r1 + 1 - b, 1 + a : wp + 1 + a]

        m = cell_moments(g[0], g[1], g[2], q_at, reconstruction)
        m = torch.nn.functional.pad(m, (0, wm - wp, 0, mult - (r1 - r0)))
        area[0][r0 : r0 + mult] = m[-1, 0]
        p, r = pos0[:, r0 : r0 + mult], rad0[r0 : r0 + mult]
        for lev in range(1, levels + 1):
            p, m, r = _merge(p, m, r)
            rows = slice(r0 >> lev, (r0 >> lev) + p.shape[1])
            pos[lev][:, rows], mom[lev][:, :, rows], rad[lev][rows] = p, m, r  # type: ignore[index]

    for _ in map_threads(band, range(0, hm, mult), workers):
        pass
    area += [m[-1, 0] for m in mom[1:]]  # type: ignore[index]
    return Pyramid(pos, mom, area, rad, fields, q, reconstruction)


def _graded_rule(ratio: float, order: int = 6) -> tuple[torch.Tensor, torch.Tensor]:
    """Gauss–Legendre nodes and weights on ``[0, 1]``, panels graded geometrically toward 0
    (``0, 1/r, 2/r, 4/r, …, 1``) for a Gaussian ``1/r`` of the interval wide centred at 0:
    every panel is at most as wide as its distance from 0 (or σ), where the integrand is
    smooth on the panel's scale."""
    x, w = _gauss_legendre(order)
    edges = [0.0, 1.0]
    if ratio > 1:
        n = math.ceil(math.log2(ratio))
        edges = [0.0] + [min(1.0, 2.0**j / ratio) for j in range(n + 1)]
    nodes, wts = [], []
    for a, b in zip(edges[:-1], edges[1:], strict=False):
        if b > a:
            nodes.append((a + b) / 2 + (b - a) / 2 * x)
            wts.append((b - a) / 2 * w)
    return torch.from_numpy(np.concatenate(nodes)), torch.from_numpy(np.concatenate(wts))


def point_field(
    targets: torch.Tensor, sources: torch.Tensor, mass: torch.Tensor, v: float
) -> torch.Tensor:
    """``Σ_S mass_S G(v, |p_S − x|)`` ``(T, C)`` for point masses ``(S, C)``."""
    return blas_product(_gaussian_matrix(targets, sources, v)[2], mass) / (2 * math.pi * v)


def cell_nodes(
    f: torch.Tensor,
    q: torch.Tensor,
    select: torch.Tensor | tuple[torch.Tensor, torch.Tensor],
    u: torch.Tensor,
    wu: torch.Tensor,
    reconstruction: str,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Quadrature points of the reconstructed field over selected cells of a window.

    ``f`` ``(6, h, w)`` = x, y, z, half, slope_x, slope_y and ``q`` ``(C, h, w)`` of a window
    with a one-pixel border, ``select`` ``(h − 2, w − 2)`` the interior cells to integrate
    (a mask, or their interior rows and columns).
    Each cell is split into its four quadrants (where the bilinear weights are bilinear) and
    each quadrant gets the tensor rule ``(u, wu)`` on ``[0, 1]²`` scaled by the half-size.
    Returns points ``(S, 3)`` and masses ``(S, C)`` (reconstructed ``q`` × area element ×
    weights).
    """
    r, c = select if isinstance(select, tuple) else torch.nonzero(select, as_tuple=True)
    if r.numel() == 0:
        return f.new_zeros(0, 3), q.new_zeros(0, q.shape[0])
    x, y, z, hh, sx, sy = f[:, r + 1, c + 1]  # (N,) each
    area = torch.sqrt(1 + sx * sx + sy * sy) * hh * hh
    n = u.numel()

    def nb(a: int, b: int) -> torch.Tensor:  # q of the neighbour at column +a, row −b
        return q[:, r + 1 - b, c + 1 + a][:, :, None, None]

    fa = u / 2 if reconstruction == "bilinear" else torch.zeros_like(u)
    a_s, a_t = fa[:, None], fa[None, :]  # weight of the neighbour across each edge
    ws = (wu[:, None] * wu[None, :]).reshape(-1)  # (n²,)
    pts, mass = [], []
    for qs in (-1, 1):
        for qt in (-1, 1):
            s = qs * hh[:, None, None] * u[None, :, None]  # (N, n, 1)
            t = qt * hh[:, None, None] * u[None, None, :]  # (N, 1, n)
            px = (x[:, None, None] + s).expand(-1, -1, n)
            py = (y[:, None, None] + t).expand(-1, n, -1)
            pz = z[:, None, None] + sx[:, None, None] * s + sy[:, None, None] * t
            pts.append(torch.stack([px, py, pz], -1).reshape(-1, 3))
            val = ((1 - a_s) * (1 - a_t)) * nb(0, 0)
            if reconstruction == "bilinear":
                val = val + (a_s * (1 - a_t)) * nb(qs, 0) + ((1 - a_s) * a_t) * nb(0, qt)
                val = val + (a_s * a_t) * nb(qs, qt)
            val = val.reshape(q.shape[0], -1, n * n) * (area[:, None] * ws[None, :])
            mass.append(val.reshape(q.shape[0], -1).t())
    return torch.cat(pts), torch.cat(mass)


def cell_patches(
    f: torch.Tensor,
    q: torch.Tensor,
    rows: torch.Tensor,
    cols: torch.Tensor,
    panels: int,
    reconstruction: str,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Each selected cell split into ``2·panels × 2·panels`` sub-patches (``panels`` per
    quadrant and axis), as expansion centres ``(S, 3)`` and moments ``(S, C, 10)`` of the
    reconstructed ``q dA`` about them (the layout of :func:`cell_moments`).

    ``f``, ``q``: the surface with a one-pixel border as :func:`cell_nodes` takes it,
    ``rows``, ``cols`` ``(N,)`` interior indices; sub-patches are ordered (quadrant, cell,
    panel along s, panel along t). On a sub-patch the integrand of every moment is, along
    each patch axis, the reconstruction's weight (constant or linear: a quadrant never
    straddles the hat's kink) times a polynomial of degree ≤ 2 in the position (the patch
    is planar), so the 2-point Gauss–Legendre rule per panel and axis (:func:`cell_nodes`)
    gives the moments exactly (to rounding); the centre is the mean of the panel's four
    nodes (the panel's centre: the rule is symmetric and the patch affine).
    """
    x, w = _gauss_legendre(2)
    centres = (np.arange(panels) + 0.5) / panels
    u = torch.from_numpy((centres[:, None] + x[None, :] / (2 * panels)).ravel())
    wu = torch.from_numpy(np.tile(w / (2 * panels), panels))
    pts, mass = cell_nodes(f, q, (rows, cols), u, wu, reconstruction)
    n, m, c = rows.numel(), panels, q.shape[0]
    pts = pts.view(4, n, m, 2, m, 2, 3)
    mass = mass.view(4, n, m, 2, m, 2, c)
    cen = pts.mean((3, 5), keepdim=True)
    d = (pts - cen)[..., None, :]  # (4, n, m, 2, m, 2, 1, 3)
    mw = mass[..., None]  # (..., C, 1)
    quad = torch.stack([d[..., k] * d[..., l] for k, l in _QPAIRS], -1)
    mom = torch.cat([mw, mw * d, mw * quad], -1).sum((3, 5))  # (4, n, m, m, C, 10)
    return cen.reshape(-1, 3), mom.reshape(-1, c, _NMOM)


def _window_px(s: Surface, reach: float, zmin: float) -> float:
    """Half-size in pixels of the window holding every cell within ``reach`` in 3D of a target
    at depth ≥ ``zmin``.

    A cell ``d`` pixels away laterally at depth ``z_b`` has ``Δx = d · foot · z_b + u_t Δz``
    (``u_t = x_t / z_t``), and ``|Δx|² + Δz² ≤ R²`` needs ``d · foot · z_b ≤ R √(1 + u_t²)``
    (Cauchy–Schwarz), with ``z_b ≥ z_t − R``.
    """
    hp, wp = s.inner.shape[1:]
    if zmin - reach > 0:
        return reach * math.sqrt(1 + s.u_max**2) / (s.foot * (zmin - reach)) + 1
    return float(max(hp, wp))


def _cuts(pyr: Pyramid, v: float, ratio: float) -> tuple[list[torch.Tensor], torch.Tensor]:
    """The blocks that evaluate a Gaussian of variance ``v``: per level, the non-empty blocks
    of radius ≤ ``σ / ratio`` whose parent is larger; and per cell the panels per quadrant and
    axis of the cells too large to be expanded (0 elsewhere), ``⌈ratio · radius / 2σ⌉``: the
    sub-patches of :func:`cell_patches` then have radius ≤ ``σ / ratio``, like the blocks."""
    sigma = math.sqrt(v)
    limit = sigma / ratio
    usable = [(r <= limit) & (a > 0) for r, a in zip(pyr.rad, pyr.area, strict=True)]
    top = max([lev for lev, u in enumerate(usable) if bool(u.any())] or [0])
    cut = []
    for lev in range(top + 1):
        c = usable[lev]
        if lev < top:
            c = c & ~usable[lev + 1].repeat_interleave(2, 0).repeat_interleave(2, 1)
        cut.append(c)
    big = (pyr.rad[0] > limit) & (pyr.area[0] > 0)
    panels = torch.where(big, torch.ceil(pyr.rad[0] / (2 * limit)), 0).to(torch.int64)
    return cut, panels


def gather(
    s: Surface,
    rows: torch.Tensor,
    cols: torch.Tensor,
    variances: list[float],
    tols: list[float],
    reconstruction: str,
    ratio: float | None,
    tile: int = 16,
    progress: object = None,
    workers: int = 1,
) -> Iterator[torch.Tensor]:
    """``∫ q G(v_g, |p − p_i|) dA`` at the targets (padded ``rows, cols``) for each Gaussian
    ``g`` in turn, per channel of ``q``: ``(T, C)`` per Gaussian (one at a time: the caller
    folds each in before the next is computed).

    With ``ratio``: the moment expansion of the blocks of :func:`_cuts` and of the
    sub-patches of the cells too large to expand (steep or wide against σ,
    :func:`cell_patches`), all of them sources of one :func:`far_field` per tile of targets
    (:func:`_sources`). Without (Gaussians
    narrower than a pixel): graded Gauss–Legendre points on every cell
    (:func:`_graded_rule`). Sources are taken from the window of :func:`_window_px` around
    each tile of targets: the cells within ``R_g = σ_g √(2 ln(1/tols_g))`` in 3D (the 2D
    Gaussian holds ``exp(−R²/2v) = tol_g`` of its mass beyond ``R``). ``tile``: the tile
    side in pixels of the graded path; the moment path takes tiles of about ``R_g / 4``
    (at least 16 pixels): a tile much smaller than the window it reads costs calls, one
    much larger costs sources per target. The tiles of a Gaussian run on ``workers`` threads
    (:func:`map_threads`).
    """
    shape = (rows.numel(), s.fields.shape[0] - 6)
    if rows.numel() == 0:
        yield from (s.fields.new_zeros(shape) for _ in variances)
        return
    hp, wp = s.inner.shape[1:]
    fields, q = s.fields[:6], s.fields[6:]
    tgt = s.inner[:3, rows, cols].t().contiguous()  # (T, 3) x, y, z
    if ratio is None:
        h_max = float(s.inner[3].max())
        for gi, v in enumerate(variances):
            rule = _graded_rule(h_max / math.sqrt(v))
            reach = math.sqrt(v) * math.sqrt(2 * math.log(1 / tols[gi]))
            tiles = _tiles(s, rows, cols, tgt, tile, reach)
            out = s.fields.new_zeros(shape)
            work = partial(_graded_tile, fields, q, tgt, rule, v, reconstruction, out)
            for n in map_threads(work, tiles, workers):
                if progress is not None:
                    progress.update(n)
            yield out
        return
    levels = _levels(max(variances), ratio, hp, wp)
    pyr = surface_pyramid(fields, q, reconstruction, levels, workers)
    for gi, v in enumerate(variances):
        reach = math.sqrt(v) * math.sqrt(2 * math.log(1 / tols[gi]))
        side = max(tile, min(max(hp, wp), 1 << max(0, math.floor(math.log2(reach / 4)))))
        src = _sources(pyr, *_cuts(pyr, v, ratio), fields, q, reconstruction, side, workers)
        tiles = _tiles(s, rows, cols, tgt, side, reach)
        out = s.fields.new_zeros(shape)
        for n in map_threads(partial(_moment_tile, src, tgt, v, reach, out), tiles, workers):
            if progress is not None:
                progress.update(n)
        del src  # before the next Gaussian's sources are made
        yield out


def _graded_tile(
    fields: torch.Tensor,
    q: torch.Tensor,
    tgt: torch.Tensor,
    rule: tuple[torch.Tensor, torch.Tensor],
    v: float,
    reconstruction: str,
    out: torch.Tensor,
    item: tuple[torch.Tensor, tuple[int, int, int, int]],
) -> int:
    """One tile of the graded path of :func:`gather`: ``out[sel]`` ``(T, C)`` from the
    quadrature points of every cell of the tile's window; returns the number of targets."""
    sel, (ra, rb, ca, cb) = item
    fw, qw = fields[:, ra : rb + 2, ca : cb + 2], q[:, ra : rb + 2, ca : cb + 2]
    pts, mass = cell_nodes(fw, qw, fw[3, 1:-1, 1:-1] > 0, *rule, reconstruction)
    if pts.shape[0]:
        out[sel] = point_field(tgt[sel], pts, mass, v)
    return sel.numel()


def _moment_tile(
    src: _Sources,
    tgt: torch.Tensor,
    v: float,
    reach: float,
    out: torch.Tensor,
    item: tuple[torch.Tensor, tuple[int, int, int, int]],
) -> int:
    """One tile of the moment path of :func:`gather`: ``out[sel]`` ``(T, C)``; returns the
    number of targets."""
    sel, window = item
    out[sel] = src.field(tgt[sel], v, reach, window)
    return sel.numel()


def _tiles(
    s: Surface,
    rows: torch.Tensor,
    cols: torch.Tensor,
    tgt: torch.Tensor,
    tile: int,
    reach: float,
):
    """The targets by tiles of ``tile²`` pixels: per tile the target indices and the pixel
    window ``(ra, rb, ca, cb)`` (rows ``ra:rb``, cols ``ca:cb``) of :func:`_window_px`."""
    hp, wp = s.inner.shape[1:]
    ntc = (wp + tile - 1) // tile
    tid = (rows // tile) * ntc + cols // tile
    order = torch.argsort(tid, stable=True)
    uniq, counts = torch.unique_consecutive(tid[order], return_counts=True)
    starts = torch.cumsum(counts, 0) - counts
    zmins = torch.segment_reduce(tgt[order, 2], "min", lengths=counts).tolist()
    for t_idx, st, cnt, zmin in zip(
        uniq.tolist(), starts.tolist(), counts.tolist(), zmins, strict=True
    ):
        r0, c0 = (t_idx // ntc) * tile, (t_idx % ntc) * tile
        rpx = _window_px(s, reach, zmin)
        ra, rb = max(0, int(r0 - rpx)), min(hp, int(r0 + tile + rpx) + 1)
        ca, cb = max(0, int(c0 - rpx)), min(wp, int(c0 + tile + rpx) + 1)
        yield order[st : st + cnt], (ra, rb, ca, cb)


@dataclass
class _Sources:
    """The sources of one Gaussian, bucketed by ``side``-pixel squares of their pixel: ``pos``
    ``(N, 3)`` expansion centres, ``mom`` ``(N, C, 10)`` moments, ``rad`` ``(N,)`` ball radii
    (blocks of the pyramid and sub-patches of large cells); bucket ``(i, j)`` holds the sources
    ``start[i · ncols + j] : start[i · ncols + j + 1]``; ``margin``: the largest distance in
    pixels from a source's pixel to a pixel of its block."""

    pos: torch.Tensor
    mom: torch.Tensor
    rad: torch.Tensor
    start: list[int]
    ncols: int
    nrows: int
    side: int
    margin: int

    def field(
        self, x: torch.Tensor, v: float, reach: float, window: tuple[int, int, int, int]
    ) -> torch.Tensor:
        """:func:`far_field` at the targets ``x`` ``(T, 3)`` of the sources of a block
        touching the pixel window ``(ra, rb, ca, cb)`` whose ball comes within ``reach`` of
        the 3D bounding box of the targets (the others hold less than the tolerance of the
        Gaussian)."""
        lo, hi = x.amin(0), x.amax(0)
        keep = self.near(window, lo, hi, reach)
        return far_field(x, self.pos[keep], self.mom[keep], v)

    def near(
        self, window: tuple[int, int, int, int], lo: torch.Tensor, hi: torch.Tensor, reach: float
    ) -> torch.Tensor:
        """Indices of the sources of a bucket under the pixel window ``(ra, rb, ca, cb)``
        widened by ``margin`` pixels whose ball comes within ``reach`` of the box
        ``[lo, hi]``."""
        ra, rb, ca, cb = window
        sd, nc, mg, start = self.side, self.ncols, self.margin, self.start
        r1, r2 = max(0, (ra - mg) // sd), min(self.nrows - 1, (rb - 1 + mg) // sd)
        c1, c2 = max(0, (ca - mg) // sd), min(nc - 1, (cb - 1 + mg) // sd)
        spans = [(start[i * nc + c1], start[i * nc + c2 + 1]) for i in range(r1, r2 + 1)]
        idx = torch.cat([torch.arange(a, b) for a, b in spans if b > a] or [torch.arange(0)])
        p = self.pos[idx]
        gap = (p - hi).clamp_min(0) + (lo - p).clamp_min(0)
        return idx[(gap * gap).sum(1) <= (reach + self.rad[idx]) ** 2]


def _sources(
    pyr: Pyramid,
    cut: list[torch.Tensor],
    panels: torch.Tensor,
    fields: torch.Tensor,
    q: torch.Tensor,
    reconstruction: str,
    side: int,
    workers: int = 1,
) -> _Sources:
    """The blocks of ``cut`` and the sub-patches of the cells too large to expand
    (:func:`cell_patches`, ``panels`` per quadrant and axis) as :class:`_Sources` (``fields``,
    ``q``: the padded surface with a one-pixel border, as :func:`cell_nodes` takes it; the
    sub-patches are made on ``workers`` threads)."""
    hp, wp = fields.shape[-2] - 2, fields.shape[-1] - 2
    nrows, ncols = (hp + side - 1) // side, (wp + side - 1) // side
    pos, rad = [q.new_zeros(0, 3)], [q.new_zeros(0)]
    pix, flat = [torch.zeros(0, 2, dtype=torch.int64)], []
    for lev, c in enumerate(cut):
        b = 1 << lev
        idx = torch.nonzero(c)
        pos.append(pyr.pos[lev][:, c].t())
        rad.append(pyr.rad[lev][c])
        pix.append(idx * b + b // 2)
        flat.append(idx[:, 0] * c.shape[1] + idx[:, 1])
    margin = max([1 << lev for lev, c in enumerate(cut) if bool(c.any())] or [1])
    panels = panels[:hp, :wp]
    big = torch.nonzero(panels > 0)
    per_cell = panels[big[:, 0], big[:, 1]]
    batches = []  # (panels, cells) with at most _PATCH_NODES quadrature nodes each
    for m in torch.unique(per_cell).tolist():
        cells = big[per_cell == m]
        step = max(1, _PATCH_NODES // (16 * m * m))
        batches += [(m, cells[a : a + step]) for a in range(0, cells.shape[0], step)]
    work = partial(_patch_batch, fields, q, reconstruction)
    patch_mom = []
    for p_, m_, r_, x_ in map_threads(work, batches, workers):
        pos.append(p_)
        patch_mom.append(m_)
        rad.append(r_)
        pix.append(x_)
    pix_all = torch.cat(pix)
    bucket = (pix_all[:, 0] // side).clamp_max(nrows - 1) * ncols
    bucket += (pix_all[:, 1] // side).clamp_max(ncols - 1)
    del pix_all
    order = torch.argsort(bucket, stable=True)
    start = [0, *torch.cumsum(torch.bincount(bucket, minlength=nrows * ncols), 0).tolist()]
    p_all, r_all = torch.cat(pos)[order], torch.cat(rad)[order]
    # the moments (the largest payload) copied into their sorted places a slice at a time
    rank = torch.empty_like(order)
    rank[order] = torch.arange(order.numel())
    m_all = q.new_empty(order.numel(), q.shape[0], _NMOM)
    first = 0
    for lev, fl in enumerate(flat):
        for a in range(0, fl.numel(), 1 << 16):
            part = fl[a : a + (1 << 16)]
            dst = rank[first + a : first + a + part.numel()]
            m_all.index_copy_(0, dst, pyr.moments(lev, part))
        first += fl.numel()
    for part in patch_mom:
        m_all.index_copy_(0, rank[first : first + part.shape[0]], part)
        first += part.shape[0]
    return _Sources(p_all, m_all, r_all, start, ncols, nrows, side, margin)


def _patch_batch(
    fields: torch.Tensor, q: torch.Tensor, reconstruction: str, item: tuple[int, torch.Tensor]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`cell_patches` of the cells ``(N, 2)`` of ``item = (panels, cells)`` with their
    ball radii ``(S,)`` and pixels ``(S, 2)`` (each sub-patch lies in its cell's pixel)."""
    m, cells = item
    r, c = cells.unbind(1)
    pos, mom = cell_patches(fields, q, r, c, m, reconstruction)
    hh, sx, sy = fields[3:6, r + 1, c + 1]
    rad = cell_radius(hh / (2 * m), sx, sy)[None, :, None, None].expand(4, -1, m, m)
    pix = cells[None, :, None, None].expand(4, -1, m, m, 2)
    return pos, mom, rad.reshape(-1), pix.reshape(-1, 2)


def _levels(v_max: float, ratio: float, hp: int, wp: int) -> int:
    """Pyramid levels worth building: a level-``l`` block is at least ``2^l / √2`` footprints
    in radius (in the unit of the smallest footprint), so none is usable (radius ≤
    ``σ / ratio``) beyond this."""
    lev = math.floor(math.log2(max(1.0, math.sqrt(2 * v_max) / ratio)))
    return max(0, min(lev, int(math.log2(max(1, min(hp, wp)))) - 1))
