"""Burley's normalized diffusion profile (Christensen & Burley 2015).

``R(r) = A (e^{−r/d} + e^{−r/(3d)}) / (8π d r)`` per channel, shape parameter ``d`` in mm and
total reflectance (surface albedo) ``A``. Closed forms used here (``r dr`` integrals of
exponentials; ``∫ e^{−√(x²+y²)/d}/√(x²+y²) dy = 2K₀(|x|/d)``):

* energy inside ρ: ``A [1 − e^{−ρ/d}/4 − 3 e^{−ρ/(3d)}/4]``, so ``total() = A``
* pre-integration: ``a_p(x) = A/(4πd) [K₀(|x|/d) + K₀(|x|/(3d))]``
* its CDF: ``A/2 ± A/(4π) [IK₀(|x|/d) + 3 IK₀(|x|/(3d))]`` with ``IK₀(X) = ∫_0^X K₀``
  (``scipy.special.iti0k0``; ``IK₀(∞) = π/2``)
* second moment of ``a_p``: ``π ∫ r³ R dr / A = 7 d²`` (mm²)
"""

from __future__ import annotations

import math

import scipy.optimize
import scipy.special
import torch

from sssbench._checks import (
    MAGNITUDES,
    check_choice,
    check_magnitude,
    check_range,
    check_scalar,
)
from sssbench.profiles.base import Profile, as_r
from sssbench.profiles.dipole import _rgb

__all__ = ["BurleyNormalized", "BURLEY_FITS", "burley_scaling", "burley_albedo_mfp"]

#: the shape-scaling fits of Christensen & Burley 2015 (``s(A)``, ``d = ℓ / s``):
#: ``mfp``: searchlight configuration with the volume mean free path ℓ,
#: ``s = 1.85 − A + 7|A − 0.8|³``; ``mfp_transmission``: diffuse surface transmission with ℓ,
#: ``s = 1.9 − A + 3.5 (A − 0.8)²``; ``dmfp``: searchlight configuration with the diffuse mean
#: free path ℓ_d, ``s = 3.5 + 100 (A − 0.33)⁴``. Unity HDRP takes *no* such fit: its
#: "scattering distance" is the shape ``d`` itself, ``S = 1 / (scatteringDistance ·
#: multiplier)`` (Unity-Technologies/Graphics, ``DiffusionProfileSettings.cs``,
#: ``UpdateKernel``): :meth:`BurleyNormalized.from_scattering_distance`
BURLEY_FITS = ("dmfp", "mfp", "mfp_transmission")


def burley_scaling(albedo: torch.Tensor, kind: str = "dmfp") -> torch.Tensor:
    """The scaling factor ``s(A)`` of fit ``kind`` (:data:`BURLEY_FITS`), same shape as
    ``albedo`` (Christensen & Burley 2015)."""
    check_choice("kind", kind, BURLEY_FITS)
    a = albedo
    if kind == "mfp":
        return 1.85 - a + 7 * (a - 0.8).abs() ** 3
    if kind == "mfp_transmission":
        return 1.9 - a + 3.5 * (a - 0.8) ** 2
    return 3.5 + 100 * (a - 0.33) ** 4


#: r (and |x|) are clamped to ``_EPS · d`` so that R(0) and a_p(0) are finite (see class doc).
_EPS = 1e-6
#: ``∫_X^∞ K₀ < 1e-23`` beyond this, so IK₀ is evaluated at min(X, _XMAX) (iti0k0 also
#: integrates I₀, which overflows for large X).
_XMAX = 50.0


def _ik0(x: torch.Tensor) -> torch.Tensor:
    """``∫_0^x K₀(t) dt`` for x >= 0 (``scipy.special.iti0k0``)."""
    xc = x.clamp_max(_XMAX).numpy()
    return torch.from_numpy(scipy.special.iti0k0(xc)[1])


def _k0(x: torch.Tensor) -> torch.Tensor:
    """``K₀(x)`` for x > 0 via the scaled ``k0e`` (no early underflow)."""
    return torch.from_numpy(scipy.special.k0e(x.numpy())) * torch.exp(-x)


class BurleyNormalized(Profile):
    """``R(r) = A (e^{−r/d} + e^{−r/(3d)}) / (8π d r)`` (Christensen & Burley 2015).

    Args:
        d: shape parameter in mm, ``(3,)`` or scalar, in [1e-6, 1e6] (``_checks.MAGNITUDES``).
        albedo: total reflectance ``A`` per channel, ``(3,)`` or scalar, in [0, 1].

    Choice at r = 0: ``R`` diverges like ``A/(4π d r)``. :meth:`evaluate` clamps ``r`` to
    ``1e-6 · d`` (per channel), so ``R(0)`` is finite and ``R`` stays continuous and
    non-increasing; the clamp changes the energy inside ``1e-6 d`` by less than 1e-6 relative,
    and everything derived from ``R`` by integration (``total``, ``preintegrated_cdf``,
    ``radius``) uses the exact closed forms, not the clamped values. ``preintegrated(x)`` is the
    exact ``K₀`` form, with the same clamp for its logarithmic singularity at ``x = 0``.
    ``radius(tol)`` uses only the energy criterion (the base's "below tol of the peak" test is
    meaningless for an unbounded peak): ``A/4 e^{−ρ/d} + 3A/4 e^{−ρ/(3d)} = tol·A``.

    Shape:
        ``__call__(r)``: ``(...,) -> (..., 3)`` in mm^-2.

    Example:
        >>> p = BurleyNormalized(torch.tensor([1.0, 0.5, 0.25]), torch.tensor([0.8, 0.6, 0.4]))
        >>> [round(v, 6) for v in p.total().tolist()]
        [0.8, 0.6, 0.4]
    """

    name = "burley"
    _preintegrated_cost = 1
    singular_at_origin = True

    def __init__(
        self, d: torch.Tensor | float | list[float], albedo: torch.Tensor | float | list[float]
    ) -> None:
        dt = _rgb("d", d)
        at = _rgb("albedo", albedo)
        check_magnitude("d", dt, "length")
        check_range("albedo", at, 0.0, 1.0)
        self.d = dt
        self.albedo = at

    @classmethod
    def from_albedo_mfp(
        cls,
        albedo: torch.Tensor | float | list[float],
        mfp_mm: torch.Tensor | float | list[float],
        kind: str = "dmfp",
    ) -> BurleyNormalized:
        """The profile of surface albedo ``A`` and mean free path ``ℓ`` (mm) per channel:
        ``d = ℓ / s(A)`` with the fit ``kind`` of :func:`burley_scaling` (``"dmfp"``: ℓ is the
        diffuse mean free path, Christensen & Burley 2015's searchlight fit; ``"mfp"`` /
        ``"mfp_transmission"``: ℓ is the volume mean free path, searchlight / diffuse surface
        transmission fit). This is *not* HDRP's parameterisation: HDRP applies no albedo fit
        (its scattering distance is ``d``; :meth:`from_scattering_distance`).

        Example:
            >>> p = BurleyNormalized.from_albedo_mfp(0.8, 1.05, kind="mfp")
            >>> round(float(p.d[0]), 12)
            1.0
        """
        at = _rgb("albedo", albedo)
        lt = _rgb("mfp_mm", mfp_mm)
        check_range("albedo", at, 0.0, 1.0)
        check_magnitude("mfp_mm", lt, "length")
        d = lt / burley_scaling(at, kind)
        lo, hi, unit = MAGNITUDES["length"]
        bad = (d < lo) | (d > hi)
        if bool(bad.any()):  # name what the user gave, not the derived d (class 5)
            i = int(bad.nonzero()[0, 0])
            raise ValueError(
                f"mfp_mm must give d = mfp_mm / s(albedo) in [{lo:g}, {hi:g}] {unit} (fit "
                f"{kind!r}), got mfp_mm={float(lt[i]):g} with albedo={float(at[i]):g}: "
                f"d={float(d[i]):g}"
            )
        return cls(d, at)

    @classmethod
    def from_scattering_distance(
        cls,
        scattering_distance: torch.Tensor | float | list[float],
        multiplier: float = 1.0,
        albedo: torch.Tensor | float | list[float] = 1.0,
    ) -> BurleyNormalized:
        """Unity HDRP's diffusion profile: ``d = scatteringDistance · multiplier`` (mm) per
        channel, i.e. its shape parameter ``S = 1/d`` (``DiffusionProfileSettings.cs``,
        ``UpdateKernel``; HDRP clamps ``S`` at 2²⁴), no albedo fit. HDRP's pass normalises
        by the weights it gathers, so ``albedo`` (default 1) does not change its result.

        Example:
            >>> p = BurleyNormalized.from_scattering_distance([0.8, 0.4, 0.2], 2.0)
            >>> p.d.tolist()
            [1.6, 0.8, 0.4]
        """
        m = check_scalar("multiplier", multiplier, 0.0, low_inclusive=False)
        return cls(_rgb("scattering_distance", scattering_distance) * m, albedo)

    def __repr__(self) -> str:
        return f"BurleyNormalized(d={self.d.tolist()}, albedo={self.albedo.tolist()})"

    def evaluate(self, r: torch.Tensor) -> torch.Tensor:
        rr = torch.maximum(r[..., None], _EPS * self.d)
        d = self.d
        return (
            self.albedo * (torch.exp(-rr / d) + torch.exp(-rr / (3 * d))) / (8 * math.pi * d * rr)
        )

    def length_scales(self) -> tuple[float, float]:
        return float(self.d.min()), float(3 * self.d.max())

    def total(self) -> torch.Tensor:
        return self.albedo.clone()

    def energy_beyond(self, rho: torch.Tensor | float) -> torch.Tensor:
        """``∫_ρ^∞ 2πr R dr = A (e^{−ρ/d} + 3 e^{−ρ/(3d)}) / 4`` per channel, ``(..., 3)``."""
        rt = as_r(rho).abs()[..., None]
        d = self.d
        return self.albedo * (torch.exp(-rt / d) + 3 * torch.exp(-rt / (3 * d))) / 4

    def radial_mass(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """``∫_a^b R(r) r dr = A/(8π) [e^{−a/d} − e^{−b/d} + 3 (e^{−a/(3d)} − e^{−b/(3d)})]``
        per channel for ``0 <= a <= b`` (mm), ``(..., 3)``; each difference as
        ``−e^{−a/s} expm1(−(b − a)/s)``, so thin far annuli keep their relative precision.
        The exact ``1/r`` is integrated (no clamp): :meth:`cell_integral` (base class, polar
        about the singular point) uses it for the cells at the singularity."""
        at = a[..., None]
        d, gap = self.d, (b - a)[..., None]
        near = -torch.exp(-at / d) * torch.expm1(-gap / d)
        far = -torch.exp(-at / (3 * d)) * torch.expm1(-gap / (3 * d))
        return self.albedo / (8 * math.pi) * (near + 3 * far)

    def preintegrated(self, x: torch.Tensor | float) -> torch.Tensor:
        """``a_p(x) = A/(4πd) [K₀(|x|/d) + K₀(|x|/(3d))]`` (module doc), ``(..., 3)``."""
        xt = as_r(x).abs()[..., None]
        d = self.d
        xc = torch.maximum(xt, _EPS * d)
        return self.albedo / (4 * math.pi * d) * (_k0(xc / d) + _k0(xc / (3 * d)))

    def preintegrated_cdf(self, x: torch.Tensor | float) -> torch.Tensor:
        """``A/2 ± A/(4π) [IK₀(|x|/d) + 3 IK₀(|x|/(3d))]`` (exact; ``±∞`` give ``A``, 0)."""
        xt = as_r(x, allow_inf=True)[..., None]
        a = xt.abs()
        d = self.d
        part = self.albedo / (4 * math.pi) * (_ik0(a / d) + 3 * _ik0(a / (3 * d)))
        return self.albedo / 2 + torch.sign(xt) * part

    def second_moment(self) -> torch.Tensor:
        """Variance of the 1D kernel in closed form, ``7 d²`` (mm², ``(3,)``).

        ``π ∫_0^∞ r³ A e^{−r/s}/(8π d r) dr = A · 2 s³ / (8 d)``; with s = d and 3d the sum is
        ``A (2d³ + 54 d³)/(8d) = 7 A d²``, divided by the total ``A``: ``7 d²``.
        """
        return 7 * self.d**2

    def radius(self, tol: float = 1e-4) -> float:
        """Radius (mm) outside which less than ``tol`` of every channel's energy lies."""
        tol = check_scalar("tol", tol, 0.0, 1.0, low_inclusive=False, high_inclusive=False)
        hi = 0.0
        for c in range(3):
            if float(self.albedo[c]) == 0.0:
                continue
            dc = float(self.d[c])

            def f(rho: float, dc: float = dc) -> float:
                return (math.exp(-rho / dc) + 3 * math.exp(-rho / (3 * dc))) / 4 - tol

            hi = max(hi, scipy.optimize.brentq(f, 0.0, 3 * dc * (math.log(1 / tol) + 2)))
        return hi


def burley_albedo_mfp(
    name: str,
    albedo: float | list[float],
    mfp_mm: float | list[float],
    fit: str = "dmfp",
) -> BurleyNormalized:
    """The profile kind ``burley_albedo_mfp`` of the app (``conf/profile/*.yaml``: ``kind:
    burley_albedo_mfp``, ``params: {albedo, mfp_mm, fit}``, ``fit`` one of
    :data:`BURLEY_FITS`): :meth:`BurleyNormalized.from_albedo_mfp`, named ``name``."""
    check_choice("fit", fit, BURLEY_FITS)  # the app's key, not the method's "kind"
    profile = BurleyNormalized.from_albedo_mfp(albedo, mfp_mm, fit)
    profile.name = name
    return profile
