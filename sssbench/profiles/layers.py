"""Layer composition with profiles as polynomials over powers of one Gaussian (001 §4, eq. 11–15).

Every profile of a slab (reflectance ``R^±``, transmittance ``T^±``) is a linear combination
``Σ_k a_k G(k v)`` of the powers ``G(v)^{*k} = G(kv)`` of one narrow Gaussian (001 eq. 14–15;
``G(0) = δ`` is allowed as ``k = 0``, the identity of convolution, e.g. a transparent layer).
Since ``G(iv) * G(jv) = G((i+j)v)`` (001 eq. 11), 2D convolution is polynomial multiplication
of the coefficient vectors (001 eq. 12), and the Kubelka–Munk series of 001 eq. 3–5 becomes

* ``T12⁺ = T1⁺ T2⁺ S``,  ``R12⁺ = R1⁺ + T1⁺ R2⁺ T1⁻ S``,
* ``T12⁻ = T2⁻ T1⁻ S``,  ``R12⁻ = R2⁻ + T2⁻ R1⁻ T2⁺ S``,  with ``S = Σ_n (R2⁺ R1⁻)^n``

(polynomials commute, so one series serves all four). ``S`` is summed until the energy still
missing from the series is below ``eps`` (001 eq. 13): with totals ``ρ = R2d⁺ R1d⁻`` (sums of
coefficients, each ``G`` has unit integral, 001 eq. 8) the tail after ``n`` terms is
``ρ^{n+1}/(1 − ρ)``; for the worst of the four products (``T1d⁺ T2d⁺`` etc.) it must be below
``eps`` in every channel. Convergence needs ``ρ < 1``; as ``ρ → 1`` the number of terms grows
like ``log(eps)/log(ρ)``, so it is capped by ``max_terms`` and a :class:`ValueError` says so
instead of looping.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy import optimize

from sssbench._checks import check_int, check_magnitude, check_scalar, check_tensor
from sssbench.profiles.base import Profile
from sssbench.profiles.fit import _gauss_matrix, _radial_nodes
from sssbench.profiles.sum_of_gaussians import SumOfGaussians

__all__ = ["Layer", "compose_layers", "fit_powers_of_gaussian", "poly_to_sog", "poly_multiply"]


def _check_poly(name: str, value: object) -> torch.Tensor:
    if isinstance(value, torch.Tensor) and not value.is_floating_point():
        value = value.double()
    check_tensor(name, value, ndim=2)
    if value.shape[1] != 3 or value.shape[0] < 1:
        raise ValueError(
            f"{name} must have shape (K, 3): coefficients of G(kv), k = 0..K-1, per channel; "
            f"got {tuple(value.shape)}"
        )
    return value.double()


@dataclass
class Layer:
    """A slab's four profiles as coefficients over ``{G(0)=δ, G(v), G(2v), ...}``, ``(K, 3)``.

    Attributes:
        r_plus: reflectance from above (``R⁺``).
        r_minus: reflectance from below (``R⁻``).
        t_plus: transmittance downward (``T⁺``).
        t_minus: transmittance upward (``T⁻``).
        v: the base variance in mm² shared by all layers being composed.
    """

    r_plus: torch.Tensor
    r_minus: torch.Tensor
    t_plus: torch.Tensor
    t_minus: torch.Tensor
    v: float

    def __post_init__(self) -> None:
        for n in ("r_plus", "r_minus", "t_plus", "t_minus"):
            setattr(self, n, _check_poly(n, getattr(self, n)))
        self.v = check_magnitude("v", self.v, "variance")

    def profile(self, which: str = "r_plus") -> SumOfGaussians:
        """One of the four profiles as a :class:`SumOfGaussians` (``δ`` terms are dropped)."""
        if which not in ("r_plus", "r_minus", "t_plus", "t_minus"):
            raise ValueError(
                f"which must be one of r_plus, r_minus, t_plus, t_minus, got {which!r}"
            )
        return poly_to_sog(getattr(self, which), self.v)


def poly_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """2D convolution of two profiles over powers of ``G(v)`` (001 eq. 11–12), ``(Ka+Kb−1, 3)``."""
    out = np.stack([np.convolve(a[:, c].numpy(), b[:, c].numpy()) for c in range(3)], 1)
    return torch.from_numpy(out)


def _add(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    n = max(a.shape[0], b.shape[0])
    out = torch.zeros(n, 3, dtype=torch.float64)
    out[: a.shape[0]] += a
    out[: b.shape[0]] += b
    return out


def poly_to_sog(coeffs: torch.Tensor, v: float) -> SumOfGaussians:
    """``Σ_{k>=1} a_k G(kv)`` as a :class:`SumOfGaussians` (001 eq. 15); the δ term (k = 0)
    has no Gaussian form and must be zero."""
    coeffs = _check_poly("coeffs", coeffs)
    v = check_magnitude("v", v, "variance")
    if bool((coeffs[0] != 0).any()):
        raise ValueError(
            f"coeffs[0] (the δ term) must be 0 to form a SumOfGaussians, got {coeffs[0].tolist()}"
        )
    k = torch.arange(1, coeffs.shape[0], dtype=torch.float64)
    if k.numel() == 0:
        return SumOfGaussians(
            torch.tensor([v], dtype=torch.float64), torch.zeros(1, 3, dtype=torch.float64)
        )
    return SumOfGaussians(k * v, coeffs[1:].clone())


def fit_powers_of_gaussian(profile: Profile, v: float, degree: int) -> torch.Tensor:
    """Non-negative least-squares coefficients of ``profile`` over ``{G(v), ..., G(degree·v)}``
    (001 eq. 14–15),
    minimising 001 eq. 6 per channel, ``(degree + 1, 3)`` with a zero δ term.

    Args:
        profile: any radial profile.
        v: base variance in mm² (001 §5: no more than the squared minimum mean free path).
        degree: highest power, in [1, 4096].
    """
    if not isinstance(profile, Profile):
        raise TypeError(f"profile must be a sssbench Profile, got {type(profile).__name__}")
    v = check_magnitude("v", v, "variance")
    degree = check_int("degree", degree, 1, 4096)
    lo, hi = profile.length_scales()
    r, w = _radial_nodes(min(lo, math.sqrt(v)), max(hi, math.sqrt(degree * v)), 80, 12)
    scale = np.sqrt(r * w)
    m = scale[:, None] * _gauss_matrix(r, v * np.arange(1, degree + 1))
    y = scale[:, None] * profile.evaluate(torch.from_numpy(r)).numpy()
    # non-negative least squares per channel: the powers of one Gaussian are nearly collinear
    # for large degrees, and unconstrained least squares answers with coefficients of 1e7-1e8
    # and alternating signs (measured on a dipole from degree 20), which the convolution
    # powers of eq. 11-15 then amplify to overflow. A reflectance profile is non-negative, so
    # its expansion is constrained to be too.
    coef = np.stack([optimize.nnls(m, y[:, c])[0] for c in range(y.shape[1])], 1)
    return torch.cat([torch.zeros(1, 3, dtype=torch.float64), torch.from_numpy(coef)], 0)


def compose_layers(
    top: Layer, bottom: Layer, *, eps: float = 1e-6, max_terms: int = 10_000
) -> Layer:
    """Profiles of two slabs placed together (001 §3 eq. 3–5, §4 eq. 11–15; module doc).

    Args:
        top: slab 1 (light enters it first going down).
        bottom: slab 2 (for a semi-infinite bottom layer pass zero transmittances).
        eps: tolerated energy missing from the truncated series (001 eq. 13), > 0.
        max_terms: cap on the number of series terms; more needed raises ``ValueError``.

    Returns:
        The combined :class:`Layer` (same ``v``).

    Raises:
        ValueError: if the layers' ``v`` differ, if ``R2d⁺ R1d⁻ >= 1`` in some channel (the
            Kubelka–Munk series diverges), or if more than ``max_terms`` terms would be needed.
    """
    if not isinstance(top, Layer) or not isinstance(bottom, Layer):
        raise TypeError(
            f"top and bottom must be Layer, got {type(top).__name__}, {type(bottom).__name__}"
        )
    eps = check_scalar("eps", eps, 0.0, None, low_inclusive=False)
    max_terms = check_int("max_terms", max_terms, 1, 10_000_000)
    if not math.isclose(top.v, bottom.v, rel_tol=1e-12):
        raise ValueError(
            f"top.v and bottom.v must be equal (one Gaussian basis), got {top.v}, {bottom.v}"
        )
    p = poly_multiply(bottom.r_plus, top.r_minus)  # R2⁺ R1⁻
    rho = p.sum(0)  # total diffuse response of each channel (001 eq. 8)
    if bool((rho.abs() >= 1).any()):
        raise ValueError(
            f"R2d+ * R1d- must be < 1 in every channel for the inter-slab series to converge "
            f"(001 eq. 5), got {rho.tolist()}"
        )
    # the largest prefactor multiplying S, so the missing energy of every output is < eps
    pre = torch.stack(
        [
            (top.t_plus.sum(0) * bottom.t_plus.sum(0)).abs(),
            (top.t_plus.sum(0) * bottom.r_plus.sum(0) * top.t_minus.sum(0)).abs(),
            (bottom.t_minus.sum(0) * top.t_minus.sum(0)).abs(),
            (bottom.t_minus.sum(0) * top.r_minus.sum(0) * bottom.t_plus.sum(0)).abs(),
        ]
    ).amax(0)
    # 001 eq. 13: pre · |ρ|^{n+1} / (1 − |ρ|) < eps after n products
    need = 0
    for c in range(3):
        q = float(rho[c].abs())
        if float(pre[c]) == 0 or q == 0:
            continue
        n = math.log(eps * (1 - q) / float(pre[c])) / math.log(q) - 1
        need = max(need, math.ceil(max(n, 0.0)))
    if need > max_terms:
        raise ValueError(
            f"the inter-slab series needs {need} terms for eps={eps:g} with R2d+ R1d- = "
            f"{rho.tolist()} (close to 1 converges slowly), more than max_terms={max_terms}; "
            "raise max_terms or eps"
        )
    s = torch.zeros(1, 3, dtype=torch.float64)
    s[0] = 1.0  # δ: the n = 0 term
    term = s.clone()
    for _ in range(need):
        term = poly_multiply(term, p)
        s = _add(s, term)
    t12p = poly_multiply(poly_multiply(top.t_plus, bottom.t_plus), s)
    r12p = _add(
        top.r_plus,
        poly_multiply(poly_multiply(poly_multiply(top.t_plus, bottom.r_plus), top.t_minus), s),
    )
    t12m = poly_multiply(poly_multiply(bottom.t_minus, top.t_minus), s)
    r12m = _add(
        bottom.r_minus,
        poly_multiply(poly_multiply(poly_multiply(bottom.t_minus, top.r_minus), bottom.t_plus), s),
    )
    return Layer(r12p, r12m, t12p, t12m, top.v)
