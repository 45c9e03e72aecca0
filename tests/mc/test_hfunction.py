"""Chandrasekhar's H-function: table values, a moment identity and two independent methods."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sssbench.mc.hfunction import h_function, h_function_integral, halfspace_reflectance


def test_conservative_h_of_one_matches_chandrasekhar_table():
    # Chandrasekhar, Radiative Transfer (1950), Table V (ϖ0 = 1): H(1) = 2.9078, H(0.5) = 2.0128
    assert float(h_function(1.0, 1.0)) == pytest.approx(2.9078, abs=5e-5)
    assert float(h_function(1.0, 0.5)) == pytest.approx(2.0128, abs=5e-5)
    assert float(h_function(1.0, 0.0)) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("a", [0.3, 0.5, 0.9, 0.99, 1.0])
def test_zeroth_moment_identity(a):
    # ∫₀¹ H(μ) dμ = 2(1 − √(1 − a))/a (Chandrasekhar 1950, ch. V eq. (18): α₀ for Ψ = a/2)
    x, w = np.polynomial.legendre.leggauss(256)
    moment = float((w / 2 * h_function(a, (x + 1) / 2)).sum())
    assert moment == pytest.approx(2 * (1 - math.sqrt(1 - a)) / a, rel=1e-8)


@pytest.mark.parametrize("a", [0.5, 0.9, 0.99, 1.0])
@pytest.mark.parametrize("mu", [0.05, 0.3, 1.0])
def test_iteration_matches_integral_representation(a, mu):
    assert float(h_function(a, mu)) == pytest.approx(h_function_integral(a, mu), rel=1e-8)


def test_reflectance_limits():
    assert halfspace_reflectance(0.0) == pytest.approx(0.0, abs=1e-12)
    assert halfspace_reflectance(1.0) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan")])
def test_bad_albedo(bad):
    with pytest.raises(ValueError, match="albedo"):
        h_function(bad, 0.5)


def test_bad_mu():
    with pytest.raises(ValueError, match="mu"):
        h_function(0.5, 1.2)
