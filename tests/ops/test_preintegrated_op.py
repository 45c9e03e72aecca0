"""PreintegratedSSS: exact on additively separable irradiance (000 §4 eq. 4–5), conservation,
and importance sampling beating uniform sampling (000 §7, Fig. 12)."""

import math

import pytest
import torch
from oracles import FOV, rel_rms_np, step_gbuffer, step_response

from sssbench.gbuffer import GBuffer
from sssbench.ops import PreintegratedSSS, ReferenceSSS
from sssbench.profiles import SumOfGaussians
from sssbench.score.metrics import rel_rms

PIX = 0.25  # mm per pixel


def wide_profile() -> SumOfGaussians:
    """Three Gaussians of 2.5, 5 and 10 px standard deviation at 0.25 mm/px."""
    s = torch.tensor([2.5, 5.0, 10.0], dtype=torch.float64) * PIX
    w = torch.tensor([[0.5, 0.3, 0.2], [0.3, 0.4, 0.3], [0.2, 0.3, 0.5]], dtype=torch.float64)
    return SumOfGaussians(s**2, w)


def test_step_edge_matches_analytic_response_with_81_taps():
    """000 eq. 4: the pre-integrated kernel is exact for a vertical shadow boundary.

    What remains is discretisation: the gather lerps between pixel centres (a 1 px ramp
    instead of the step) and sums K taps (a staircase of K ramps). Measured relative RMS
    (importance sampling) on this scene: 7 taps 1.6e-2, 33 taps 2.3e-3, 65 taps 1.06e-3,
    81 taps 8.2e-4 — 81 taps is the smallest tested count below 1e-3.
    """
    p = wide_profile()
    h, w = 16, 256
    z = h * PIX / (2 * math.tan(FOV / 2))
    g, x, edge = step_gbuffer(h, w, z, 0.1, 1.0)
    out = PreintegratedSSS(p, 81, "importance")(g)[0, :, h // 2].numpy().T
    assert rel_rms_np(out, step_response(p, x, edge, 0.1, 1.0)) < 1e-3


def test_step_edge_with_subpixel_skin_gaussians():
    """With skin_deon6 at 0.25 mm/px the two narrowest Gaussians (σ 0.08 and 0.22 mm) are
    sub-pixel. The reference integrates them over cells and stays within 1e-6 of the analytic
    response; the two-pass method point-samples a lerped image, whose 1 px ramp dominates
    those Gaussians: measured 8.8e-3 relative RMS at 7 taps and a floor near 4e-3 at 65 taps.
    """
    p = SumOfGaussians.from_table("skin_deon6")
    h, w = 16, 256
    z = h * PIX / (2 * math.tan(FOV / 2))
    g, x, edge = step_gbuffer(h, w, z, 0.1, 1.0)
    ref = step_response(p, x, edge, 0.1, 1.0)
    exact = ReferenceSSS(p)(g)[0, :, h // 2].numpy().T
    assert rel_rms_np(exact, ref) < 1e-6
    err7 = rel_rms_np(PreintegratedSSS(p, 7)(g)[0, :, h // 2].numpy().T, ref)
    err65 = rel_rms_np(PreintegratedSSS(p, 65)(g)[0, :, h // 2].numpy().T, ref)
    assert 1e-3 < err65 < err7 < 2e-2


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_constant_image_is_unchanged(dtype):
    depth = 250 + 50 * torch.rand(1, 1, 16, 16, generator=torch.Generator().manual_seed(0))
    g = GBuffer(torch.full((1, 3, 16, 16), 0.8, dtype=dtype), depth.to(dtype), FOV)
    for samples, sampling in [(7, "importance"), (9, "uniform"), (5, "power")]:
        op = PreintegratedSSS(SumOfGaussians.from_table("skin_deon6"), samples, sampling)
        assert float((op(g) - 0.8).abs().max()) < 1e-6


@pytest.mark.parametrize(
    "scene, table, params",
    [
        ("light_dot", "skin_deon6", {}),
        ("sphere", "marble_jg10", {"distance": 200.0, "radius": 40.0, "background": 300.0}),
    ],
)
def test_importance_sampling_beats_uniform_with_7_taps(scene, table, params):
    """000 §7 / Fig. 12: 7 importance-sampled taps beat 7 uniform taps.

    Measured rel_rms (64², follow-surface lerp): light_dot/skin 0.089 vs 0.313; sphere/marble
    at 200 mm 7.2e-4 vs 1.38e-3. On the default sphere with skin both are within 1e-3 of the
    reference and uniform is slightly better (7e-4 vs 3e-4): its lighting is smooth at 0.8 mm
    per pixel, so the unblurred input itself is within 3e-4 and a kernel that keeps most weight
    on the centre tap wins; that scene does not discriminate sampling strategies.
    """
    data_synth = pytest.importorskip("data_synth")
    g = data_synth.make_scene(scene, resolution=(64, 64), dtype=torch.float64, **params)
    p = SumOfGaussians.from_table(table)
    ref = ReferenceSSS(p)(g)
    err = {
        s: float(rel_rms(PreintegratedSSS(p, 7, s, "lerp")(g), ref, g.mask))
        for s in ("importance", "uniform")
    }
    assert err["importance"] < err["uniform"], err
