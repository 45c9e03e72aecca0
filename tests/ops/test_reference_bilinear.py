"""The bilinear irradiance reconstruction of ReferenceSSS against independent closed forms and
quadratures on a plane, and conservation on a curved surface."""

import math

import numpy as np
import pytest
import torch
from oracles import FOV, flat, step_gbuffer
from scipy import integrate, ndimage
from scipy.special import ndtr

from sssbench.ops import ReferenceSSS, reference_sss
from sssbench.ops.reference import reference_radius_px
from sssbench.profiles import SumOfGaussians


def tent_weights(p: SumOfGaussians, pix: float, k: int) -> np.ndarray:
    """1D weights (G, 2k+1) ∫ Λ(x/pix − d) φ_σ(x) dx by scipy's adaptive quadrature."""
    out = np.zeros((p.variances.numel(), 2 * k + 1))
    for gi, v in enumerate(p.variances.tolist()):
        s = math.sqrt(v)
        for j, d in enumerate(range(-k, k + 1)):

            def f(x, d=d, s=s):
                return (
                    max(0.0, 1 - abs(x / pix - d))
                    * math.exp(-0.5 * (x / s) ** 2)
                    / (s * math.sqrt(2 * math.pi))
                )

            lo, hi = (d - 1) * pix, (d + 1) * pix
            out[gi, j] = integrate.quad(f, lo, hi, points=[d * pix], epsabs=1e-15)[0]
    return out


def test_flat_plane_bilinear_equals_convolution_with_profile_times_hat():
    p = SumOfGaussians.from_table("skin_jg10")
    gen = torch.Generator().manual_seed(11)
    img = torch.rand(1, 3, 20, 22, generator=gen, dtype=torch.float64)
    g = flat(img, 90.0)
    pix = 2 * 90.0 * math.tan(FOV / 2) / 20
    k = reference_radius_px(g, p)
    m = tent_weights(p, pix, k)  # (G, n)
    w = p.weights.numpy()
    ker = np.einsum("gi,gj,gc->cij", m, m, w)
    want = np.stack(
        [
            ndimage.correlate(img[0, c].numpy(), ker[c], mode="nearest") / ker[c].sum()
            for c in range(3)
        ]
    )
    got = reference_sss(g, p, reconstruction="bilinear")[0].numpy()
    np.testing.assert_allclose(got, want, rtol=0, atol=3e-6)


def test_step_edge_bilinear_equals_the_linear_ramp_convolved_with_the_marginal():
    # the linearly interpolated step ramps from lo at the last dark centre x_a to hi at the
    # first bright one x_b; its convolution with the 1D marginal of each Gaussian is
    # (σ/p) [ψ((x − x_a)/σ) − ψ((x − x_b)/σ)], ψ(t) = t Φ(t) + φ(t)
    p = SumOfGaussians.from_table("skin_deon6")
    h, w = 8, 96
    z = h * 0.3 / (2 * math.tan(FOV / 2))
    g, x, edge = step_gbuffer(h, w, z, 0.1, 1.0)
    pix = 0.3
    xa, xb = edge - pix / 2, edge + pix / 2
    s = np.sqrt(p.variances.numpy())

    def psi(t):
        return t * ndtr(t) + np.exp(-0.5 * t * t) / math.sqrt(2 * math.pi)

    ramp = (s / pix) * (psi((x[:, None] - xa) / s) - psi((x[:, None] - xb) / s))  # (n, G)
    wts = p.weights.numpy()
    want = 0.1 + 0.9 * (ramp @ wts) / wts.sum(0)
    got = reference_sss(g, p, reconstruction="bilinear")[0, :, h // 2].numpy().T
    assert np.abs(got - want).max() < 2e-6


@pytest.mark.parametrize("method", ["multipole", "fft"])
def test_constant_irradiance_stays_constant_with_bilinear(method):
    from data_synth import make_scene

    p = SumOfGaussians.from_table("skin_deon6")
    if method == "fft":
        g = flat(torch.full((1, 3, 16, 16), 0.4, dtype=torch.float64), 50.0)
    else:
        # footprint ~0.55 mm: the narrower Gaussians by points, the wider by moments
        g = make_scene("sphere", (12, 12), dtype=torch.float64, radius=5.0, distance=20.0)
        g = g.replace(diffuse=torch.full_like(g.diffuse, 0.4))
    out = ReferenceSSS(p, method=method, reconstruction="bilinear")(g)
    on = g.mask_or_ones().expand_as(out) > 0
    assert float((out[on] - 0.4).abs().max()) < 1e-12


def test_gather_rejects_bilinear():
    g = flat(torch.rand(1, 3, 6, 6, dtype=torch.float64), 50.0)
    with pytest.raises(ValueError, match="bilinear"):
        reference_sss(
            g, SumOfGaussians.from_table("skin_deon6"), method="gather", reconstruction="bilinear"
        )
