"""The 2012 separable SSS kernel: a stretched base profile plus a delta (002 §3.1 eq. 1).

``s(w, t, f)[x] = p[x · w / (0.001 + f)] · t + δ(x) · (1 − t)`` (002 eq. 1), with ``p`` the red
channel of the d'Eon six-Gaussian skin profile (002 §3.1), per channel strength ``t`` and
falloff ``f``, and a global width ``w`` applied by the pass. Taps follow the 2012 SSSS shader's
kernel construction (002 appendix: "kernels range from -3 to 3"; its kernel builder uses a range
of 2, or 3 above 20 samples, and exponent 2 placement).
"""

from __future__ import annotations

import math

import torch

from sssbench._checks import MAGNITUDES, check_choice, check_int
from sssbench.kernels.artist import _per_channel
from sssbench.kernels.kernel1d import Kernel1D
from sssbench.kernels.sampling import (
    MAX_SAMPLES,
    gaussian_mixture_interval,
    interval_weights,
    tap_positions,
)
from sssbench.profiles.sum_of_gaussians import SOG_TABLES, SumOfGaussians

__all__ = ["JIMENEZ2012_PRESETS", "jimenez2012", "jimenez2012_preset", "QUADRATURES"]

#: name -> parameters. ``table1``: 002 Table 1 (the fit to the skin kernel; ``width`` in the
#: paper's scene units, which it does not state). ``shader_default``: the 2012 SSSS shader's
#: default strength and falloff (its width is a scene parameter, not part of the preset).
JIMENEZ2012_PRESETS: dict[str, dict[str, tuple[float, ...] | float | None]] = {
    "table1": {"strength": (0.78, 0.70, 0.75), "falloff": (0.57, 0.13, 0.08), "width": 0.014},
    "shader_default": {"strength": (0.48, 0.41, 0.28), "falloff": (1.0, 0.37, 0.3), "width": None},
}

QUADRATURES = ("shader", "integrated")

#: tap placement exponent of the 2012 shader's kernel builder (002 appendix)
_EXPONENT = 2.0
#: world length of one kernel unit, in widths, along the vertical axis (see jimenez2012)
_WIDTHS_PER_UNIT = 2.0 / 3.0


def _base_profile(profile: str | SumOfGaussians) -> tuple[torch.Tensor, torch.Tensor]:
    """(variances (J,), red weights (J,)) of the profile without its narrowest Gaussian."""
    if isinstance(profile, str):
        check_choice("profile", profile, sorted(SOG_TABLES))
        profile = SumOfGaussians.from_table(profile)
    elif not isinstance(profile, SumOfGaussians):
        raise TypeError(
            f"profile must be a table name or a SumOfGaussians, got {type(profile).__name__}"
        )
    v = profile.variances
    if v.numel() < 2:
        raise ValueError(
            f"profile must hold at least 2 Gaussians (the narrowest is dropped), got {v.numel()}"
        )
    keep = torch.ones_like(v, dtype=torch.bool)
    keep[int(torch.argmin(v))] = False  # directly bounced light, carried by the strength
    return v[keep], profile.weights[keep, 0]


def jimenez2012(
    strength: object,
    falloff: object,
    samples: int,
    *,
    profile: str | SumOfGaussians = "skin_deon6",
    quadrature: str = "shader",
) -> Kernel1D:
    """Taps of the 2012 separable kernel (002 eq. 1), offsets in units of the pass width.

    Construction, following the 2012 SSSS shader's kernel builder:

    1. base profile ``p(r)``: the radial profile ``R(r)`` (2D Gaussians ``exp(−r²/2v)/(2πv)``)
       of the **red** channel of ``profile``, without its narrowest Gaussian (002 §3.1; that
       one is "directly bounced light" which the strength term carries);
    2. per channel ``c``: ``p_c(x) = p(x / (0.001 + f_c))`` (002 eq. 1; a larger falloff widens
       the channel, and ``f = 0`` does not divide by zero);
    3. ``samples`` taps at ``R · sign(t)|t|²``, ``t`` evenly spaced in [−1, 1], range ``R = 2``
       (``3`` for more than 20 samples), via :func:`~sssbench.kernels.tap_positions`
       (``"power"``, exponent 2);
    4. weights: ``quadrature="shader"`` (default, as the shader) the point value ``p_c`` at the
       tap times the tap's interval width (half the distance to each neighbour; the end taps
       get only their inner half); ``"integrated"`` the exact integral of ``p_c`` over the tap
       interval (:func:`~sssbench.kernels.interval_weights`, tails lumped into the end taps);
       then normalised to sum 1 per channel (a channel whose stretched profile vanishes at
       every tap, e.g. ``f = 0`` with an even ``samples``, collapses onto the centre delta);
    5. strength: the centre tap becomes ``(1 − t_c) + t_c · w_0`` and the others ``t_c · w_i``
       (002 eq. 1's ``δ(x)(1 − t)``); for an even ``samples`` no tap sits on 0, so a tap at 0
       carrying ``1 − t_c`` is inserted (``samples + 1`` taps; the shader instead folds it into
       tap ``samples/2``, off centre).

    Units (a documented choice; the paper leaves them implicit): the returned offsets are
    in **widths**, ready for ``Kernel1D.scaled(width_mm)`` or a pass ``width`` in mm. The shader
    steps ``kernel.a · sssWidth · (d / z) / 3`` in texture coordinates (``d = 1/tan(fov_y/2)``);
    a texture coordinate spans half the projection window, so along the vertical axis one
    kernel unit is ``2/3`` of a width in world units, and we return ``offset = 2/3 · kernel.a``
    (range ±2 widths above 20 samples, ±4/3 otherwise). The shader ignores the aspect ratio, so
    its horizontal pass is wider by it; we use the vertical (fov_y) mapping for both axes.

    Args:
        strength: ``t`` per channel, scalar or ``(3,)`` in [0, 1] (0: no scattering).
        falloff: ``f`` per channel, scalar or ``(3,)`` in [0, 1e6].
        samples: taps before the delta insertion, in [1, MAX_SAMPLES].
        profile: a :data:`~sssbench.profiles.SOG_TABLES` name or a :class:`SumOfGaussians`
            (its red channel is the base profile).
        quadrature: ``"shader"`` or ``"integrated"`` (step 4).

    Returns:
        A :class:`Kernel1D`, offsets in widths, weights summing to 1 per channel.

    Shape:
        offsets ``(K,)``, weights ``(K, 3)`` with ``K = samples`` (odd) or ``samples + 1``.

    Example:
        >>> k = jimenez2012((0.48, 0.41, 0.28), (1.0, 0.37, 0.3), 17)
        >>> len(k), round(k.extent, 4), [round(float(s), 6) for s in k.sum()]
        (17, 1.3333, [1.0, 1.0, 1.0])
    """
    t = _per_channel("strength", strength, 0.0, 1.0)
    f = _per_channel("falloff", falloff, 0.0, MAGNITUDES["factor"][1])
    k = check_int("samples", samples, 1, MAX_SAMPLES)
    check_choice("quadrature", quadrature, QUADRATURES)
    var, wr = _base_profile(profile)
    stretch = 0.001 + f  # 002 eq. 1: p[x / (0.001 + f)]

    rng = 3.0 if k > 20 else 2.0  # 2012 shader kernel builder: RANGE
    centres, edges = tap_positions(k, "power", rng, exponent=_EXPONENT)
    centres = 0.5 * (centres - centres.flip(0))  # exact symmetry, centre tap exactly on 0
    if k == 1:
        w = torch.ones(1, 3, dtype=torch.float64)
    elif quadrature == "shader":
        prev = torch.cat([centres[:1], centres[:-1]])
        nxt = torch.cat([centres[1:], centres[-1:]])
        area = 0.5 * (nxt - prev)  # (w0 + w1) / 2 of the shader
        r = centres[:, None] / stretch  # (K, 3)
        g = torch.exp(-(r[..., None] ** 2) / (2 * var)) / (2 * math.pi * var)  # (K, 3, J)
        w = area[:, None] * (g * wr).sum(-1)
    else:
        # ∫ exp(−(x/f)²/2v)/(2πv) dx = f/√(2πv) · (unit-mass Gaussian of σ = f√v)
        sig = stretch[None, :] * torch.sqrt(var)[:, None]  # (J, 3)
        mass = wr[:, None] * stretch[None, :] / torch.sqrt(2 * math.pi * var)[:, None]
        w = interval_weights(edges, lambda a, b: gaussian_mixture_interval(a, b, sig, mass))
    total = w.sum(0)
    # a channel whose stretched profile vanishes at every tap (f -> 0 with no tap on 0)
    # is narrower than the tap spacing: it collapses onto the centre delta
    empty = ~(total > 0)
    w = torch.where(empty, 0.0, w / torch.where(empty, 1.0, total))
    w = w * t  # 002 eq. 1: p · t
    centre = (1.0 - t) + torch.where(empty, t, 0.0)  # + δ(x)(1 − t)
    if k % 2 == 1:
        w[k // 2] += centre
        offsets = centres
    else:
        half = k // 2
        offsets = torch.cat([centres[:half], centres.new_zeros(1), centres[half:]])
        w = torch.cat([w[:half], centre[None, :], w[half:]])
    return Kernel1D(offsets * _WIDTHS_PER_UNIT, w)


def jimenez2012_preset(
    name: str,
    samples: int,
    *,
    profile: str | SumOfGaussians = "skin_deon6",
    quadrature: str = "shader",
) -> Kernel1D:
    """:func:`jimenez2012` with a preset of :data:`JIMENEZ2012_PRESETS` (``"table1"``,
    ``"shader_default"``); the preset's width is applied by the pass.

    Example:
        >>> len(jimenez2012_preset("table1", 9))
        9
    """
    check_choice("name", name, sorted(JIMENEZ2012_PRESETS))
    p = JIMENEZ2012_PRESETS[name]
    return jimenez2012(p["strength"], p["falloff"], samples, profile=profile, quadrature=quadrature)
