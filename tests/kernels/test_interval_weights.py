"""The shared tap-interval integrator and its Gaussian-mixture closed forms."""

from __future__ import annotations

import math

import pytest
import torch

from sssbench.kernels import (
    gaussian_mixture_cdf,
    gaussian_mixture_interval,
    interval_weights,
    preintegrated,
    tap_positions,
)
from sssbench.profiles import SumOfGaussians


def test_gaussian_mixture_interval_closed_form() -> None:
    sig = torch.tensor([[0.5, 1.0, 2.0], [3.0, 0.1, 1.0]], dtype=torch.float64)
    w = torch.tensor([[0.2, 0.5, 1.0], [0.8, 0.5, 0.0]], dtype=torch.float64)
    a = torch.tensor([-math.inf, -1.0, 0.3], dtype=torch.float64)
    b = torch.tensor([-1.0, 0.3, math.inf], dtype=torch.float64)
    out = gaussian_mixture_interval(a, b, sig, w)

    def phi(x: float) -> float:
        return 0.5 * math.erfc(-x / math.sqrt(2))

    for i in range(3):
        for c in range(3):
            ref = sum(
                float(w[j, c])
                * (phi(float(b[i]) / float(sig[j, c])) - phi(float(a[i]) / float(sig[j, c])))
                for j in range(2)
            )
            assert float(out[i, c]) == pytest.approx(ref, rel=1e-12, abs=1e-15)
    torch.testing.assert_close(out.sum(0), w.sum(0))
    cdf = gaussian_mixture_cdf(torch.tensor([0.0]), sig, w)
    torch.testing.assert_close(cdf[0], 0.5 * w.sum(0))


def test_interval_weights_normaliser_and_profile_taps_unchanged() -> None:
    skin = SumOfGaussians.from_table("skin_deon6")
    centres, edges = tap_positions(9, "uniform", 5.0)
    raw = interval_weights(edges, skin.preintegrated_interval)
    torch.testing.assert_close(raw.sum(0), skin.total())
    k = preintegrated(skin, 9, "uniform", 5.0)
    torch.testing.assert_close(k.weights, raw / skin.total(), rtol=0, atol=0)
    torch.testing.assert_close(k.offsets, centres)
