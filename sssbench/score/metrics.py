"""Quality metrics of a result against a reference (DESIGN §1: ``sssbench/score/metrics.py``).

One module because the metrics share one input check (:func:`_check_pair`), one display
transform and its memo (:func:`_display`, read by ΔE and FLIP alike) and the FLIP map's
conventions (:func:`flip_map`, :func:`flip_map_over` and their consumers' check
:func:`masked_flip_map`): split, each part would import the others' private helpers.

Every metric takes a result and a reference of shape ``(B, 3, H, W)`` (linear radiance, >= 0 is
not required by the error metrics but is by the tone-mapped ones) and an optional mask
``(B, 1, H, W)`` with values in ``[0, 1]``. The mask acts as a per-pixel *weight*: a binary mask
restricts the metric to the pixels where it is 1, a soft mask weights them. Each metric is
computed per image and averaged over the batch; it returns a Python ``float``.

Colour-space conventions (one place, shared by :func:`delta_e`, :func:`flip` and the app's PNG
previews):

* :func:`tonemap` maps linear radiance to display sRGB in ``[0, 1]``: Reinhard
  ``y = e x / (1 + e x)`` per channel (``e`` = exposure, default 1), then the sRGB transfer
  function (IEC 61966-2-1, ``kornia.color.linear_rgb_to_rgb``). Reinhard never clips, so two
  different HDR values never map to the same display value.
* :func:`rmse`, :func:`rel_rms`, :func:`psnr`, :func:`ssim` work on the *linear* values.
* :func:`delta_e` and :func:`flip` work on the tone-mapped sRGB values, as a viewer sees them;
  negative values (e.g. ringing of a low-rank kernel with negative weights) are clamped to 0
  first, as a display would.

Example:
    >>> ref = torch.full((1, 3, 8, 8), 0.5)
    >>> round(rmse(ref + 0.1, ref), 6)
    0.1
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import math
from collections.abc import Iterator
from pathlib import Path

import kornia.color
import numpy as np
import torch
from scipy.ndimage import uniform_filter
from skimage.color import deltaE_cie76, deltaE_ciede2000
from skimage.metrics import peak_signal_noise_ratio
from skimage.util import crop

from sssbench._checks import check_choice, check_range, check_scalar, check_tensor
from sssbench._memo import by_content
from sssbench.score.flip_ldr import filter_radii, flip_from_planes, flip_planes

__all__ = [
    "tonemap",
    "rmse",
    "rel_rms",
    "psnr",
    "ssim",
    "delta_e",
    "flip",
    "flip_map",
    "flip_map_over",
    "flip_support",
    "METRICS",
    "compute_all",
]


# ----------------------------------------------------------------------------- validation
def _check_pair(
    result: object, reference: object, mask: object | None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Validate the inputs; return float64 copies (and the mask, or ``None``)."""
    res = check_tensor("result", result, ndim=4, channels=3)
    ref = check_tensor("reference", reference, ndim=4, channels=3)
    if res.shape != ref.shape:
        raise ValueError(
            f"result must have the shape of reference {tuple(ref.shape)}, got {tuple(res.shape)}"
        )
    b, _, h, w = ref.shape
    if b < 1 or h < 1 or w < 1:
        raise ValueError(f"reference must have non-empty B, H, W, got shape {tuple(ref.shape)}")
    m = None
    if mask is not None:
        m = check_tensor("mask", mask, ndim=4, channels=1)
        if m.shape != (b, 1, h, w):
            raise ValueError(f"mask must have shape ({b}, 1, {h}, {w}), got {tuple(m.shape)}")
        check_range("mask", m, 0.0, 1.0)
        sums = m.reshape(b, -1).sum(1)
        if bool((sums <= 0).any()):
            raise ValueError(
                "mask must select at least one pixel in every image (sum > 0), "
                f"got per-image sums {sums.tolist()}"
            )
        m = m.detach().double().cpu()
    return res.detach().double().cpu(), ref.detach().double().cpu(), m


def _weighted_mean(values: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Per-image mean of ``(B, C, H, W)`` values over C, H, W, weighted by a ``(B,1,H,W)`` mask."""
    b, c = values.shape[:2]
    if mask is None:
        return values.reshape(b, -1).mean(1)
    wsum = mask.reshape(b, -1).sum(1) * c
    return (values * mask).reshape(b, -1).sum(1) / wsum


def _mse(res: torch.Tensor, ref: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    return _weighted_mean((res - ref) ** 2, mask)


def _peak(ref: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Per-image peak of the reference (over the mask's support): the PSNR/SSIM data range."""
    b = ref.shape[0]
    r = ref if mask is None else torch.where(mask > 0, ref, torch.full_like(ref, -math.inf))
    return r.reshape(b, -1).max(1).values


# ----------------------------------------------------------------------------- colour
def tonemap(image: torch.Tensor, exposure: float = 1.0) -> torch.Tensor:
    """Linear radiance -> display sRGB in ``[0, 1]``: Reinhard, then the sRGB curve.

    Args:
        image: linear RGB radiance, >= 0, ``(B, 3, H, W)``.
        exposure: scale applied before the Reinhard curve ``y = x / (1 + x)``, > 0.

    Returns:
        sRGB-encoded values in ``[0, 1]``, same shape and dtype.

    Shape:
        - image: :math:`(B, 3, H, W)`
        - output: :math:`(B, 3, H, W)`

    Example:
        >>> tonemap(torch.zeros(1, 3, 1, 1)).flatten().tolist()
        [0.0, 0.0, 0.0]
    """
    check_tensor("image", image, ndim=4, channels=3)
    check_range("image", image, 0.0)
    return _tonemap(image, check_scalar("exposure", exposure, 0.0, low_inclusive=False))


def _tonemap(image: torch.Tensor, exposure: float) -> torch.Tensor:
    """:func:`tonemap` of an image and exposure already checked."""
    x = image * exposure
    y = x / (1.0 + x)  # Reinhard
    return kornia.color.linear_rgb_to_rgb(y).clamp(0.0, 1.0)


def _display(image: torch.Tensor, exposure: float) -> torch.Tensor:
    """What a viewer sees of a checked float64 image (:func:`_check_pair`): negative values
    clamped to 0 (a display shows no negative light), then :func:`_tonemap`.

    Memoised on the image's contents (:func:`sssbench._memo.by_content`): a sweep scores
    every method of a scene against the same reference (read anew from the reference cache
    by each run), and :func:`flip_map` and :func:`delta_e` tone-map the same result; the
    values are those of the computation itself, bit for bit (the same operations on the same
    bits; the key holds torch's thread count, on which no value may depend but which costs
    nothing to rule out)."""
    tag = ("display", exposure, torch.get_num_threads())
    return by_content((image,), tag, lambda: _tonemap(image.clamp(min=0.0), exposure))


def _reference_lab(ref: torch.Tensor, exposure: float) -> torch.Tensor:
    """``kornia.color.rgb_to_lab`` of :func:`_display` of a checked float64 reference,
    memoised on its contents like :func:`_display` (the same for every method of a scene)."""
    tag = ("lab", exposure, torch.get_num_threads())
    return by_content((ref,), tag, lambda: kornia.color.rgb_to_lab(_display(ref, exposure)))


# ----------------------------------------------------------------------------- metrics
def rmse(result: torch.Tensor, reference: torch.Tensor, mask: torch.Tensor | None = None) -> float:
    """Root-mean-square error over pixels and channels, in the images' (linear) units.

    Args:
        result: ``(B, 3, H, W)``.
        reference: ``(B, 3, H, W)``.
        mask: optional ``(B, 1, H, W)`` weights in ``[0, 1]``.

    Returns:
        ``sqrt(Σ m (x - y)² / (3 Σ m))`` per image, averaged over the batch; >= 0.
    """
    return _rmse(*_check_pair(result, reference, mask))


def _rmse(res: torch.Tensor, ref: torch.Tensor, m: torch.Tensor | None) -> float:
    return float(_mse(res, ref, m).sqrt().mean())


def rel_rms(
    result: torch.Tensor, reference: torch.Tensor, mask: torch.Tensor | None = None
) -> float:
    """Relative RMS error: ``RMS(result - reference) / RMS(reference)`` (dimensionless).

    Raises ``ValueError`` when the reference is zero on the mask (the ratio is undefined).
    """
    return _rel_rms(*_check_pair(result, reference, mask))


def _rel_rms(res: torch.Tensor, ref: torch.Tensor, m: torch.Tensor | None) -> float:
    num = _mse(res, ref, m).sqrt()
    den = _weighted_mean(ref**2, m).sqrt()
    if bool((den <= 0).any()):
        raise ValueError("reference must be non-zero on the mask for rel_rms, got RMS = 0")
    return float((num / den).mean())


def psnr(result: torch.Tensor, reference: torch.Tensor, mask: torch.Tensor | None = None) -> float:
    """Peak signal-to-noise ratio in dB, ``10 log10(peak² / MSE)``.

    ``data_range`` (the peak) is the maximum of the *reference* over the mask's support: the
    images are linear HDR radiance with no fixed white, and radiance is >= 0, so the reference's
    own peak is the natural signal range; it also makes the value independent of the result
    (``skimage.metrics.peak_signal_noise_ratio`` with ``data_range=reference.max()``).
    Identical images give ``inf``.

    Returns:
        dB per image, averaged over the batch (``inf`` if any image is exact).
    """
    return _psnr(*_check_pair(result, reference, mask))


def _psnr(res: torch.Tensor, ref: torch.Tensor, m: torch.Tensor | None) -> float:
    peaks = _peak(ref, m)
    if bool((peaks <= 0).any()):
        raise ValueError("reference must have a positive peak on the mask for psnr")
    out = []
    for i in range(ref.shape[0]):
        if m is None:
            mse = float(_mse(res[i : i + 1], ref[i : i + 1], None))
            if mse == 0.0:
                out.append(math.inf)
                continue
            out.append(
                peak_signal_noise_ratio(ref[i].numpy(), res[i].numpy(), data_range=float(peaks[i]))
            )
        else:  # the same formula with the mask-weighted MSE
            mse = float(_mse(res[i : i + 1], ref[i : i + 1], m[i : i + 1]))
            out.append(math.inf if mse == 0.0 else 10.0 * math.log10(float(peaks[i]) ** 2 / mse))
    return float(np.mean(out))


def ssim(result: torch.Tensor, reference: torch.Tensor, mask: torch.Tensor | None = None) -> float:
    """Structural similarity (``skimage.metrics.structural_similarity``) on linear values.

    Computed with ``channel_axis`` over RGB, a 7×7 uniform window (smaller, odd, on images under
    7 pixels) and ``data_range`` = the reference peak (as in :func:`psnr`). With a mask, the
    full SSIM map (mean over channels) is averaged with the mask as weights.

    Returns:
        SSIM in ``[-1, 1]`` (1 for identical images), averaged over the batch.
    """
    return _ssim(*_check_pair(result, reference, mask))


def _ssim(res: torch.Tensor, ref: torch.Tensor, m: torch.Tensor | None) -> float:
    _, _, h, w = ref.shape
    win = min(7, h, w)
    win = win if win % 2 == 1 else win - 1
    if win < 3:
        raise ValueError(f"reference must be at least 3×3 pixels for ssim, got {h}×{w}")
    peaks = _peak(ref, m)
    out = []
    for i in range(ref.shape[0]):
        data_range = float(peaks[i]) if float(peaks[i]) > 0 else 1.0
        value, smap = _structural_similarity(ref[i], res[i], win, data_range)
        if m is None:
            out.append(float(value))
        else:
            wgt = m[i, 0].numpy()
            out.append(float((smap.mean(-1) * wgt).sum() / wgt.sum()))
    return float(np.mean(out))


def _structural_similarity(
    ref: torch.Tensor, res: torch.Tensor, win: int, data_range: float
) -> tuple[float, np.ndarray]:
    """``skimage.metrics.structural_similarity(ref, res, win_size=win, data_range=data_range,
    channel_axis=-1, full=True)`` of two float64 ``(3, H, W)`` images (as ``(H, W, 3)``):
    ``(mean SSIM, (H, W, 3) SSIM map)``, bit for bit, with the reference's filtered moments
    (its window means and variances, two of the five uniform filters per channel) memoised
    on its contents (:func:`sssbench._memo.by_content`): a sweep scores every method of a
    scene against the same reference.

    skimage's steps (0.26, ``_structural_similarity.py``: uniform window, sample covariance,
    ``K1 = 0.01``, ``K2 = 0.03``) in its order of operations; ``tests/test_content_memo.py``
    compares the two on random images, so a change of skimage's shows there."""
    a = ref.permute(1, 2, 0).numpy()
    b = res.permute(1, 2, 0).numpy()
    cov_norm = win**2 / (win**2 - 1)  # sample covariance
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2

    def moments() -> tuple[np.ndarray, ...]:
        out = []
        for ch in range(a.shape[-1]):
            ux = uniform_filter(a[..., ch], size=win)
            uxx = uniform_filter(a[..., ch] * a[..., ch], size=win)
            out.append(np.stack([ux, cov_norm * (uxx - ux * ux), ux**2]))
        return tuple(out)

    ref_moments = by_content((ref,), ("ssim_reference", win, cov_norm), moments)
    pad = (win - 1) // 2
    mssim = np.empty(a.shape[-1])
    smap = np.empty(a.shape)
    for ch, (ux, vx, ux2) in enumerate(ref_moments):
        im1, im2 = a[..., ch], b[..., ch]
        uy = uniform_filter(im2, size=win)
        uyy = uniform_filter(im2 * im2, size=win)
        uxy = uniform_filter(im1 * im2, size=win)
        vy = cov_norm * (uyy - uy * uy)
        vxy = cov_norm * (uxy - ux * uy)
        a1, a2, b1, b2 = (2 * ux * uy + c1, 2 * vxy + c2, ux2 + uy**2 + c1, vx + vy + c2)
        smap[..., ch] = (a1 * a2) / (b1 * b2)
        mssim[ch] = crop(smap[..., ch], pad).mean(dtype=np.float64)
    return float(mssim.mean()), smap


def delta_e(
    result: torch.Tensor,
    reference: torch.Tensor,
    mask: torch.Tensor | None = None,
    *,
    formula: str = "cie76",
    exposure: float = 1.0,
) -> float:
    """Mean CIE colour difference of the tone-mapped images.

    Both images go through :func:`tonemap` (Reinhard + sRGB encoding), then
    ``kornia.color.rgb_to_lab`` (which linearises sRGB and uses D65 / 2°). ``formula="cie76"``
    is the Euclidean Lab distance ΔE*ab (1976); ``"ciede2000"`` uses
    ``skimage.color.deltaE_ciede2000`` on the same Lab values. A ΔE of about 2.3 is a
    just-noticeable difference.

    Returns:
        Mask-weighted mean ΔE per image, averaged over the batch; >= 0.
    """
    res, ref, m = _check_pair(result, reference, mask)
    check_choice("formula", formula, ("cie76", "ciede2000"))
    exposure = check_scalar("exposure", exposure, 0.0, low_inclusive=False)
    return _delta_e(res, ref, m, formula, exposure)


def _delta_e(
    res: torch.Tensor,
    ref: torch.Tensor,
    m: torch.Tensor | None,
    formula: str = "cie76",
    exposure: float = 1.0,
) -> float:
    lab_res = kornia.color.rgb_to_lab(_display(res, exposure))
    lab_ref = _reference_lab(ref, exposure)
    fn = deltaE_cie76 if formula == "cie76" else deltaE_ciede2000
    de = fn(lab_ref.numpy(), lab_res.numpy(), channel_axis=1)  # (B, H, W)
    return float(_weighted_mean(torch.from_numpy(np.ascontiguousarray(de))[:, None], m).mean())


def flip_map(
    result: torch.Tensor,
    reference: torch.Tensor,
    *,
    exposure: float = 1.0,
    ppd: float = 67.0,
) -> np.ndarray:
    """Per-pixel LDR-FLIP error (Andersson et al. 2020) of the tone-mapped sRGB images.

    Both images go through :func:`tonemap` and are handed to FLIP as LDR sRGB, viewed at
    ``ppd`` pixels per degree (FLIP's default, 67: a 0.7 m distance from a 24" 4K monitor).
    The map is computed by :func:`sssbench.score.flip_ldr.flip_ldr_map`, NVIDIA's FLIP 1.7
    pipeline re-implemented in torch (float32, one thread per torch's intra-op setting): it
    is the map of NVIDIA's FLIP 1.7, ``flip_evaluator.evaluate(reference, test, "LDR",
    inputsRGB=True)``, within a measured max |difference| of 2e-6 on synthetic images and
    2.7e-5 on renders (at a few pixels of a map; mean 2e-8; ``tests/score/test_flip_ldr.py``
    asserts 1e-5 and 3e-5), at under a third of its CPU time (3.2-3.7x less at 512^2, 3.6x
    at 1080p, one thread). The mean FLIP of the stored runs moved by at most 3.5e-7 relative.

    Returns:
        ``(B, H, W)`` float32 FLIP map in ``[0, 1]`` (0 where the images agree).
    """
    res, ref, _ = _check_pair(result, reference, None)
    ppd = check_scalar("ppd", ppd, 0.0, low_inclusive=False)
    exposure = check_scalar("exposure", exposure, 0.0, low_inclusive=False)
    t_res = _display(res, exposure)
    t_ref = _display(ref, exposure)
    return np.stack([_flip_ldr(t_ref[i], t_res[i], ppd) for i in range(ref.shape[0])])


def flip_support(ppd: float = 67.0) -> int:
    """How far, in pixels, FLIP's map at one pixel reads its inputs at ``ppd`` pixels per
    degree: the larger radius of its two separable spatial filters, which both read the
    (pointwise) YCxCz images side by side, never each other's output.

    * the colour CSF filter: ``ceil(3 sqrt(b_max / (2 pi^2)) ppd)`` with the largest scale
      parameter ``b_max = 0.04`` of the contrast sensitivity Gaussians (FLIP, the colour
      pipeline's spatial filters; ``calculateSpatialFilterRadius`` in FLIP's ``FLIP.h``):
      10 px at 67 ppd;
    * the edge and point (feature) filters: ``ceil(3 sigma)`` with
      ``sigma = 0.5 w ppd``, ``w = 0.082`` degrees (FLIP, the feature pipeline;
      ``setFeatureFilter`` in ``FLIP.h``): 9 px at 67 ppd.

    The radii are those :func:`sssbench.score.flip_ldr.flip_ldr_map` filters with
    (:func:`sssbench.score.flip_ldr.filter_radii`, computed in float32 as FLIP 1.7 does),
    plus one pixel of margin (it costs a pixel of the crop; the reach alone suffices, as
    ``tests/score/test_flip_crop.py`` measures, with the crop's map equal to the whole
    image's at this distance from the cut, bit for bit).

    Args:
        ppd: pixels per degree of visual angle, > 0.

    Returns:
        the radius in pixels, >= 1.
    """
    ppd = check_scalar("ppd", ppd, 0.0, low_inclusive=False)
    return max(filter_radii(ppd)) + 1


def _mask_windows(
    mask: torch.Tensor, margin: int
) -> list[tuple[tuple[slice, slice], tuple[slice, slice]] | None]:
    """Per image of a ``(B, 1, H, W)`` mask: ``None`` if no pixel has mask > 0, else
    ``(crop, trusted)``, two ``(rows, cols)`` slices of the image: ``crop`` is the bounding box
    of mask > 0 grown by ``margin`` and clipped to the image; ``trusted`` is ``crop`` less
    ``margin`` pixels at each side where it was cut inside the image (a side on the image's
    own border keeps its pixels: FLIP pads the crop there as it pads the image). ``trusted``
    holds the bounding box."""
    _, _, h, w = mask.shape
    out: list[tuple[tuple[slice, slice], tuple[slice, slice]] | None] = []
    for i in range(mask.shape[0]):
        rows = torch.nonzero((mask[i, 0] > 0).any(1)).flatten()
        cols = torch.nonzero((mask[i, 0] > 0).any(0)).flatten()
        if rows.numel() == 0:
            out.append(None)
            continue
        spans = []
        for ids, n in ((rows, h), (cols, w)):
            lo, hi = max(int(ids[0]) - margin, 0), min(int(ids[-1]) + 1 + margin, n)
            kept = (lo if lo == 0 else lo + margin, hi if hi == n else hi - margin)
            spans.append(((lo, hi), kept))
        (r, rt), (c, ct) = spans
        out.append(((slice(*r), slice(*c)), (slice(*rt), slice(*ct))))
    return out


def flip_map_over(
    result: torch.Tensor,
    reference: torch.Tensor,
    mask: torch.Tensor | None,
    *,
    exposure: float = 1.0,
    ppd: float = 67.0,
) -> np.ndarray:
    """:func:`flip_map` where a mask reads it: bit for bit on the mask's bounding box, ``NaN``
    wherever it was not computed.

    FLIP's map at a pixel reads the images only within :func:`flip_support` pixels (its
    filters' radius), so FLIP is run on the crop = the bounding box of mask > 0 grown by
    that margin and clipped to the image; the crop's map is kept where it lies at least the
    margin inside each side cut inside the image (FLIP pads at a crop's edge by clamping,
    as at the image's, so pixels near the image's own border are kept too). There it is the
    whole image's map bit for bit (the same float32 operations on the same values;
    ``tests/score/test_flip_crop.py`` compares them on random and structured images and
    several masks). Every other pixel is ``NaN``: a value never computed is never shown as
    one. The consumers (:func:`flip`, :func:`compute_all`,
    :func:`sssbench.score.verdict.visibility_stats`) read only the pixels with mask > 0 and
    raise if one of those is ``NaN``. A mask covering most of the image gains little (the
    crop is the whole image once the box reaches within the margin of each border).

    Args:
        result: ``(B, 3, H, W)`` linear radiance.
        reference: ``(B, 3, H, W)`` linear radiance.
        mask: ``(B, 1, H, W)`` in ``[0, 1]`` or ``None`` (then the whole map,
            :func:`flip_map`). An image whose mask is 0 everywhere gets an all-``NaN`` map
            and costs no FLIP evaluation.
        exposure: as in :func:`flip_map`, > 0.
        ppd: as in :func:`flip_map`, > 0.

    Returns:
        ``(B, H, W)`` float32 FLIP map in ``[0, 1]`` on the kept pixels, ``NaN`` elsewhere.
    """
    if mask is None:
        return flip_map(result, reference, exposure=exposure, ppd=ppd)
    res, ref, _ = _check_pair(result, reference, None)
    m = check_tensor("mask", mask, ndim=4, channels=1)
    b, _, h, w = ref.shape
    if m.shape != (b, 1, h, w):
        raise ValueError(f"mask must have shape ({b}, 1, {h}, {w}), got {tuple(m.shape)}")
    check_range("mask", m, 0.0, 1.0)
    ppd = check_scalar("ppd", ppd, 0.0, low_inclusive=False)
    exposure = check_scalar("exposure", exposure, 0.0, low_inclusive=False)
    windows = _mask_windows(m.detach().cpu(), flip_support(ppd))
    out = np.full((b, h, w), np.nan, dtype=np.float32)
    for i, win in enumerate(windows):
        if win is None:
            continue
        (rows, cols), (t_rows, t_cols) = win
        crop_map = _flip_ldr(
            _display(ref[i : i + 1], exposure)[0, :, rows, cols],
            _display(res[i : i + 1], exposure)[0, :, rows, cols],
            ppd,
        )
        r0, c0 = rows.start, cols.start
        out[i, t_rows, t_cols] = crop_map[
            t_rows.start - r0 : t_rows.stop - r0, t_cols.start - c0 : t_cols.stop - c0
        ]
    return out


def _flip_ldr(t_ref: torch.Tensor, t_res: torch.Tensor, ppd: float) -> np.ndarray:
    """FLIP's ``(H, W)`` float32 LDR map of two displayed ``(3, H, W)`` images (sRGB in
    ``[0, 1]``, :func:`_display`), memoised on the float32 images FLIP reads.

    Computed by :func:`sssbench.score.flip_ldr.flip_ldr_map` (FLIP 1.7's pipeline in torch,
    float32): within 3e-5 of NVIDIA's ``flip_evaluator`` (:func:`_flip_ldr_official`, the
    oracle of ``tests/score/test_flip_ldr.py``; :func:`flip_map` gives the figures) and
    3.2-3.7x cheaper in CPU at 512^2; the reference's planes
    (:func:`~sssbench.score.flip_ldr.flip_planes`, half the work) memoised on its bits, the
    map from the two images' planes (bit for bit ``flip_ldr_map``'s)."""
    a = t_ref.detach().to("cpu", torch.float32).contiguous()
    b = t_res.detach().to("cpu", torch.float32).contiguous()

    def evaluate() -> np.ndarray:
        # the reference's planes (half of FLIP's work) memoised on its bits: a sweep compares
        # every method of a scene with the same reference (flip_from_planes: the same map,
        # bit for bit, as flip_ldr_map)
        ref = by_content((a.numpy(),), ("flip_planes_torch", ppd), lambda: flip_planes(a, ppd))
        return flip_from_planes(torch.stack([ref, flip_planes(b, ppd)]))

    # memoised on the two LDR images FLIP reads (the do-nothing run scores the image its
    # scene's baseline scored already): the map for those bits (the key names the torch
    # implementation: a map of the official evaluator is never returned for it)
    return by_content((a.numpy(), b.numpy()), ("flip_ldr_torch", ppd), evaluate)


def _flip_ldr_official(t_ref: torch.Tensor, t_res: torch.Tensor, ppd: float) -> np.ndarray:
    """NVIDIA's FLIP 1.7 (``flip_evaluator.evaluate``, C++) on the same inputs as
    :func:`_flip_ldr`, not memoised: the oracle the torch implementation is tested against."""
    import flip_evaluator  # imported lazily: the extension is only needed for the oracle

    a = np.ascontiguousarray(t_ref.permute(1, 2, 0).numpy(), dtype=np.float32)
    b = np.ascontiguousarray(t_res.permute(1, 2, 0).numpy(), dtype=np.float32)
    with _flip_threads(torch.get_num_threads()):
        fmap, _, _ = flip_evaluator.evaluate(
            a,
            b,
            "LDR",
            inputsRGB=True,
            applyMagma=False,
            computeMeanError=False,
            parameters={"ppd": ppd},
        )
    return np.asarray(fmap, dtype=np.float32)[..., 0]


@functools.cache
def _flip_openmp() -> ctypes.CDLL | None:
    """The OpenMP runtime ``flip_evaluator``'s extension runs on: the copy its wheel vendors
    (``flip_evaluator.libs/libgomp*``, already loaded by the extension, so this is the same
    library), or ``None`` where there is none (another build: FLIP then keeps its own
    threads)."""
    import flip_evaluator

    libs = Path(flip_evaluator.__file__).resolve().parent.parent / "flip_evaluator.libs"
    found = sorted(libs.glob("libgomp*"))
    if not found:
        return None
    try:
        lib = ctypes.CDLL(str(found[0]))
        lib.omp_set_num_threads.argtypes = [ctypes.c_int]
        lib.omp_get_max_threads.restype = ctypes.c_int
    except (OSError, AttributeError):
        return None
    return lib


@contextlib.contextmanager
def _flip_threads(threads: int) -> Iterator[None]:
    """FLIP's OpenMP threads set to ``threads`` for the block (restored after it).

    FLIP's C++ code runs its loops on all the cores by default, whatever torch's threads:
    in a sweep of two single-threaded processes on two cores (the paper benchmark) each
    FLIP evaluation asked for both cores while the other process scored on one, about 10 %
    more CPU time for the same map. The map does not depend on the thread count (its loops
    are per pixel; the mean, a reduction, is computed here): ``tests/test_content_memo.py``
    compares it bit for bit."""
    lib = _flip_openmp()
    if lib is None:
        yield
        return
    before = lib.omp_get_max_threads()
    lib.omp_set_num_threads(max(int(threads), 1))
    try:
        yield
    finally:
        lib.omp_set_num_threads(before)


def flip(
    result: torch.Tensor,
    reference: torch.Tensor,
    mask: torch.Tensor | None = None,
    *,
    exposure: float = 1.0,
    ppd: float = 67.0,
    fmap: np.ndarray | None = None,
) -> float:
    """Mean LDR-FLIP error: the :func:`flip_map` averaged with the mask as weights.

    Args:
        fmap: ``flip_map(result, reference, exposure=exposure, ppd=ppd)`` when the caller has
            it already (the runner shares one map between this mean and the local statistic
            of :func:`sssbench.score.verdict.error_visibility`: FLIP is the dearest metric);
            its shape must be ``(B, H, W)``.

    Returns:
        Mean FLIP error in ``[0, 1]`` (0 for identical images), averaged over the batch.
    """
    _, _, m = _check_pair(result, reference, mask)
    if fmap is None:
        fmap = flip_map_over(result, reference, mask, exposure=exposure, ppd=ppd)
    return _flip_mean(check_flip_map(fmap, result), m)


def _flip_mean(fmap: np.ndarray, m: torch.Tensor | None) -> float:
    """The mask-weighted mean of a checked float64 FLIP map (:func:`flip`)."""
    if m is None:
        return float(masked_flip_map(fmap, None).mean())
    wgt = m[:, 0].numpy()
    read = masked_flip_map(fmap, wgt)
    return float(np.mean((read * wgt).sum(axis=(1, 2)) / wgt.sum(axis=(1, 2))))


def masked_flip_map(fmap: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    """A checked float64 FLIP map ``(B, H, W)`` with its ``NaN`` (pixels
    :func:`flip_map_over` did not compute) set to 0, for the consumers that weight it by the
    ``(B, H, W)`` weights (``None``: all 1): such a pixel is never read, and ``0 * 0`` is
    what ``value * 0`` was there, so the weighted sums keep their bits. A map without
    ``NaN`` is returned as it is. Raises ``ValueError`` if a pixel with a positive weight
    has no value (a map computed over another mask)."""
    nan = np.isnan(fmap)
    if not nan.any():
        return fmap
    read = nan if weights is None else nan & (weights > 0)
    if read.any():
        raise ValueError(
            f"fmap has no value (NaN) at {int(read.sum())} pixels the mask reads: it was "
            "computed over another mask (flip_map_over) or is not a FLIP map"
        )
    return np.where(nan, 0.0, fmap)


def check_flip_map(fmap: np.ndarray, image: torch.Tensor) -> np.ndarray:
    """``fmap`` (a :func:`flip_map`) as float64, checked to be ``(B, H, W)`` for ``image``
    ``(B, 3, H, W)``."""
    b, _, h, w = image.shape
    if not isinstance(fmap, np.ndarray) or fmap.shape != (b, h, w):
        raise ValueError(
            f"fmap must be the (B, H, W) = {(b, h, w)} FLIP map of the images, got "
            f"{getattr(fmap, 'shape', type(fmap).__name__)}"
        )
    return fmap.astype(np.float64)


#: the metrics the app computes for every run, by name
METRICS = {
    "rmse": rmse,
    "rel_rms": rel_rms,
    "psnr": psnr,
    "ssim": ssim,
    "delta_e": delta_e,
    "flip": flip,
}


def compute_all(
    result: torch.Tensor,
    reference: torch.Tensor,
    mask: torch.Tensor | None = None,
    *,
    fmap: np.ndarray | None = None,
) -> dict[str, float]:
    """Every metric of :data:`METRICS` as ``{name: value}``; ``fmap``: the images'
    :func:`flip_map` if the caller has it (see :func:`flip`)."""
    res, ref, m = _check_pair(result, reference, mask)  # checked once for every metric
    if fmap is None:
        fmap = flip_map_over(result, reference, mask)
    out = {name: fn(res, ref, m) for name, fn in _CHECKED.items()}
    out["flip"] = _flip_mean(check_flip_map(fmap, result), m)
    return {name: out[name] for name in METRICS}


#: the bodies of :data:`METRICS` but FLIP, on inputs :func:`_check_pair` returned (the public
#: functions are ``body(*_check_pair(...))``, so :func:`compute_all` gives their numbers)
_CHECKED = {"rmse": _rmse, "rel_rms": _rel_rms, "psnr": _psnr, "ssim": _ssim, "delta_e": _delta_e}
