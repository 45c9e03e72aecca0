"""LDR-FLIP in torch.

The per-pixel LDR-FLIP error map of Andersson et al. 2020, "FLIP: A Difference Evaluator for
Alternating Images" (HPG 2020; ``FLIP`` below, equations numbered as in the paper), with every
constant, normalisation and border rule of NVIDIA's reference code, FLIP 1.7 (``FLIP.h`` of
NVlabs/flip, the single-header C++ code the ``flip-evaluator`` wheel wraps; functions cited as
``FLIP.h: name``). :func:`flip_ldr_map` computes what
``flip_evaluator.evaluate(reference, test, "LDR", inputsRGB=True, applyMagma=False,
computeMeanError=False, parameters={"ppd": ppd})`` returns, in float32 as FLIP does, with
FLIP's operations in FLIP's order: every filter tap is a product rounded to float32 and then
added, from the first tap to the last (no fused multiply-add), and ``powf``/``expf`` are
computed in float64 and rounded once. What is left are last-bit
differences of ``powf`` in rare values (glibc's is at most 0.82 ulp off; here the float64
value is rounded once), which FLIP itself magnifies (``HyAB ** 0.7`` of a distance of an ulp
or two; the square root of the feature filters' rounding noise on flat areas): max
|difference| 2.7e-5 measured, at a few pixels of a map (see :func:`flip_ldr_map`).

Why float32 and not float64: FLIP's map on flat or nearly equal areas *is* float32 rounding
noise, magnified (a flat 1x1 image pair: FLIP's feature difference is ~1e-4 of pure noise);
float64 would compute the exact value instead, 8.7e-6 away from FLIP's on a 1x1 pair, where
the float32 emulation is within 1.5e-8.

Every spatial filter is a separable sum of shifted slices of an edge-replicated (FLIP's
clamp-to-edge) tensor, ``acc = acc + w[k] * x[..., k:k + W]`` for ``k`` in order: the value
at a pixel depends only on its filter window and is computed by the same float32 operations at
every position (no elementwise function whose vectorised and scalar paths round differently),
so a crop's map equals the whole image's bit for bit wherever the crop holds the pixel's
window (:func:`sssbench.score.metrics.flip_map_over`; ``tests/score/test_flip_crop.py``). The
map is computed in strips of rows, each through both pipelines, so that a strip's
intermediates stay in the cache; the strips change no value. The pipelines run on each image
alone up to their last per-image planes (:func:`flip_planes`: L*, a*, b*, edge, point) and
only then compare the two (:func:`flip_from_planes`), so a reference's planes can be computed
once for every image compared with it, bit for bit the same map.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch

__all__ = ["filter_radii", "flip_from_planes", "flip_ldr_map", "flip_planes"]

_F = np.float32

# FLIP.h: xFLIPConstants (FLIP §3-4: q_c, p_c, p_t, w, q_f)
_GQC, _GPC, _GPT, _GW, _GQF = _F(0.7), _F(0.4), _F(0.95), _F(0.082), _F(0.5)
_PI = _F(3.14159265358979)  # FLIP.h: FLIP::PI (float)
_PI_SQ = _F(_PI * _PI)
# FLIP.h: xGaussianConstants (FLIP eq. 2 and Table 1: a1, b1, a2, b2 for A, RG, BY)
_A1 = (_F(1.0), _F(1.0), _F(34.1))
_B1 = (_F(0.0047), _F(0.0053), _F(0.04))
_A2 = (_F(0.0), _F(0.0), _F(13.5))
_B2 = (_F(1.0e-5), _F(1.0e-5), _F(0.025))
# FLIP.h: DEFAULT_ILLUMINANT / INV_DEFAULT_ILLUMINANT (D65 white, XYZ)
_ILLUM = (_F(0.950428545), _F(1.0), _F(1.088900371))
_INV_ILLUM = (_F(1.052156925), _F(1.0), _F(0.918357670))
# FLIP.h: color3::LinearRGBToXYZ (sRGB primaries, D65), entries as float quotients
_RGB2XYZ = tuple(
    tuple(_F(n) / _F(d) for n in row)
    for row, d in (
        ((10135552.0, 8788810.0, 4435075.0), 24577794.0),
        ((2613072.0, 8788810.0, 887015.0), 12288897.0),
        ((1425312.0, 8788810.0, 70074185.0), 73733382.0),
    )
)
# FLIP.h: color3::XYZToLinearRGB
_XYZ2RGB = (
    (_F(3.241003275), _F(-1.537398934), _F(-0.498615861)),
    (_F(-0.969224334), _F(1.875930071), _F(0.041554224)),
    (_F(0.055639423), _F(-0.204011202), _F(1.057148933)),
)
# FLIP.h: color3::XYZToCIELab (CIE 1976 L*a*b*; delta = 6/29)
_DELTA = _F(6.0) / _F(29.0)
_DELTA_CUBE = _F(_DELTA * _F(_DELTA * _DELTA))
_LAB_FACTOR = _F(1.0) / _F(_F(3.0) * _F(_DELTA * _DELTA))
_LAB_TERM = _F(4.0) / _F(29.0)


def _expf(x: np.float32) -> np.float32:
    """``expf``: float32 exp, computed in float64 and rounded once (as glibc's ``expf``,
    which is correctly rounded but in rare ties)."""
    return _F(np.exp(np.float64(x)))


def _powf(x: np.float32, y: np.float32) -> np.float32:
    """``powf`` with a float32 exponent, computed in float64 and rounded once (as glibc's)."""
    return _F(np.float64(x) ** np.float64(_F(y)))


def _rgb_to_xyz_scalar(rgb: tuple[np.float32, ...]) -> tuple[np.float32, ...]:
    """FLIP.h: color3::LinearRGBToXYZ on one float32 colour."""
    return tuple(_F(_F(m[0] * rgb[0] + m[1] * rgb[1]) + m[2] * rgb[2]) for m in _RGB2XYZ)


def _lab_scalar(xyz: tuple[np.float32, ...]) -> tuple[np.float32, ...]:
    """FLIP.h: color3::XYZToCIELab on one float32 colour."""
    f = []
    for c, inv in zip(xyz, _INV_ILLUM, strict=True):
        t = _F(c * inv)
        cube_root = t > _DELTA_CUBE
        f.append(_powf(t, _F(1.0) / _F(3.0)) if cube_root else _F(_LAB_FACTOR * t + _LAB_TERM))
    lum = _F(_F(116.0) * f[1] - _F(16.0))
    return (lum, _F(_F(500.0) * (f[0] - f[1])), _F(_F(200.0) * (f[1] - f[2])))


@functools.cache
def _cmax() -> tuple[float, float]:
    """``(cmax, p_c * cmax)``: the largest HyAB distance of Hunt-adjusted colours in the sRGB
    gamut (green vs blue) to the power ``q_c`` (FLIP §3.2, eq. 5; FLIP.h:
    color3::computeMaxDistance), and the knee of the power remapping (FLIP eq. 6)."""
    hunt = []
    for rgb in ((_F(0), _F(1), _F(0)), (_F(0), _F(0), _F(1))):
        lab = _lab_scalar(_rgb_to_xyz_scalar(rgb))
        k = _F(_F(0.01) * lab[0])  # FLIP eq. 4 (Hunt): 0.01 L* a*, 0.01 L* b*
        hunt.append((lab[0], _F(k * lab[1]), _F(k * lab[2])))
    (l1, a1, b1), (l2, a2, b2) = hunt
    da, db = _F(a1 - a2), _F(b1 - b2)
    hyab = _F(abs(_F(l1 - l2)) + np.sqrt(_F(da * da + db * db)))  # FLIP eq. 3 (HyAB)
    cmax = _powf(hyab, _GQC)
    return float(cmax), float(_F(_GPC * cmax))


def filter_radii(ppd: float) -> tuple[int, int]:
    """The radii in pixels of the map's two separable filters at ``ppd`` pixels per degree,
    ``(colour, feature)``, each computed in float32 as FLIP 1.7 computes it (the map at a
    pixel reads its inputs no farther than the larger):

    * the colour CSF filter, FLIP.h: calculateSpatialFilterRadius:
      ``ceil(3 sqrt(b_max / (2 pi^2)) ppd)``, ``b_max = 0.04`` (10 px at 67 ppd);
    * the feature filters, FLIP.h: setFeatureFilter: ``ceil(3 sigma)``,
      ``sigma = 0.5 w ppd``, ``w = 0.082`` degrees (9 px at 67 ppd)."""
    ppd32 = _F(ppd)
    b_max = max(*_B1, *_B2)
    colour = np.ceil(_F(_F(_F(3.0) * np.sqrt(_F(b_max / _F(_F(2.0) * _PI_SQ)))) * ppd32))
    feature = np.ceil(_F(_F(3.0) * _F(_F(_F(0.5) * _GW) * ppd32)))
    return int(colour), int(feature)


@functools.cache
def _spatial_filters(ppd: float) -> tuple[np.ndarray, np.ndarray]:
    """The colour pipeline's separable CSF filters (FLIP §3.1, eq. 2; FLIP.h:
    setSpatialFilters, misc/separatedConvolutions.pdf): ``(4, 2r+1)`` float32 rows
    ``[Y, Cx, Cz1, Cz2]`` (the blue-yellow filter is the sum of two separable Gaussians, so its
    2D filter is ``Cz1 x Cz1 + Cz2 x Cz2``) and the radius ``r``."""
    r = filter_radii(ppd)[0]
    dx = _F(_F(1.0) / _F(ppd))
    taps = np.zeros((4, 2 * r + 1), dtype=_F)
    sums = [_F(0.0)] * 4
    for i in range(2 * r + 1):
        ix = _F(_F(i - r) * dx)
        x2 = _F(ix * ix)

        def e(b: np.float32, x2: np.float32 = x2) -> np.float32:
            return _expf(_F(_F(-_PI_SQ * x2) / b))

        g_y = _F(_F(_A1[0] * np.sqrt(_F(_PI / _B1[0]))) * e(_B1[0]))  # FLIP eq. 2, a sqrt(pi/b)
        g_cx = _F(_F(_A1[1] * np.sqrt(_F(_PI / _B1[1]))) * e(_B1[1]))
        # FLIP.h: GaussianSqrt: sqrt(a sqrt(pi/b)) exp(-pi^2 x^2 / b), one factor of a
        # separated 2D Gaussian a (pi/b) exp(-pi^2 (x^2+y^2) / b)
        g_z1 = _F(np.sqrt(_F(_A1[2] * np.sqrt(_F(_PI / _B1[2])))) * e(_B1[2]))
        g_z2 = _F(np.sqrt(_F(_A2[2] * np.sqrt(_F(_PI / _B2[2])))) * e(_B2[2]))
        for c, g in enumerate((g_y, g_cx, g_z1, g_z2)):
            taps[c, i] = g
            sums[c] = _F(sums[c] + g)
    # FLIP.h: setSpatialFilters: Y and Cx sum to 1; the Cz pair so that the 2D sum is 1
    norm_y, norm_cx = _F(_F(1.0) / sums[0]), _F(_F(1.0) / sums[1])
    norm_z = _F(_F(1.0) / np.sqrt(_F(_F(sums[2] * sums[2]) + _F(sums[3] * sums[3]))))
    taps[0] = taps[0] * norm_y
    taps[1] = taps[1] * norm_cx
    taps[2] = taps[2] * norm_z
    taps[3] = taps[3] * norm_z
    taps.setflags(write=False)
    return taps, r


@functools.cache
def _feature_filter(ppd: float) -> tuple[np.ndarray, int]:
    """The feature pipeline's separable filters (FLIP §4, eqs. 7-8; FLIP.h: setFeatureFilter):
    ``(3, 2r+1)`` float32 rows ``[g, dg, ddg]`` — the Gaussian of ``sigma = 0.5 w ppd`` summing
    to 1, its first derivative with positive and negative weights each summing to +-1, and its
    second derivative likewise — and the radius ``r = ceil(3 sigma)``."""
    sd = _F(_F(_F(0.5) * _GW) * _F(ppd))
    r = filter_radii(ppd)[1]  # ceil(3 sd)
    taps = np.zeros((3, 2 * r + 1), dtype=_F)
    g_sum = dg_pos = dg_neg = ddg_pos = ddg_neg = _F(0.0)
    for i in range(2 * r + 1):
        x = _F(i - r)
        g = _expf(_F(_F(-_F(x * x)) / _F(_F(_F(2.0) * sd) * sd)))  # FLIP.h: Gaussian(x, sigma)
        dg = _F(-x * g)  # FLIP eq. 7: first derivative (up to a positive factor)
        ddg = _F(_F(_F(_F(x * x) / _F(sd * sd)) - _F(1.0)) * g)  # FLIP eq. 8: second derivative
        g_sum = _F(g_sum + g)
        if dg > 0:
            dg_pos = _F(dg_pos + dg)
        else:
            dg_neg = _F(dg_neg - dg)
        if ddg > 0:
            ddg_pos = _F(ddg_pos + ddg)
        else:
            ddg_neg = _F(ddg_neg - ddg)
        taps[:, i] = (g, dg, ddg)
    for i in range(2 * r + 1):
        g, dg, ddg = taps[:, i]
        taps[:, i] = (
            _F(g / g_sum),
            _F(dg / (dg_pos if dg > 0 else dg_neg)),
            _F(ddg / (ddg_pos if ddg > 0 else ddg_neg)),
        )
    taps.setflags(write=False)
    return taps, r


def _srgb_to_ycxcz(srgb: torch.Tensor) -> torch.Tensor:
    """``(..., 3, H, W)`` sRGB in [0, 1] -> YCxCz, float32.

    The sRGB transfer function inverted (IEC 61966-2-1; FLIP.h: color3::sRGBToLinearRGB),
    clamped to [0, 1] (FLIP.h: evaluate, LDR), to XYZ (FLIP.h: color3::LinearRGBToXYZ) and to
    the opponent space YCxCz (FLIP §3.1; FLIP.h: color3::XYZToYCxCz)."""
    # powf(x, 2.4f) as glibc rounds it: in float64, rounded once (torch's float32 pow is off
    # by an ulp in ~1 % of values, which moves the feature filters' rounding noise)
    powed = _pow32((srgb + 0.055) / 1.055, float(_F(2.4)))  # x ** 2.4 = exp(2.4 log x)
    lin = torch.where(srgb <= 0.04045, srgb / 12.92, powed)
    lin = lin.clamp_(0.0, 1.0)
    r, g, b = lin.unbind(-3)
    x, y, z = (float(m[0]) * r + float(m[1]) * g + float(m[2]) * b for m in _RGB2XYZ)
    x = x * float(_INV_ILLUM[0])
    z = z * float(_INV_ILLUM[2])
    return torch.stack((116.0 * y - 16.0, 500.0 * (x - y), 200.0 * (y - z)), dim=-3)


def _pow32(x: torch.Tensor, y: float | torch.Tensor) -> torch.Tensor:
    """``powf(x, y)`` elementwise for float32 ``x >= 0``: ``exp(y log x)`` in float64, rounded
    once to float32 (as glibc's ``powf`` rounds, but in rare near-ties; ``pow(0, 0) = 1``).

    Not torch's float32 ``pow``: it is an ulp off glibc's in ~10 % of values. float64 ``exp``
    and ``log`` err far below a float32 ulp (and are 2.3x cheaper than float64 ``pow``), but
    torch computes most of a tensor's elements in vectors (SLEEF) and a row's tail, or each
    thread's, one at a time (the C library), and the two may differ by an ulp or two of
    float64. Rounded to float32, that changes a value only where the float64 one lies that
    close to a float32 rounding boundary; so those values (:func:`_near_ties`, about one in
    2^15) are computed again one at a time by Python's ``math`` (the C library's ``log`` and
    ``exp``): every value is then the same function of its input wherever it lies in a
    tensor, and a crop's map is the whole image's bit for bit."""
    if isinstance(y, torch.Tensor) and y.shape != x.shape:
        raise ValueError(f"y must have x's shape {tuple(x.shape)}, got {tuple(y.shape)}")
    x64 = x.double().reshape(-1)  # flat: the near-ties are indexed by position
    y64 = y.double().reshape(-1) if isinstance(y, torch.Tensor) else float(_F(y))
    out = x64.log().mul_(y64).exp_()
    if isinstance(y64, torch.Tensor):
        out = out.nan_to_num_(nan=1.0)  # 0 ** 0 (= exp(0 * -inf)) is 1
    near = _near_ties(out).nonzero().flatten()
    if near.numel():
        xs = x64[near].tolist()
        ys = y64[near].tolist() if isinstance(y64, torch.Tensor) else [y64] * len(xs)
        out[near] = torch.tensor(
            [math.exp(b * math.log(a)) for a, b in zip(xs, ys, strict=True)], dtype=out.dtype
        )
    return out.float().view(x.shape)


#: how close (relative) to a float32 rounding boundary a float64 ``exp(y log x)`` is computed
#: again one at a time (:func:`_pow32`): SLEEF's and the C library's ``log`` and ``exp`` are
#: each within 1.5 ulp of float64, so the two paths differ by at most ``(1.5 |y log x| + 1.5)``
#: ulp = 2^-43.7 relative for ``|y log x| <= 210`` (``x >= 1e-38``, ``y <= 2.4``); 2^-40 leaves
#: a factor 13
_TIE_WINDOW = 2.0**-40


def _near_ties(v: torch.Tensor) -> torch.Tensor:
    """Where float64 ``v`` lies within :data:`_TIE_WINDOW` (relative) of a float32 rounding
    boundary (a midpoint between two adjacent float32 values): where ``v (1 - 2 w)`` and
    ``v (1 + 2 w)`` round to different float32 values (rounding is monotone, so they differ
    exactly when a boundary lies between them). A bool tensor of ``v``'s shape; ``NaN`` is
    never near."""
    w = 2 * _TIE_WINDOW
    return torch.ne(v.mul(1 - w).float(), v.mul(1 + w).float()).logical_and_(v == v)


# Output rows per strip: about this many elements (channels x rows x columns) in a strip's
# filter outputs; measured fastest at 512^2 and 1080p (larger strips miss the cache and fault
# in fresh pages; smaller ones pay torch's per-call overhead and recompute more halo rows).
_STRIP_ELEMENTS = 1 << 20


def _strip_rows(width: int) -> int:
    """Output rows per strip for images ``width`` pixels wide."""
    return max(8, _STRIP_ELEMENTS // (8 * max(1, width)))


def _filter(
    src: torch.Tensor, taps: list[torch.Tensor], out: torch.Tensor, dim: int
) -> torch.Tensor:
    """One pass of a separable filter: ``out = sum_k taps[k] * src.narrow(dim, k, n)`` with
    ``n = out.shape[dim]``, summed in order of ``k`` from 0, each product rounded to float32
    and then added (FLIP.h: the ``ix`` and ``iy`` loops of computeColorDifference and
    computeFeatureDifferenceAndFinalError, which start from 0 and add ``weight * value``:
    the same rounding, bit for bit). ``taps[k]`` broadcasts against the slices (per-channel
    weights); ``src`` holds the ``2r`` extra (replicated) pixels along ``dim``.

    The fused multiply-add (``torch.addcmul``, one pass instead of two) is not used: its
    single rounding moves FLIP's colour difference by up to 4e-5 where the two images differ
    only under a filter's far, tiny taps (the power ``q_c = 0.7`` of a distance of a few
    ulps), against 6e-6 with FLIP's two roundings."""
    n = out.shape[dim]
    torch.mul(src.narrow(dim, 0, n), taps[0], out=out)
    tmp = torch.empty_like(out)
    for k in range(1, len(taps)):
        torch.mul(src.narrow(dim, k, n), taps[k], out=tmp)
        out.add_(tmp)
    return out


def _replicate_border(x: torch.Tensor, r: int) -> None:
    """Fill the ``r``-pixel border of ``x`` ``(..., H + 2r, W + 2r)`` (whose interior holds
    an image) with copies of the image's edge pixels: FLIP's clamp-to-edge border (FLIP.h:
    ``Min(Max(0, x + ix), w - 1)`` in every filter loop)."""
    if r == 0:
        return
    x[..., :r] = x[..., r : r + 1]
    x[..., -r:] = x[..., -r - 1 : -r]
    x[..., :r, :] = x[..., r : r + 1, :]
    x[..., -r:, :] = x[..., -r - 1 : -r, :]


def _columns(taps: np.ndarray, shape: tuple[int, ...]) -> list[torch.Tensor]:
    """Per tap ``k``, the ``(C, K)`` float32 ``taps[:, k]`` shaped to broadcast as ``shape``
    (``C`` in the channel dimension, 1 elsewhere)."""
    t = torch.from_numpy(np.array(taps, dtype=np.float32)).reshape(*shape, taps.shape[-1])
    return list(t.unbind(-1))


def _color_strip(
    src: torch.Tensor, taps: list[torch.Tensor], r: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """FLIP's colour pipeline (FLIP §3; FLIP.h: computeColorDifference) on a strip, up to
    what each image gives on its own: ``src`` ``(B, 4, n + 2r, W + 2r)`` holds the padded
    YCxCz rows ``[Y, Cx, Cz, Cz]`` of B images, ``taps`` the ``(1, 4, 1, 1)`` CSF weights
    ``[Y, Cx, Cz1, Cz2]`` per tap. Returns ``L*``, and ``a*``, ``b*`` scaled by ``0.01 L*``
    (FLIP eq. 4), each ``(B, n, W)``; :func:`_color_difference` compares two images'."""
    nb, _, rows, wp = src.shape
    n, w = rows - 2 * r, wp - 2 * r
    mid = _filter(src, taps, torch.empty(nb, 4, rows, w), -1)  # along x
    out = _filter(mid, taps, torch.empty(nb, 4, n, w), -2)  # along y
    y, cx, cz = out[:, 0], out[:, 1], out[:, 2].add_(out[:, 3])  # FLIP.h: Cz.x + Cz.y
    # FLIP.h: color3::YCxCzToXYZ (inverse of FLIP §3.1's opponent transform)
    yy = y.add_(16.0).div_(116.0)
    xyz = (
        cx.div_(500.0).add_(yy).mul_(float(_ILLUM[0])),
        yy,
        torch.sub(yy, cz.div_(200.0)).mul_(float(_ILLUM[2])),
    )
    # FLIP.h: color3::XYZToLinearRGB, then clamp to [0, 1] (FLIP §3.1: into the sRGB gamut)
    rgb = [
        (xyz[0] * float(m[0])).add_(xyz[1] * float(m[1])).add_(xyz[2] * float(m[2])).clamp_(0, 1)
        for m in _XYZ2RGB
    ]
    # FLIP.h: color3::LinearRGBToXYZ then color3::XYZToCIELab (CIE 1976 L*a*b*, D65 white)
    f = []
    for c, m in enumerate(_RGB2XYZ):
        t = (rgb[0] * float(m[0])).add_(rgb[1] * float(m[1])).add_(rgb[2] * float(m[2]))
        if c != 1:
            t.mul_(float(_INV_ILLUM[c]))  # (the Y white is 1)
        cube = _pow32(t, float(_F(1.0) / _F(3.0)))
        f.append(
            torch.where(
                t > float(_DELTA_CUBE), cube, t.mul_(float(_LAB_FACTOR)).add_(float(_LAB_TERM))
            )
        )
    lum = f[1].mul(116.0).sub_(16.0)
    k = lum * 0.01  # FLIP eq. 4 (Hunt): a* and b* scaled by 0.01 L*
    a = torch.sub(f[0], f[1]).mul_(500.0).mul_(k)
    b = torch.sub(f[1], f[2]).mul_(200.0).mul_(k)
    return lum, a, b


def _color_difference(lum: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """FLIP's remapped colour difference in [0, 1] of the planes of :func:`_color_strip` of
    two images (the leading axis of each: reference, test), ``(..., W)`` (consumes ``a``
    and ``b``)."""
    da, db = a[0].sub_(a[1]), b[0].sub_(b[1])
    # FLIP eq. 3 (HyAB): |dL| + sqrt(da^2 + db^2), then to the power q_c (FLIP eq. 5)
    hyab = torch.sub(lum[0], lum[1]).abs_().add_(da.mul_(da).add_(db.mul_(db)).sqrt_())
    cd = _pow32(hyab, float(_GQC))
    cmax, pccmax = _cmax()
    # FLIP eq. 6: [0, p_c cmax) -> [0, p_t), [p_c cmax, cmax] -> [p_t, 1]
    low = cd * float(_F(_GPT / _F(pccmax)))
    scale = float(_F(_F(cmax) - _F(pccmax)))
    high = (cd - pccmax).div_(scale).mul_(float(_F(1.0) - _GPT)).add_(float(_GPT))
    return torch.where(cd < pccmax, low, high)


def _feature_strip(
    src: torch.Tensor, taps_x: list[torch.Tensor], taps_y: list[torch.Tensor], r: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """FLIP's feature pipeline (FLIP §4; FLIP.h: computeFeatureDifferenceAndFinalError) on a
    strip, up to what each image gives on its own: ``src`` ``(B, 1, n + 2r, W + 2r)`` holds
    the padded normalised achromatic rows of B images; ``taps_x`` the ``(1, 3, 1, 1)`` weights
    ``[dg, ddg, g]`` and ``taps_y`` the ``(1, 4, 1, 1)`` weights ``[g, g, dg, ddg]`` per tap.
    Returns the edge and point detectors' magnitudes (FLIP eq. 9), each ``(B, n, W)``;
    :func:`_feature_difference` compares two images'."""
    nb, _, rows, wp = src.shape
    n, w = rows - 2 * r, wp - 2 * r
    # along x: [dx, ddx, Gaussian-filtered] (FLIP.h: 1st and 2nd derivative, Gaussian)
    mid = _filter(src, taps_x, torch.empty(nb, 3, rows, w), -1)
    # along y: [dx, ddx, gf, gf] by [g, g, dg, ddg] -> dx, ddx, dy, ddy
    out = _filter(mid[:, (0, 1, 2, 2)], taps_y, torch.empty(nb, 4, n, w), -2)
    dx, ddx, dy, ddy = out.unbind(1)
    edge = dx.mul_(dx).add_(dy.mul_(dy)).sqrt_()  # FLIP eq. 9: the edge detector's magnitude
    point = ddx.mul_(ddx).add_(ddy.mul_(ddy)).sqrt_()  # FLIP eq. 9: the point detector's
    return edge, point


def _feature_difference(edge: torch.Tensor, point: torch.Tensor) -> torch.Tensor:
    """FLIP's feature difference in [0, 1] of the planes of :func:`_feature_strip` of two
    images (the leading axis of each: reference, test), ``(..., W)`` (consumes them)."""
    diff = torch.maximum(edge[0].sub_(edge[1]).abs_(), point[0].sub_(point[1]).abs_())
    # FLIP eq. 10: (max(|de|, |dp|) / sqrt(2)) ** q_f, q_f = 0.5 (powf(x, 0.5) = sqrt(x))
    return diff.mul_(float(_F(1.0) / np.sqrt(_F(2.0)))).sqrt_()


def flip_ldr_map(reference: torch.Tensor, test: torch.Tensor, ppd: float) -> np.ndarray:
    """The LDR-FLIP error map of two displayed sRGB images (FLIP eq. 11:
    ``deltaE_c ** (1 - deltaE_f)``), as NVIDIA's FLIP 1.7 computes it.

    Args:
        reference: ``(3, H, W)`` sRGB in [0, 1] (float32 or float64; read as float32, as
            FLIP reads its inputs).
        test: ``(3, H, W)`` sRGB in [0, 1], the same shape.
        ppd: pixels per degree of visual angle, > 0 (FLIP's default: 67).

    Returns:
        ``(H, W)`` float32 FLIP map in [0, 1] (0 where the images agree within the filters'
        reach).

    Against FLIP 1.7 (``flip_evaluator``), measured: max |difference| 1.9e-6 on random
    512^2 images, 2.8e-6 at 1080p, 1.6e-6 on random, smooth, saturated, small and
    non-square images at 30, 67 and 120 ppd (``tests/score/test_flip_ldr.py`` asserts
    1e-5); on 42 render maps (7 scenes x PreintegratedSSS / SumOfGaussiansSSS against
    ReferenceSSS x 30, 67, 120 ppd, 128^2) max 2.7e-5, above 1e-5 at no more than 6 pixels
    of a map, mean |difference| <= 2.2e-8 (the tests assert 3e-5); 0 on identical images,
    as FLIP. CPU time, one thread, median of rounds interleaved with FLIP 1.7: 0.074-0.083 s
    against 0.27 s at 512^2 (7 rounds, two runs), 0.63 s against 2.28 s at 1920x1080 (3
    rounds): 3.2-3.7x less (0.061-0.065 s and 0.56 s before :func:`_pow32` recomputed its
    near-ties).

    Raises:
        TypeError: ``reference`` or ``test`` is not a tensor, ``ppd`` not a number.
        ValueError: a shape is not ``(3, H, W)`` or the two differ; ``ppd`` <= 0 or not
            finite.
    """
    if not isinstance(reference, torch.Tensor):
        raise TypeError(f"reference must be a torch.Tensor, got {type(reference).__name__}")
    if not isinstance(test, torch.Tensor):
        raise TypeError(f"test must be a torch.Tensor, got {type(test).__name__}")
    if reference.ndim != 3 or reference.shape[0] != 3 or min(reference.shape[1:]) < 1:
        raise ValueError(f"reference must have shape (3, H, W), got {tuple(reference.shape)}")
    if test.shape != reference.shape:
        raise ValueError(
            f"test must have the reference's shape {tuple(reference.shape)}, "
            f"got {tuple(test.shape)}"
        )
    _check_ppd(ppd)
    with torch.no_grad():
        pair = torch.stack([x.detach().to("cpu") for x in (reference, test)])
        return flip_from_planes(_planes(pair, ppd))


def _check_ppd(ppd: float) -> float:
    if isinstance(ppd, bool) or not isinstance(ppd, (int, float)):
        raise TypeError(f"ppd must be a number, got {type(ppd).__name__}")
    if not math.isfinite(ppd) or ppd <= 0:
        raise ValueError(f"ppd must be a finite number > 0, got {ppd!r}")
    return float(_F(ppd))  # FLIP reads ppd as a float


def flip_planes(image: torch.Tensor, ppd: float) -> torch.Tensor:
    """What FLIP computes from one image alone, ``(5, H, W)`` float32: ``L*``, ``a*`` and
    ``b*`` (scaled by ``0.01 L*``, FLIP eq. 4) of the CSF-filtered image and the edge and
    point detectors' magnitudes (FLIP eq. 9) of its achromatic channel. Two images' planes
    give their map (:func:`flip_from_planes`) bit for bit as :func:`flip_ldr_map`, so a
    sweep can compute a reference's planes once for all its methods.

    Args:
        image: ``(3, H, W)`` sRGB in [0, 1] (read as float32).
        ppd: pixels per degree of visual angle, > 0.
    """
    if not isinstance(image, torch.Tensor):
        raise TypeError(f"image must be a torch.Tensor, got {type(image).__name__}")
    if image.ndim != 3 or image.shape[0] != 3 or min(image.shape[1:]) < 1:
        raise ValueError(f"image must have shape (3, H, W), got {tuple(image.shape)}")
    with torch.no_grad():
        return _planes(image.detach().to("cpu")[None], ppd)[0]


def _planes(images: torch.Tensor, ppd: float) -> torch.Tensor:
    """:func:`flip_planes` of ``(B, 3, H, W)`` images, ``(B, 5, H, W)``: the filters run in
    strips of rows over all B images at once (the strips and the batch change no value:
    every value is the same float32 operations on its own filter window)."""
    ppd = _check_ppd(ppd)
    ctaps, rc = _spatial_filters(ppd)
    ftaps, rf = _feature_filter(ppd)
    nb, _, h, w = images.shape
    step = max(1, _strip_rows(w) * 2 // nb)  # about the same elements per strip
    # the filters' inputs, padded by replication (FLIP's clamp-to-edge): per image the
    # YCxCz channels [Y, Cx, Cz, Cz] (the colour filters [Y, Cx, Cz1, Cz2] read them) and
    # the achromatic channel normalised to [0, 1] (the feature filters read it)
    csrc = torch.empty(nb, 4, h + 2 * rc, w + 2 * rc)
    fsrc = torch.empty(nb, 1, h + 2 * rf, w + 2 * rf)
    for a in range(0, h, step):
        b = min(a + step, h)
        ycc = _srgb_to_ycxcz(images[:, :, a:b].float())
        csrc[:, :, rc + a : rc + b, rc : rc + w] = ycc[:, (0, 1, 2, 2)]
        # FLIP.h: Y / 116 + 16 / 116
        yn = ycc[:, 0].mul_(float(_F(1.0) / _F(116.0))).add_(float(_F(16.0) / _F(116.0)))
        fsrc[:, 0, rf + a : rf + b, rf : rf + w] = yn
    _replicate_border(csrc, rc)
    _replicate_border(fsrc, rf)
    ct = _columns(ctaps, (1, 4, 1, 1))
    fx = _columns(ftaps[(1, 2, 0),], (1, 3, 1, 1))
    fy = _columns(ftaps[(0, 0, 1, 2),], (1, 4, 1, 1))
    out = torch.empty(nb, 5, h, w)
    for a in range(0, h, step):
        b = min(a + step, h)
        lum, sa, sb = _color_strip(csrc[:, :, a : b + 2 * rc], ct, rc)
        edge, point = _feature_strip(fsrc[:, :, a : b + 2 * rf], fx, fy, rf)
        for k, plane in enumerate((lum, sa, sb, edge, point)):
            out[:, k, a:b] = plane
    return out


def flip_from_planes(planes: torch.Tensor) -> np.ndarray:
    """The LDR-FLIP map ``(H, W)`` float32 of two images from their :func:`flip_planes`
    stacked ``(2, 5, H, W)`` (reference, test): FLIP eq. 3–6 (the colour difference), eq.
    10 (the feature difference) and eq. 11 (``deltaE_c ** (1 - deltaE_f)``)."""
    if planes.ndim != 4 or planes.shape[:2] != (2, 5):
        raise ValueError(f"planes must have shape (2, 5, H, W), got {tuple(planes.shape)}")
    p = planes.transpose(0, 1).clone()  # (5, 2, H, W): the differences consume their inputs
    cd = _color_difference(p[0], p[1], p[2])
    fd = _feature_difference(p[3], p[4])
    return _pow32(cd, fd.neg_().add_(1.0)).numpy()  # FLIP eq. 11: cd ** (1 - fd)
