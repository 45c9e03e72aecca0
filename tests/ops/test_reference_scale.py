"""ReferenceSSS at extreme scales: energy is kept, the scene's scale does not matter, and
depths it cannot represent are a clear error."""

import math

import pytest
import torch
from oracles import FOV, flat

from sssbench.gbuffer import GBuffer
from sssbench.ops import ReferenceSSS, reference_sss
from sssbench.profiles import SumOfGaussians

SKIN = SumOfGaussians.from_table("skin_deon6")


def _noisy(g: GBuffer, amount: float) -> GBuffer:
    gen = torch.Generator().manual_seed(1)
    noise = torch.rand(g.depth.shape, generator=gen, dtype=g.depth.dtype)
    return g.replace(depth=g.depth * (1 + amount * noise))


@pytest.mark.parametrize("z", [1e-17, 1e-60, 1e12, 1e60])
def test_a_constant_irradiance_stays_constant_at_any_depth(z):
    # pixel footprint 1e-19 .. 1e58 mm against a profile of 0.08..2.7 mm: the kernel is much
    # wider than the image, or much narrower than a pixel; conservation holds either way
    g = flat(torch.full((1, 3, 12, 12), 0.6, dtype=torch.float64), z)
    for scene in (g, _noisy(g, 1e-6)):
        out = ReferenceSSS(SKIN)(scene)
        assert float((out - 0.6).abs().max()) < 1e-12


@pytest.mark.parametrize("z", [1e12, 1e60])
def test_a_profile_far_narrower_than_a_pixel_leaves_the_image_unchanged(z):
    # the nearest neighbour is 1e10 σ away: its weight underflows (exp(-1e20)), so every pixel
    # keeps its own value
    gen = torch.Generator().manual_seed(2)
    img = torch.rand(1, 3, 10, 10, generator=gen, dtype=torch.float64)
    for g in (flat(img, z), _noisy(flat(img, z), 1e-3)):
        torch.testing.assert_close(ReferenceSSS(SKIN)(g), img, rtol=1e-12, atol=0)


@pytest.mark.parametrize("scale", [1e-5, 1e5])
def test_scaling_scene_and_profile_together_changes_nothing(scale):
    # the reference is dimensionless: depths ×s and profile widths ×s give the same image.
    # The scale spans the whole range a profile may take (variances 1e-12 .. 1e12 mm² are
    # validated on entry, docs/reliability.md): 0.02 mm² × 1e-10 and 1.5 mm² × 1e10
    gen = torch.Generator().manual_seed(3)
    h = w = 24
    img = torch.rand(1, 3, h, w, generator=gen, dtype=torch.float64)
    yy, xx = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    depth = (30.0 + 0.15 * xx + 0.05 * (yy - 12.0) ** 2).to(torch.float64)[None, None]
    mask = ((xx - 12.0) ** 2 + (yy - 12.0) ** 2 < 100).to(torch.float64)[None, None]
    g = GBuffer(img, depth, FOV, mask=mask)
    small = SumOfGaussians(torch.tensor([0.02, 0.3, 1.5]), SKIN.weights[[1, 3, 4]])
    scaled = SumOfGaussians(small.variances * scale**2, small.weights)
    base = reference_sss(g, small)
    out = reference_sss(g.replace(depth=depth * scale), scaled)
    torch.testing.assert_close(out, base, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("z", [1e-120, 1e120])
def test_depths_beyond_the_documented_range_are_a_clear_error(z):
    g = flat(torch.full((1, 3, 4, 4), 0.5, dtype=torch.float64), z)
    with pytest.raises(ValueError, match="depth"):
        reference_sss(g, SKIN)


def test_float32_gbuffer_at_a_tiny_depth_keeps_energy():
    g = flat(torch.full((1, 3, 8, 8), 0.25, dtype=torch.float32), 1e-17)
    out = ReferenceSSS(SKIN)(g)
    assert out.dtype == torch.float32
    assert float((out - 0.25).abs().max()) < 1e-6
    assert math.isfinite(float(out.sum()))
