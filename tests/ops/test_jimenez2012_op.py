"""Jimenez2012SSS (002 appendix shader): width in mm, strength from the mask as
``finalStep *= SSSS_STRENGTH_SOURCE``, the follow-surface lerp, conservation."""

import pytest
import torch
from oracles import FOV, flat

from sssbench.gbuffer import GBuffer
from sssbench.ops import Jimenez2012SSS, jimenez2012_sss, record_passes

STRENGTH, FALLOFF = (0.48, 0.41, 0.28), (1.0, 0.37, 0.3)


def rand_img(h=16, w=16, seed=0):
    return torch.rand(1, 3, h, w, generator=torch.Generator().manual_seed(seed)).double()


def test_mask_strength_scales_the_step_like_the_shader():
    """``finalStep *= SSSS_STRENGTH_SOURCE``: a mask of ½ blurs exactly like half the width;
    a mask of 0 is not computed (copied through, and not counted by the pass)."""
    img = rand_img()
    g = flat(img, 200.0)
    half = g.replace(mask=torch.full_like(g.depth, 0.5))
    a = Jimenez2012SSS(STRENGTH, FALLOFF, 4.0, follow_surface=False)(half)
    b = Jimenez2012SSS(STRENGTH, FALLOFF, 2.0, follow_surface=False)(g)
    torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)
    mask = torch.ones_like(g.depth)
    mask[..., :8] = 0
    with record_passes() as rec:
        out = jimenez2012_sss(g.replace(mask=mask), STRENGTH, FALLOFF, 4.0)
    assert torch.equal(out[..., :8], img[..., :8])
    assert [r.pixels for r in rec] == [16 * 8, 16 * 8]


def test_width_is_in_mm():
    """Width w at depth z covers the same pixels as width 2w at depth 2z."""
    img = rand_img(seed=1)
    a = Jimenez2012SSS(STRENGTH, FALLOFF, 3.0, follow_surface=False)(flat(img, 150.0))
    b = Jimenez2012SSS(STRENGTH, FALLOFF, 6.0, follow_surface=False)(flat(img, 300.0))
    torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)
    # and it blurs: the kernel spans ±4/3 widths (17 taps), i.e. several pixels here
    assert float((a - img).abs().max()) > 0.05


def test_zero_strength_is_the_identity():
    img = rand_img(seed=2)
    out = Jimenez2012SSS(0.0, FALLOFF, 5.0)(flat(img, 100.0))
    torch.testing.assert_close(out, img, rtol=0, atol=1e-15)


def test_follow_surface_stops_bleeding_across_a_depth_step():
    """The shader's lerp: a sample whose depth differs by more than ``surface_scale``
    (default: the width) is replaced by the centre colour, so the dark near plane stays
    dark next to a bright plane 50 mm behind it; without it, light bleeds in."""
    h, w = 8, 24
    img = torch.zeros(1, 3, h, w, dtype=torch.float64)
    img[..., w // 2 :] = 1.0
    depth = torch.full((1, 1, h, w), 100.0, dtype=torch.float64)
    depth[..., w // 2 :] = 150.0
    g = GBuffer(img, depth, FOV)
    on = Jimenez2012SSS(STRENGTH, FALLOFF, 5.0)(g)
    off = Jimenez2012SSS(STRENGTH, FALLOFF, 5.0, follow_surface=False)(g)
    # what leaks (measured 1.5e-3 vs 0.070 without) comes from samples within a tenth of a
    # pixel of the boundary, where the linearly interpolated depth is still within 5 mm
    assert float(on[..., : w // 2].max()) < 0.05 * float(off[..., : w // 2].max())
    assert float(off[..., : w // 2].max()) > 0.05


@pytest.mark.parametrize("dtype, tol", [(torch.float32, 1e-5), (torch.float64, 1e-12)])
def test_constant_image_is_unchanged(dtype, tol):
    gen = torch.Generator().manual_seed(0)
    depth = (80 + 40 * torch.rand(1, 1, 16, 16, generator=gen, dtype=torch.float64)).to(dtype)
    mask = torch.rand(1, 1, 16, 16, generator=gen, dtype=torch.float64).to(dtype)
    g = GBuffer(torch.full((1, 3, 16, 16), 0.8, dtype=dtype), depth, FOV, mask=mask)
    for kw in [{}, {"samples": 9, "quadrature": "integrated"}, {"samples": 33, "rotation": 0.3}]:
        out = Jimenez2012SSS.preset("shader_default", width=4.0, **kw)(g)
        assert out.dtype == dtype
        assert float((out - 0.8).abs().max()) < tol


def test_bad_arguments():
    with pytest.raises(ValueError, match="width"):
        Jimenez2012SSS(STRENGTH, FALLOFF, 0.0)
    with pytest.raises(TypeError, match="follow_surface"):
        Jimenez2012SSS(STRENGTH, FALLOFF, 1.0, follow_surface="lerp")
    with pytest.raises(ValueError, match="width"):
        Jimenez2012SSS.preset("table1")
