"""The base class's numeric defaults against a profile with closed forms (SumOfGaussians)."""

from __future__ import annotations

import time

import torch

from sssbench.profiles import Profile, SumOfGaussians


class _Numeric(Profile):
    """The same R(r) as a SumOfGaussians, but only evaluate/length_scales: all numeric."""

    def __init__(self, sog: SumOfGaussians) -> None:
        self.sog = sog

    def evaluate(self, r):
        return self.sog.evaluate(r)

    def length_scales(self):
        return self.sog.length_scales()


def test_numeric_defaults_match_closed_forms():
    sog = SumOfGaussians.from_table("skin_deon6")
    num = _Numeric(sog)
    x = torch.tensor([-40.0, -3.0, -0.01, 0.0, 0.2, 1.5, 7.0, 1e4], dtype=torch.float64)
    assert torch.allclose(num.total(), sog.total(), rtol=1e-12)
    assert torch.allclose(num.preintegrated(x), sog.preintegrated(x), rtol=1e-10, atol=1e-15)
    assert torch.allclose(num.preintegrated_cdf(x), sog.preintegrated_cdf(x), rtol=0, atol=1e-12)
    inf = torch.tensor([-float("inf"), float("inf")], dtype=torch.float64)
    ends = num.preintegrated_cdf(inf)
    assert torch.allclose(ends[0], torch.zeros(3, dtype=torch.float64))
    assert torch.allclose(ends[1], sog.total())


def test_numeric_cdf_vectorised_speed():
    num = _Numeric(SumOfGaussians.from_table("skin_jg10"))
    x = torch.linspace(-10, 10, 200, dtype=torch.float64)
    t0 = time.perf_counter()
    num.preintegrated_cdf(x)
    assert time.perf_counter() - t0 < 10.0  # was ~0.3 s per point with the Python loop
