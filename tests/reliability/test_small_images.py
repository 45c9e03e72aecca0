"""Every method keeps a constant image on a flat fronto-parallel plane constant on the
smallest images: 1×1, 1×N, N×1 and 2×2 (a normalised kernel on a constant neighbourhood; the
border clamp makes every tap read the constant)."""

from __future__ import annotations

import pytest
import torch

from sssbench import GBuffer, ops
from sssbench.profiles import SumOfGaussians

SHAPES = [(1, 1), (1, 5), (5, 1), (2, 2)]
SKIN = SumOfGaussians.from_table("skin_jg10")

METHODS = {
    "preintegrated": lambda h: ops.PreintegratedSSS(SKIN, 7),
    "preintegrated_lerp": lambda h: ops.PreintegratedSSS(SKIN, 7, follow_surface="lerp"),
    "sum_of_gaussians": lambda h: ops.SumOfGaussiansSSS(SKIN, lod=False),
    "sum_of_gaussians_jg10": lambda h: ops.SumOfGaussiansSSS(SKIN, stretch=ops.jg10_stretch(h)),
    "sum_of_gaussians_jg10_no_lod": lambda h: ops.SumOfGaussiansSSS(
        SKIN, stretch=ops.jg10_stretch(h), lod=False, follow_surface="gaussian"
    ),
    "low_rank_full": lambda h: ops.LowRankSSS(SKIN, rank=9, n=9, extent=3.0),
    "artist": lambda h: ops.ArtistSSS.preset("production"),
    "jimenez2012": lambda h: ops.Jimenez2012SSS.preset("shader_default", width=3.0),
    "reference": lambda h: ops.ReferenceSSS(SKIN),
}
#: documented tolerances (docs/numerics.md): normalised kernel on a constant image
TOL = {torch.float32: 1e-5, torch.float64: 1e-12}


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
@pytest.mark.parametrize("shape", SHAPES, ids=[f"{h}x{w}" for h, w in SHAPES])
@pytest.mark.parametrize("method", sorted(METHODS))
def test_constant_stays_constant_on_small_images(method, shape, dtype):
    h, w = shape
    c = torch.tensor([0.8, 0.5, 0.3], dtype=dtype).view(1, 3, 1, 1)
    g = GBuffer(c.expand(1, 3, h, w).clone(), torch.full((1, 1, h, w), 40.0, dtype=dtype), 0.5)
    op = METHODS[method](h)
    out = op(g)
    assert out.shape == (1, 3, h, w) and out.dtype == dtype
    # the low-rank kernel at full rank sums to 1 only to its SVD's rounding
    tol = TOL[dtype] * (10 if method == "low_rank_full" else 1)
    assert torch.allclose(out, g.diffuse, rtol=tol, atol=0), (out - g.diffuse).abs().max()
