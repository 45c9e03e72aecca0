"""SVD rank-N separable approximation of the discretised kernel (000 §3 eq. 2; 002 §3.1 Fig. 2).

``A(x, y) = Σ_{i=1}^N a_i(x) a_i(y)`` (000 eq. 2) with the factors taken from the singular value
decomposition of the kernel matrix, which by Eckart–Young is the best rank-N approximation in
the Frobenius norm (000 §3). Each term is applied as two 1D passes (2N passes in total).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from sssbench._checks import check_int, check_magnitude, check_tensor
from sssbench.kernels.kernel1d import Kernel1D
from sssbench.kernels.matrix import MAX_MATRIX_SIZE, cell_centres, kernel_matrix
from sssbench.profiles.base import Profile

__all__ = ["LowRankKernel", "low_rank", "singular_energy", "reconstruct"]


@dataclass(frozen=True)
class LowRankKernel:
    """The separable terms of a rank-N SVD approximation and its spectrum.

    Attributes:
        terms: ``N`` pairs ``(horizontal, vertical)`` of :class:`Kernel1D`; term ``i`` is the
            outer product ``vertical(y) · horizontal(x)`` per channel. Weights are cell masses
            (not normalised), may be negative, and sum over all terms to the kernel matrix.
        singular_values: ``(n, 3)`` all singular values per channel, descending.
        energy: ``(n, 3)`` energy fraction ``s_i² / Σ_j s_j²`` of each singular value.
        extent: half-width (mm) of the discretised square.
    """

    terms: list[tuple[Kernel1D, Kernel1D]]
    singular_values: torch.Tensor
    energy: torch.Tensor
    extent: float

    @property
    def rank(self) -> int:
        return len(self.terms)


def singular_energy(singular_values: torch.Tensor) -> torch.Tensor:
    """Energy fraction ``s_i² / Σ_j s_j²`` of each singular value along dim 0.

    We define energy as the squared singular value: ``Σ s_i²`` is the squared Frobenius norm of
    the matrix, so the fraction left out by a rank-N truncation is exactly the relative squared
    Frobenius error (000 §8: "the error ... is determined by the squared sum of the higher-order
    singular values"). 002 Fig. 2 does not define its "energy"; ``s_i / Σ s_j`` gives smaller
    first-value fractions (see the tests' measured numbers).

    Example:
        >>> [round(e, 6) for e in singular_energy(torch.tensor([3.0, 4.0])).tolist()]
        [0.36, 0.64]
    """
    sq = singular_values**2
    return sq / sq.sum(0, keepdim=True).clamp_min(1e-300)


def low_rank(
    profile_or_matrix: Profile | torch.Tensor,
    rank: int,
    *,
    extent: float | None = None,
    n: int = 101,
) -> LowRankKernel:
    """Rank-``rank`` separable SVD terms of a discretised kernel, per channel (000 eq. 2).

    Per channel ``M_c = U S Vᵀ`` (rows of ``M`` along y). Term ``i`` is packed as the pair
    ``(horizontal = v_i √s_i, vertical = u_i √s_i)``: column ``c`` of each ``Kernel1D``'s weights
    holds channel ``c``'s factor, offsets are the cell centres (mm). The sign of a singular pair
    is arbitrary; we flip ``(u_i, v_i)`` together so that the horizontal factor has a
    non-negative sum (the product, which is all that matters, is unchanged). For a symmetric
    kernel matrix, ``u_i = ±v_i``; a negative eigenvalue shows up as opposite-signed factors.

    Args:
        profile_or_matrix: a :class:`Profile` (discretised with :func:`kernel_matrix`) or a
            ``(3, n, n)`` float kernel matrix whose cells tile ``[-extent, extent]²``.
        rank: number of separable terms N, in [1, n].
        extent: half-width in mm; default ``profile.radius()`` for a profile; required for a
            matrix (it sets the offsets).
        n: cells per side when discretising a profile (odd puts a cell on the centre).

    Returns:
        A :class:`LowRankKernel` (terms, all singular values, energy fractions).

    Shape:
        each term's Kernel1D: offsets ``(n,)``, weights ``(n, 3)``.

    Example:
        >>> from sssbench.profiles import SumOfGaussians
        >>> lr = low_rank(SumOfGaussians.from_table("skin_deon6"), 3, extent=10.0, n=61)
        >>> lr.rank, lr.energy.shape
        (3, torch.Size([61, 3]))
    """
    if isinstance(profile_or_matrix, Profile):
        if extent is None:
            extent = profile_or_matrix.radius()
        extent = check_magnitude("extent", extent, "length")
        n = check_int("n", n, 1, MAX_MATRIX_SIZE)
        m = kernel_matrix(profile_or_matrix, extent, n)
    elif isinstance(profile_or_matrix, torch.Tensor):
        m = check_tensor("profile_or_matrix", profile_or_matrix, ndim=3)
        if m.shape[0] != 3 or m.shape[1] != m.shape[2]:
            raise ValueError(f"profile_or_matrix must have shape (3, n, n), got {tuple(m.shape)}")
        if extent is None:
            raise ValueError("extent must be given (mm, > 0) when passing a kernel matrix")
        extent = check_magnitude("extent", extent, "length")
        n = m.shape[1]
        m = m.double()
    else:
        raise TypeError(
            "profile_or_matrix must be a sssbench Profile or a (3, n, n) torch.Tensor, "
            f"got {type(profile_or_matrix).__name__}"
        )
    rank = check_int("rank", rank, 1, n)

    u, s, vh = torch.linalg.svd(m)  # 000 §3: per channel, (3, n, n), (3, n), (3, n, n)
    v = vh.transpose(-2, -1)
    sign = torch.where(v.sum(1) < 0, -1.0, 1.0).to(m)  # (3, n): per component
    u = u * sign[:, None, :]
    v = v * sign[:, None, :]
    root = torch.sqrt(s)
    offsets = cell_centres(extent, n)
    terms = []
    for i in range(rank):  # 000 eq. 2: A = Σ a_i(x) a_i(y)
        h = (v[:, :, i] * root[:, None, i]).T.contiguous()  # (n, 3)
        vert = (u[:, :, i] * root[:, None, i]).T.contiguous()
        terms.append((Kernel1D(offsets, h), Kernel1D(offsets, vert)))
    return LowRankKernel(terms, s.T.contiguous(), singular_energy(s.T), extent)


def reconstruct(terms: list[tuple[Kernel1D, Kernel1D]]) -> torch.Tensor:
    """``Σ_i vertical_i(y) horizontal_i(x)`` per channel: the 2D kernel the terms apply.

    Args:
        terms: pairs ``(horizontal, vertical)`` as returned in :attr:`LowRankKernel.terms`.

    Returns:
        ``(3, K_v, K_h)`` float64 matrix (rows along y).
    """
    if not terms:
        raise ValueError("terms must hold at least one (horizontal, vertical) pair, got []")
    out = None
    for h, vert in terms:
        t = vert.weights.T.double()[:, :, None] * h.weights.T.double()[:, None, :]
        out = t if out is None else out + t
    return out
