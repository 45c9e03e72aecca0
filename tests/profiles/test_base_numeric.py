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


def test_generic_cell_integral_on_a_tilted_cell_matches_dblquad():
    """Profile.cell_integral (any profile) integrates the tilted planar patch the reference
    uses, p = (dx+s, dy+t, dz + sx s + sy t) with area element √(1 + sx² + sy²): checked
    against scipy's adaptive dblquad for a smooth (wide) profile."""
    import math

    import numpy as np
    import torch
    from scipy.integrate import dblquad

    from sssbench.profiles import SumOfGaussians
    from sssbench.profiles.base import Profile

    prof = SumOfGaussians(
        torch.tensor([1.5, 4.0], dtype=torch.float64), torch.full((2, 3), 0.5, dtype=torch.float64)
    )
    dx, dy, dz, h, sx, sy = 0.6, -0.3, 0.2, 0.4, 0.35, -0.25
    t = torch.tensor
    got = Profile.cell_integral(prof, t([dx]), t([dy]), t([dz]), t([h]), t([h]), t([sx]), t([sy]))[
        0, 0
    ].item()
    area = math.sqrt(1 + sx * sx + sy * sy)

    def f(b, a):
        r = math.sqrt((dx + a) ** 2 + (dy + b) ** 2 + (dz + sx * a + sy * b) ** 2)
        return float(prof.evaluate(torch.tensor([r], dtype=torch.float64))[0, 0]) * area

    want, _ = dblquad(f, -h, h, -h, h, epsabs=1e-12, epsrel=1e-10)
    assert np.isclose(got, want, rtol=1e-7)
