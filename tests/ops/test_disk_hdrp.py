"""``DiskSSS(estimator="hdrp")`` against HDRP's published formulas, evaluated here by an
independent, slow implementation: plain Python loops over pixels and samples with NumPy
scalars, written from the shader's text (Unity-Technologies/Graphics,
``Runtime/Material/SubsurfaceScattering/SubsurfaceScattering.compute``: ``EvaluateSss``,
``EvaluateSample``, ``ComputeBilateralWeight``; ``DiffusionProfile.hlsl``:
``EvalBurleyDiffusionProfile``, ``SampleBurleyDiffusionProfile``; core
``Sampling/Fibonacci.hlsl``: ``Golden2dSeq``, ``SampleDiskGolden``;
``DiffusionProfileSettings.cs``: ``shapeParam``, ``filterRadius``, ``SSS_PIXELS_PER_SAMPLE``).
Nothing from :mod:`sssbench.ops.disk` is used by the oracle except the per-pixel rotation
(its input: HDRP hashes pixel and device depth, we hash pixel, seed and frame)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from sssbench.gbuffer import GBuffer
from sssbench.ops import DiskSSS
from sssbench.ops._disk_radial import burley_radius, hdrp_burley_sample
from sssbench.ops.disk import hash_uniform
from sssbench.profiles import BurleyNormalized, SumOfGaussians

FOV = 0.5
LOG2_E = 1.0 / math.log(2.0)
FLT_MIN = np.float32(np.finfo(np.float32).tiny).item()


# ----------------------------------------------------------------------------- the oracle
def hdrp_sample(u: float, rcp_s: float) -> tuple[float, float]:
    """``SampleBurleyDiffusionProfile(u, rcpS)`` (DiffusionProfile.hlsl), in exp2/log2 as
    published."""
    u = 1.0 - u
    g = 1.0 + (4.0 * u) * (2.0 * u + math.sqrt(1.0 + (4.0 * u) * u))
    n = 2.0 ** (math.log2(g) * (-1.0 / 3.0))
    p = (g * n) * n
    c = 1.0 + p + n
    d = (3.0 / LOG2_E * 2.0) + (3.0 / LOG2_E) * math.log2(u)
    x = (3.0 / LOG2_E) * math.log2(c) - d
    rcp_exp = ((c * c) * c) / ((4.0 * u) * ((c * c) + (4.0 * u) * (4.0 * u)))
    return x * rcp_s, (8.0 * math.pi * rcp_s) * rcp_exp


def eval_burley(r: float, s: np.ndarray) -> np.ndarray:
    """``EvalBurleyDiffusionProfile(r, S)``: ``S/(8π) (e^{−Sr/3} + e^{−Sr})``."""
    exp_13 = np.exp2(((LOG2_E * (-1.0 / 3.0)) * r) * s)
    return (s / (8.0 * math.pi)) * (exp_13 * (1.0 + exp_13 * exp_13))


def hdrp_pass(
    irradiance: np.ndarray,
    depth: np.ndarray,
    stencil: np.ndarray,
    fov_y: float,
    scattering_distance: np.ndarray,
    budget: int,
    phase: np.ndarray,
) -> np.ndarray:
    """HDRP's pass on one image: ``irradiance (H, W, 3)``, linear ``depth (H, W)`` in mm,
    ``stencil (H, W)`` bool (HDRP: the blue channel's SSS tag), the rotation ``phase (H, W)``
    in turns. Lengths in mm; HDRP's world unit is the metre (``mmPerUnit = 1000``, mask 1),
    so its pixel footprint floor of 0.0001 units is 0.1 mm."""
    h, w, _ = irradiance.shape
    s = 1.0 / scattering_distance  # shapeParam = 1 / (scatteringDistance · multiplier)
    d = float(scattering_distance.max())  # the widest channel is sampled
    filter_radius = hdrp_sample(0.997, d)[0]  # DiffusionProfileSettings.UpdateKernel
    golden = (1.0 + math.sqrt(5.0)) / 2.0
    out = irradiance.copy()
    for py in range(h):
        for px in range(w):
            if not stencil[py, px]:
                continue
            z = depth[py, px]
            # unitsPerPixel = max(0.0001, 2 |corner.x − centre.x|), the corner half a pixel
            # away; in metres, then pixelsPerMm = 1 / (1000 unitsPerPixel)
            half_pixel_m = 0.5 * 2.0 * z * math.tan(fov_y / 2.0) / h / 1000.0
            units_per_pixel = max(0.0001, 2.0 * half_pixel_m)
            pixels_per_mm = 1.0 / units_per_pixel / 1000.0
            filter_area = math.pi * (filter_radius * pixels_per_mm) ** 2
            sample_count = int(filter_area / 4.0)  # SSS_PIXELS_PER_SAMPLE
            if sample_count < 1:
                continue  # no filtering: the centre's irradiance
            n = min(sample_count, budget)
            ph = 2.0 * math.pi * phase[py, px]
            total_irr = np.zeros(3)
            total_w = np.zeros(3)
            for i in range(n):
                r, rcp_pdf = hdrp_sample(i * (1.0 / n) + (1.0 / n) * 0.5, d)
                phi = 2.0 * math.pi * math.modf(i / golden)[0]  # SampleDiskGolden(i, n).y
                sin_psi = math.cos(ph) * math.sin(phi) + math.sin(ph) * math.cos(phi)
                cos_psi = math.cos(ph) * math.cos(phi) - math.sin(ph) * math.sin(phi)
                qx = px + int(np.round(pixels_per_mm * r * cos_psi))
                qy = py + int(np.round(pixels_per_mm * r * sin_psi))
                if not (0 <= qx < w and 0 <= qy < h):
                    continue  # an out-of-bounds load returns 0: fails the SSS tag test
                rel_z = depth[qy, qx] - z
                r3 = math.sqrt(r * r + rel_z * rel_z)  # xy2 = r², no tangent plane
                weight = eval_burley(r3, s) * rcp_pdf
                if stencil[qy, qx]:
                    total_irr += weight * irradiance[qy, qx]
                    total_w += weight
            out[py, px] = total_irr / np.maximum(total_w, FLT_MIN)
    return out


# ----------------------------------------------------------------------------- scenes
def scene(kind: str, h: int = 14, w: int = 17) -> GBuffer:
    gen = torch.Generator().manual_seed(3)
    e = torch.rand(1, 3, h, w, generator=gen, dtype=torch.float64)
    rows = torch.arange(h, dtype=torch.float64).view(h, 1)
    cols = torch.arange(w, dtype=torch.float64).view(1, w)
    if kind == "step":  # a 1.5 mm depth step down the middle, lit on the left only
        z = torch.where(cols < w // 2, 60.0, 61.5).double().expand(h, w)
        e[..., : w // 2] += 2.0
    elif kind == "curved":  # a sphere cap (depth varies: the sample count varies per pixel)
        rr = ((rows - h / 2) ** 2 + (cols - w / 2) ** 2) / (0.6 * max(h, w)) ** 2
        z = 45.0 + 30.0 * rr
    else:  # a steep tilted plane, 50 … 470 mm: counts from the budget down to 0 (no filter)
        z = 50.0 + 25.0 * cols + 0.4 * rows
    mask = (torch.rand(1, 1, h, w, generator=gen) > 0.15).double()
    return GBuffer(e, z.reshape(1, 1, h, w).contiguous(), FOV, mask=mask)


def oracle(g: GBuffer, sd: list[float], budget: int, phase: torch.Tensor) -> torch.Tensor:
    e = g.diffuse[0].permute(1, 2, 0).numpy()
    z = g.depth[0, 0].numpy()
    st = (g.mask_or_ones()[0, 0] > 0).numpy()
    out = hdrp_pass(e, z, st, g.fov_y, np.array(sd), budget, phase.numpy())
    return torch.from_numpy(out).permute(2, 0, 1)[None]


@pytest.mark.parametrize("kind", ["step", "curved", "tilted"])
@pytest.mark.parametrize("budget", [5, 40])
def test_hdrp_estimator_equals_hdrp_formulas_without_rotation(kind, budget):
    g = scene(kind)
    sd = [1.1, 0.45, 0.2]  # scattering distance (mm) per channel, multiplier 1
    op = DiskSSS(BurleyNormalized(sd, 1.0), budget, rotation="none", estimator="hdrp")
    got = op(g)
    want = oracle(g, sd, budget, torch.zeros(g.shape[1:], dtype=torch.float64))
    counts = op.last_counts
    assert int(counts.max()) == budget
    if kind == "tilted":  # every regime: capped, below the budget, and no filtering at all
        assert int(counts.min()) == 0 and bool(((counts > 0) & (counts < budget)).any())
    assert torch.allclose(got, want, rtol=1e-12, atol=1e-12), float((got - want).abs().max())


def test_hdrp_estimator_equals_hdrp_formulas_with_the_hash_rotation():
    g = scene("step")
    sd = [0.9, 0.5, 0.3]
    seed = 7
    h, w = g.shape[1:]
    phase = hash_uniform(torch.arange(h * w), seed, 0, 0).reshape(h, w)  # the rotation input
    got = DiskSSS(BurleyNormalized(sd, 0.7), 24, seed=seed, estimator="hdrp")(g)
    want = oracle(g, sd, 24, phase)
    assert torch.allclose(got, want, rtol=1e-12, atol=1e-12), float((got - want).abs().max())


def test_hdrp_sample_count_is_the_projected_disk_over_four_pixels():
    # pixel footprint p = 2 z tan(fov/2) / H: the count is ⌊π (R_f / p)² / 4⌋ up to the budget,
    # and the footprint is floored at 0.1 mm (HDRP's 0.0001 world units of 1 m)
    p = BurleyNormalized(0.5, 1.0)
    op = DiskSSS(p, 60000, estimator="hdrp")
    z = torch.tensor([0.05, 0.15, 0.5, 2.0, 8.0, 30.0], dtype=torch.float64)
    g = GBuffer(torch.ones(1, 3, 1, 6, dtype=torch.float64), z.view(1, 1, 1, 6), FOV)
    # the G-buffer is 1 row high: footprints are 2 z tan(fov/2) / 1
    counts = op.hdrp_counts(g)[0, 0, 0]
    radius = hdrp_sample(0.997, 0.5)[0]
    foot = torch.clamp(2 * z * math.tan(FOV / 2) / 1, min=0.1)
    want = torch.floor(math.pi * (radius / foot) ** 2 / 4).clamp_max(60000).long()
    assert torch.equal(counts, want)
    assert int(counts[0]) == int(counts[1]) > int(counts[2]) > int(counts[-1]) == 0


def test_hdrp_closed_form_equals_the_cardano_sinh_form():
    u = torch.tensor([1e-6, 0.01, 0.3, 0.5, 0.9, 0.997, 1 - 1e-9], dtype=torch.float64)
    r, rcp = hdrp_burley_sample(u, 0.8)
    assert torch.allclose(r, burley_radius(u, 0.8), rtol=1e-9, atol=1e-15)
    dens = (torch.exp(-r / 0.8) + torch.exp(-r / 2.4)) / (8 * math.pi * 0.8)  # pdf in (r, φ)
    assert torch.allclose(rcp, 1 / dens, rtol=1e-9)
    for ui, ri, ci in zip(u.tolist(), r.tolist(), rcp.tolist(), strict=True):
        assert (ri, ci) == pytest.approx(hdrp_sample(ui, 0.8), rel=1e-12)


def test_hdrp_weight_is_ours_times_r3d_over_r2d():
    # the audit's finding, as formulas: HDRP weighs a sample by EvalBurley(r3D) · rcpPdf(r2D)
    # (polar measure), ours by R(r3D) / pdf_area(r2D): the ratio is r3D / r2D per channel
    p = BurleyNormalized([1.0, 0.6, 0.3], 0.7)
    kernel = DiskSSS(p, estimator="hdrp").kernels[0]
    u = torch.tensor([0.1, 0.5, 0.9], dtype=torch.float64)
    r2, rcp_polar = kernel.sampler.sample_polar(u)
    _, inv_area = kernel.sampler.sample(u)
    r3 = torch.sqrt(r2**2 + 1.5**2)  # across a 1.5 mm depth step
    hdrp = kernel.polar(r3) * rcp_polar[:, None]
    ours = p.evaluate(r3) / p.total() * inv_area[:, None]
    assert torch.allclose(hdrp / ours, (r3 / r2)[:, None].expand(3, 3), rtol=1e-9)
    s = 1 / p.d  # and HDRP's EvalBurley is S/(8π)(e^{−S r/3} + e^{−S r}) exactly
    expect = s / (8 * math.pi) * (torch.exp(-s * r3[:, None] / 3) + torch.exp(-s * r3[:, None]))
    assert torch.allclose(kernel.polar(r3), expect, rtol=1e-14)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(jitter_radius=True),
        dict(normalise=False),
        dict(fetch="bilinear"),
        dict(pattern="r2"),
        dict(adaptive=(4, 16)),
        dict(surface_area=True),
    ],
)
def test_hdrp_refuses_options_hdrp_does_not_have(kwargs):
    (key,) = kwargs
    with pytest.raises(ValueError, match=key):
        DiskSSS(BurleyNormalized(1.0, 0.5), estimator="hdrp", **kwargs)


def test_estimator_default_is_unchanged():
    p = BurleyNormalized(1.0, 0.5)
    g = scene("tilted")
    assert DiskSSS(p).estimator == "sssbench" and DiskSSS(p).jitter_radius is True
    assert torch.equal(DiskSSS(p, 8)(g), DiskSSS(p, 8, estimator="sssbench")(g))
    with pytest.raises(ValueError, match="estimator"):
        DiskSSS(p, estimator="unreal")


def test_hdrp_on_a_tabulated_profile_keeps_constants_constant():
    # HDRP has only Burley; its rules with the tabulated sampler still reproduce a constant
    g = scene("curved").replace(diffuse=torch.full((1, 3, 14, 17), 0.3, dtype=torch.float64))
    out = DiskSSS(SumOfGaussians.from_table("skin_deon6"), 16, estimator="hdrp")(g)
    assert torch.allclose(out, g.diffuse, rtol=1e-12)


def test_app_passes_the_estimator(tmp_path):
    # `sssbench method=disk method.params.estimator=hdrp`: conf/method/disk.yaml carries the
    # option (its jitter_radius is null: each estimator's own default)
    from sssbench.app import compose_spec
    from sssbench.run import registry

    spec = compose_spec(
        "method=disk",
        "method.params.estimator=hdrp",
        "profile=burley_skin1",
        "scene=step_edge",
        "resolution=[16,16]",
        store=tmp_path / "s.sqlite",
    )
    assert spec.method_params["estimator"] == "hdrp"
    profile = registry.build_profile(spec.profile, spec.profile_kind, **spec.profile_params)
    op = registry.method_from_spec(spec, profile)
    assert op.estimator == "hdrp" and op.jitter_radius is False and op.samples == 32
    default = compose_spec("method=disk", store=tmp_path / "t.sqlite")
    op = registry.method_from_spec(default, profile)
    assert op.estimator == "sssbench" and op.jitter_radius is True
