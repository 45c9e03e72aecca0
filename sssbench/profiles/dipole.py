"""The classical dipole diffusion profile (Jensen et al. 2001, ``reference/materials.md``).

``R(r) = α'/(4π) [ z_r P(r, σ_tr, z_r) + z_v P(r, σ_tr, z_v) ]`` with the pole function
``P(r, σ, z) = (1 + σ d) e^{−σ d} / d³``, ``d = √(r² + z²)`` (001 Appendix A eq. 17).
Every quantity sssbench needs has a closed form built from three pole identities, derived with
``r dr = d dd`` and ``(σd + 1) e^{−σd}/d³ = −(1/d) ∂_d (e^{−σd}/d)``:

* energy beyond ρ:  ``∫_ρ^∞ r P dr = e^{−σ D}/D``, ``D = √(ρ² + z²)`` (ρ = 0: 001 App. A ``P_d``)
* pre-integration: ``∫ P(√(x²+y²), σ, z) dy = 2 σ K₁(σ ρ)/ρ``, ``ρ = √(x² + z²)``
  (``−(1/ρ) ∂_ρ`` of ``∫ e^{−σd}/d dy = 2 K₀(σρ)``); ``2/ρ²`` when σ = 0
* second moment: ``∫_0^∞ r³ P dr = 2 e^{−σ z}/σ``

All in float64; σ_tr = 0 (Spectralon) is handled by its own branches, never by division.
"""

from __future__ import annotations

import math

import scipy.optimize
import scipy.special
import torch

from sssbench._checks import check_magnitude, check_scalar, check_tensor
from sssbench.profiles.base import Profile, as_r

__all__ = ["Dipole", "MATERIALS"]

#: reference/materials.md (JMLH01): name -> (σs' (R, G, B), σa (R, G, B)) in mm^-1, η = 1.3.
MATERIALS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "apple": ((2.29, 2.39, 1.97), (0.0030, 0.0034, 0.046)),
    "chicken1": ((0.15, 0.21, 0.38), (0.015, 0.077, 0.19)),
    "chicken2": ((0.19, 0.25, 0.32), (0.018, 0.088, 0.20)),
    "cream": ((7.38, 5.47, 3.15), (0.0002, 0.0028, 0.0163)),
    "ketchup": ((0.18, 0.07, 0.03), (0.061, 0.97, 1.45)),
    "marble": ((2.19, 2.62, 3.00), (0.0021, 0.0041, 0.0071)),
    "potato": ((0.68, 0.70, 0.55), (0.0024, 0.0090, 0.12)),
    "skimmilk": ((0.70, 1.22, 1.90), (0.0014, 0.0025, 0.0142)),
    "skin1": ((0.74, 0.88, 1.01), (0.032, 0.17, 0.48)),
    "skin2": ((1.09, 1.59, 1.79), (0.013, 0.070, 0.145)),
    "spectralon": ((11.6, 20.4, 14.9), (0.00, 0.00, 0.00)),
    "wholemilk": ((2.55, 3.21, 3.77), (0.0011, 0.0024, 0.014)),
}


def _rgb(name: str, value: object) -> torch.Tensor:
    """A per-channel coefficient as a ``(3,)`` float64 tensor (scalars broadcast)."""
    if isinstance(value, bool) or (
        isinstance(value, (list, tuple)) and any(isinstance(v, bool) for v in value)
    ):
        raise TypeError(f"{name} must be a number or a (3,) sequence/tensor of floats, got a bool")
    if isinstance(value, torch.Tensor):
        t = value
    else:
        try:
            t = torch.as_tensor(value, dtype=torch.float64)
        except (TypeError, ValueError, RuntimeError) as exc:
            raise TypeError(
                f"{name} must be a number or a (3,) sequence/tensor of floats in mm^-1, "
                f"got {type(value).__name__}"
            ) from exc
    if not t.is_floating_point():
        t = t.double()
    if t.ndim == 0:
        t = t.expand(3)
    check_tensor(name, t, ndim=1)
    if t.shape != (3,):
        raise ValueError(f"{name} must have shape (3,) (R, G, B), got {tuple(t.shape)}")
    return t.double().clone()


def pole_energy_beyond(rho: torch.Tensor, sigma: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """``∫_ρ^∞ r P(r, σ, z) dr = e^{−σD}/D``, ``D = √(ρ² + z²)`` (001 App. A, ``P_d`` at ρ = 0)."""
    d = torch.sqrt(rho**2 + z**2)
    return torch.exp(-sigma * d) / d


def pole_preintegrated(x: torch.Tensor, sigma: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """``∫ P(√(x²+y²), σ, z) dy = 2σK₁(σρ)/ρ`` with ``ρ = √(x²+z²)``; ``2/ρ²`` for σ = 0.

    Broadcasts; uses the scaled Bessel function ``k1e`` so large ``σρ`` does not underflow early.
    """
    rho = torch.sqrt(x**2 + z**2)
    pos = sigma > 0
    t = torch.where(pos, sigma * rho, torch.ones_like(rho))  # dummy 1 where σ = 0
    k1e = torch.from_numpy(scipy.special.k1e(t.numpy()))
    with_sigma = 2 * sigma * k1e * torch.exp(-t) / rho
    return torch.where(pos, with_sigma, 2 / rho**2)


class Dipole(Profile):
    """The classical dipole of Jensen et al. 2001 (``reference/materials.md``), per RGB channel.

    Args:
        sigma_s_prime: reduced scattering coefficient σs' in mm^-1, ``(3,)`` or scalar, in
            [1e-6, 1e6] (``_checks.MAGNITUDES``).
        sigma_a: absorption coefficient σa in mm^-1, ``(3,)`` or scalar, in [0, 1e6]
            (0 = Spectralon:
            σ_tr = 0 and the profile decays as the power law ``(z_r + z_v)/(4π r³)``).
        eta: relative index of refraction in [1, 3] (the ``F_dr`` polynomial of JMLH01 is a fit
            for η >= 1).

    Attributes (all ``(3,)`` float64): ``alpha_prime`` α', ``sigma_tr`` σ_tr (mm^-1),
    ``z_r``, ``z_v`` (mm), ``A`` (boundary term).

    Choices:
        * ``radius(tol)`` keeps the base definition (largest of the ``tol``-of-peak radius and
          the radius holding all but ``tol`` of every channel's energy) but solves it in closed
          form (energy beyond ρ is ``α'/2 Σ z e^{−σD}/D``), so it is exact for any σ_tr. For
          Spectralon the energy beyond ρ decays only as ``(z_r+z_v)/(2ρ)``, so the radius is
          ≈ ``(z_r+z_v)/(2 tol)`` (≈ 2.4 m for tol = 1e-4): long-range light transport is what a
          lossless medium does, and truncating earlier would silently drop energy. Callers who
          want a screen-sized kernel pass a larger ``tol`` (1e-2 gives ≈ 24 mm).
        * ``length_scales()`` = (smallest z_r, largest of z_v and 1/σ_tr over channels with
          σ_tr > 0); with σ_tr = 0 the largest pole depth z_v stands in for the absent decay
          length (the numeric quadratures extend geometrically from there).
        * ``second_moment()`` is the closed form ``Σ z e^{−σz}/(σ Σ e^{−σz})`` (mm²); it diverges
          for σ_tr = 0, so for such channels we return the moment of the profile truncated at
          ``radius()`` (closed form too), a finite width that still ranks channels sensibly.

    Shape:
        ``__call__(r)``: ``(...,) -> (..., 3)`` in mm^-2.

    Example:
        >>> p = Dipole.from_material("Marble")
        >>> round(float(p.total()[1]), 4)
        0.8338
    """

    name = "dipole"
    _preintegrated_cost = 1

    def __init__(
        self,
        sigma_s_prime: torch.Tensor | float | list[float],
        sigma_a: torch.Tensor | float | list[float],
        eta: float = 1.3,
    ) -> None:
        ss = _rgb("sigma_s_prime", sigma_s_prime)
        sa = _rgb("sigma_a", sigma_a)
        check_magnitude("sigma_s_prime", ss, "coefficient")
        check_magnitude("sigma_a", sa, "coefficient", zero=True)
        eta = check_scalar("eta", eta, 1.0, 3.0)
        self.sigma_s_prime = ss
        self.sigma_a = sa
        self.eta = eta
        st = sa + ss  # σt'
        self.alpha_prime = ss / st
        self.sigma_tr = torch.sqrt(3 * sa * st)
        fdr = -1.440 / eta**2 + 0.710 / eta + 0.668 + 0.0636 * eta
        self.F_dr = fdr
        self.A = torch.full((3,), (1 + fdr) / (1 - fdr), dtype=torch.float64)
        D = 1 / (3 * st)
        self.z_r = 1 / st
        self.z_v = self.z_r + 4 * self.A * D

    @classmethod
    def from_material(cls, name: str, eta: float = 1.3) -> Dipole:
        """A dipole of one of the twelve measured materials of ``reference/materials.md``.

        Args:
            name: material name, case-insensitive (``"Marble"``, ``"skin1"``, ...).
            eta: relative index of refraction (the table is for 1.3).
        """
        if not isinstance(name, str):
            raise TypeError(f"name must be a material name (str), got {type(name).__name__}")
        key = name.strip().lower()
        if key not in MATERIALS:
            raise ValueError(
                f"name must be one of {sorted(MATERIALS)} (case-insensitive), got {name!r}"
            )
        ss, sa = MATERIALS[key]
        prof = cls(
            torch.tensor(ss, dtype=torch.float64), torch.tensor(sa, dtype=torch.float64), eta
        )
        prof.name = key
        return prof

    def __repr__(self) -> str:
        return (
            f"Dipole(name={self.name!r}, sigma_s_prime={self.sigma_s_prime.tolist()}, "
            f"sigma_a={self.sigma_a.tolist()}, eta={self.eta})"
        )

    # ------------------------------------------------------------ closed forms
    def _poles(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(z, σ)`` as ``(2, 3)``: row 0 the real source, row 1 the virtual one."""
        return torch.stack([self.z_r, self.z_v]), self.sigma_tr.expand(2, 3)

    def evaluate(self, r: torch.Tensor) -> torch.Tensor:
        rr = r[..., None, None]  # (..., 1, 1) against (2, 3) poles
        z, s = self._poles()
        d = torch.sqrt(rr**2 + z**2)
        pole = z * (s * d + 1) * torch.exp(-s * d) / d**3  # 001 eq. 17 times z
        return self.alpha_prime / (4 * math.pi) * pole.sum(-2)  # materials.md R(r)

    def length_scales(self) -> tuple[float, float]:
        lo = float(self.z_r.min())
        s = self.sigma_tr
        decay = torch.where(s > 0, 1 / torch.where(s > 0, s, torch.ones_like(s)), self.z_v)
        hi = float(torch.maximum(self.z_v, decay).max())
        return lo, hi

    def total(self) -> torch.Tensor:
        """Closed form (materials.md): ``Rd = α'/2 (1 + e^{−4/3 A √(3(1−α'))}) e^{−√(3(1−α'))}``."""
        s = torch.sqrt(3 * (1 - self.alpha_prime))
        return self.alpha_prime / 2 * (1 + torch.exp(-4 / 3 * self.A * s)) * torch.exp(-s)

    def energy_beyond(self, rho: torch.Tensor | float) -> torch.Tensor:
        """``∫_ρ^∞ 2πr R(r) dr`` per channel, ``(..., 3)``: ``α'/2 Σ z e^{−σD}/D`` (closed form).

        Args:
            rho: radius in mm, >= 0, any shape.
        """
        rt = as_r(rho).abs()[..., None, None]
        z, s = self._poles()
        return self.alpha_prime / 2 * (z * pole_energy_beyond(rt, s, z)).sum(-2)

    def preintegrated(self, x: torch.Tensor | float) -> torch.Tensor:
        """Closed form ``a_p(x) = α'/(4π) Σ z · 2σK₁(σρ)/ρ``, ``ρ = √(x² + z²)`` (module doc)."""
        xt = as_r(x)
        z, s = self._poles()
        val = pole_preintegrated(xt[..., None, None], s, z)
        return self.alpha_prime / (4 * math.pi) * (z * val).sum(-2)

    def second_moment(self) -> torch.Tensor:
        z, s = self._poles()
        pos = self.sigma_tr > 0
        s_safe = torch.where(s > 0, s, torch.ones_like(s))
        # ∫ x² a_p dx / Rd = π ∫ r³ R dr / Rd = Σ z e^{−σz}/σ / Σ e^{−σz}   (module doc)
        closed = (z * torch.exp(-s * z) / s_safe).sum(0) / torch.exp(-s * z).sum(0)
        if bool(pos.all()):
            return closed
        # σ = 0: ∫_0^ρ r³ z/d³ dr = zD − 2z² + z³/D, D = √(ρ² + z²), truncated at radius()
        rho = self.radius()
        big_d = torch.sqrt(rho**2 + z**2)
        # π ∫ r³ R dr / Rd with Rd = α' (σ = 0): (α'/4) Σ (...) / α'
        trunc = (z * big_d - 2 * z**2 + z**3 / big_d).sum(0) / 4
        return torch.where(pos, closed, trunc)

    def radius(self, tol: float = 1e-4) -> float:
        """Support radius (mm): see the class docstring (closed form, exact for σ_tr = 0)."""
        tol = check_scalar("tol", tol, 0.0, 1.0, low_inclusive=False, high_inclusive=False)
        total = self.total()
        peak = self.evaluate(torch.zeros((), dtype=torch.float64))

        def excess(rho: float) -> float:
            rt = torch.tensor(rho, dtype=torch.float64)
            e = (self.energy_beyond(rt) / total - tol).max()
            p = (self.evaluate(rt) / peak - tol).max()  # R is decreasing in r
            return float(torch.maximum(e, p))

        lo, hi = self.length_scales()
        b = hi
        while excess(b) > 0:
            b *= 2.0
            if b > 1e12:  # unreachable for valid inputs: energy beyond ρ ≤ O(z/ρ)
                raise ValueError(f"radius did not converge for tol={tol:g}")
        if excess(0.0) <= 0:
            return 0.0
        return float(scipy.optimize.brentq(excess, 0.0, b, xtol=1e-12 * b, rtol=1e-12))

    def as_numpy_channel(self, channel: int) -> tuple[float, float, float, float]:
        """``(α', σ_tr, z_r, z_v)`` of one channel as floats (for scalar quadrature oracles)."""
        return (
            float(self.alpha_prime[channel]),
            float(self.sigma_tr[channel]),
            float(self.z_r[channel]),
            float(self.z_v[channel]),
        )
