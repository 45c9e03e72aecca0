"""Chandrasekhar's H-function for isotropic scattering (the half-space oracle of the walk).

For a half-space of single-scattering albedo ``a`` with isotropic scattering and no refractive
boundary, the H-function solves (Chandrasekhar, *Radiative Transfer*, 1950, ch. V, eq. (8)
and the equivalent form (25) for a characteristic function ``Ψ = a/2``)

    ``1/H(μ) = √(1 − a) + (a/2) ∫₀¹ μ' H(μ') / (μ + μ') dμ'``

and has the integral representation (ibid. ch. V §39; Fock's formula)

    ``ln H(μ) = −(μ/π) ∫₀^{π/2} ln(1 − a θ cot θ) / (cos²θ + μ² sin²θ) dθ``.

The total diffuse reflectance of the index-matched half-space under a collimated beam with
direction cosine ``μ₀`` is ``R(μ₀) = 1 − H(μ₀) √(1 − a)`` (ibid. ch. IV, the "albedo
problem": the planetary albedo for isotropic scattering).

Two independent evaluations are provided so each can check the other:
:func:`h_function` iterates the first equation on Gauss–Legendre nodes (the "alternative
form" above converges in a few dozen iterations even at ``a = 1``, where the plain form
``H = 1/(1 − (a/2) μ ∫ H/(μ+μ'))`` creeps; we iterate the geometric mean of H and its
image, which converges to 1e-10 in ~30 iterations for every ``a``);
:func:`h_function_integral` evaluates the integral representation with adaptive quadrature (scipy).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.integrate

from sssbench._checks import check_int, check_scalar

__all__ = ["h_function", "h_function_integral", "halfspace_reflectance"]


def _as_mu(mu: float | np.ndarray) -> np.ndarray:
    m = np.asarray(mu, dtype=np.float64)
    if not np.all(np.isfinite(m)) or np.any(m < 0) or np.any(m > 1):
        raise ValueError(f"mu must be direction cosines in [0, 1], got {mu!r}")
    return m


def h_function(
    albedo: float, mu: float | np.ndarray, *, nodes: int = 400, tol: float = 1e-10
) -> np.ndarray:
    """``H(μ)`` for isotropic scattering of single-scattering albedo ``albedo``.

    Args:
        albedo: single-scattering albedo ``a`` in [0, 1].
        mu: direction cosine(s) in [0, 1], any shape.
        nodes: Gauss–Legendre nodes on [0, 1] (H has a ``μ ln μ`` term at 0, so the node
            count, not the iteration, limits the accuracy: 400 nodes give ~1e-8).
        tol: stop when the largest change of H on the nodes is below ``tol``.

    Returns:
        ``H(μ)`` with the shape of ``mu`` (float64), by Nyström interpolation of the
        converged node values through the same equation.
    """
    a = check_scalar("albedo", albedo, 0.0, 1.0)
    nodes = check_int("nodes", nodes, 8, 20000)
    tol = check_scalar("tol", tol, 0.0, 1.0, low_inclusive=False)
    m = _as_mu(mu)
    x, w = np.polynomial.legendre.leggauss(nodes)
    x, w = (x + 1) / 2, w / 2
    root = math.sqrt(1 - a)
    kernel = (a / 2) * (w * x)[None, :] / (x[:, None] + x[None, :])  # (nodes, nodes)
    h = np.ones(nodes)
    for _ in range(100_000):
        # geometric mean of H and its image: at a = 1 the plain map flips H -> c/H (a
        # period-2 cycle, the equation being invariant under that scaling); the mean contracts
        new = np.sqrt(h / (root + kernel @ h))
        done = np.max(np.abs(new - h)) < tol
        h = new
        if done:
            break
    else:  # pragma: no cover - the damped map contracts for every a in [0, 1]
        raise RuntimeError(f"H-function iteration did not converge for albedo={a}")
    flat = m.reshape(-1)
    inv = root + (a / 2) * ((w * x * h)[None, :] / (flat[:, None] + x[None, :])).sum(1)
    return (1 / inv).reshape(m.shape)


def h_function_integral(albedo: float, mu: float) -> float:
    """``H(μ)`` from the integral representation (module doc), by ``scipy.integrate.quad``."""
    a = check_scalar("albedo", albedo, 0.0, 1.0)
    m = float(_as_mu(mu))
    if m == 0.0 or a == 0.0:
        return 1.0

    def f(t: float) -> float:
        tcot = 1.0 if t == 0.0 else t / math.tan(t)
        return math.log(1 - a * tcot) / (math.cos(t) ** 2 + m * m * math.sin(t) ** 2)

    # ln(1 − a θ cot θ) has a log singularity at θ = 0 when a = 1: quad handles it (points)
    val, _ = scipy.integrate.quad(f, 0.0, math.pi / 2, limit=400, epsabs=1e-11, epsrel=1e-10)
    return math.exp(-m / math.pi * val)


def halfspace_reflectance(albedo: float, mu0: float = 1.0) -> float:
    """Total diffuse reflectance ``1 − H(μ₀)√(1 − a)`` of the index-matched isotropic
    half-space under a collimated beam of direction cosine ``μ₀`` (module doc)."""
    a = check_scalar("albedo", albedo, 0.0, 1.0)
    return 1.0 - float(h_function(a, mu0)) * math.sqrt(1 - a)
