"""Dipole: closed forms against the materials.md formula and scipy quadrature."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import torch
from scipy import integrate, special

from sssbench.profiles import Dipole
from sssbench.profiles.dipole import MATERIALS


def quad(f, a, b, **kw):
    kw.setdefault("epsabs", 0.0)
    kw.setdefault("epsrel", 1e-11)
    kw.setdefault("limit", 1000)
    return integrate.quad(f, a, b, **kw)[0]


def rd_formula(ss: float, sa: float, eta: float = 1.3) -> float:
    """materials.md, written out independently of the implementation."""
    st = ss + sa
    alpha = ss / st
    fdr = -1.440 / eta**2 + 0.710 / eta + 0.668 + 0.0636 * eta
    big_a = (1 + fdr) / (1 - fdr)
    s = math.sqrt(3 * (1 - alpha))
    return alpha / 2 * (1 + math.exp(-4 / 3 * big_a * s)) * math.exp(-s)


def r_formula(r: float, ss: float, sa: float, eta: float = 1.3) -> float:
    st = ss + sa
    alpha = ss / st
    str_ = math.sqrt(3 * sa * st)
    fdr = -1.440 / eta**2 + 0.710 / eta + 0.668 + 0.0636 * eta
    big_a = (1 + fdr) / (1 - fdr)
    zr = 1 / st
    zv = zr + 4 * big_a / (3 * st)
    dr, dv = math.hypot(r, zr), math.hypot(r, zv)
    return (
        alpha
        / (4 * math.pi)
        * (
            zr * (str_ * dr + 1) * math.exp(-str_ * dr) / dr**3
            + zv * (str_ * dv + 1) * math.exp(-str_ * dv) / dv**3
        )
    )


@pytest.mark.parametrize("name", sorted(MATERIALS))
def test_total_closed_form_and_quadrature(name):
    p = Dipole.from_material(name)
    ss, sa = MATERIALS[name]
    tot = p.total()

    def R(r, c):
        return r_formula(r, ss[c], sa[c])

    for c in range(3):
        assert float(tot[c]) == pytest.approx(rd_formula(ss[c], sa[c]), rel=1e-13)
        # 2πr R(r): split at the length scales so quad sees each feature
        z = float(p.z_r[c])
        pts = [0.0, z, 10 * z, 100 * z, 1e3 * z, 1e4 * z, 1e5 * z]
        num = sum(
            quad(lambda r, c=c: 2 * math.pi * r * R(r, c), a, b)
            for a, b in zip(pts[:-1], pts[1:], strict=True)
        )
        num += quad(lambda r, c=c: 2 * math.pi * r * R(r, c), pts[-1], np.inf)
        assert float(tot[c]) == pytest.approx(num, rel=1e-7)


@pytest.mark.parametrize("name", ["marble", "ketchup", "spectralon", "skin1"])
def test_evaluate_matches_formula(name):
    p = Dipole.from_material(name)
    ss, sa = MATERIALS[name]
    r = np.array([0.0, 1e-3, 0.1, 1.0, 10.0, 100.0])
    got = p(torch.from_numpy(r))
    assert got.shape == (6, 3)
    for i, rv in enumerate(r):
        for c in range(3):
            assert float(got[i, c]) == pytest.approx(r_formula(rv, ss[c], sa[c]), rel=1e-12)


def test_case_insensitive_and_unknown():
    assert torch.equal(
        Dipole.from_material("MaRbLe").total(), Dipole.from_material("marble").total()
    )
    with pytest.raises(ValueError, match="name must be one of .*marble.*got 'jade'"):
        Dipole.from_material("jade")
    with pytest.raises(TypeError, match="name"):
        Dipole.from_material(3)


@pytest.mark.parametrize(
    ("kw", "arg"),
    [
        ({"sigma_s_prime": [-1.0, 1, 1], "sigma_a": [0.1] * 3}, "sigma_s_prime"),
        ({"sigma_s_prime": [0.0, 1, 1], "sigma_a": [0.1] * 3}, "sigma_s_prime"),
        ({"sigma_s_prime": [1.0] * 3, "sigma_a": [-0.1, 0, 0]}, "sigma_a"),
        ({"sigma_s_prime": [1.0] * 3, "sigma_a": [float("nan"), 0, 0]}, "sigma_a"),
        ({"sigma_s_prime": [1.0, 1.0], "sigma_a": 0.1}, "sigma_s_prime"),
        ({"sigma_s_prime": 1.0, "sigma_a": 0.1, "eta": 0.5}, "eta"),
        ({"sigma_s_prime": 1.0, "sigma_a": 0.1, "eta": float("nan")}, "eta"),
    ],
)
def test_bad_inputs(kw, arg):
    with pytest.raises((ValueError, TypeError), match=arg):
        Dipole(**kw)


def test_r_nan_rejected():
    with pytest.raises(ValueError, match="r must be finite"):
        Dipole.from_material("marble")(torch.tensor([float("nan")]))


def test_spectralon_power_law():
    p = Dipole.from_material("spectralon")
    assert torch.allclose(p.total(), torch.ones(3, dtype=torch.float64), rtol=0, atol=1e-15)
    r = torch.tensor([0.0, 1.0, 1e3, 1e6], dtype=torch.float64)
    vals = p(r)
    assert torch.isfinite(vals).all()
    # far field: R ≈ α'(z_r + z_v)/(4π r³) with α' = 1
    tail = (p.z_r + p.z_v) / (4 * math.pi * 1e6**3)
    assert torch.allclose(vals[-1], tail, rtol=1e-9)
    for q in (p.preintegrated(r), p.preintegrated_cdf(r), p.second_moment()):
        assert torch.isfinite(q).all()
    # energy beyond ρ ≈ (z_r + z_v)/(2ρ): radius(1e-2) ≈ 50 (z_r + z_v) per channel
    rad = p.radius(1e-2)
    expect = float(((p.z_r + p.z_v) / (2 * 1e-2)).max())
    assert rad == pytest.approx(expect, rel=1e-3)
    e = p.energy_beyond(rad)
    assert float(e.max()) == pytest.approx(1e-2, rel=1e-9)


def test_ketchup_blue_tiny_total():
    p = Dipole.from_material("ketchup")
    tot = p.total()
    ss, sa = MATERIALS["ketchup"]

    def R(r, c):
        return r_formula(r, ss[c], sa[c])

    assert 1e-3 < float(tot[2]) < 2e-3
    # profile quadrature agrees for the tiny channel too
    z = float(p.z_r[2])
    num = quad(lambda r: 2 * math.pi * r * R(r, 2), 0, 50 * z) + quad(
        lambda r: 2 * math.pi * r * R(r, 2), 50 * z, np.inf
    )
    assert float(tot[2]) == pytest.approx(num, rel=1e-8)


@pytest.mark.parametrize("name", ["marble", "ketchup", "spectralon"])
def test_preintegrated_against_quad(name):
    p = Dipole.from_material(name)
    ss, sa = MATERIALS[name]

    def R(r, c):
        return r_formula(r, ss[c], sa[c])

    for x in (0.0, 0.05, 0.7, 4.0, 25.0):
        got = p.preintegrated(x)
        for c in range(3):
            ref = 2 * quad(lambda y, x=x, c=c: R(math.hypot(x, y), c), 0, 1.0) + 2 * quad(
                lambda y, x=x, c=c: R(math.hypot(x, y), c), 1.0, np.inf
            )
            assert float(got[c]) == pytest.approx(ref, rel=1e-8)


def test_preintegrated_closed_form_against_bessel():
    # σK1 form vs scipy.special.k1 directly for one pole
    p = Dipole.from_material("skin1")
    x = 0.3
    c = 1
    s, zr, zv = float(p.sigma_tr[c]), float(p.z_r[c]), float(p.z_v[c])
    ref = 0.0
    for z in (zr, zv):
        rho = math.hypot(x, z)
        ref += z * 2 * s * special.k1(s * rho) / rho
    ref *= float(p.alpha_prime[c]) / (4 * math.pi)
    assert float(p.preintegrated(x)[c]) == pytest.approx(ref, rel=1e-13)


@pytest.mark.parametrize("name", ["marble", "ketchup", "spectralon"])
def test_preintegrated_cdf_against_quad(name):
    p = Dipole.from_material(name)
    xs = [-3.0, -0.2, 0.0, 0.01, 0.5, 2.0, 40.0]
    got = p.preintegrated_cdf(torch.tensor(xs, dtype=torch.float64))
    tot = p.total()
    for i, x in enumerate(xs):
        for c in range(3):
            part = quad(lambda t, c=c: float(p.preintegrated(t)[c]), 0, abs(x)) if x else 0.0
            ref = 0.5 * float(tot[c]) + math.copysign(part, x)
            assert float(got[i, c]) == pytest.approx(ref, rel=1e-9, abs=1e-13)
    ends = p.preintegrated_cdf(torch.tensor([-math.inf, math.inf], dtype=torch.float64))
    assert torch.allclose(ends[0], torch.zeros(3, dtype=torch.float64))
    assert torch.allclose(ends[1], tot)


def test_preintegrated_cdf_fast():
    p = Dipole.from_material("skin1")
    x = torch.linspace(-30, 30, 300, dtype=torch.float64)
    p.preintegrated_cdf(x)
    t0 = time.perf_counter()
    out = p.preintegrated_cdf(x)
    assert time.perf_counter() - t0 < 0.5
    assert bool((out.diff(dim=0) >= -1e-15).all())  # monotone


@pytest.mark.parametrize("name", ["marble", "skin1", "ketchup"])
def test_second_moment_and_radius(name):
    p = Dipole.from_material(name)
    ss, sa = MATERIALS[name]

    def R(r, c):
        return r_formula(r, ss[c], sa[c])

    m = p.second_moment()
    for c in range(3):
        z = float(p.z_r[c])
        num = quad(lambda r, c=c: math.pi * r**3 * R(r, c), 0, 10 * z) + quad(
            lambda r, c=c: math.pi * r**3 * R(r, c), 10 * z, np.inf
        )
        assert float(m[c]) == pytest.approx(num / float(p.total()[c]), rel=1e-7)
    rad = p.radius()
    # by definition: at most tol of every channel's energy beyond, and R below tol of peak
    e = p.energy_beyond(rad) / p.total()
    assert float(e.max()) <= 1e-4 * (1 + 1e-9)
    assert float((p(rad) / p(0.0)).max()) <= 1e-4 * (1 + 1e-9)
    assert (
        float((p.energy_beyond(rad * 0.99) / p.total()).max()) > 1e-4
        or float((p(rad * 0.99) / p(0.0)).max()) > 1e-4
    )


def test_energy_beyond_against_quad():
    p = Dipole.from_material("potato")
    ss, sa = MATERIALS["potato"]

    def R(r, c):
        return r_formula(r, ss[c], sa[c])

    for rho in (0.0, 0.5, 5.0):
        e = p.energy_beyond(rho)
        for c in range(3):
            ref = quad(lambda r, c=c: 2 * math.pi * r * R(r, c), rho, rho + 10) + quad(
                lambda r, c=c: 2 * math.pi * r * R(r, c), rho + 10, np.inf
            )
            assert float(e[c]) == pytest.approx(ref, rel=1e-8)
