"""kernel_matrix and low_rank against independent oracles (scipy dblquad, numpy SVD)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import integrate

from sssbench.kernels import cell_centres, kernel_matrix, low_rank, reconstruct, singular_energy
from sssbench.profiles import SumOfGaussians

SKIN = SumOfGaussians.from_table("skin_deon6")


def _radial_numpy(r: float, channel: int) -> float:
    """Independent evaluation of the skin_deon6 R(r) (001 eq. 7) in plain Python."""
    from sssbench.profiles import SOG_TABLES

    variances, weights = SOG_TABLES["skin_deon6"]
    return sum(
        w[channel] * math.exp(-r * r / (2 * v)) / (2 * math.pi * v)
        for v, w in zip(variances, weights, strict=True)
    )


@pytest.mark.parametrize("cell", [(4, 4), (4, 5), (0, 2), (6, 8)])
def test_kernel_matrix_matches_dblquad(cell: tuple[int, int]) -> None:
    extent, n = 2.0, 9
    m = kernel_matrix(SKIN, extent, n)
    c = cell_centres(extent, n).numpy()
    h = extent / n
    j, i = cell
    for ch in range(3):
        ref, _ = integrate.dblquad(
            lambda y, x, ch=ch: _radial_numpy(math.hypot(x, y), ch),
            c[i] - h,
            c[i] + h,
            c[j] - h,
            c[j] + h,
            epsabs=1e-13,
            epsrel=1e-10,
        )
        assert float(m[ch, j, i]) == pytest.approx(ref, rel=1e-7, abs=1e-13)


def test_kernel_matrix_is_symmetric_and_sums_to_energy_inside() -> None:
    m = kernel_matrix(SKIN, 10.0, 31)
    assert m.shape == (3, 31, 31) and m.dtype == torch.float64
    torch.testing.assert_close(m, m.transpose(1, 2), rtol=0, atol=1e-15)
    torch.testing.assert_close(m, m.flip(1), rtol=0, atol=1e-15)
    # closed form: a unit 2D Gaussian puts (erf(E / σ√2))² of its mass in the square [-E, E]²
    from sssbench.profiles import SOG_TABLES

    variances, weights = SOG_TABLES["skin_deon6"]
    ref = [
        sum(
            w[c] * math.erf(10.0 / math.sqrt(2 * v)) ** 2
            for v, w in zip(variances, weights, strict=True)
        )
        for c in range(3)
    ]
    np.testing.assert_allclose(m.sum((1, 2)).numpy(), ref, rtol=1e-12)


def test_cell_not_point_sampled() -> None:
    """A Gaussian much narrower than a cell keeps its mass in the centre cell."""
    narrow = SumOfGaussians(torch.tensor([1e-4]), torch.tensor([[1.0, 1.0, 1.0]]))
    m = kernel_matrix(narrow, 1.5, 3)  # cells 1 mm wide, σ = 0.01 mm
    assert float(m[0, 1, 1]) == pytest.approx(1.0, abs=1e-12)


def test_low_rank_matches_numpy_svd() -> None:
    extent, n = 10.0, 41
    m = kernel_matrix(SKIN, extent, n)
    lr = low_rank(m, 4, extent=extent)
    for ch in range(3):
        s_ref = np.linalg.svd(m[ch].numpy(), compute_uv=False)
        np.testing.assert_allclose(lr.singular_values[:, ch].numpy(), s_ref, rtol=1e-10, atol=1e-15)
        np.testing.assert_allclose(
            lr.energy[:, ch].numpy(), s_ref**2 / (s_ref**2).sum(), atol=1e-12
        )
        # rank-N reconstruction = Eckart–Young truncation of the numpy SVD
        u, s, vt = np.linalg.svd(m[ch].numpy())
        best = (u[:, :4] * s[:4]) @ vt[:4]
        np.testing.assert_allclose(reconstruct(lr.terms)[ch].numpy(), best, atol=1e-13)


def test_full_rank_reconstruction_equals_matrix() -> None:
    extent, n = 8.0, 35
    lr = low_rank(SKIN, n, extent=extent, n=n)
    torch.testing.assert_close(
        reconstruct(lr.terms), kernel_matrix(SKIN, extent, n), rtol=0, atol=1e-14
    )


def test_terms_packing_offsets_symmetry_sign() -> None:
    lr = low_rank(SKIN, 2, extent=10.0, n=51)
    h, v = lr.terms[0]
    torch.testing.assert_close(h.offsets, cell_centres(10.0, 51))
    # symmetric kernel: first component is symmetric and positive, horizontal == vertical
    torch.testing.assert_close(h.weights, v.weights, rtol=0, atol=1e-12)
    torch.testing.assert_close(h.weights, h.weights.flip(0), rtol=0, atol=1e-12)
    assert bool((h.weights > -1e-14).all()) and bool((h.weights[25] > 0).all())
    for hh, _ in lr.terms:
        assert bool((hh.weights.sum(0) >= -1e-15).all())


def test_first_singular_value_dominates_skin() -> None:
    """002 §3.1 / Fig. 2: the first singular value holds most of the energy (~80%).

    Measured for skin_deon6, extent 10 mm, 101 cells: s1²/Σs² = (0.977, 0.992, 0.997),
    s1/Σs = (0.842, 0.911, 0.950). Either way the first value dominates every channel and red,
    the widest channel, is the least separable.
    """
    lr = low_rank(SKIN, 1, extent=10.0, n=101)
    e1 = lr.energy[0]
    torch.testing.assert_close(
        e1, torch.tensor([0.9771, 0.9917, 0.9973], dtype=torch.float64), rtol=0, atol=5e-4
    )
    s = lr.singular_values
    frac = s[0] / s.sum(0)
    assert bool((frac > 0.8).all())
    assert float(e1[0]) < float(e1[1]) < float(e1[2])


def test_singular_energy_example() -> None:
    torch.testing.assert_close(
        singular_energy(torch.tensor([3.0, 4.0])), torch.tensor([0.36, 0.64])
    )


def test_low_rank_bad_inputs() -> None:
    m = kernel_matrix(SKIN, 5.0, 11)
    with pytest.raises(ValueError, match="rank"):
        low_rank(m, 12, extent=5.0)
    with pytest.raises(ValueError, match="rank"):
        low_rank(m, 0, extent=5.0)
    with pytest.raises(TypeError, match="rank"):
        low_rank(m, 1.0, extent=5.0)
    with pytest.raises(ValueError, match="extent"):
        low_rank(m, 1)
    with pytest.raises(ValueError, match="profile_or_matrix"):
        low_rank(m[:2], 1, extent=5.0)
    with pytest.raises(TypeError, match="profile_or_matrix"):
        low_rank([1, 2], 1, extent=5.0)
    bad = m.clone()
    bad[0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="profile_or_matrix"):
        low_rank(bad, 1, extent=5.0)
    with pytest.raises(ValueError, match="extent"):
        kernel_matrix(SKIN, -1.0, 11)
    with pytest.raises(ValueError, match="n must"):
        kernel_matrix(SKIN, 1.0, 0)
    with pytest.raises(TypeError, match="profile"):
        kernel_matrix("skin", 1.0, 3)
