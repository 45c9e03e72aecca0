"""Every separable method forwards curvature width and halo weights to its passes."""

import pytest
import torch

import data_synth
from sssbench.ops import ArtistSSS, Jimenez2012SSS, PreintegratedSSS, SumOfGaussiansSSS
from sssbench.profiles import SumOfGaussians

SKIN = SumOfGaussians.from_table("skin_deon6")
METHODS = {
    "preintegrated": lambda: PreintegratedSSS(SKIN, 7),
    "sum_of_gaussians": lambda: SumOfGaussiansSSS(SKIN, 7),
    "artist": lambda: ArtistSSS.preset("production", 7),
    "jimenez2012": lambda: Jimenez2012SSS.preset("shader_default", 2.0, 9),
}


@pytest.mark.parametrize("name", sorted(METHODS))
def test_neutral_width_and_weights_change_nothing_and_zero_width_is_identity(name):
    g = data_synth.make_scene("halo", resolution=(24, 24), dtype=torch.float64)
    op = METHODS[name]()
    plain = op(g)
    ones = torch.ones_like(g.depth)
    # a bilateral weight of 1 everywhere renormalises a normalised kernel by 1
    same = op(g, width=ones, guide=ones, sample_weight=lambda c, s: torch.ones_like(c[:, :1]))
    if name == "artist":
        # 000 eq. 7 drops energy across depth steps; a bilateral pass renormalises by the
        # summed weights, depth factor included, so it can only give the energy back
        assert bool((same >= plain - 1e-12).all()) and not torch.allclose(same, plain)
    else:
        torch.testing.assert_close(same, plain, rtol=1e-12, atol=1e-12)
    # half the width everywhere is a different (narrower) blur, zero width the identity
    assert not torch.allclose(op(g, width=0.5 * ones), plain)
    torch.testing.assert_close(op(g, width=0 * ones), g.diffuse, rtol=0, atol=1e-12)


@pytest.mark.parametrize("backend", ["native", "torch"])
@pytest.mark.parametrize("name", [*sorted(METHODS), "low_rank"])
def test_inplace_call_writes_the_same_result_into_the_diffuse(name, backend):
    """``inplace=True`` (a renderer overwriting its lit target) gives the copying call's
    result bit for bit, in ``gbuffer.diffuse``; two-pass methods change no pixel outside the
    stencil, so the untouched pixels are the input's."""
    from sssbench.ops import LowRankSSS
    from sssbench.ops import backend as use_backend

    make = METHODS.get(name, lambda: LowRankSSS(SKIN, 2, n=7))
    g = data_synth.make_scene("head", resolution=(40, 48), dtype=torch.float64)
    with use_backend(backend):
        op = make()
        ref = op(g)
        work = g.replace(diffuse=g.diffuse.clone())
        got = op(work, inplace=True)
    assert got is work.diffuse
    torch.testing.assert_close(got, ref, rtol=0, atol=0)
    outside = g.mask == 0
    assert bool(outside.any()) and torch.equal(got * outside, g.diffuse * outside)


def test_inplace_call_refuses_a_diffuse_autograd_records():
    g = data_synth.make_scene("head", resolution=(16, 16), dtype=torch.float64)
    g = g.replace(diffuse=g.diffuse.clone().requires_grad_(True))
    with pytest.raises(ValueError, match="inplace=True overwrites gbuffer.diffuse"):
        PreintegratedSSS(SKIN, 5)(g, inplace=True)
    with torch.no_grad():
        assert PreintegratedSSS(SKIN, 5)(g, inplace=True) is g.diffuse
