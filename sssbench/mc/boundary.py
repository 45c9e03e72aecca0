"""The smooth dielectric boundary of the walk: exact unpolarised Fresnel reflectance."""

from __future__ import annotations

import torch

__all__ = ["fresnel_dielectric", "normal_specular"]


def fresnel_dielectric(cos_i: torch.Tensor, eta_rel: float) -> torch.Tensor:
    """Unpolarised Fresnel reflectance of a smooth dielectric interface.

    ``eta_rel = n_i / n_t`` (side of incidence over far side): ``η`` for light inside the
    medium hitting air, ``1/η`` for light entering from air. With Snell's law
    ``sin θ_t = eta_rel sin θ_i`` (total internal reflection, F = 1, when it exceeds 1):

        ``r_s = (n_i cos θ_i − n_t cos θ_t)/(n_i cos θ_i + n_t cos θ_t)``,
        ``r_p = (n_t cos θ_i − n_i cos θ_t)/(n_t cos θ_i + n_i cos θ_t)``,
        ``F = (r_s² + r_p²)/2``  (Born & Wolf, *Principles of Optics*, §1.5.2, eq. (21a)).

    Args:
        cos_i: cosine of the angle of incidence, ``|cos θ_i|`` in [0, 1], any shape.
        eta_rel: ``n_i/n_t`` > 0 (1 = index-matched: F = 0).

    Returns:
        ``F`` with the shape and dtype of ``cos_i``.
    """
    c = cos_i.abs().clamp(0.0, 1.0)
    sin_t2 = eta_rel * eta_rel * (1 - c * c)
    tir = sin_t2 >= 1
    cos_t = torch.sqrt((1 - sin_t2).clamp_min(0.0))
    rs = (eta_rel * c - cos_t) / (eta_rel * c + cos_t)
    rp = (c - eta_rel * cos_t) / (c + eta_rel * cos_t)
    f = 0.5 * (rs * rs + rp * rp)
    # grazing incidence without TIR (cos_i = 0, eta_rel < 1) gives 0/0 in r_p: F = 1 there
    return torch.where(tir | (c == 0), torch.ones_like(f), f)


def normal_specular(eta: float) -> float:
    """Fresnel reflectance at normal incidence, ``((η − 1)/(η + 1))²`` (either side)."""
    return ((eta - 1) / (eta + 1)) ** 2
