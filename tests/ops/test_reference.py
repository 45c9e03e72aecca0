"""ReferenceSSS against an FFT convolution, conservation, and the analytic step response."""

import math

import numpy as np
import pytest
import torch
from oracles import FOV, flat, step_gbuffer, step_response
from scipy.special import ndtr

from sssbench.ops import ReferenceSSS, reference_sss
from sssbench.ops import reference as reference
from sssbench.profiles import SumOfGaussians


def cell_kernel(p: SumOfGaussians, pix: float, k: int) -> np.ndarray:
    """Per-cell kernel (3, 2k+1, 2k+1) computed independently with scipy's ndtr."""
    v = p.variances.numpy()
    s = np.sqrt(v)
    w = p.weights.numpy()
    offs = np.arange(-k, k + 1) * pix
    lo = (offs[:, None] - pix / 2) / s
    hi = (offs[:, None] + pix / 2) / s
    m = ndtr(hi) - ndtr(lo)  # (n, G) mass of each 1D Gaussian over a cell
    ker = np.einsum("ig,jg,gc->cij", m, m, w)
    return ker / w.sum(0)[:, None, None]


def fft_convolve(img: np.ndarray, ker: np.ndarray) -> np.ndarray:
    """Replicate-pad and convolve each channel with torch.fft (independent of the gather)."""
    c, kh, kw = ker.shape
    k = kh // 2
    t = torch.from_numpy(img)[None]
    pad = torch.nn.functional.pad(t, (k, k, k, k), mode="replicate")[0]
    h, w = pad.shape[-2:]
    out = []
    for ch in range(c):
        kk = torch.zeros(h, w, dtype=torch.float64)
        kk[:kh, :kw] = torch.from_numpy(ker[ch])
        kk = torch.roll(kk, (-k, -k), (0, 1))
        res = torch.fft.irfft2(torch.fft.rfft2(pad[ch]) * torch.fft.rfft2(kk), s=(h, w))
        out.append(res[k : k + img.shape[1], k : k + img.shape[2]])
    return torch.stack(out).numpy()


def test_flat_plane_equals_fft_convolution_float64():
    p = SumOfGaussians.from_table("skin_jg10")
    gen = torch.Generator().manual_seed(3)
    img = torch.rand(1, 3, 24, 28, generator=gen, dtype=torch.float64)
    g = flat(img, 150.0)
    pix = 2 * 150.0 * math.tan(FOV / 2) / 24
    k = 8
    got = reference_sss(g, p, radius_px=k, method="gather")
    ref = fft_convolve(img[0].numpy(), cell_kernel(p, pix, k))
    np.testing.assert_allclose(got[0].numpy(), ref, atol=1e-6, rtol=0)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_constant_image_on_a_plane_is_unchanged(dtype):
    g = flat(torch.full((1, 3, 20, 20), 0.6, dtype=dtype), 400.0)
    out = ReferenceSSS(SumOfGaussians.from_table("skin_deon6"))(g)
    assert out.dtype == dtype
    assert float((out - 0.6).abs().max()) < 1e-6


def test_reference_reproduces_the_analytic_step_response_even_with_subpixel_gaussians():
    # skin_deon6 at 0.3 mm/px: its narrowest Gaussian (sigma 0.08 mm) is a quarter pixel.
    # Cell integration keeps its full weight, so the reference still equals the analytic
    # response of the piecewise-constant irradiance at the pixel centres.
    p = SumOfGaussians.from_table("skin_deon6")
    h, w = 8, 96
    z = h * 0.3 / (2 * math.tan(FOV / 2))
    g, x, edge = step_gbuffer(h, w, z, 0.1, 1.0)
    got = reference_sss(g, p)[0, :, h // 2].numpy().T
    ref = step_response(p, x, edge, 0.1, 1.0)
    assert np.abs(got - ref).max() < 2e-6


def test_fft_path_equals_gather_path_with_a_mask():
    p = SumOfGaussians.from_table("marble_jg10")
    gen = torch.Generator().manual_seed(5)
    img = torch.rand(1, 3, 20, 18, generator=gen, dtype=torch.float64)
    mask = (torch.rand(1, 1, 20, 18, generator=gen, dtype=torch.float64) > 0.2).double()
    g = flat(img, 120.0).replace(mask=mask)
    a = reference_sss(g, p, method="gather")
    b = reference_sss(g, p, method="fft")
    torch.testing.assert_close(a, b, rtol=0, atol=1e-10)


class _LoopSoG(SumOfGaussians):
    """The same profile through the generic offset-by-offset loop of ``cell_integral``."""

    def cell_integral(self, *args, **kwargs):
        return super().cell_integral(*args, **kwargs)


def _as_loop(p: SumOfGaussians) -> _LoopSoG:
    return _LoopSoG(p.variances, p.weights)


@pytest.fixture
def cell_integral_skip(monkeypatch):
    """The batched path with SumOfGaussians.cell_integral's own skip radius (e^-40)."""
    monkeypatch.setattr(reference, "_SOG_SKIP", 40.0)


@pytest.mark.parametrize(
    ("scene", "res", "table"),
    [("head", 48, "skin_deon6"), ("sphere", 40, "marble_jg10"), ("head_cheek", 24, "skin_jg10")],
)
def test_batched_sum_of_gaussians_path_equals_the_offset_loop(
    scene, res, table, cell_integral_skip
):
    from data_synth import make_scene

    p = SumOfGaussians.from_table(table)
    g = make_scene(scene, (res, res), dtype=torch.float64)
    fast = reference_sss(g, p, method="gather")
    loop = reference_sss(g, _as_loop(p), method="gather")
    torch.testing.assert_close(fast, loop, rtol=0, atol=1e-12)


def test_batched_path_equals_the_offset_loop_on_a_masked_plane(cell_integral_skip):
    # no slopes: the fronto-parallel closed form, and off-surface neighbours
    p = SumOfGaussians.from_table("skin_deon6")
    gen = torch.Generator().manual_seed(7)
    img = torch.rand(1, 3, 18, 22, generator=gen, dtype=torch.float64)
    mask = (torch.rand(1, 1, 18, 22, generator=gen, dtype=torch.float64) > 0.3).double()
    g = flat(img, 60.0).replace(mask=mask * 0.8)
    fast = reference_sss(g, p, method="gather")
    loop = reference_sss(g, _as_loop(p), method="gather")
    torch.testing.assert_close(fast, loop, rtol=0, atol=1e-12)


@pytest.mark.parametrize(("scene", "res"), [("head", 64), ("head_cheek", 32), ("pores", 20)])
def test_earlier_skip_of_far_gauss_legendre_cells_stays_within_its_bound(scene, res):
    # documented bound: 2 max E · 4.5e-10 over the gathered fraction of the weight (≥ ~0.1)
    from data_synth import make_scene

    p = SumOfGaussians.from_table("skin_deon6")
    g = make_scene(scene, (res, res), dtype=torch.float64)
    fast = reference_sss(g, p, method="gather")
    loop = reference_sss(g, _as_loop(p))  # cell_integral's skip radius
    bound = 2 * float(g.diffuse.abs().max()) * 4.5e-10 / 0.1
    assert float((fast - loop).abs().max()) < bound


@pytest.mark.parametrize("order", [2, 3, 4, 6, 10])
def test_gauss_legendre_block_equals_the_per_gaussian_rule(order):
    # the node polynomial and the two matrix products against the direct node sum of
    # sum_of_gaussians._tilted_gauss_legendre (same nodes), slopes up to the 85° clamp
    from sssbench.profiles.sum_of_gaussians import _tilted_gauss_legendre

    gen = torch.Generator().manual_seed(order)
    n = 500

    def rand(lo, hi):
        return lo + (hi - lo) * torch.rand(n, generator=gen, dtype=torch.float64)

    dx, dy, dz = rand(-4, 4), rand(-4, 4), rand(-3, 3)
    hh = rand(0.05, 0.6)
    sx, sy = rand(-11.4, 11.4) * rand(0, 1) ** 4, rand(-11.4, 11.4) * rand(0, 1) ** 4
    p = SumOfGaussians.from_table("skin_deon6")
    var = p.variances.tolist()[2:]
    w = p.weights[2:]
    got = reference._sog_gauss_legendre(dx, dy, dz, hh, sx, sy, var, [order] * len(var), w)
    want = sum(
        _tilted_gauss_legendre(dx, dy, dz, hh, hh, sx, sy, vi, order)[None, :] * w[i][:, None]
        for i, vi in enumerate(var)
    )
    torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-300)


@pytest.mark.parametrize(
    "name",
    [
        "reference.py",
        "_reference_far.py",
        "_reference_flat.py",
        "_reference_near.py",
        "_reference_quad.py",
        "quad.c",
        "quad_simd.h",
        "exp2_32.h",
        "burley.py",
        "base.py",
    ],
)
def test_code_digest_covers_every_reference_module(name, monkeypatch):
    # caches of references are keyed by the digest: editing any module that computes them
    # must change it
    import pathlib

    base = reference.reference_code_digest()
    read = pathlib.Path.read_text

    def edited(self, *args, **kwargs):
        text = read(self, *args, **kwargs)
        return text + "\n# edited" if self.name == name else text

    monkeypatch.setattr(pathlib.Path, "read_text", edited)
    assert reference.reference_code_digest() != base
