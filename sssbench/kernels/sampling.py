"""Tap placement shared by every kernel builder (one implementation; 000 §7, 002 appendix).

A kernel of ``K`` taps is described by tap *centres* (where the gather samples) and tap
*edges* (the interval each tap stands for). Weights are integrals of the 1D kernel over those
intervals (000 §7, "area integration"), with the outermost intervals running to ±inf so that
the tails are lumped into the end taps and a normalised kernel sums to exactly 1.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from sssbench._checks import check_choice, check_int, check_scalar

__all__ = ["SAMPLINGS", "MAX_SAMPLES", "tap_positions", "inverse_cdf"]

SAMPLINGS = ("uniform", "power", "importance")
#: largest supported tap count (000 Fig. 12 uses 513 uniform taps as its ground truth)
MAX_SAMPLES = 1025


def inverse_cdf(
    cdf: Callable[[torch.Tensor], torch.Tensor],
    u: torch.Tensor,
    lo: float,
    hi: float,
    iterations: int = 80,
) -> torch.Tensor:
    """Solve ``cdf(x) = u`` by vectorised bisection on ``[lo, hi]`` (float64).

    Args:
        cdf: non-decreasing function of float64 positions (mm) -> values, same shape.
        u: targets, any shape, within ``[cdf(lo), cdf(hi)]``.
        lo, hi: bracket in mm.

    Returns:
        positions in mm, same shape as ``u``.
    """
    a = torch.full_like(u, lo, dtype=torch.float64)
    b = torch.full_like(u, hi, dtype=torch.float64)
    for _ in range(iterations):
        m = 0.5 * (a + b)
        below = cdf(m) < u
        a = torch.where(below, m, a)
        b = torch.where(below, b, m)
    return 0.5 * (a + b)


def tap_positions(
    samples: int,
    sampling: str,
    extent: float | None,
    *,
    cdf: Callable[[torch.Tensor], torch.Tensor] | None = None,
    exponent: float = 2.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Tap centres and interval edges for ``samples`` taps.

    Args:
        samples: number of taps K, in [1, MAX_SAMPLES].
        sampling: ``"uniform"`` (evenly spaced over ``[-extent, extent]``, ends included),
            ``"power"`` (``extent · sign(t)|t|^exponent`` for t evenly spaced in [-1, 1], the
            2012 shader's placement, 002 appendix) or ``"importance"`` (centres at the
            ``(i + ½)/K`` quantiles and edges at the ``i/K`` quantiles of ``cdf``, 000 §7).
        extent: half-width in mm; required by ``uniform`` and ``power``; for ``importance`` it
            restricts the quantiles to ``[-extent, extent]`` (``None``: the whole line).
        cdf: normalised CDF (0 -> 1) of the dominant channel's 1D kernel, for ``importance``.
        exponent: exponent of ``power`` placement, > 0.

    Returns:
        ``(centres (K,), edges (K+1,))`` float64 in mm; ``edges[0] = -inf``, ``edges[-1] = inf``.
    """
    k = check_int("samples", samples, 1, MAX_SAMPLES)
    check_choice("sampling", sampling, SAMPLINGS)
    if sampling in ("uniform", "power") or extent is not None:
        if extent is None:
            raise ValueError(f"extent must be given (mm, > 0) for sampling={sampling!r}")
        extent = check_scalar("extent", extent, 0.0, low_inclusive=False)
    if sampling == "importance":
        if cdf is None:
            raise ValueError("cdf must be given for sampling='importance'")
        lo_u = float(cdf(torch.tensor(-extent, dtype=torch.float64))) if extent else 0.0
        hi_u = float(cdf(torch.tensor(extent, dtype=torch.float64))) if extent else 1.0
        q = torch.arange(2 * k + 1, dtype=torch.float64) / (2 * k)  # edges at even, centres odd
        u = lo_u + (hi_u - lo_u) * q
        span = extent if extent else _bracket(cdf)
        x = inverse_cdf(cdf, u[1:-1], -span, span)
        centres = x[0::2]
        inner_edges = x[1::2]
        if k % 2 == 1:  # exact symmetry: the middle tap sits on 0
            centres[k // 2] = 0.0
        centres = 0.5 * (centres - centres.flip(0))
        inner_edges = 0.5 * (inner_edges - inner_edges.flip(0))
    else:
        t = torch.linspace(-1.0, 1.0, k, dtype=torch.float64) if k > 1 else torch.zeros(1, dtype=torch.float64)
        if sampling == "power":
            exponent = check_scalar("exponent", exponent, 0.0, low_inclusive=False)
            t = torch.sign(t) * t.abs() ** exponent
        centres = extent * t
        inner_edges = 0.5 * (centres[1:] + centres[:-1])
    inf = torch.tensor([float("inf")], dtype=torch.float64)
    edges = torch.cat([-inf, inner_edges, inf])
    return centres, edges


def _bracket(cdf: Callable[[torch.Tensor], torch.Tensor]) -> float:
    """A half-width X with cdf(-X) ≈ 0 and cdf(X) ≈ 1 (doubling search)."""
    x = 1.0
    for _ in range(200):
        t = torch.tensor([-x, x], dtype=torch.float64)
        c = cdf(t)
        if float(c[0]) < 1e-12 and float(c[1]) > 1 - 1e-12:
            return x
        x *= 2.0
    return x
