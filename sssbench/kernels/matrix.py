"""The 2D discretised diffusion kernel as a matrix (000 §3, 002 §3.1).

000 §3 analyses "discretized diffusion kernels, which can be interpreted and analyzed as 2D
matrices"; 002 §3.1 calls it ``S[x, y]``. Each entry here is the integral of the profile over
its cell (``Profile.cell_integral``), not the profile value at the cell centre, so a profile
narrower than a cell keeps its energy and the matrix sums to the profile's energy inside the
square (up to truncation outside ``[-extent, extent]²``).
"""

from __future__ import annotations

import torch

from sssbench._checks import check_int, check_magnitude
from sssbench.profiles.base import Profile

__all__ = ["kernel_matrix", "cell_centres", "MAX_MATRIX_SIZE"]

#: largest supported matrix side (memory: 3·n² float64)
MAX_MATRIX_SIZE = 2049
#: cells integrated per chunk: a numeric ``cell_integral`` holds 8×8 quadrature nodes × 3
#: channels per cell (~1.5 kB), so a chunk stays near 100 MB at any ``n``
_CELLS_PER_CHUNK = 1 << 16


def cell_centres(extent: float, n: int) -> torch.Tensor:
    """Centres (mm) of ``n`` equal cells tiling ``[-extent, extent]``, float64, ``(n,)``.

    Example:
        >>> cell_centres(1.5, 3).tolist()
        [-1.0, 0.0, 1.0]
    """
    extent = check_magnitude("extent", extent, "length")
    n = check_int("n", n, 1, MAX_MATRIX_SIZE)
    h = 2.0 * extent / n
    return -extent + h * (torch.arange(n, dtype=torch.float64) + 0.5)


def kernel_matrix(profile: Profile, extent: float, n: int) -> torch.Tensor:
    """The profile integrated over an ``n × n`` grid of cells covering ``[-extent, extent]²``.

    Args:
        profile: a radial profile ``R(r)`` (mm⁻²).
        extent: half-width of the square in mm, > 0.
        n: cells per side, in [1, MAX_MATRIX_SIZE]; odd ``n`` puts a cell on the centre.

    Returns:
        ``M`` with ``M[c, j, i] = ∫∫_cell(i, j) R_c(√(x²+y²)) dx dy`` (dimensionless), rows ``j``
        along y and columns ``i`` along x, cell centres :func:`cell_centres`.

    Shape:
        ``(3, n, n)`` float64.

    Example:
        >>> from sssbench.profiles import SumOfGaussians
        >>> m = kernel_matrix(SumOfGaussians.from_table("skin_deon6"), 10.0, 41)
        >>> m.shape, [round(float(s), 3) for s in m.sum((1, 2))]
        (torch.Size([3, 41, 41]), [1.0, 1.0, 1.0])
    """
    if not isinstance(profile, Profile):
        raise TypeError(f"profile must be a sssbench Profile, got {type(profile).__name__}")
    c = cell_centres(extent, n)
    rows = max(1, _CELLS_PER_CHUNK // n)  # bounded memory at MAX_MATRIX_SIZE too
    m = torch.empty(3, n, n, dtype=torch.float64)
    for r0 in range(0, n, rows):
        dy, dx = torch.meshgrid(c[r0 : r0 + rows], c, indexing="ij")
        half = torch.full_like(dx, extent / n)
        part = profile.cell_integral(dx, dy, torch.zeros_like(dx), half, half)  # (r, n, 3)
        m[:, r0 : r0 + rows] = part.permute(2, 0, 1)
    return m
