"""The disk (``DiskSSS``, both estimators) as a GL fragment shader equals the torch operator on
a flat, a tilted, a curved scene and across depth discontinuities, through ``run_method`` and
``backend("gl")``; options without a shader are refused naming them.

Float64 geometry (the default; GLSL 400, which llvmpipe has): the shader forms each sample's
geometry in double in the torch loop's order (docs/gl.md), so whole images equal torch's to
``≤ 1e-5`` relative RMS with no pixel set aside, and every pixel to ``1e-5`` of the image's
maximum — a sample landing in a different pixel than in torch moves its pixel by that sample's
share (``~1/N`` of its value), far above that. The shader's double ``exp`` / ``log`` / ``sin``
/ ``cos`` are checked against Python's ``math`` (an independent libm) to a few ulp.

Float32 geometry (the explicit fallback for drivers without doubles,
``set_disk_geometry("float32")``) has its own documented tolerance: a sample within float32
rounding of a pixel boundary may land on the neighbour. Such samples are found here
independently, in float64 (:func:`boundary_pixels`: a sample offset within ``1e-5`` relative of
a rounding boundary, or HDRP's sample count within it of an integer); the other pixels agree to
``≤ 1e-5`` relative RMS, the flagged ones are few (``≤ 5 %``), and the whole image is within
``FLOAT32_WHOLE`` (a tail sample's float32 radius can also move it: the flags are a diagnostic,
not an exact account).

Skipped only when no headless GL context can be made (the reason names what to install), the
float64 tests also when the driver has no doubles (then the float32 fallback is what runs)."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
import torch

import data_synth
from sssbench import gl
from sssbench.gbuffer import GBuffer, pixel_size_mm
from sssbench.gl.disk_shader64 import double_math_source
from sssbench.ops import DiskSSS, backend
from sssbench.ops.disk import GOLDEN_RATIO, HDRP_MIN_PIXEL_MM, pattern_points
from sssbench.profiles import BurleyNormalized
from sssbench.run import registry

OK, WHY = gl.available()
pytestmark = pytest.mark.skipif(not OK, reason=f"no headless GL: {WHY}")
FP64 = OK and gl.context().fp64
needs_fp64 = pytest.mark.skipif(not FP64, reason=f"the GL driver has no doubles: {WHY}")

TOL = 1e-5
#: a sample offset (px) within this fraction of itself (at least 1 px) of a rounding boundary
#: is one float32 cannot place on the same side as float64 (~100 float32 ulp)
BOUNDARY = 1e-5
RES = (48, 48)
#: the float32 geometry's whole-image bound (docs/gl.md; measured worst 5.1e-5)
FLOAT32_WHOLE = 1e-4

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


def gl_result(m, g) -> torch.Tensor:
    with backend("gl"), torch.no_grad():
        return m(g)


def rel_rms(out: torch.Tensor, ref: torch.Tensor) -> float:
    a, b = out.double(), ref.double()
    return float(((a - b) ** 2).mean().sqrt() / (b**2).mean().sqrt())


def check_whole(out: torch.Tensor, ref: torch.Tensor) -> float:
    """Float64 geometry: the whole image, no pixel set aside (module doc)."""
    assert out.dtype == ref.dtype and out.shape == ref.shape
    rel = rel_rms(out, ref)
    assert rel <= TOL, f"whole-image rel RMS {rel:.3g}"
    worst = float((out.double() - ref.double()).abs().max() / ref.double().abs().max())
    assert worst <= TOL, f"a pixel off by {worst:.3g} of the image's maximum (a moved sample)"
    return rel


def check_float32(out: torch.Tensor, ref: torch.Tensor, flag: torch.Tensor) -> float:
    """Float32 geometry's documented tolerance (module doc)."""
    keep = ~flag[:, None].expand_as(ref)
    a, b = out.double(), ref.double()
    rel = float(((a - b)[keep] ** 2).mean().sqrt() / (b[keep] ** 2).mean().sqrt())
    assert rel <= TOL, f"rel RMS {rel:.3g} off the boundary pixels"
    # the set aside is small: the band is 1e-5 of an offset wide around each boundary
    assert float(flag.double().mean()) <= 0.05, f"{int(flag.sum())} boundary pixels"
    whole = rel_rms(out, ref)
    print(f"float32 geometry: off the boundary {rel:.3g}, whole image {whole:.3g}, "
          f"flagged {float(flag.double().mean()):.3%}")  # fmt: skip
    assert whole <= FLOAT32_WHOLE, f"whole-image rel RMS {whole:.3g}"
    return rel


@pytest.fixture
def float32_geometry():
    old = gl.set_disk_geometry("float32")
    try:
        yield
    finally:
        gl.set_disk_geometry(old)


# ---------------------------------------------------------------- float64 geometry (default)
@needs_fp64
@pytest.mark.parametrize("scene_key", list(SCENES))
@pytest.mark.parametrize("profile_key", list(PROFILES))
@pytest.mark.parametrize("estimator,samples", [("sssbench", 8), ("sssbench", 32),
                                               ("hdrp", 8), ("hdrp", 32)])  # fmt: skip
def test_backend_gl_disk_equals_torch(scene_key, profile_key, estimator, samples):
    g = scene(scene_key)
    m = DiskSSS(profile(profile_key), samples=samples, estimator=estimator)
    assert gl.disk_geometry() == "float64"
    check_whole(gl_result(m, g), torch_result(m, g))


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


@needs_fp64
@pytest.mark.parametrize("profile_key", list(PROFILES))
@pytest.mark.parametrize("option", list(OPTIONS))
def test_every_option_equals_torch(option, profile_key):
    g = scene("discontinuity")
    m = DiskSSS(profile(profile_key), samples=16, **OPTIONS[option])
    check_whole(gl_result(m, g), torch_result(m, g))


@needs_fp64
def test_partial_strength_and_batch_equal_torch():
    """mask in (0, 1) lerps; a batch's images carry the noise of their own pixels."""
    g0 = scene("curved")
    mask = g0.mask_or_ones() * torch.linspace(0.2, 1.0, RES[1])
    g = type(g0)(
        torch.cat([g0.diffuse, g0.diffuse.flip(-1)]), torch.cat([g0.depth, g0.depth.flip(-1)]),
        g0.fov_y, mask=torch.cat([mask, mask.flip(-1)]),
    )  # fmt: skip
    m = DiskSSS(profile("burley"), samples=16)
    check_whole(gl_result(m, g), torch_result(m, g))


@needs_fp64
@pytest.mark.parametrize("estimator", ["sssbench", "hdrp"])
def test_run_method_times_the_disk_draw(estimator):
    g = scene("discontinuity")
    m = DiskSSS(profile("skin_jg10"), samples=16, estimator=estimator, frames=2)
    run = gl.run_method(m, g, repeats=2, warmup=1)
    check_whole(run.image, torch_result(m, g))
    assert list(run.pass_times_ms) == ["disk"] and run.pass_times_ms["disk"] > 0
    (rec,) = run.passes
    assert rec.samples == 16 and rec.pixels == int((g.mask_or_ones() > 0).sum())
    assert len(run.repeats) == 2
    assert run.renderer["disk_geometry"] == "float64"  # recorded by the run


def _run_double_math(x: torch.Tensor, fn: int) -> tuple[np.ndarray, np.ndarray]:
    """The shader's ``(expD, logD)`` (``fn=0``) or ``sinCosD`` (``fn=1``) of the doubles
    ``x``, read back bit for bit from an RGBA32UI target."""
    glc = gl.context()
    prog = glc.program(
        "#version 400\n"
        + double_math_source()
        + """
uniform usampler2D xTex;
uniform int fn;
out uvec4 fragColor;
void main() {
    double x = packDouble2x32(texelFetch(xTex, ivec2(gl_FragCoord.xy), 0).xy);
    double a, b;
    if (fn == 0) { a = expD(x); b = x > 0.0LF ? logD(x) : 0.0LF; }
    else sinCosD(x, a, b);
    fragColor = uvec4(unpackDouble2x32(a), unpackDouble2x32(b));
}"""
    )
    n = x.numel()
    tex = glc.texture_f64(x.reshape(1, 1, n))
    out = glc.ctx.texture((n, 1), 4, dtype="u4")
    fb = glc.ctx.framebuffer([out])
    try:
        fb.use()
        tex.use(0)
        prog["xTex"].value = 0
        prog["fn"].value = fn
        glc.draw(prog)
        r = np.frombuffer(out.read(), dtype=np.uint32).copy().view(np.float64).reshape(n, 2)
    finally:
        for obj in (tex, out, fb):
            obj.release()
    return r[:, 0], r[:, 1]


def _ulps(got: np.ndarray, want: np.ndarray) -> float:
    return float(np.max(np.abs(got - want) / np.spacing(np.abs(want))))


@needs_fp64
def test_double_math_matches_pythons_libm():
    """GLSL has no double exp / log / sin / cos; the shader's own are within 4 ulp of Python's
    ``math`` (measured 1, 3, 2, 2) over the ranges the disk uses: exponents of weights, logs
    of radii, angles up to 2e5 rad (65536 golden-angle samples plus a rotation)."""
    gen = torch.Generator().manual_seed(0)

    def rand(n, lo, hi):
        return lo + (hi - lo) * torch.rand(n, generator=gen, dtype=torch.float64)

    x = torch.cat([rand(2000, -700.0, 700.0), torch.randn(2000, generator=gen).double()])
    e, _ = _run_double_math(x, 0)
    want = np.array([math.exp(v) for v in x.tolist()])
    assert _ulps(e, want) <= 4
    x = torch.cat([10 ** rand(2000, -300.0, 300.0), 1 + 1e-3 * torch.randn(2000).double()])
    _, lg = _run_double_math(x, 0)
    assert _ulps(lg, np.array([math.log(v) for v in x.tolist()])) <= 4
    x = torch.cat([rand(3000, 0.0, 2e5), rand(1000, -10.0, 10.0)])
    sn, cs = _run_double_math(x, 1)
    assert _ulps(sn, np.array([math.sin(v) for v in x.tolist()])) <= 4
    assert _ulps(cs, np.array([math.cos(v) for v in x.tolist()])) <= 4


# ---------------------------------------------------------------- float32 geometry (fallback)
@pytest.mark.parametrize("scene_key", list(SCENES))
@pytest.mark.parametrize("profile_key", list(PROFILES))
@pytest.mark.parametrize("estimator", ["sssbench", "hdrp"])
def test_float32_geometry_within_its_documented_tolerance(
    float32_geometry, scene_key, profile_key, estimator
):
    g = scene(scene_key)
    m = DiskSSS(profile(profile_key), samples=32, estimator=estimator)
    assert gl.disk_geometry() == "float32"
    assert gl.run_method(m, g, repeats=0, warmup=0).renderer["disk_geometry"] == "float32"
    check_float32(gl_result(m, g), torch_result(m, g), boundary_pixels(m, g))


@pytest.mark.parametrize("option", ["bilinear", "surface_area", "r2", "hdrp_frames_ign"])
def test_float32_geometry_options(float32_geometry, option):
    g = scene("discontinuity")
    m = DiskSSS(profile("skin_jg10"), samples=16, **OPTIONS[option])
    check_float32(gl_result(m, g), torch_result(m, g), boundary_pixels(m, g))


def test_float64_on_a_driver_without_doubles_is_refused_naming_the_fallback(monkeypatch):
    """Never a silent different answer: without doubles the disk fails naming how to choose
    the float32 geometry; a bad choice is refused naming the argument."""
    monkeypatch.setattr(type(gl.context()), "fp64", property(lambda self: False))
    m = DiskSSS(profile("burley"), samples=4)
    with pytest.raises(gl.GLMethodError, match="set_disk_geometry"):
        gl_result(m, scene("flat"))
    with pytest.raises(gl.GLMethodError, match="set_disk_geometry"):
        gl.run_method(m, scene("flat"), repeats=0, warmup=0)
    with pytest.raises(ValueError, match="precision"):
        gl.set_disk_geometry("half")


# ---------------------------------------------------------------- refusals
def test_adaptive_is_refused_naming_it():
    g = scene("flat")
    m = DiskSSS(profile("burley"), adaptive=(4, 32))
    with pytest.raises(gl.GLMethodError, match="adaptive"):
        gl.run_method(m, g, repeats=0, warmup=0)
    with backend("gl"), pytest.raises(gl.GLMethodError, match="adaptive"):
        m(g)


def _seamed(key: str):
    """``scene(key)`` with three materials: columns from 20 on profile 1, rows from 30 on
    profile 2 (seams through the face's depth steps)."""
    g0 = scene(key)
    ids = torch.zeros_like(g0.depth, dtype=torch.long)
    ids[..., :, 20:] = 1
    ids[..., 30:, :] = 2
    return GBuffer(g0.diffuse, g0.depth, g0.fov_y, mask=g0.mask, profile_id=ids)


LIST = [
    lambda: profile("burley"),
    lambda: profile("skin_jg10"),
    lambda: BurleyNormalized([2.0, 1.0, 0.5], [0.7, 0.5, 0.3]),
]


@needs_fp64
@pytest.mark.parametrize("estimator", ["sssbench", "hdrp"])
def test_a_list_of_profiles_equals_torch(estimator):
    """Per-pixel profiles (one draw per profile and frame): both ``cross_profile`` rules equal
    torch on whole images, through ``backend("gl")`` and ``run_method``; the two rules differ
    (the seams matter in this scene, so the comparison is not vacuous)."""
    g = _seamed("discontinuity")
    images = {}
    for cross in ("reject", "accept"):
        m = DiskSSS([p() for p in LIST], samples=16, estimator=estimator, cross_profile=cross,
                    frames=2)  # fmt: skip
        ref = torch_result(m, g)
        check_whole(gl_result(m, g), ref)
        run = gl.run_method(m, g, repeats=1, warmup=0)
        check_whole(run.image, ref)
        assert list(run.pass_times_ms) == ["disk"]
        images[cross] = ref
    assert rel_rms(images["accept"], images["reject"]) > 100 * TOL


def test_a_list_of_profiles_needs_a_valid_profile_id():
    m = DiskSSS([p() for p in LIST[:2]], samples=4)
    g = scene("flat")
    with backend("gl"), pytest.raises(ValueError, match="profile_id"):
        m(g)
    bad = GBuffer(g.diffuse, g.depth, g.fov_y, mask=g.mask,
                  profile_id=torch.full_like(g.depth, 2, dtype=torch.long))  # fmt: skip
    with backend("gl"), pytest.raises(ValueError, match="profile_id must index the 2"):
        m(bad)
    with pytest.raises(ValueError, match="profile_id must index the 2"):
        gl.run_method(m, bad, repeats=0, warmup=0)


@needs_fp64
def test_burley_from_albedo_and_mfp_runs():
    """BurleyNormalized built from albedo and mfp is still BurleyNormalized: it runs."""
    m = DiskSSS(BurleyNormalized.from_albedo_mfp([0.44, 0.23, 0.13], [3.7, 1.4, 0.7]))
    check_whole(gl_result(m, scene("flat")), torch_result(m, scene("flat")))


def test_a_profile_without_a_shader_formula_is_refused():
    from sssbench.profiles.dipole import Dipole

    m = DiskSSS(Dipole.from_material("skin1"), samples=4)
    with backend("gl"), pytest.raises(gl.GLMethodError, match="profile=Dipole"):
        m(scene("flat"))
