"""Layer composition (001 §4 eq. 11–15) against brute-force 2D FFT convolution."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sssbench.profiles import Dipole
from sssbench.profiles.layers import Layer, compose_layers, fit_powers_of_gaussian, poly_to_sog

V = 0.05  # mm²


def poly(entries: dict[int, list[float]], k: int = 4) -> torch.Tensor:
    out = torch.zeros(k, 3, dtype=torch.float64)
    for i, w in entries.items():
        out[i] = torch.tensor(w, dtype=torch.float64)
    return out


def two_layers():
    top = Layer(
        r_plus=poly({1: [0.2, 0.1, 0.05]}),
        r_minus=poly({1: [0.3, 0.2, 0.1], 2: [0.1, 0.1, 0.1]}),
        t_plus=poly({2: [0.5, 0.6, 0.7]}),
        t_minus=poly({1: [0.4, 0.5, 0.6]}),
        v=V,
    )
    bottom = Layer(
        r_plus=poly({3: [0.5, 0.3, 0.2]}),
        r_minus=poly({1: [0.1, 0.1, 0.1]}),
        t_plus=poly({1: [0.3, 0.3, 0.3]}),
        t_minus=poly({2: [0.2, 0.3, 0.4]}),
        v=V,
    )
    return top, bottom


def fft_compose(top: Layer, bottom: Layer, n: int = 256, h: float = 0.05):
    """Kubelka–Munk in frequency space (001 eq. 5) on sampled profiles: brute-force oracle."""
    ax = (np.arange(n) - n // 2) * h
    xx, yy = np.meshgrid(ax, ax, indexing="ij")
    rr = torch.from_numpy(np.sqrt(xx**2 + yy**2))

    def ft(p):
        img = poly_to_sog(p, V)(rr).numpy() * h * h  # (n, n, 3) cell masses
        return np.fft.fft2(np.fft.ifftshift(img, axes=(0, 1)), axes=(0, 1))

    def back(f):
        return np.fft.fftshift(np.fft.ifft2(f, axes=(0, 1)).real, axes=(0, 1)) / (h * h)

    r1p, r1m, t1p, t1m = (ft(getattr(top, k)) for k in ("r_plus", "r_minus", "t_plus", "t_minus"))
    r2p, r2m, t2p, t2m = (
        ft(getattr(bottom, k)) for k in ("r_plus", "r_minus", "t_plus", "t_minus")
    )
    km = 1 / (1 - r2p * r1m)
    out = {
        "t_plus": back(t1p * t2p * km),
        "r_plus": back(r1p + t1p * r2p * t1m * km),
        "t_minus": back(t2m * t1m * km),
        "r_minus": back(r2m + t2m * r1m * t2p * km),
    }
    return rr, out


def test_compose_matches_fft_convolution():
    top, bottom = two_layers()
    comp = compose_layers(top, bottom, eps=1e-12)
    rr, ref = fft_compose(top, bottom)
    for k, img in ref.items():
        got = comp.profile(k)(rr).numpy()
        scale = np.abs(img).max()
        assert np.abs(got - img).max() < 1e-6 * scale, k


def test_totals_match_kubelka_munk():
    top, bottom = two_layers()
    comp = compose_layers(top, bottom, eps=1e-12)
    r1m, r2p = top.r_minus.sum(0), bottom.r_plus.sum(0)
    km = top.t_plus.sum(0) * bottom.t_plus.sum(0) / (1 - r2p * r1m)  # 001 eq. 5 totals
    assert torch.allclose(comp.t_plus.sum(0), km, rtol=0, atol=1e-12)
    assert torch.allclose(comp.profile("t_plus").total(), km, atol=1e-12)


def test_eps_controls_missing_energy():
    top, bottom = two_layers()
    km = top.t_plus.sum(0) * bottom.t_plus.sum(0) / (1 - bottom.r_plus.sum(0) * top.r_minus.sum(0))
    for eps in (1e-2, 1e-4, 1e-8):
        got = compose_layers(top, bottom, eps=eps).t_plus.sum(0)
        assert float((km - got).max()) < eps
        assert float((km - got).min()) >= 0


def test_slow_convergence_capped():
    top = Layer(
        poly({1: [0.1] * 3}), poly({1: [0.9999] * 3}), poly({1: [0.5] * 3}), poly({1: [0.5] * 3}), V
    )
    bottom = Layer(
        poly({1: [0.9999] * 3}), poly({1: [0.1] * 3}), poly({1: [0.5] * 3}), poly({1: [0.5] * 3}), V
    )
    with pytest.raises(ValueError, match="max_terms"):
        compose_layers(top, bottom, eps=1e-9, max_terms=2000)
    bad = Layer(
        poly({1: [1.0] * 3}), poly({1: [0.1] * 3}), poly({1: [0.5] * 3}), poly({1: [0.5] * 3}), V
    )
    worse = Layer(
        poly({1: [0.1] * 3}), poly({1: [1.0] * 3}), poly({1: [0.5] * 3}), poly({1: [0.5] * 3}), V
    )
    with pytest.raises(ValueError, match="must be < 1"):
        compose_layers(worse, bad)


def test_transparent_layer_is_identity():
    _, bottom = two_layers()
    k = 4
    delta = poly({0: [1.0] * 3}, k)
    zero = poly({}, k)
    clear = Layer(zero, zero, delta, delta, V)
    comp = compose_layers(clear, bottom, eps=1e-14)
    for name in ("r_plus", "t_plus", "t_minus", "r_minus"):
        a, b = getattr(comp, name), getattr(bottom, name)
        n = max(a.shape[0], b.shape[0])
        pa = torch.zeros(n, 3, dtype=torch.float64)
        pb = torch.zeros(n, 3, dtype=torch.float64)
        pa[: a.shape[0]] = a
        pb[: b.shape[0]] = b
        assert torch.allclose(pa, pb, atol=1e-14), name


def test_fit_powers_of_gaussian_dipole():
    p = Dipole.from_material("skin1")
    coef = fit_powers_of_gaussian(p, 0.04, 120)
    from sssbench.profiles.fit import rel_rms_power

    err = rel_rms_power(p, poly_to_sog(coef, 0.04))
    assert float(err.max()) < 0.05


def test_bad_inputs():
    top, bottom = two_layers()
    with pytest.raises(ValueError, match="r_plus must have shape"):
        Layer(torch.zeros(3, 2).double(), top.r_minus, top.t_plus, top.t_minus, V)
    with pytest.raises(ValueError, match="t_plus contains"):
        Layer(top.r_plus, top.r_minus, torch.full((2, 3), float("nan")).double(), top.t_minus, V)
    with pytest.raises(ValueError, match="v must"):
        Layer(top.r_plus, top.r_minus, top.t_plus, top.t_minus, -1.0)
    other = Layer(bottom.r_plus, bottom.r_minus, bottom.t_plus, bottom.t_minus, 2 * V)
    with pytest.raises(ValueError, match="v must be equal"):
        compose_layers(top, other)
    with pytest.raises(ValueError, match="eps"):
        compose_layers(top, bottom, eps=0.0)


def test_power_fit_of_a_dipole_stays_bounded_and_non_negative():
    """Unconstrained least squares gave 1e7–1e8 alternating coefficients at degree 40; the
    fit is of a non-negative profile, so its coefficients are constrained non-negative and
    their sum cannot exceed a few times the profile's total (here Σc ≈ total, tested 2×)."""
    from sssbench.profiles import Dipole
    from sssbench.profiles.layers import fit_powers_of_gaussian

    d = Dipole.from_material("skin1")
    c = fit_powers_of_gaussian(d, 0.01, 40)
    assert bool((c >= 0).all())
    assert bool((c.sum(0) <= 2 * d.total()).all())
