"""Translucency (004 §3.2 eq. 3.10, Fig. 3.11; 001 eq. 16)."""

import pytest
import torch

from data_synth import make_scene
from sssbench.gbuffer import GBuffer
from sssbench.ops import Translucency, translucency, transmittance
from sssbench.profiles import SumOfGaussians

PROFILE = SumOfGaussians.from_table("skin_deon6")


def _slab(thickness: float, light: tuple[float, float, float], n: int = 4) -> GBuffer:
    """A camera-facing patch with constant thickness and a directional light."""
    shape = (1, 1, n, n)
    normal = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).view(1, 3, 1, 1)
    return GBuffer(
        torch.zeros(1, 3, n, n, dtype=torch.float64),
        torch.full(shape, 200.0, dtype=torch.float64),
        0.5,
        normal=normal.expand(1, 3, n, n).contiguous(),
        thickness=torch.full(shape, thickness, dtype=torch.float64),
        light_dir=torch.tensor([light], dtype=torch.float64),
    )


@pytest.mark.parametrize("form", ["jimenez2012", "deon"])
def test_zero_for_very_large_thickness(form):
    g = _slab(1e3, (0.0, 0.0, -1.0))
    assert float(translucency(g, PROFILE, form=form).abs().max()) < 1e-12


def test_zero_when_light_in_front():
    # n·(−l) = −0.3 exactly (the clamp's zero) and further in front
    for lz in (0.3, 0.6, 1.0):
        lx = (1.0 - lz**2) ** 0.5
        g = _slab(0.0, (lx, 0.0, lz))
        assert float(translucency(g, PROFILE).abs().max()) < 1e-12


@pytest.mark.parametrize("nl", [0.0, 0.2, 0.5, 1.0])
def test_closed_form_at_zero_thickness(nl):
    # s = 0: T(0) = Σ w_i, times clamp(0.3 + n·(−l), 0, 1) (004 eq. 3.10, Fig. 3.11)
    lz = -nl
    lx = (1.0 - lz**2) ** 0.5
    g = _slab(0.0, (lx, 0.0, lz))
    out = translucency(g, PROFILE, 0.4, 3.0)
    expect = PROFILE.weights.sum(0) * min(max(0.3 + nl, 0.0), 1.0)
    torch.testing.assert_close(out[0, :, 0, 0], expect)


def test_shader_scale_and_deon_form():
    # 2012: s = thickness · 8.25 (1 − t) / width; deon: d = m |n·l|, weights w_i e^{−d²/v_i}
    g = _slab(2.0, (0.0, 0.6, -0.8))
    out = translucency(g, PROFILE, 0.5, 4.125)  # scale = 1
    expect = transmittance(torch.tensor(2.0, dtype=torch.float64), PROFILE) * 1.0
    torch.testing.assert_close(out[0, :, 1, 1], expect)
    out = translucency(g, PROFILE, form="deon")
    d = torch.tensor(2.0 * 0.8, dtype=torch.float64)
    w = PROFILE.weights * torch.exp(-(d**2) / PROFILE.variances)[:, None]
    torch.testing.assert_close(out[0, :, 1, 1], w.sum(0) * 0.8)


def test_albedo_mask_and_missing_fields():
    g = make_scene("backlit_ear", (24, 24), dtype=torch.float64)
    plain = translucency(g, PROFILE, 0.9, 8.0, apply_albedo=False)
    tinted = translucency(g, PROFILE, 0.9, 8.0)
    assert float(plain.max()) > 0.05
    torch.testing.assert_close(tinted, plain * g.albedo)
    assert float(plain[(g.mask == 0).expand_as(plain)].abs().max()) == 0.0
    for name in ("thickness", "normal", "light_dir"):
        with pytest.raises(ValueError, match=name):
            Translucency(PROFILE)(g.replace(**{name: None}))
