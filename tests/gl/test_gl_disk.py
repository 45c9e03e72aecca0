"""The disk (``DiskSSS``, both estimators) as a GL fragment shader equals the torch operator on
a flat, a tilted, a curved scene and across depth discontinuities, through ``run_method`` and
``backend("gl")``; options without a shader are refused naming them.

Tolerance (docs/gl.md): the torch disk forms a sample's position in float64, the shader in
float32. A point fetch rounds the position to a pixel, so a sample within float32 rounding of
a pixel boundary may land on the neighbour in one and not the other. Such samples are found
here independently, in float64 (:func:`boundary_pixels`: a sample offset within ``1e-5``
relative of a rounding boundary, or HDRP's sample count within it of an integer); the other
pixels agree to ``≤ 1e-5`` relative RMS, and the flagged ones are few (``≤ 5 %``; a pixel
whose sample does land on the neighbour is off by that sample's share).

Skipped only when no headless GL context can be made (the reason names what to install)."""

from __future__ import annotations

import functools
import math

import pytest
import torch

import data_synth
from sssbench import gl
from sssbench.gbuffer import pixel_size_mm
from sssbench.ops import DiskSSS, backend
from sssbench.ops.disk import GOLDEN_RATIO, HDRP_MIN_PIXEL_MM, pattern_points
from sssbench.profiles import BurleyNormalized
from sssbench.run import registry

OK, WHY = gl.available()
pytestmark = pytest.mark.skipif(not OK, reason=f"no headless GL: {WHY}")

TOL = 1e-5
#: a sample offset (px) within this fraction of itself (at least 1 px) of a rounding boundary
#: is one float32 cannot place on the same side as float64 (~100 float32 ulp)
BOUNDARY = 1e-5
RES = (48, 48)

#: flat, tilted, curved (in front of a wall, mask 0 on it), depth discontinuities (the face)
SCENES = {
    "flat": ("step_edge", dict(pixel_mm=0.05)),
    "tilted": ("halo", dict(pixel_mm=0.05)),
    "curved": ("sphere", dict(radius=5.0, distance=25.0)),
    "discontinuity": ("face", dict(pixel_mm=0.1)),
}
PROFILES = {
    # closed-form sampler and weight (HDRP's profile)
    "burley": lambda: BurleyNormalized([1.0, 0.5, 0.25], [0.8, 0.6, 0.4]),
    # tabulated sampler, sum-of-Gaussians weight (the app's default profile)
    "skin_jg10": lambda: registry.build_profile("skin_jg10"),
}


@functools.cache
def scene(key: str):
    name, kw = SCENES[key]
    return data_synth.make_scene(name, RES, **kw)


@functools.cache
def profile(key: str):
    return PROFILES[key]()


def boundary_pixels(m: DiskSSS, g) -> torch.Tensor:
    """``(B, H, W)`` bool: pixels with a sample whose rounded pixel float32 may not reproduce
    (module doc), recomputed here in float64 from the pattern, the sampler and the noise."""
    b, _, h, w = g.depth.shape
    z = g.depth[:, 0].double()
    flag = torch.zeros(b, h, w, dtype=torch.bool)
    sampler = m.kernels[0].sampler

    def near(x: torch.Tensor, half: bool) -> torch.Tensor:
        edge = torch.floor(x) + 0.5 if half else torch.round(x + 0.5) - 0.5
        return (x - edge).abs() < BOUNDARY * x.abs().clamp_min(1.0)

    for f in range(m.frames):
        phase, shift = (t[:, 0] for t in m.noise(g, f, 0))
        if m.estimator == "hdrp":
            ppm = 1.0 / pixel_size_mm(z, g.fov_y, h).clamp_min(HDRP_MIN_PIXEL_MM)
            quarter = math.pi * (m.kernels[0].filter_radius * ppm) ** 2 / 4
            near_count = (quarter - torch.round(quarter)).abs() < BOUNDARY * quarter
            flag |= near_count & (quarter < m.samples + 1)  # (a capped count cannot flip)
            counts = m.hdrp_counts(g)[:, 0]
            for n in set(counts.flatten().tolist()) - {0}:
                i = torch.arange(n, dtype=torch.float64)
                r, _ = sampler.sample_polar((i + 0.5) / n)
                psi = 2 * math.pi * torch.frac(i / GOLDEN_RATIO) + 2 * math.pi * phase[..., None]
                off = ppm[..., None] * r
                bad = near(off * torch.cos(psi), True) | near(off * torch.sin(psi), True)
                flag |= (counts == n) & bad.any(-1)
            continue
        u0, th0 = pattern_points(m.pattern, m.samples)
        u = torch.frac(u0 + shift[..., None]) if m.jitter_radius else u0.expand(b, h, w, -1)
        r, _ = sampler.sample(u.reshape(-1))
        r = r.reshape(u.shape)
        theta = th0 + 2 * math.pi * phase[..., None]
        step = (1.0 / pixel_size_mm(z, g.fov_y, h))[..., None]
        dcol, drow = r * torch.cos(theta) * step, r * torch.sin(theta) * step
        flag |= (near(dcol, False) | near(drow, False)).any(-1)
    return flag & (g.mask_or_ones()[:, 0] > 0)


def torch_result(m, g) -> torch.Tensor:
    with backend("torch"), torch.no_grad():
        return m(g)


def check_equal(out: torch.Tensor, ref: torch.Tensor, flag: torch.Tensor) -> float:
    keep = ~flag[:, None].expand_as(ref)
    a, b = out.double(), ref.double()
    rel = float(((a - b)[keep] ** 2).mean().sqrt() / (b[keep] ** 2).mean().sqrt())
    assert rel <= TOL, f"rel RMS {rel:.3g} off the boundary pixels"
    # the set aside is small: the band is 1e-5 of an offset wide around each boundary
    assert float(flag.double().mean()) <= 0.05, f"{int(flag.sum())} boundary pixels"
    return rel


@pytest.mark.parametrize("scene_key", list(SCENES))
@pytest.mark.parametrize("profile_key", list(PROFILES))
@pytest.mark.parametrize("estimator,samples", [("sssbench", 8), ("sssbench", 32),
                                               ("hdrp", 8), ("hdrp", 32)])  # fmt: skip
def test_backend_gl_disk_equals_torch(scene_key, profile_key, estimator, samples):
    g = scene(scene_key)
    m = DiskSSS(profile(profile_key), samples=samples, estimator=estimator)
    ref = torch_result(m, g)
    with backend("gl"), torch.no_grad():
        out = m(g)
    assert out.dtype == ref.dtype and out.shape == ref.shape
    check_equal(out, ref, boundary_pixels(m, g))


OPTIONS = {
    "frames": dict(frames=3),
    "ign": dict(rotation="ign"),
    "blue_noise": dict(rotation="blue_noise"),
    "no_rotation": dict(rotation="none"),
    "r2": dict(pattern="r2"),
    "unnormalised": dict(normalise=False),
    "bilinear": dict(fetch="bilinear"),
    "surface_area": dict(surface_area=True),
    "seed_63_bits": dict(seed=2**62 + 12345),
    "fixed_radii": dict(jitter_radius=False),
    "hdrp_frames_ign": dict(estimator="hdrp", frames=2, rotation="ign"),
    "bilinear_area_mc": dict(fetch="bilinear", surface_area=True, normalise=False),
}


@pytest.mark.parametrize("profile_key", list(PROFILES))
@pytest.mark.parametrize("option", list(OPTIONS))
def test_every_option_equals_torch(option, profile_key):
    g = scene("discontinuity")
    m = DiskSSS(profile(profile_key), samples=16, **OPTIONS[option])
    ref = torch_result(m, g)
    with backend("gl"), torch.no_grad():
        out = m(g)
    check_equal(out, ref, boundary_pixels(m, g))


def test_partial_strength_and_batch_equal_torch():
    """mask in (0, 1) lerps; a batch's images carry the noise of their own pixels."""
    g0 = scene("curved")
    mask = g0.mask_or_ones() * torch.linspace(0.2, 1.0, RES[1])
    g = type(g0)(
        torch.cat([g0.diffuse, g0.diffuse.flip(-1)]), torch.cat([g0.depth, g0.depth.flip(-1)]),
        g0.fov_y, mask=torch.cat([mask, mask.flip(-1)]),
    )  # fmt: skip
    m = DiskSSS(profile("burley"), samples=16)
    ref = torch_result(m, g)
    with backend("gl"), torch.no_grad():
        out = m(g)
    check_equal(out, ref, boundary_pixels(m, g))


@pytest.mark.parametrize("estimator", ["sssbench", "hdrp"])
def test_run_method_times_the_disk_draw(estimator):
    g = scene("discontinuity")
    m = DiskSSS(profile("skin_jg10"), samples=16, estimator=estimator, frames=2)
    run = gl.run_method(m, g, repeats=2, warmup=1)
    check_equal(run.image, torch_result(m, g), boundary_pixels(m, g))
    assert list(run.pass_times_ms) == ["disk"] and run.pass_times_ms["disk"] > 0
    (rec,) = run.passes
    assert rec.samples == 16 and rec.pixels == int((g.mask_or_ones() > 0).sum())
    assert len(run.repeats) == 2


def test_options_without_a_shader_are_refused_naming_them():
    g = scene("flat")
    cases = [
        (DiskSSS(profile("burley"), adaptive=(4, 32)), "adaptive"),
        (DiskSSS([profile("burley"), profile("skin_jg10")]), "list of profiles"),
        (DiskSSS(BurleyNormalized.from_albedo_mfp([0.44, 0.23, 0.13], [3.7, 1.4, 0.7])), None),
    ]
    for m, word in cases[:2]:
        with pytest.raises(gl.GLMethodError, match=word):
            gl.run_method(m, g, repeats=0, warmup=0)
        with backend("gl"), pytest.raises(gl.GLMethodError, match=word):
            m(g)
    # BurleyNormalized built from albedo and mfp is still BurleyNormalized: it runs
    m = cases[2][0]
    with backend("gl"), torch.no_grad():
        out = m(g)
    check_equal(out, torch_result(m, g), boundary_pixels(m, g))


def test_a_profile_without_a_shader_formula_is_refused():
    from sssbench.profiles.dipole import Dipole

    m = DiskSSS(Dipole.from_material("skin1"), samples=4)
    with backend("gl"), pytest.raises(gl.GLMethodError, match="profile=Dipole"):
        m(scene("flat"))
