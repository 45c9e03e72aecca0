"""Metrics against closed-form oracles."""

from __future__ import annotations

import math

import pytest
import torch

from sssbench.score import metrics
from sssbench.score.metrics import delta_e, flip, psnr, rel_rms, rmse, ssim, tonemap


def _ramp(b: int = 1, h: int = 16, w: int = 16, dtype=torch.float64) -> torch.Tensor:
    g = torch.Generator().manual_seed(0)
    return torch.rand(b, 3, h, w, generator=g, dtype=dtype) * 0.8 + 0.1


def test_rmse_constant_offset():
    ref = _ramp()
    assert rmse(ref + 0.25, ref) == pytest.approx(0.25, rel=1e-12)
    assert rmse(ref - 0.25, ref) == pytest.approx(0.25, rel=1e-12)
    assert rmse(ref, ref) == 0.0


def test_rmse_mask_selects_pixels():
    ref = torch.zeros(1, 3, 4, 4, dtype=torch.float64)
    res = ref.clone()
    res[..., :2, :] = 1.0  # error only in the top half
    mask = torch.zeros(1, 1, 4, 4, dtype=torch.float64)
    mask[..., 2:, :] = 1.0
    assert rmse(res, ref, mask) == 0.0
    assert rmse(res, ref, 1 - mask) == pytest.approx(1.0)
    assert rmse(res, ref) == pytest.approx(math.sqrt(0.5))


def test_rel_rms_scaling():
    ref = _ramp()
    assert rel_rms(ref * 1.1, ref) == pytest.approx(0.1, rel=1e-10)
    with pytest.raises(ValueError, match="non-zero"):
        rel_rms(ref, torch.zeros_like(ref))


def test_psnr_closed_form():
    ref = _ramp()
    peak = float(ref.max())
    d = 0.01
    assert psnr(ref + d, ref) == pytest.approx(20 * math.log10(peak / d), rel=1e-10)
    assert psnr(ref, ref) == math.inf
    ones = torch.ones(1, 1, 16, 16, dtype=torch.float64)
    assert psnr(ref + d, ref, ones) == pytest.approx(psnr(ref + d, ref), rel=1e-12)


def test_ssim_identical_is_one_and_degrades():
    ref = _ramp()
    assert ssim(ref, ref) == pytest.approx(1.0)
    mask = torch.zeros(1, 1, 16, 16, dtype=torch.float64)
    mask[..., 4:12, 4:12] = 1
    assert ssim(ref, ref, mask) == pytest.approx(1.0)
    noisy = ref + 0.2 * torch.randn(
        ref.shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64
    )
    assert ssim(noisy, ref) < 0.9


def test_ssim_tiny_image_window():
    ref = _ramp(h=5, w=5)
    assert ssim(ref, ref) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="at least 3"):
        ssim(_ramp(h=2, w=8), _ramp(h=2, w=8))


def test_delta_e_identical_is_zero():
    ref = _ramp()
    assert delta_e(ref, ref) == pytest.approx(0.0, abs=1e-9)
    assert delta_e(ref, ref, formula="ciede2000") == pytest.approx(0.0, abs=1e-9)


def test_delta_e_hand_computed_greys():
    # linear grey x -> Reinhard x/(1+x) -> sRGB -> (kornia linearises) -> Y = x/(1+x)
    # L* = 116 Y^(1/3) - 16 (Y > 0.008856), a* = b* = 0 for a neutral grey (D65 white).
    ref = torch.full((1, 3, 4, 4), 1.0, dtype=torch.float64)  # Y = 0.5
    res = torch.full((1, 3, 4, 4), 3.0, dtype=torch.float64)  # Y = 0.75
    expected = 116 * (0.75 ** (1 / 3) - 0.5 ** (1 / 3))
    assert delta_e(res, ref) == pytest.approx(expected, abs=2e-3)
    black = torch.zeros_like(ref)
    assert delta_e(black, ref) == pytest.approx(116 * 0.5 ** (1 / 3) - 16, abs=2e-3)


def test_flip_identical_zero_and_positive_on_difference():
    ref = _ramp(h=32, w=32)
    assert flip(ref, ref) == pytest.approx(0.0, abs=1e-6)
    value = flip(ref * 1.5, ref)
    assert 0.0 < value <= 1.0
    ones = torch.ones(1, 1, 32, 32, dtype=torch.float64)
    assert flip(ref * 1.5, ref, ones) == pytest.approx(value, rel=1e-5)


def test_batch_average():
    ref = _ramp(b=2)
    res = ref.clone()
    res[0] += 0.1
    res[1] += 0.3
    assert rmse(res, ref) == pytest.approx(0.2)


def test_tonemap_range_and_float32():
    x = torch.tensor([0.0, 1.0, 1e6]).view(1, 3, 1, 1)
    y = tonemap(x)
    assert y.dtype == torch.float32
    assert 0.0 <= float(y.min()) and float(y.max()) <= 1.0
    assert float(y[0, 1]) == pytest.approx(0.7354, abs=1e-3)  # sRGB(0.5)


@pytest.mark.parametrize("name", sorted(metrics.METRICS))
def test_validation_messages(name):
    fn = metrics.METRICS[name]
    ref = _ramp()
    with pytest.raises(ValueError, match="result must have the shape"):
        fn(ref[..., :8], ref)
    with pytest.raises(ValueError, match="reference must have 3 channels"):
        fn(ref, ref[:, :1])
    with pytest.raises(TypeError, match="result must be a torch.Tensor"):
        fn(ref.numpy(), ref)
    bad = ref.clone()
    bad[0, 0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        fn(bad, ref)
    with pytest.raises(ValueError, match="mask must have shape"):
        fn(ref, ref, torch.ones(1, 1, 4, 4, dtype=torch.float64))
    with pytest.raises(ValueError, match="at least one pixel"):
        fn(ref, ref, torch.zeros(1, 1, 16, 16, dtype=torch.float64))


def test_compute_all_keys():
    ref = _ramp()
    out = metrics.compute_all(ref * 1.05, ref)
    assert set(out) == {"rmse", "rel_rms", "psnr", "ssim", "delta_e", "flip"}
    assert all(isinstance(v, float) for v in out.values())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_compute_all_checks_once_and_gives_each_metrics_own_number(dtype):
    """compute_all validates the pair once and runs the metrics' bodies on it: every value
    is bit for bit the public function's (float32 and float64 inputs, a mask, a batch of 2,
    a negative pixel that the display metrics clamp)."""
    ref = _ramp(b=2, dtype=dtype)
    res = ref * 1.05
    res[0, 1, 3, 3] = -0.2
    mask = torch.zeros(2, 1, 16, 16, dtype=dtype)
    mask[..., 2:12, 4:14] = 1.0
    mask[1, 0, 0, 0] = 0.5
    out = metrics.compute_all(res, ref, mask)
    assert list(out) == list(metrics.METRICS)
    for name, fn in metrics.METRICS.items():
        assert out[name] == fn(res, ref, mask), name
    fmap = metrics.flip_map(res, ref)
    assert metrics.compute_all(res, ref, mask, fmap=fmap) == out


def test_compute_all_still_names_a_bad_argument():
    ref = _ramp()
    with pytest.raises(ValueError, match="mask"):
        metrics.compute_all(ref, ref, torch.zeros(1, 1, 16, 16, dtype=torch.float64))
    bad = ref.clone()
    bad[0, 0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="result"):
        metrics.compute_all(bad, ref)


def test_display_metrics_clamp_negative_light():
    ref = _ramp()
    neg = ref.clone()
    neg[..., 0, 0] = -0.5
    clamped = neg.clamp(min=0)
    assert delta_e(neg, ref) == pytest.approx(delta_e(clamped, ref))
    assert flip(neg, ref) == pytest.approx(flip(clamped, ref))
    assert rmse(neg, ref) > rmse(clamped, ref)  # the linear metrics see the negative value
