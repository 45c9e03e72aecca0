"""Burley normalized diffusion: closed forms against scipy quadrature and Bessel functions."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import integrate, special

from sssbench.profiles import BurleyNormalized

D = [1.0, 0.5, 0.01]
A = [0.8, 0.6, 0.4]


def quad(f, a, b):
    return integrate.quad(f, a, b, epsabs=0.0, epsrel=1e-12, limit=1000)[0]


def r_ref(r, c):
    d, a = D[c], A[c]
    return a * (math.exp(-r / d) + math.exp(-r / (3 * d))) / (8 * math.pi * d * r)


@pytest.fixture
def p():
    return BurleyNormalized(
        torch.tensor(D, dtype=torch.float64), torch.tensor(A, dtype=torch.float64)
    )


def test_total(p):
    assert torch.allclose(p.total(), torch.tensor(A, dtype=torch.float64))
    for c in range(3):
        num = quad(lambda r, c=c: 2 * math.pi * r * r_ref(r, c), 0, 30 * D[c]) + quad(
            lambda r, c=c: 2 * math.pi * r * r_ref(r, c), 30 * D[c], np.inf
        )
        assert num == pytest.approx(A[c], rel=1e-11)


def test_r_zero_finite_and_monotone(p):
    r = torch.tensor([0.0, 1e-300, 1e-9, 1e-3, 0.1, 1.0], dtype=torch.float64)
    v = p(r)
    assert torch.isfinite(v).all()
    assert bool((v.diff(dim=0) <= 0).all())
    # away from the clamp the formula is exact
    assert float(v[-1, 0]) == pytest.approx(r_ref(1.0, 0), rel=1e-14)
    # at 0: the value at the clamp radius 1e-6 d
    assert float(v[0, 1]) == pytest.approx(r_ref(1e-6 * D[1], 1), rel=1e-14)
    assert torch.isfinite(p.preintegrated(0.0)).all()


def test_preintegrated_bessel_and_quad(p):
    for x in (1e-4, 0.1, 1.0, 5.0):
        got = p.preintegrated(x)
        for c in range(3):
            d, a = D[c], A[c]
            bes = a / (4 * math.pi * d) * (special.k0(x / d) + special.k0(x / (3 * d)))
            assert float(got[c]) == pytest.approx(bes, rel=1e-13)
            if x / d < 100:
                ref = 2 * (
                    quad(lambda y, x=x, c=c: r_ref(math.hypot(x, y), c), 0, x)
                    + quad(lambda y, x=x, c=c: r_ref(math.hypot(x, y), c), x, np.inf)
                )
                assert float(got[c]) == pytest.approx(ref, rel=1e-9)


def test_preintegrated_cdf_exact(p):
    xs = [-2.0, -1e-3, 0.0, 1e-12, 0.05, 0.7, 3.0, 1e4]
    got = p.preintegrated_cdf(torch.tensor(xs, dtype=torch.float64))
    for i, x in enumerate(xs):
        for c in range(3):
            d, a = D[c], A[c]

            def ap(t, d=d, a=a):
                return a / (4 * math.pi * d) * (special.k0(t / d) + special.k0(t / (3 * d)))

            ax = min(abs(x), 100 * d)
            part = quad(ap, 0, ax) if ax else 0.0
            ref = a / 2 + math.copysign(part, x)
            assert float(got[i, c]) == pytest.approx(ref, rel=1e-10, abs=1e-14)
    ends = p.preintegrated_cdf(torch.tensor([-math.inf, math.inf], dtype=torch.float64))
    assert torch.allclose(ends[1], p.total()) and torch.allclose(ends[0], torch.zeros(3).double())


def test_second_moment_radius(p):
    m = p.second_moment()
    for c in range(3):
        num = quad(lambda r, c=c: math.pi * r**3 * r_ref(r, c), 0, 200 * D[c])
        assert float(m[c]) == pytest.approx(num / A[c], rel=1e-9)
    rad = p.radius(1e-4)
    e = p.energy_beyond(rad) / p.total()
    assert float(e.max()) == pytest.approx(1e-4, rel=1e-8)
    ref = quad(lambda r, c=c: 2 * math.pi * r * r_ref(r, 0), rad, np.inf) / A[0]
    assert ref == pytest.approx(1e-4, rel=1e-7)


@pytest.mark.parametrize(
    ("d", "albedo", "arg"),
    [
        ([-1.0, 1, 1], 0.5, "d"),
        ([0.0, 1, 1], 0.5, "d"),
        (1.0, [0.5, 1.5, 0.2], "albedo"),
        (1.0, [0.5, float("nan"), 0.2], "albedo"),
        ([1.0, float("inf"), 1], 0.5, "d"),
        ("x", 0.5, "d"),
    ],
)
def test_bad_inputs(d, albedo, arg):
    with pytest.raises((ValueError, TypeError), match=arg):
        BurleyNormalized(d, albedo)


# --------------------------------------------------------------- albedo / mean free path
# Christensen & Burley 2015's fits evaluated by hand at a few albedos:
#   searchlight (mfp):       s = 1.85 − A + 7|A − 0.8|³   A=0.8: 1.05; A=0.3: 1.55 + 7·0.125
#   transmission (mfp):      s = 1.9 − A + 3.5(A − 0.8)²  A=0.8: 1.1;  A=0.3: 1.6 + 3.5·0.25
#   diffuse mfp (dmfp):      s = 3.5 + 100(A − 0.33)⁴     A=0.33: 3.5; A=0.83: 3.5 + 100/16
FIT_CASES = [
    ("mfp", 0.8, 1.05),
    ("mfp", 0.3, 1.55 + 0.875),
    ("mfp_transmission", 0.8, 1.1),
    ("mfp_transmission", 0.3, 1.6 + 0.875),
    ("dmfp", 0.33, 3.5),
    ("dmfp", 0.83, 3.5 + 6.25),
]


@pytest.mark.parametrize("kind, albedo, s", FIT_CASES)
def test_from_albedo_mfp_fits(kind, albedo, s):
    p = BurleyNormalized.from_albedo_mfp(albedo, 2.0, kind=kind)
    assert torch.allclose(p.d, torch.full((3,), 2.0 / s, dtype=torch.float64), rtol=1e-12)
    assert torch.allclose(p.total(), torch.full((3,), albedo, dtype=torch.float64))


def test_from_albedo_mfp_per_channel_and_default_dmfp():
    # the engines' default: dmfp; each channel its own fit value
    albedo, mfp = [0.33, 0.83, 0.33], [1.0, 2.0, 3.0]
    p = BurleyNormalized.from_albedo_mfp(albedo, mfp)
    expect = torch.tensor([1.0 / 3.5, 2.0 / 9.75, 3.0 / 3.5], dtype=torch.float64)
    assert torch.allclose(p.d, expect, rtol=1e-12)


@pytest.mark.parametrize(
    "albedo, mfp, kind, exc",
    [
        (1.5, 1.0, "dmfp", ValueError),
        (0.5, 0.0, "dmfp", ValueError),
        (0.5, -1.0, "mfp", ValueError),
        (0.5, 1.0, "searchlight", ValueError),
        ("x", 1.0, "dmfp", TypeError),
    ],
)
def test_from_albedo_mfp_bad_inputs(albedo, mfp, kind, exc):
    with pytest.raises(exc):
        BurleyNormalized.from_albedo_mfp(albedo, mfp, kind=kind)
