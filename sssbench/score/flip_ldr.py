"""LDR-FLIP in torch (DESIGN §1: ``sssbench/score/flip_ldr.py``).

The per-pixel LDR-FLIP error map of Andersson et al. 2020, "FLIP: A Difference Evaluator for
Alternating Images" (HPG 2020; ``FLIP`` below, equations numbered as in the paper), with every
constant, normalisation and border rule of NVIDIA's reference code, FLIP 1.7 (``FLIP.h`` of
NVlabs/flip, the single-header C++ code the ``flip-evaluator`` wheel wraps; functions cited as
``FLIP.h: name``). :func:`flip_ldr_map` computes what
``flip_evaluator.evaluate(reference, test, "LDR", inputsRGB=True, applyMagma=False,
computeMeanError=False, parameters={"ppd": ppd})`` returns, in float32 as FLIP does, with the
same operations in the same order at every pixel; it differs from FLIP 1.7 only by the last-bit
differences of the transcendental functions (``exp``, ``pow``) of two maths libraries and the
fused multiply-adds a compiler may form (tolerance: see :func:`flip_ldr_map`).

Every spatial filter is a separable sum of shifted slices of an edge-replicated (FLIP's
clamp-to-edge) tensor, ``acc = acc + w[k] * x[..., k:k + W]`` for ``k`` in order: the value
at a pixel depends only on its filter window and is computed by the same float32 operations at
every position, so a crop's map equals the whole image's bit for bit wherever the crop holds
the pixel's window (:func:`sssbench.score.metrics.flip_map_over`;
``tests/score/test_flip_crop.py``). The image is processed in strips of rows so that each
strip's working set stays in the core's cache; the strips do not change any value.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch

__all__ = ["flip_ldr_map"]

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


def _spatial_radius(ppd: float) -> int:
    """FLIP.h: calculateSpatialFilterRadius: ``ceil(3 sqrt(b_max / (2 pi^2)) ppd)``, float32."""
    b_max = max(*_B1, *_B2)
    return int(np.ceil(_F(_F(_F(3.0) * np.sqrt(_F(b_max / _F(_F(2.0) * _PI_SQ)))) * _F(ppd))))


@functools.cache
def _spatial_filters(ppd: float) -> tuple[np.ndarray, np.ndarray]:
    """The colour pipeline's separable CSF filters (FLIP §3.1, eq. 2; FLIP.h:
    setSpatialFilters, misc/separatedConvolutions.pdf): ``(4, 2r+1)`` float32 rows
    ``[Y, Cx, Cz1, Cz2]`` (the blue-yellow filter is the sum of two separable Gaussians, so its
    2D filter is ``Cz1 x Cz1 + Cz2 x Cz2``) and the radius ``r``."""
    r = _spatial_radius(ppd)
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
    r = int(np.ceil(_F(_F(3.0) * sd)))
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
    base = ((srgb + 0.055) / 1.055).double()
    powed = base.log_().mul_(float(_F(2.4))).exp_().float()  # x ** 2.4 = exp(2.4 log x)
    lin = torch.where(srgb <= 0.04045, srgb / 12.92, powed)
    lin = lin.clamp_(0.0, 1.0)
    r, g, b = lin.unbind(-3)
    x, y, z = (float(m[0]) * r + float(m[1]) * g + float(m[2]) * b for m in _RGB2XYZ)
    x = x * float(_INV_ILLUM[0])
    z = z * float(_INV_ILLUM[2])
    return torch.stack((116.0 * y - 16.0, 500.0 * (x - y), 200.0 * (y - z)), dim=-3)


def _pow32(x: torch.Tensor, y: float | torch.Tensor) -> torch.Tensor:
    """``powf`` elementwise: in float64, rounded once to float32. torch's float32 ``pow``
    takes a vectorised path for most elements and a scalar one for a row's tail, which round
    differently; in float64 both agree to far below a float32 ulp, so the float32 value at a
    pixel does not depend on its position (a crop's map is the whole image's)."""
    y64 = y.double() if isinstance(y, torch.Tensor) else float(_F(y))
    return torch.pow(x.double(), y64).float()


# Elements (channels x rows x columns) per strip: measured fastest at 512^2 and 1080p (the
# per-call overhead of smaller strips costs more than the cache misses of larger ones).
_STRIP_ELEMENTS = 1 << 19


def _strips(n: int, width: int, channels: int) -> list[tuple[int, int]]:
    """Row ranges ``[a, b)`` covering ``0..n`` in strips of about ``_STRIP_ELEMENTS``."""
    rows = max(1, _STRIP_ELEMENTS // max(1, width * channels))
    return [(a, min(a + rows, n)) for a in range(0, n, rows)]


def _separable(
    src: torch.Tensor, taps: torch.Tensor, out: torch.Tensor, dim: int, *, fused: bool
) -> None:
    """One separable pass of a padded ``src`` ``(C, n (+2r), W (+2r))`` into ``out``
    ``(C, n, W)`` along ``dim`` (-2: rows, -1: columns): ``out[c, .., j] = sum_k taps[c, k]
    src[c, .., j + k]``, summed in order of ``k`` from 0 in float32 (FLIP.h: the ``ix`` and
    ``iy`` loops), strip by strip.

    ``fused=False``: each term is rounded, then added (``acc + w * x``, FLIP's arithmetic bit
    for bit); ``fused=True``: one fused multiply-add per term (``torch.addcmul``; half the
    passes, the colour filters only, whose outputs are well conditioned)."""
    k_n = taps.shape[1]
    w = taps.unsqueeze(-1).unsqueeze(-1)  # (C, K, 1, 1)
    for a, b in _strips(out.shape[1], src.shape[2], out.shape[0]):
        acc = out[:, a:b]
        size = b - a if dim == -2 else out.shape[2]
        rows = slice(a, b + (k_n - 1 if dim == -2 else 0))
        part = src[:, rows]
        torch.mul(part.narrow(dim, 0, size), w[:, 0], out=acc)
        tmp = None if fused else torch.empty_like(acc)
        for k in range(1, k_n):
            x = part.narrow(dim, k, size)
            if fused:
                acc.addcmul_(x, w[:, k])
            else:
                torch.mul(x, w[:, k], out=tmp)
                acc.add_(tmp)


def _padded(x: torch.Tensor, r: int) -> torch.Tensor:
    """``(C, H, W)`` -> ``(C, H + 2r, W + 2r)`` with the edge pixels replicated: FLIP's
    clamp-to-edge border (FLIP.h: ``Min(Max(0, x + ix), w - 1)`` in every filter loop)."""
    return torch.nn.functional.pad(x[None], (r, r, r, r), mode="replicate")[0]


def _color_difference(ycc: torch.Tensor, ppd: float) -> torch.Tensor:
    """FLIP's colour pipeline (FLIP §3; FLIP.h: computeColorDifference) on ``ycc`` ``(2, 3, H,
    W)`` (reference, test in YCxCz): the ``(H, W)`` remapped colour difference in [0, 1]."""
    taps, r = _spatial_filters(ppd)
    _, _, h, w = ycc.shape
    # channels: per image [Y, Cx, Cz, Cz], filtered by [Y, Cx, Cz1, Cz2]
    src = _padded(ycc[:, (0, 1, 2, 2)].reshape(8, h, w), r)
    wt = torch.from_numpy(np.tile(taps, (2, 1))).to(ycc.dtype)
    mid = torch.empty(8, h + 2 * r, w, dtype=ycc.dtype)
    _separable(src, wt, mid, -1, fused=True)
    out = torch.empty(8, h, w, dtype=ycc.dtype)
    _separable(mid, wt, out, -2, fused=True)
    out = out.view(2, 4, h, w)
    y, cx = out[:, 0], out[:, 1]
    cz = out[:, 2] + out[:, 3]  # FLIP.h: filteredCz.x + filteredCz.y
    # FLIP.h: color3::YCxCzToXYZ (inverse of FLIP §3.1's opponent transform)
    yy = (y + 16.0) / 116.0
    xyz = ((yy + cx / 500.0) * float(_ILLUM[0]), yy, (yy - cz / 200.0) * float(_ILLUM[2]))
    # FLIP.h: color3::XYZToLinearRGB, then clamp to [0, 1] (FLIP §3.1: into the sRGB gamut)
    rgb = [
        (float(m[0]) * xyz[0] + float(m[1]) * xyz[1] + float(m[2]) * xyz[2]).clamp_(0.0, 1.0)
        for m in _XYZ2RGB
    ]
    # FLIP.h: color3::LinearRGBToXYZ then color3::XYZToCIELab
    f = []
    for c, m in enumerate(_RGB2XYZ):
        t = (float(m[0]) * rgb[0] + float(m[1]) * rgb[1] + float(m[2]) * rgb[2]) * float(
            _INV_ILLUM[c]
        )
        f.append(
            torch.where(
                t > float(_DELTA_CUBE),
                _pow32(t, float(_F(1.0) / _F(3.0))),
                float(_LAB_FACTOR) * t + float(_LAB_TERM),
            )
        )
    lum = 116.0 * f[1] - 16.0
    k = 0.01 * lum  # FLIP eq. 4 (Hunt): a* and b* scaled by 0.01 L*
    a = k * (500.0 * (f[0] - f[1]))
    b = k * (200.0 * (f[1] - f[2]))
    da, db = a[0] - a[1], b[0] - b[1]
    # FLIP eq. 3 (HyAB): |dL| + sqrt(da^2 + db^2), to the power q_c (FLIP eq. 5)
    hyab = (lum[0] - lum[1]).abs_() + torch.sqrt(da * da + db * db)
    cd = _pow32(hyab, float(_GQC))
    cmax, pccmax = _cmax()
    # FLIP eq. 6: [0, p_c cmax) -> [0, p_t), [p_c cmax, cmax] -> [p_t, 1]
    low = cd * float(_F(_GPT / _F(pccmax)))
    high = float(_GPT) + ((cd - pccmax) / float(_F(_F(cmax) - _F(pccmax)))) * float(_F(1.0) - _GPT)
    return torch.where(cd < pccmax, low, high)


def _feature_difference(ycc: torch.Tensor, ppd: float) -> torch.Tensor:
    """FLIP's feature pipeline (FLIP §4; FLIP.h: computeFeatureDifferenceAndFinalError) on
    ``ycc`` ``(2, 3, H, W)``: the ``(H, W)`` feature difference in [0, 1]."""
    taps, r = _feature_filter(ppd)
    _, _, h, w = ycc.shape
    # FLIP.h: the achromatic channel normalised to [0, 1]: Y / 116 + 16 / 116
    yn = ycc[:, 0] * float(_F(1.0) / _F(116.0)) + float(_F(16.0) / _F(116.0))
    g, dg, ddg = torch.from_numpy(taps.copy()).to(ycc.dtype)
    # along x: per image [dg, ddg, g] (FLIP.h: dx, ddx, Gaussian-filtered)
    src = _padded(yn, r)[:, None].expand(2, 3, h + 2 * r, w + 2 * r).reshape(6, h + 2 * r, -1)
    mid = torch.empty(6, h + 2 * r, w, dtype=ycc.dtype)
    _separable(src, torch.stack((dg, ddg, g)).repeat(2, 1), mid, -1, fused=False)
    # along y: per image [dx, ddx, gf, gf] by [g, g, dg, ddg] -> dx, ddx, dy, ddy
    mid = mid.view(2, 3, h + 2 * r, w)[:, (0, 1, 2, 2)].reshape(8, h + 2 * r, w)
    out = torch.empty(8, h, w, dtype=ycc.dtype)
    _separable(mid, torch.stack((g, g, dg, ddg)).repeat(2, 1), out, -2, fused=False)
    dx, ddx, dy, ddy = out.view(2, 4, h, w).unbind(1)
    edge = torch.sqrt(dx * dx + dy * dy)  # FLIP eq. 9: |gradient| of the edge detector
    point = torch.sqrt(ddx * ddx + ddy * ddy)  # FLIP eq. 9: the point detector
    diff = torch.maximum((edge[0] - edge[1]).abs_(), (point[0] - point[1]).abs_())
    # FLIP eq. 10: (max(|de|, |dp|) / sqrt(2)) ** q_f
    return torch.sqrt(float(_F(1.0) / np.sqrt(_F(2.0))) * diff)  # ** q_f, q_f = 0.5


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
    if isinstance(ppd, bool) or not isinstance(ppd, (int, float)):
        raise TypeError(f"ppd must be a number, got {type(ppd).__name__}")
    if not math.isfinite(ppd) or ppd <= 0:
        raise ValueError(f"ppd must be a finite number > 0, got {ppd!r}")
    ppd = float(_F(ppd))  # FLIP reads ppd as a float
    with torch.no_grad():
        imgs = torch.stack((reference, test)).detach().to("cpu", torch.float32)
        ycc = _srgb_to_ycxcz(imgs)
        cd = _color_difference(ycc, ppd)
        fd = _feature_difference(ycc, ppd)
        out = _pow32(cd, 1.0 - fd)  # FLIP eq. 11
    return out.float().numpy()
