"""Empirical dipole fit (001 Appendix A): C_i limits, structure, measured error."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from sssbench.profiles import Dipole
from sssbench.profiles.empirical import (
    VARIANCE_RATIOS,
    c_curves,
    empirical_dipole_fit,
    empirical_pole_fit,
    pole_fit_error,
)
from sssbench.profiles.fit import rel_rms_power


def c_naive(x: float) -> list[float]:
    """001 App. A as printed, in plain float arithmetic (valid away from 0)."""
    e = math.exp
    return [
        -0.3454 + 1.2422 / x - 1.2422 * e(-0.7452 * x) / x,
        5.34071 * ((1 - e(-0.716 * x)) * (0.9029 * x - 0.7401) / x + 0.90295 * e(-0.7165 * x)),
        10.2416
        * (
            (1 - e(-1.0961 * x)) * (0.2420 * x + 0.1804) / x
            - 0.00244 * e(-1.0961 * x) * (0.2041 * x + 0.1752)
        ),
        23.185
        * (
            (1 - e(-1.433 * x)) * (0.0505 - 0.0395 * x) / x
            + 0.04425 * e(-1.433 * x) * (0.09187 * x + 0.06034)
        ),
    ]


def c_limit0() -> list[float]:
    """x -> 0 limits: (1 − e^{−ax})/x -> a."""
    return [
        -0.3454 + 1.2422 * 0.7452,
        5.34071 * (0.716 * -0.7401 + 0.90295),
        10.2416 * (1.0961 * 0.1804 - 0.00244 * 0.1752),
        23.185 * (1.433 * 0.0505 + 0.04425 * 0.06034),
    ]


def test_c_curves_near_zero_exact():
    lim = c_limit0()
    for x in (0.0, 1e-300, 1e-12):
        got = c_curves(x).tolist()
        for g, ref in zip(got, lim, strict=True):
            assert g == pytest.approx(ref, rel=1e-11, abs=1e-15)
    # first-order term: C(x) ≈ C(0) + C'(0) x; at 1e-8 the change is ~1e-8
    assert torch.allclose(c_curves(1e-8), torch.tensor(lim, dtype=torch.float64), rtol=1e-7)


@pytest.mark.parametrize("x", [1e-3, 0.1, 1.0, 7.0, 100.0, 1e4])
def test_c_curves_match_formula(x):
    assert c_curves(x).tolist() == pytest.approx(c_naive(x), rel=1e-12, abs=1e-14)


def test_c_curves_large_x_finite_no_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        c = c_curves(torch.tensor([1e4, 1e8], dtype=torch.float64))
    assert torch.isfinite(c).all()
    with pytest.raises(ValueError, match="x must be"):
        c_curves(-1.0)
    with pytest.raises(ValueError, match="x must be"):
        c_curves(float("nan"))


def test_pole_fit_structure():
    sog = empirical_pole_fit(0.5, 2.0)
    x = 1.0
    v0 = 4.0 / (1 + x)
    assert torch.allclose(sog.variances, v0 * torch.tensor(VARIANCE_RATIOS, dtype=torch.float64))
    pd = math.exp(-x) / 2.0
    assert torch.allclose(sog.weights[:, 0], c_curves(x) * pd)
    assert empirical_pole_fit([0.1, 0.2, 0.3], 1.0).variances.numel() == 12


def test_dipole_fit_structure_and_spectralon():
    sog = empirical_dipole_fit("marble")
    assert sog.variances.numel() == 24
    assert ((sog.weights != 0).sum(1) == 1).all()
    s = empirical_dipole_fit(Dipole.from_material("spectralon"))
    assert torch.isfinite(s.weights).all() and torch.isfinite(s.variances).all()


def test_error_depends_only_on_sigma_z_and_measured_range():
    # the documented invariance: error(σ, z) == error(σ z, 1)
    e1 = pole_fit_error(0.3, 2.0)
    e2 = pole_fit_error(0.6, 1.0)
    assert torch.allclose(e1, e2, rtol=1e-6)
    # coarse grid over 001 Fig. 11's square: the documented (measured) range 0.68 %..7.6 %
    g = np.geomspace(1e-3, 15, 4)
    errs = np.array([[float(pole_fit_error(s, z)[0]) for z in g] for s in g])
    assert errs.max() == pytest.approx(0.0758, abs=0.001)  # x = 1e-6 ≈ the x -> 0 limit
    assert errs.min() > 0.0068
    assert float(pole_fit_error(0.46, 1.0)[0]) == pytest.approx(0.0068, abs=0.0002)


def test_dipole_fit_errors_documented():
    e = rel_rms_power(Dipole.from_material("skin1"), empirical_dipole_fit("skin1"))
    assert 0.009 < float(e.min()) and float(e.max()) < 0.012
    e = rel_rms_power(Dipole.from_material("marble"), empirical_dipole_fit("marble"))
    assert 0.04 < float(e.min()) and float(e.max()) < 0.052


def test_bad_inputs():
    with pytest.raises(ValueError, match="z must"):
        empirical_pole_fit(0.5, 0.0)
    with pytest.raises(ValueError, match="sigma_tr must"):
        empirical_pole_fit(-0.5, 1.0)
    with pytest.raises(ValueError, match="sigma_tr"):
        empirical_pole_fit(float("nan"), 1.0)
    with pytest.raises(ValueError, match="name must be one of"):
        empirical_dipole_fit("jade")
    with pytest.raises(TypeError, match="material_or_dipole"):
        empirical_dipole_fit(3.0)
