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
  the same CDF in closed form too (Unity-Technologies/Graphics, ``DiffusionProfile.hlsl``,
  ``SampleBurleyDiffusionProfile``, after https://zero-radiance.github.io/post/sampling-diffusion/):
  Cardano's root written with ``g = 1 + 4v(2v + √(1 + 4v²))``, ``v = 1 − u``, as
  ``r = 3d ln(c / 4v)``, ``c = 1 + g^{1/3} + g^{−1/3}``; :func:`hdrp_burley_sample` is that
  form (the ``estimator="hdrp"`` of :class:`~sssbench.ops.DiskSSS`), equal to ours to
  rounding (``tests/ops/test_disk_hdrp.py``). Only the filter radius on the CPU side of HDRP
  (``DiffusionProfileSettings.cs``) has a Halley iteration, unused by the sampler.
- :class:`TabulatedRadial`: any profile: ``q`` evaluated with ``profile.evaluate`` on a radial
  grid (float64), its CDF by the trapezoid rule, inverted by linear interpolation. The
  returned ``1/pdf`` is that of the piecewise-linear CDF actually sampled (constant density
  per grid interval), so the estimator stays unbiased for the profile itself; the grid only
  sets the variance. The grid ends at ``profile.radius(1e-7)``: the energy beyond is dropped.
  A profile whose sampled channel is negative on the grid by more than 1e-6 of its peak (a
  negative lobe) is refused: its "CDF" is not monotone, so it is no density to sample;
  smaller dips (a fitted tail) are sampled with density 0. The other channels
  are only integrands: a signed ``R_c / pdf`` is still an unbiased importance-sampling
  weight, so a small negative lobe there (``empirical_dipole_fit("skin1")``'s green channel,
  −1e-6 mm⁻² at 12 mm) is accepted.

Both give :meth:`RadialSampler.sample_polar` too: ``(r, 1/pdf_polar)`` with the density in
``(r, φ)`` (``pdf_polar = pdf · r``), the form HDRP's weight uses, and
:meth:`RadialSampler.quantile_radius` (the radius holding a fraction of the energy; HDRP's
filter radius is the 0.997 quantile).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from sssbench.profiles.base import Profile
from sssbench.profiles.burley import BurleyNormalized

__all__ = [
    "RadialSampler",
    "BurleyRadial",
    "TabulatedRadial",
    "radial_sampler",
    "hdrp_burley_sample",
]

#: energy left beyond the end of a tabulated grid
_TABLE_TOL = 1e-7
#: grid nodes of a tabulated sampler (geometric in r)
_TABLE_NODES = 4096
#: the sampled channel may dip below 0 by this fraction of its peak (a fitted tail:
#: ``empirical_dipole_fit("skin1")`` reaches −7e-9 mm⁻² at 20 mm); sampled with density 0
#: there, so the signed energy it holds (below 1e-7 of the channel's) is not gathered
_NEGATIVE_TOL = 1e-6


class RadialSampler:
    """``u -> (r, 1/pdf)``: radius in mm and the inverse *area* density (mm²)."""

    def sample(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        raise NotImplementedError

    def sample_polar(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(r, 1/pdf_polar)``: the radius and the inverse density in ``(r, φ)`` (mm)."""
        r, inv_area = self.sample(u)
        return r, inv_area / r

    def quantile_radius(self, q: float) -> float:
        """The radius (mm) inside which the fraction ``q`` of the sampled energy lies."""
        return float(self.sample(torch.tensor([q], dtype=torch.float64))[0][0])


def hdrp_burley_sample(u: torch.Tensor, d: float) -> tuple[torch.Tensor, torch.Tensor]:
    """HDRP's closed-form Burley sampler (module doc), float64: ``u`` (the CDF value) to
    ``(r, 1/pdf_polar)``, ``pdf_polar = (e^{−r/d} + e^{−r/(3d)}) / (8π d)``.

    With ``v = 1 − u``: ``g = 1 + 4v(2v + √(1 + 4v²))``, ``c = 1 + g^{1/3} + g^{−1/3}``,
    ``r = 3d ln(c / 4v)``; then ``e^{−r/(3d)} = 4v/c`` and ``1/pdf_polar = 8π d c³ /
    (4v (c² + 16v²))`` (the published formulas, written here in float64)."""
    v = 1.0 - u.double()
    g = 1.0 + 4.0 * v * (2.0 * v + torch.sqrt(1.0 + 4.0 * v * v))
    n = g ** (-1.0 / 3.0)
    c = 1.0 + g * n * n + n
    r = 3.0 * d * torch.log(c / (4.0 * v))
    rcp_exp = c**3 / (4.0 * v * (c * c + 16.0 * v * v))
    return r, 8.0 * math.pi * d * rcp_exp


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

    def sample_polar(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return hdrp_burley_sample(u, self.d)

    def quantile_radius(self, q: float) -> float:
        return float(hdrp_burley_sample(torch.tensor([q], dtype=torch.float64), self.d)[0][0])


class TabulatedRadial(RadialSampler):
    """Tabulated inverse CDF of channel ``channel`` of ``profile`` (module doc). Raises
    ``ValueError`` (message without the argument's name, which the caller prefixes) for a
    profile that is not finite or negative on the grid."""

    def __init__(self, profile: Profile, channel: int) -> None:
        lo, _ = profile.length_scales()
        r_max = profile.radius(_TABLE_TOL)
        grid = np.concatenate([[0.0], np.geomspace(min(lo, r_max) * 1e-3, r_max, _TABLE_NODES)])
        r = torch.from_numpy(grid)
        #: the profile on the grid, every channel ``(N, 3)``
        self.values = profile.evaluate(r)
        if not bool(torch.isfinite(self.values).all()):
            raise ValueError("is not finite on the sampler's radial grid")
        sampled = self.values[:, channel]
        peak = float(sampled.max())
        if float(sampled.min()) < -_NEGATIVE_TOL * peak:  # a negative lobe is no density
            k = int(torch.argmin(sampled))
            raise ValueError(
                f"is negative in its sampled (widest) channel {channel} (R = "
                f"{float(sampled[k]):.3g} at r = {float(r[k]):.3g} mm, peak {peak:.3g}): the "
                "disk samples that channel as a density, which needs R >= 0 (a negative lobe "
                "is not a density)"
            )
        # dips below 0 within the tolerance (a fit's tail) are sampled with density 0
        q = 2 * math.pi * r * sampled.clamp_min(0.0)  # radial density, unnormalised
        cdf = torch.cat([torch.zeros(1, dtype=torch.float64), torch.cumsum(
            0.5 * (q[1:] + q[:-1]) * (r[1:] - r[:-1]), 0)])  # fmt: skip
        if not float(cdf[-1]) > 0:
            raise ValueError(f"has no energy to sample in channel {channel}")
        if bool((cdf[1:] < cdf[:-1]).any()):
            raise ValueError(
                f"has a non-monotone radial CDF in channel {channel}: it cannot be sampled as "
                "a density"
            )
        self.r = r
        self.cdf = cdf / cdf[-1]

    def sample(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        u = u.double().contiguous()  # (an expanded u would make searchsorted copy and warn)
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
