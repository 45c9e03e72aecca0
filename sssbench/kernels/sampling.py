"""Tap placement shared by every kernel builder (one implementation; 000 §7, 002 appendix).

A kernel of ``K`` taps is described by tap *centres* (where the gather samples) and tap
*edges* (the interval each tap stands for). Weights are integrals of the 1D kernel over those
intervals (000 §7, "area integration"), with the outermost intervals running to ±inf so that
the tails are lumped into the end taps and a normalised kernel sums to exactly 1.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from sssbench._checks import check_choice, check_int, check_magnitude

__all__ = [
    "SAMPLINGS",
    "OPTIMISED",
    "METHOD_SAMPLINGS",
    "MAX_SAMPLES",
    "tap_positions",
    "inverse_cdf",
    "interval_weights",
    "gaussian_mixture_interval",
    "gaussian_mixture_cdf",
]

#: the published placement rules (000 §7, 002 appendix), which every kernel builder accepts
SAMPLINGS = ("uniform", "power", "importance")
#: taps fitted by gradient descent through the passes (:mod:`sssbench.tune.optimise`); a
#: method option, not a placement rule: ``tap_positions`` does not take it
OPTIMISED = "optimised"
#: the ``sampling`` choices of the pre-integrated method: the rules and ``optimised``
METHOD_SAMPLINGS = (*SAMPLINGS, OPTIMISED)
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
        extent = check_magnitude("extent", extent, "length")
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
        t = (
            torch.linspace(-1.0, 1.0, k, dtype=torch.float64)
            if k > 1
            else torch.zeros(1, dtype=torch.float64)
        )
        if sampling == "power":
            exponent = check_magnitude("exponent", exponent, "factor")
            # exactly odd first: linspace's middle value is ~1e-16, not 0, and its |t|^0.5
            # would put the centre tap 1e-8 of the extent off 0
            t = 0.5 * (t - t.flip(0))
            t = torch.sign(t) * t.abs() ** exponent
        centres = extent * t
        inner_edges = 0.5 * (centres[1:] + centres[:-1])
    inf = torch.tensor([float("inf")], dtype=torch.float64)
    edges = torch.cat([-inf, inner_edges, inf])
    return centres, edges


def interval_weights(
    edges: torch.Tensor,
    interval: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    normaliser: torch.Tensor | None = None,
) -> torch.Tensor:
    """Integrate a 1D kernel over tap intervals: THE one place that does it (000 §7).

    Every kernel builder turns tap edges into weights here, so "area integration" means the
    same thing for every method: weight ``i`` is ``∫_{edges[i]}^{edges[i+1]} a(x) dx`` per
    channel, optionally divided by ``normaliser`` (e.g. the kernel's total, 000 eq. 5).

    Args:
        edges: ``(K+1,)`` non-decreasing interval edges in mm (the ends may be ±inf).
        interval: ``interval(a, b) -> (K, 3)``, the per-channel integral of the 1D kernel
            over ``[a, b]`` (closed form where one exists, e.g. :func:`gaussian_mixture_interval`).
        normaliser: optional ``(3,)`` divisor per channel, or ``None`` for raw integrals.

    Returns:
        ``(K, 3)`` float64 weights.

    Example:
        >>> e = torch.tensor([-float("inf"), 0.0, float("inf")], dtype=torch.float64)
        >>> f = lambda a, b: gaussian_mixture_interval(a, b, torch.ones(1, 3), torch.ones(1, 3))
        >>> interval_weights(e, f)[:, 0].tolist()
        [0.5, 0.5]
    """
    w = interval(edges[:-1], edges[1:])
    if normaliser is not None:
        w = w / normaliser
    return w


def gaussian_mixture_interval(
    a: torch.Tensor, b: torch.Tensor, sigmas: torch.Tensor, weights: torch.Tensor
) -> torch.Tensor:
    """``∫_a^b Σ_j w_j N(x; 0, σ_j²) dx`` per channel for unit-mass 1D Gaussians.

    Args:
        a, b: ``(K,)`` interval ends in mm (may be ±inf).
        sigmas: ``(J, 3)`` or ``(J,)`` standard deviations in mm, > 0.
        weights: ``(J, 3)`` mass of each Gaussian per channel.

    Returns:
        ``(K, 3)`` float64, via :func:`~sssbench.profiles.sum_of_gaussians.interval_mass`
        (no cancellation in the tails).
    """
    from sssbench.profiles.sum_of_gaussians import interval_mass

    s = sigmas.to(torch.float64)
    if s.ndim == 1:
        s = s[:, None].expand(-1, 3)
    w = weights.to(torch.float64)
    a = a.to(torch.float64)[:, None, None]
    b = b.to(torch.float64)[:, None, None]
    return (interval_mass(a / s, b / s) * w).sum(1)


def gaussian_mixture_cdf(
    x: torch.Tensor, sigmas: torch.Tensor, weights: torch.Tensor
) -> torch.Tensor:
    """``∫_{-∞}^x Σ_j w_j N(t; 0, σ_j²) dt`` per channel, ``(*x.shape, 3)``."""
    s = sigmas.to(torch.float64)
    if s.ndim == 1:
        s = s[:, None].expand(-1, 3)
    phi = torch.special.ndtr(x.to(torch.float64)[..., None, None] / s)  # (..., J, 3)
    return (phi * weights.to(torch.float64)).sum(-2)


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
