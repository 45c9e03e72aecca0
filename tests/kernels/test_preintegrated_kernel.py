"""Pre-integrated kernel taps (000 §4 eq. 5, §7 importance sampling) against closed forms."""

import numpy as np
import pytest
import torch
from scipy import optimize
from scipy.special import ndtr

from sssbench.kernels import Kernel1D, preintegrated
from sssbench.profiles import SumOfGaussians


def sog_cdf(p: SumOfGaussians, x: float, c: int) -> float:
    s = np.sqrt(p.variances.numpy())
    w = p.weights.numpy()[:, c]
    return float((w * ndtr(x / s)).sum() / w.sum())


@pytest.mark.parametrize("sampling", ["uniform", "power", "importance"])
@pytest.mark.parametrize("samples", [1, 2, 7, 33])
def test_weights_sum_to_one_and_kernel_is_symmetric(sampling, samples):
    k = preintegrated(SumOfGaussians.from_table("skin_deon6"), samples, sampling)
    assert k.sum().tolist() == pytest.approx([1.0, 1.0, 1.0], abs=1e-12)
    assert torch.allclose(k.offsets, -k.offsets.flip(0), atol=1e-12)
    assert torch.allclose(k.weights, k.weights.flip(0), atol=1e-12)


def test_importance_taps_sit_at_quantiles_of_the_dominant_channel():
    p = SumOfGaussians.from_table("skin_deon6")
    k = preintegrated(p, 7, "importance")
    # red is the widest channel of skin (000 §7: "the red channel for the skin")
    assert p.dominant_channel() == 0
    for i, off in enumerate(k.offsets.tolist()):
        target = (i + 0.5) / 7
        ref = optimize.brentq(
            lambda x, target=target: sog_cdf(p, x, 0) - target, -50, 50, xtol=1e-13
        )
        assert off == pytest.approx(ref, abs=1e-9)
    # each channel's weight is the mass of its own 1D kernel between the quantile edges
    edges = (
        [-np.inf]
        + [
            optimize.brentq(lambda x, t=t: sog_cdf(p, x, 0) - t / 7, -50, 50, xtol=1e-13)
            for t in range(1, 7)
        ]
        + [np.inf]
    )
    for c in range(3):
        masses = [
            sog_cdf(p, b, c) - sog_cdf(p, a, c) for a, b in zip(edges[:-1], edges[1:], strict=True)
        ]
        assert k.weights[:, c].tolist() == pytest.approx(masses, abs=1e-9)
    # red taps carry equal mass: that is what importance sampling means
    assert k.weights[:, 0].tolist() == pytest.approx([1 / 7] * 7, abs=1e-9)


def test_uniform_taps_span_the_profile_radius():
    p = SumOfGaussians.from_table("marble_jg10")
    k = preintegrated(p, 5, "uniform", extent=4.0)
    assert k.offsets.tolist() == pytest.approx([-4.0, -2.0, 0.0, 2.0, 4.0])


@pytest.mark.parametrize("samples", [0, -3])
def test_samples_below_one_is_rejected(samples):
    with pytest.raises(ValueError, match="samples"):
        preintegrated(SumOfGaussians.from_table("skin_deon6"), samples)


def test_non_integer_samples_and_unknown_sampling():
    p = SumOfGaussians.from_table("skin_deon6")
    with pytest.raises(TypeError, match="samples"):
        preintegrated(p, 7.5)
    with pytest.raises(ValueError, match="sampling"):
        preintegrated(p, 7, "stratified")


def test_kernel1d_validation():
    with pytest.raises(ValueError, match="sorted"):
        Kernel1D(torch.tensor([1.0, 0.0]), torch.ones(2, 3))
    with pytest.raises(ValueError, match="weights"):
        Kernel1D(torch.tensor([0.0, 1.0]), torch.ones(2, 2))
