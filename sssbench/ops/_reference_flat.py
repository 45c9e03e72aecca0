"""Per-offset weights of the exact reference on a fronto-parallel plane (the FFT path).

On a plane at depth ``z`` every neighbour at pixel offset ``(du, dv)`` sits at ``(du p, −dv p,
0)`` mm (``p`` the footprint) and the weight of a Gaussian factorises into one-dimensional
integrals (001 eq. 7): of the normal density over the pixel's interval (box reconstruction) or
against the pixel's hat function (bilinear reconstruction). Both are written so that they keep
their relative precision at every ratio ``p / σ`` (a difference of CDFs loses every digit when
the pixel is 1e-17 of the Gaussian).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from sssbench.profiles.base import Profile, _gauss_legendre
from sssbench.profiles.sum_of_gaussians import SumOfGaussians, interval_mass

__all__ = ["box_mass_1d", "tent_mass_1d", "flat_kernel"]

#: below this ``width · (1 + |c|/σ) / σ`` the Taylor forms are used (next term ~1e-12)
_TAYLOR = 1e-3
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


def _density(c: torch.Tensor, s: float) -> torch.Tensor:
    return torch.exp(-0.5 * (c / s) ** 2) * (_INV_SQRT_2PI / s)


def box_mass_1d(c: torch.Tensor, half: float, s: float) -> torch.Tensor:
    """``∫_{c−h}^{c+h} φ_σ(x) dx``: the normal's mass over a pixel interval.

    ``Φ`` differences (without cancellation in the tails, :func:`interval_mass`), or where the
    interval is tiny against ``σ`` the Taylor form ``2h φ_σ(c) [1 + h² (c²/σ² − 1) / 6σ²]``
    (the CDF difference would cancel).
    """
    small = half * (1 + c.abs() / s) / s < _TAYLOR
    taylor = 2 * half * _density(c, s) * (1 + half**2 * ((c / s) ** 2 - 1) / (6 * s * s))
    exact = interval_mass((c - half) / s, (c + half) / s)
    return torch.where(small, taylor, exact)


def _psi(t: torch.Tensor) -> torch.Tensor:
    """Second antiderivative of the standard normal density: ``t Φ(t) + φ(t)``."""
    return t * torch.special.ndtr(t) + torch.exp(-0.5 * t * t) * _INV_SQRT_2PI


def tent_mass_1d(c: torch.Tensor, width: float, s: float) -> torch.Tensor:
    """``∫ Λ((x − c)/p) φ_σ(x) dx`` with the hat ``Λ(t) = max(0, 1 − |t|)`` of half-width
    ``p = width``: the 1D weight of a neighbour under linear interpolation.

    The hat is the second difference of the ramp, so the integral is the second difference of
    ``σ ψ(x/σ)`` (``ψ`` = :func:`_psi`) over ``c − p, c, c + p``, divided by ``p``; taken at
    ``−|c|`` (the integrand is symmetric) where ``ψ`` is small, and replaced by the Taylor form
    ``p φ_σ(c) [1 + p² (c²/σ² − 1) / 12σ²]`` where ``p`` is tiny against ``σ``.
    """
    a = -c.abs()
    second = s * (_psi((a + width) / s) - 2 * _psi(a / s) + _psi((a - width) / s)) / width
    small = width * (1 + c.abs() / s) / s < _TAYLOR
    taylor = width * _density(c, s) * (1 + width**2 * ((c / s) ** 2 - 1) / (12 * s * s))
    return torch.where(small, taylor, second.clamp_min(0.0))


def flat_kernel(
    profile: Profile, pix: float, k: int, radius_mm: float, reconstruction: str
) -> torch.Tensor:
    """Weights of the offsets ``−k..k`` on a plane with footprint ``pix`` mm, ``(3, n, n)``.

    Offsets whose reconstruction support lies beyond ``radius_mm`` (nearest point of the
    pixel's cell, or of its 2×2-pixel hat) are 0. Sums of Gaussians use the closed forms above;
    other profiles :meth:`Profile.cell_integral` (box) or a Gauss–Legendre rule of order 8 on
    each quadrant of the hat, where the hat is bilinear (bilinear).
    """
    offs = torch.arange(-k, k + 1, dtype=torch.float64) * pix
    reach = pix / 2 if reconstruction == "box" else pix
    near1 = (offs.abs() - reach).clamp_min(0)
    near = torch.sqrt(near1[:, None] ** 2 + near1[None, :] ** 2)
    if isinstance(profile, SumOfGaussians):
        ker = torch.zeros(3, 2 * k + 1, 2 * k + 1, dtype=torch.float64)
        for v, w in zip(profile.variances.tolist(), profile.weights, strict=True):
            s = math.sqrt(v)
            m = (
                box_mass_1d(offs, pix / 2, s)
                if reconstruction == "box"
                else tent_mass_1d(offs, pix, s)
            )
            ker += w[:, None, None] * (m[:, None] * m[None, :])[None]
    elif reconstruction == "box":
        dx = offs.view(1, -1).expand(2 * k + 1, -1)
        dy = -offs.view(-1, 1).expand(-1, 2 * k + 1)
        half = torch.full_like(dx, pix / 2)
        ker = profile.cell_integral(dx, dy, torch.zeros_like(dx), half, half).permute(2, 0, 1)
    else:
        x, w = _gauss_legendre(8)
        t = torch.from_numpy(np.concatenate([(x - 1) / 2, (x + 1) / 2])) * pix  # [−p, p]
        wt = torch.from_numpy(np.concatenate([w, w]) / 2) * pix * (1 - t.abs() / pix)
        px = offs[:, None] + t[None, :]  # (n, 16)
        r = torch.sqrt(px[:, None, :, None] ** 2 + px[None, :, None, :] ** 2)
        vals = profile.evaluate(r)  # (n, n, 16, 16, 3)
        ker = torch.einsum("ijabc,a,b->cij", vals, wt, wt)
    return torch.where(near > radius_mm, 0.0, ker)
