"""Radial importance sampling of a diffusion profile for the disk method (:mod:`.disk`).

A disk sample at radius ``r`` (mm) is drawn with the *area* density
``pdf(r) = q(r) / (2π r)``, ``q`` the normalised radial density ``2π r R(r) / ‖R‖₁`` of the
profile's widest channel (Golubev 2018: radii for the widest channel, weights per channel).
Two samplers map a uniform ``u ∈ [0, 1)`` to ``(r, 1 / pdf(r))``:

- :class:`BurleyRadial`: the closed-form inverse of Burley's radial CDF
  ``F(r) = 1 − e^{−r/d}/4 − 3 e^{−r/(3d)}/4`` (Christensen & Burley 2015). With
  ``x = e^{−r/(3d)}`` the equation ``F(r) = u`` is the depressed cubic ``x³ + 3x − 4(1 − u) = 0``
  whose one real root (Cardano) is ``x = 2 sinh(asinh(2(1 − u)) / 3)`` — written with
  ``sinh``/``asinh`` there is no cancellation as ``u → 1`` — so ``r = −3d ln x``. HDRP inverts
  the same CDF numerically (Golubev 2018); the cubic is exact.
- :class:`TabulatedRadial`: any profile: ``q`` evaluated with ``profile.evaluate`` on a radial
  grid (float64), its CDF by the trapezoid rule, inverted by linear interpolation. The
  returned ``1/pdf`` is that of the piecewise-linear CDF actually sampled (constant density
  per grid interval), so the estimator stays unbiased for the profile itself; the grid only
  sets the variance. The grid ends at ``profile.radius(1e-7)``: the energy beyond is dropped.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from sssbench.profiles.base import Profile
from sssbench.profiles.burley import BurleyNormalized

__all__ = ["RadialSampler", "BurleyRadial", "TabulatedRadial", "radial_sampler"]

#: energy left beyond the end of a tabulated grid
_TABLE_TOL = 1e-7
#: grid nodes of a tabulated sampler (geometric in r)
_TABLE_NODES = 4096


class RadialSampler:
    """``u -> (r, 1/pdf)``: radius in mm and the inverse *area* density (mm²)."""

    def sample(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        raise NotImplementedError


def burley_radius(u: torch.Tensor, d: float) -> torch.Tensor:
    """Inverse of ``F(r) = 1 − e^{−r/d}/4 − 3 e^{−r/(3d)}/4`` (module doc), float64 ``u``."""
    x = 2.0 * torch.sinh(torch.asinh(2.0 * (1.0 - u)) / 3.0)
    return -3.0 * d * torch.log(x.clamp_min(torch.finfo(torch.float64).tiny))


class BurleyRadial(RadialSampler):
    """Exact inverse-CDF sampling of Burley's profile with shape ``d`` (mm)."""

    def __init__(self, d: float) -> None:
        self.d = float(d)

    def sample(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        u = u.double()
        r = burley_radius(u, self.d)
        d = self.d
        # F'(r) = (e^{−r/d} + e^{−r/(3d)}) / (4d); area density = F'(r) / (2π r)
        dens = (torch.exp(-r / d) + torch.exp(-r / (3 * d))) / (4 * d)
        return r, 2 * math.pi * r / dens


class TabulatedRadial(RadialSampler):
    """Tabulated inverse CDF of channel ``channel`` of ``profile`` (module doc)."""

    def __init__(self, profile: Profile, channel: int) -> None:
        lo, _ = profile.length_scales()
        r_max = profile.radius(_TABLE_TOL)
        grid = np.concatenate([[0.0], np.geomspace(min(lo, r_max) * 1e-3, r_max, _TABLE_NODES)])
        r = torch.from_numpy(grid)
        q = 2 * math.pi * r * profile.evaluate(r)[:, channel]  # radial density, unnormalised
        cdf = torch.cat([torch.zeros(1, dtype=torch.float64), torch.cumsum(
            0.5 * (q[1:] + q[:-1]) * (r[1:] - r[:-1]), 0)])  # fmt: skip
        if not float(cdf[-1]) > 0:
            raise ValueError(f"profile channel {channel} has no energy to sample")
        self.r = r
        self.cdf = cdf / cdf[-1]

    def sample(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        u = u.double()
        k = (torch.searchsorted(self.cdf, u, right=True) - 1).clamp(0, len(self.r) - 2)
        c0, c1 = self.cdf[k], self.cdf[k + 1]
        r0, r1 = self.r[k], self.r[k + 1]
        slope = (c1 - c0) / (r1 - r0)  # density of the sampled (piecewise-linear) CDF
        r = r0 + (u - c0) / slope.clamp_min(torch.finfo(torch.float64).tiny)
        r = torch.minimum(r, r1)
        return r, 2 * math.pi * r / slope.clamp_min(torch.finfo(torch.float64).tiny)


def radial_sampler(profile: Profile) -> RadialSampler:
    """The sampler of ``profile``'s widest channel (:meth:`Profile.dominant_channel`):
    closed form for :class:`BurleyNormalized`, tabulated otherwise."""
    channel = profile.dominant_channel()
    if type(profile) is BurleyNormalized:
        return BurleyRadial(float(profile.d[channel]))
    return TabulatedRadial(profile, channel)
