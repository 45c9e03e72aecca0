"""Texturing modes (001 §5.3)."""

import pytest
import torch

from data_synth import make_scene
from sssbench.ops import PreintegratedSSS, Texturing, texture_after, texture_before
from sssbench.ops.timing import record_passes
from sssbench.profiles import SumOfGaussians


@pytest.fixture(scope="module")
def scene():
    return make_scene("step_edge", (32, 32), dtype=torch.float64)


@pytest.mark.parametrize("mode", ["pre", "post", "sqrt"])
def test_unblurred_pixel_gets_albedo_times_irradiance(scene, mode):
    out = texture_after(texture_before(scene.diffuse, scene, mode), scene, mode)
    torch.testing.assert_close(out, scene.albedo * scene.diffuse)


def test_modes_differ_where_the_colour_bleeds():
    g = make_scene("step_edge", (32, 32), dtype=torch.float64)
    # an albedo edge across the irradiance edge
    alb = torch.full_like(g.albedo, 0.8)
    alb[..., 16:] = torch.tensor([0.2, 0.6, 0.9], dtype=torch.float64).view(1, 3, 1, 1)
    g = g.replace(albedo=alb)
    blur = PreintegratedSSS(SumOfGaussians.from_table("skin_jg10"), 9)
    out = {}
    for mode in ("pre", "post", "sqrt"):
        src = g.replace(diffuse=texture_before(g.diffuse, g, mode))
        out[mode] = texture_after(blur(src), g, mode)
    # post keeps the texture sharp: the result over the albedo is the blurred irradiance
    torch.testing.assert_close(out["post"] / alb, blur(g))
    # sqrt sits between pre and post (geometric mean of the colour on each side)
    assert float((out["pre"] - out["post"]).abs().max()) > 1e-3
    lo = torch.minimum(out["pre"], out["post"]) - 1e-9
    hi = torch.maximum(out["pre"], out["post"]) + 1e-9
    assert bool(((out["sqrt"] >= lo) & (out["sqrt"] <= hi)).all())


def test_stencil_and_records(scene):
    mask = torch.zeros_like(scene.depth)
    mask[..., 4:12, 4:20] = 1.0
    g = scene.replace(mask=mask)
    with record_passes() as rec:
        out = Texturing("sqrt").before(g.diffuse, g)
    assert [(r.name, r.pixels) for r in rec] == [("texturing.before", 8 * 16)]
    outside = (mask == 0).expand_as(out)
    torch.testing.assert_close(out[outside], g.diffuse[outside])
    with record_passes() as rec:
        Texturing("pre").after(g.diffuse, g)  # nothing to do after the blur in "pre"
    assert rec == []


def test_needs_albedo(scene):
    with pytest.raises(ValueError, match="albedo"):
        texture_before(scene.diffuse, scene.replace(albedo=None), "pre")
    with pytest.raises(ValueError, match="mode"):
        Texturing("both")
